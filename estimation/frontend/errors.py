"""Errors raised by the visual front end (each also a builtin ``ValueError``)."""
from __future__ import annotations

from estimation.errors import EstimationError


class FrontEndError(EstimationError, ValueError):
    """Bad input to the front end: wrong image shape or type, mismatched pair, unusable setting."""
