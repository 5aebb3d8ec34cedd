"""``--set FIELD=VALUE`` options of the benchmarks: FastSLAMConfig overrides, one parser for every script.

A value is read by the field's type, so that the command lines of the docs keep working both ways they were written:
a string bare or JSON-quoted (``merge_look=newer``, ``weight_evidence='"shared_creation"'``), a bool as
``true``/``false`` (or 1/0, yes/no), a number as Python reads it (``inf`` included), a tuple as a JSON list. An unknown
field or a value of the wrong kind stops the script with one line naming the item.
"""
from __future__ import annotations

import json
from dataclasses import fields

from estimation.fastslam import FastSLAMConfig

_TRUE, _FALSE = ("true", "1", "yes"), ("false", "0", "no")


def config_overrides(items: list[str]) -> dict:
    """The ``--set`` items as a dict of FastSLAMConfig field values (SystemExit with one line on a bad item)."""
    defaults = FastSLAMConfig()
    names = {f.name for f in fields(FastSLAMConfig)}
    overrides = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep:
            raise SystemExit(f"--set {item!r}: give FIELD=VALUE")
        if key not in names:
            raise SystemExit(f"--set {item!r}: FastSLAMConfig has no field {key!r}")
        try:
            overrides[key] = _value(getattr(defaults, key), text.strip())
        except ValueError as exc:
            raise SystemExit(f"--set {item!r}: {exc}") from None
    return overrides


def _value(default, text: str):
    if isinstance(default, bool):   # before int: a bool is an int
        if text.lower() in _TRUE + _FALSE:
            return text.lower() in _TRUE
        raise ValueError("give true or false")
    if isinstance(default, int):
        return int(text)
    if isinstance(default, float):
        return float(text)
    if isinstance(default, str):
        return json.loads(text) if len(text) >= 2 and text[0] == text[-1] == '"' else text
    if isinstance(default, tuple):
        try:
            values = json.loads(text)
        except json.JSONDecodeError:
            raise ValueError("give a JSON list, e.g. [0.1, 0.0, 0.3]") from None
        if not isinstance(values, list):
            raise ValueError("give a JSON list, e.g. [0.1, 0.0, 0.3]")
        return tuple(float(v) for v in values)
    raise ValueError(f"a field of type {type(default).__name__} cannot be set from the command line")
