"""Errors raised by scan matching and its log reader (each also a builtin, so callers may catch either)."""
from __future__ import annotations

from estimation.errors import EstimationError


class ScanMatchError(EstimationError, ValueError):
    """A scan or a matching request is unusable (too few points, bad shapes, unknown method)."""


class LogFormatError(ScanMatchError):
    """A CARMEN log line is malformed; the message names the file and the line number."""
