"""Landmark storage shared between particles: fixed-size blocks, reference counts, copy-on-write.

Every particle's map is a row of the block table: ``table[m, k]`` is the physical block holding its k-th
group of ``block_size`` landmark slots. Resampling copies table rows (integers), never landmarks; a particle
that writes to a block another particle also references first gets its own copy of that block (copy-on-write).
So two particles never see each other's updates, and an unchanged map region costs nothing to duplicate.

Per slot (``state``, 9 numbers, so that one gather reads both): ``mean`` (3,), ``cov`` (6,) the covariance's
upper triangle (xx, xy, xz, yy, yz, zz, see
``linalg.sym_components``: two thirds of a 3×3's memory, and what the filter's closed forms read), ``lid`` the
global landmark id (-1: empty slot; also the row of its descriptor in the filter's descriptor table), ``count``
(times matched, creation included), ``misses`` (times it was in view and not matched), ``logodds`` (the
landmark's existence estimate, log p/(1 − p), see the filter's landmark management). Per physical block:
``refcount`` and ``bbox`` (xmin, ymin, xmax, ymax of its landmarks' means), which lets association preselect
the blocks near a particle without scanning every landmark.
"""
from __future__ import annotations

import numpy as np

_EMPTY_BOX = np.array([np.inf, np.inf, -np.inf, -np.inf])
_RECORD = np.dtype((np.void, 9 * 8))   # one slot's 9 float64s as one item (put_state): made once, not per call


