"""Errors raised by the estimation layer (each also a builtin, so callers may catch either)."""


class EstimationError(Exception):
    """Root of every error the estimation layer raises."""


class MapFileError(EstimationError, ValueError):
    """A landmark-map file is missing, corrupt, of an unknown version or inconsistent."""
