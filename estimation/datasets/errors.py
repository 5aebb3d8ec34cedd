"""Errors raised by the dataset readers (each also a ``ValueError``, so callers may catch either)."""
from __future__ import annotations

from ..errors import EstimationError


class DatasetError(EstimationError, ValueError):
    """A dataset file is missing, unreadable or malformed; the message names the file, the line and the field."""