class LandmarkStore:
    """Block storage of the maps of ``n_particles`` particles (see the module docstring)."""

    def __init__(self, n_particles: int, block_size: int = 64, capacity_blocks: int = 16) -> None:
        self.block_size = int(block_size)
        self.n_particles = int(n_particles)
        self._allocate_arrays(max(int(capacity_blocks), 1))
        self.table = np.full((self.n_particles, 4), -1, np.int64)  # (M, K) physical block or -1
        self.n_blocks = np.zeros(self.n_particles, np.int64)        # (M,) blocks in use by each particle
        self.tail_fill = np.zeros(self.n_particles, np.int64)       # (M,) used slots of each particle's last block

    # -- raw storage ----------------------------------------------------------------------------------------
    def _allocate_arrays(self, capacity: int) -> None:
        b = self.block_size
        self.state = np.zeros((capacity, b, 9))      # per slot: mean (3) then covariance components (6)
        self.lid = np.full((capacity, b), -1, np.int64)
        self.count = np.zeros((capacity, b), np.int64)
        self.misses = np.zeros((capacity, b), np.int64)
        self.logodds = np.zeros((capacity, b))
        self.refcount = np.zeros(capacity, np.int64)
        self.bbox = np.tile(_EMPTY_BOX, (capacity, 1))

    @property
    def capacity(self) -> int:
        return len(self.refcount)

    def _grow(self, needed: int) -> None:
        old = self.capacity
        new = max(2 * old, old + needed)
        arrays = {k: getattr(self, k) for k in ("state", "lid", "count", "misses", "logodds", "refcount", "bbox")}
        self._allocate_arrays(new)
        for name, values in arrays.items():
            getattr(self, name)[:old] = values

    def _allocate(self, k: int) -> np.ndarray:
        """k free physical blocks (refcount set to 1, slots emptied)."""
        free = np.flatnonzero(self.refcount == 0)
        if len(free) < k:
            self._grow(k - len(free))
            free = np.flatnonzero(self.refcount == 0)
        blocks = free[:k]
        self.refcount[blocks] = 1
        self.lid[blocks] = -1
        self.count[blocks] = 0
        self.misses[blocks] = 0
        self.logodds[blocks] = 0.0
        self.bbox[blocks] = _EMPTY_BOX
        return blocks

    def _ensure_table_width(self, width: int) -> None:
        if width > self.table.shape[1]:
            grown = np.full((self.n_particles, max(width, 2 * self.table.shape[1])), -1, np.int64)
            grown[:, : self.table.shape[1]] = self.table
            self.table = grown

    # -- particle-level operations --------------------------------------------------------------------------
    def resample(self, indices: np.ndarray) -> None:
        """Particle m becomes a copy of particle ``indices[m]`` (M,): table rows copied, blocks shared."""
        self.table = self.table[indices]
        self.n_blocks = self.n_blocks[indices]
        self.tail_fill = self.tail_fill[indices]
        used = self.table[self.table >= 0]
        self.refcount = np.bincount(used, minlength=self.capacity).astype(np.int64)

    def make_writable(self, particles: np.ndarray, positions: np.ndarray) -> None:
        """Copy-on-write: give every (particle, table position) pair (P,) a block only that particle holds."""
        if len(particles) == 0:
            return
        width = self.table.shape[1]
        wanted = np.zeros(self.n_particles * width, bool)          # dense (particle, position) keys: no sort
        wanted[np.asarray(particles, np.int64) * width + np.asarray(positions, np.int64)] = True
        p, k = np.divmod(np.flatnonzero(wanted), width)
        phys = self.table[p, k]
        shared = self.refcount[phys] > 1
        if not np.any(shared):
            return
        p, k, src = p[shared], k[shared], phys[shared]
        dst = self._allocate(len(src))
        for name in ("state", "lid", "count", "misses", "logodds", "bbox"):
            arr = getattr(self, name)
            arr[dst] = np.take(arr, src, axis=0)
        np.subtract.at(self.refcount, src, 1)
        self.table[p, k] = dst

    def append_slots(self, particles: np.ndarray) -> np.ndarray:
        """Reserve one new slot per entry of ``particles`` (L,), grouped by particle, in order.

        Returns the flat slot indices (L,) (``block * block_size + slot``), already writable (copy-on-write
        of a shared tail block, new blocks allocated as needed); fills the tail block first.
        """
        particles = np.asarray(particles, np.int64)
        if len(particles) == 0:
            return np.zeros(0, np.int64)
        b = self.block_size
        order = np.argsort(particles, kind="stable")
        sorted_p = particles[order]
        first = np.searchsorted(sorted_p, sorted_p, side="left")
        rank = np.arange(len(sorted_p)) - first                       # rank of each new slot within its particle
        nb = self.n_blocks[sorted_p]
        fill = np.where(nb > 0, self.tail_fill[sorted_p], b)          # no blocks yet: behave as if the tail is full
        offset = fill + rank
        position = nb - 1 + offset // b                               # table position of each new slot
        slot = offset % b
        new_count = np.bincount(particles, minlength=self.n_particles)
        last_offset = np.where(self.n_blocks > 0, self.tail_fill, b) + new_count - 1
        needed_width = np.where(new_count > 0, self.n_blocks - 1 + last_offset // b + 1, self.n_blocks)
        self._ensure_table_width(int(needed_width.max()))
        # the tail blocks that receive slots must be private; then allocate the wholly new blocks
        to_tail = position == nb - 1
        self.make_writable(sorted_p[to_tail], position[to_tail])
        grow = needed_width > self.n_blocks
        n_new = (needed_width - self.n_blocks)[grow]
        owners = np.repeat(np.flatnonzero(grow), n_new)
        starts = np.repeat(self.n_blocks[grow], n_new)
        within = np.arange(len(owners)) - np.repeat(np.cumsum(n_new) - n_new, n_new)
        self.table[owners, starts + within] = self._allocate(len(owners))
        self.n_blocks = needed_width
        has_new = new_count > 0
        self.tail_fill[has_new] = (last_offset[has_new] % b) + 1
        flat_sorted = self.table[sorted_p, position] * b + slot
        out = np.empty_like(flat_sorted)
        out[order] = flat_sorted
        return out

    # -- queries --------------------------------------------------------------------------------------------
    def particle_slots(self, m: int) -> np.ndarray:
        """Flat indices of particle m's occupied slots."""
        blocks = self.table[m, : self.n_blocks[m]]
        flat = (blocks[:, None] * self.block_size + np.arange(self.block_size)).ravel()
        return flat[self.lid.reshape(-1)[flat] >= 0]

    def blocks_near(self, centres: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
        """(particle, table position) pairs whose block's bounding box comes within ``radius`` of the
        particle's ``centres`` (M, 2) point. Cost: one box test per held block, no landmark is touched."""
        k = int(self.n_blocks.max(initial=0))
        if k == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        phys = self.table[:, :k]
        held = phys >= 0
        box = np.take(self.bbox, np.where(held, phys, 0), axis=0)        # (M, K, 4)
        dx = np.maximum(np.maximum(box[..., 0] - centres[:, None, 0], centres[:, None, 0] - box[..., 2]), 0.0)
        dy = np.maximum(np.maximum(box[..., 1] - centres[:, None, 1], centres[:, None, 1] - box[..., 3]), 0.0)
        near = held & (dx * dx + dy * dy <= radius * radius)
        return np.nonzero(near)

    def include_in_bbox(self, slots: np.ndarray, xy: np.ndarray | None = None) -> None:
        """Grow the bounding boxes of the blocks of flat ``slots`` (L,) to contain those landmarks' means.

        Cheaper than :meth:`refresh_bbox` after small EKF moves; boxes never shrink here, which only makes
        the preselection slightly conservative (a dropped landmark's room stays inside its block's box).
        """
        if len(slots) == 0:
            return
        blocks = slots // self.block_size
        if xy is None:     # (L, 2) the landmarks' new positions, when the caller has them at hand
            xy = np.take(self.flat_state, slots, axis=0)[:, :2]
        box = np.take(self.bbox, blocks, axis=0)
        outside = np.flatnonzero((xy[:, 0] < box[:, 0]) | (xy[:, 1] < box[:, 1]) | (xy[:, 0] > box[:, 2])
                                 | (xy[:, 1] > box[:, 3]))
        if len(outside) == 0:   # the usual case after small EKF moves: no scattered min/max needed
            return
        blocks, xy = blocks[outside], xy[outside]
        np.minimum.at(self.bbox[:, 0], blocks, xy[:, 0])
        np.minimum.at(self.bbox[:, 1], blocks, xy[:, 1])
        np.maximum.at(self.bbox[:, 2], blocks, xy[:, 0])
        np.maximum.at(self.bbox[:, 3], blocks, xy[:, 1])

    def refresh_bbox(self, blocks: np.ndarray) -> None:
        """Recompute the bounding boxes of physical ``blocks`` after their landmarks moved or died."""
        blocks = np.unique(blocks)
        if len(blocks) == 0:
            return
        xy = self.mean[blocks, :, :2]
        alive = (self.lid[blocks] >= 0)[..., None]
        lo = np.where(alive, xy, np.inf).min(axis=1)
        hi = np.where(alive, xy, -np.inf).max(axis=1)
        self.bbox[blocks] = np.concatenate([lo, hi], axis=1)

    def put_state(self, slots: np.ndarray, rows: np.ndarray) -> None:
        """flat_state[slots] = rows (L, 9), one 72-byte record per slot (a 1-D scatter of records is several
        times faster than fancy assignment of rows)."""
        np.put(self.state.reshape(-1, 9).view(_RECORD).ravel(), slots,
               np.ascontiguousarray(rows, self.state.dtype).view(_RECORD).ravel())

    # flat views (slot index = block * block_size + slot)
    @property
    def mean(self) -> np.ndarray:
        """(blocks, block_size, 3) landmark means, a view of ``state``."""
        return self.state[..., :3]

    @property
    def cov(self) -> np.ndarray:
        """(blocks, block_size, 6) covariance components, a view of ``state``."""
        return self.state[..., 3:]

    @property
    def flat_state(self) -> np.ndarray:
        """(slots, 9) mean and covariance components of every slot: one gather reads both."""
        return self.state.reshape(-1, 9)

    @property
    def flat_mean(self) -> np.ndarray:
        return self.state.reshape(-1, 9)[:, :3]

    @property
    def flat_cov(self) -> np.ndarray:
        """(slots, 6) covariance components (upper triangle), a view."""
        return self.state.reshape(-1, 9)[:, 3:]

    @property
    def flat_lid(self) -> np.ndarray:
        return self.lid.reshape(-1)

    @property
    def flat_count(self) -> np.ndarray:
        return self.count.reshape(-1)

    @property
    def flat_misses(self) -> np.ndarray:
        return self.misses.reshape(-1)

    @property
    def flat_logodds(self) -> np.ndarray:
        return self.logodds.reshape(-1)
