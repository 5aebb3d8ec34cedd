"""The CLI's ``--json`` text: strict JSON, so that jq and other strict parsers read every output.

Python's ``json.dumps`` writes a float that could not be computed (a median of nothing, a score without ground truth)
as ``NaN`` or ``Infinity``, which are not JSON. Here such a figure is ``null``: "not computed", the same for every
consumer. Finite values, key order and nesting are unchanged.
"""
from __future__ import annotations

import json
import math
from collections.abc import Mapping


def finite_or_null(value):
    """``value`` with every non-finite float, at any depth of dicts, lists and tuples, replaced by None."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Mapping):
        return {k: finite_or_null(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_or_null(v) for v in value]
    return value


def json_text(value, **kwargs) -> str:
    """``value`` as strict JSON text (non-finite floats as null); ``kwargs`` go to :func:`json.dumps`."""
    return json.dumps(finite_or_null(value), allow_nan=False, **kwargs)
