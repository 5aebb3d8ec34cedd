"""Helper for the fuzz tests: every reader gives a clean error or a valid object, with memory bounded."""
from __future__ import annotations

import tracemalloc
from collections.abc import Callable
from typing import Any

# Peak Python + numpy allocation allowed while reading one fuzzed file. The inputs are at most a few hundred
# kilobytes, so a reader that trusts a size field (10¹² rows, a 1000:1 zip bomb) overshoots this by orders of
# magnitude, while any honest reading of such a file stays well below it.
MEMORY_BOUND = 64 << 20


def read_bounded(read: Callable[[], Any], clean: type[BaseException] | tuple[type[BaseException], ...]) -> Any:
    """``read()`` -> its result, or None if it raised one of ``clean``; any other exception propagates (the
    test fails) and so does a peak allocation past MEMORY_BOUND."""
    tracemalloc.start()
    try:
        try:
            return read()
        except clean:
            return None
        finally:
            peak = tracemalloc.get_traced_memory()[1]
            assert peak < MEMORY_BOUND, f"reading took {peak / 1e6:.1f} MB"
    finally:
        tracemalloc.stop()

