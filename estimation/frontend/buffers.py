"""Reusable image-sized scratch arrays, so that a stream of frames does not allocate ~20 MB per frame.

With glibc's default allocator settings, every freed image-sized array goes back to the kernel and the next
frame page-faults it in again (measured: ~2,700 faults and ~5 ms per 640×480 image). A ``FrontEnd`` keeps one
``ScratchBuffers`` and hands it to the pure functions; passing ``None`` gives fresh arrays (same results).
Not thread-safe: one per front end, used by one thread at a time.
"""
from __future__ import annotations

import math

import numpy as np


class ScratchBuffers:
    """Named arrays reused across calls: each name owns a flat block that only grows (so a varying number of
    keypoints per frame does not reallocate), handed out as a contiguous view of the requested shape."""

    def __init__(self) -> None:
        self._blocks: dict[str, np.ndarray] = {}

    def get(self, name: str, shape: tuple[int, ...], dtype) -> np.ndarray:
        """An uninitialised contiguous array (shape, dtype) backed by this name's block."""
        dtype = np.dtype(dtype)
        size = math.prod(shape)
        block = self._blocks.get(name)
        if block is None or block.dtype != dtype or block.size < size:
            block = np.empty(max(size, 1), dtype)
            self._blocks[name] = block
        return block[:size].reshape(shape)


def scratch(buffers: ScratchBuffers | None, name: str, shape: tuple[int, ...], dtype) -> np.ndarray:
    """``buffers.get(...)``, or a fresh array without buffers."""
    return np.empty(shape, dtype) if buffers is None else buffers.get(name, shape, dtype)
