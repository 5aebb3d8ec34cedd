"""Per-configuration values computed once: a cache keyed by the (frozen, hashable) configuration itself."""
from __future__ import annotations

import functools
from collections.abc import Callable
from typing import TypeVar

Key = TypeVar("Key")
Value = TypeVar("Value")


def once_per_value(function: Callable[[Key], Value]) -> Callable[[Key], Value]:
    """``function`` of one argument, cached by that argument's value (the last 16 of them).

    A configuration holding a list is unhashable; it is then computed afresh each time rather than refused.
    Cached results are shared: treat them as read-only.
    """
    cached = functools.lru_cache(maxsize=16)(function)

    @functools.wraps(function)
    def wrapper(argument: Key) -> Value:
        try:
            return cached(argument)
        except TypeError:  # unhashable argument
            return function(argument)

    return wrapper
