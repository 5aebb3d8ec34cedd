"""Errors raised by the fusion layer (each also a builtin, so callers may catch either)."""
from __future__ import annotations


class FusionError(Exception):
    """Root of every error the fusion layer raises."""


class IncompatibleMapsError(FusionError, ValueError):
    """The maps cannot be compared (different descriptor sizes, empty map, bad argument)."""


class NoOverlapError(FusionError, LookupError):
    """No alignment exists between the maps: they do not (detectably) overlap."""
