"""Putative landmark correspondences from descriptor similarity (step 1 of the paper's RANSAC).

Two strategies:

* ``nearest_correspondences`` — the paper: every landmark of map 1 is paired with the landmark of map 2
  whose descriptor is nearest (Euclidean), if that distance is below ``th0``.  Several map-1 landmarks may
  share one map-2 landmark.
* ``distinctive_correspondences`` — the robust preset: Lowe's ratio test (nearest / second nearest below
  ``ratio``) and mutual best matches, so that every landmark takes part in at most one correspondence and
  ambiguous (repeated-texture) landmarks are dropped before RANSAC ever sees them.  The ratio test runs from
  map 1's side only, so the pairs of (A, B) are not those of (B, A) swapped.
* ``symmetric_correspondences`` — the same with the ratio test on both sides, required of both landmarks or of
  either (``AlignmentConfig.ratio_sides``; session 45, an option the presets do not use): the pairs of (B, A) are
  exactly those of (A, B) swapped.

Descriptor search is exact, by blocked matrix products (float32 BLAS).  A k-d tree does not help on 64-D
descriptors: measured here, ``cKDTree.query`` of 2,000 descriptors against 50,000 took 9.5 s (any ``eps``
up to 1) where the matrix product of 5,000 against 50,000 took 1.6 s — in 64 dimensions every cell is
near every query.  For very large maps the search is bounded instead by matching a random subset of map 1
(:func:`query_subset`); the k-d trees work on positions (guided matching, chance rate, Method 2).
"""
from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

# Descriptor distances computed at most per alignment (see query_subset), and per block of rows (memory).
SEARCH_BUDGET_PAIRS = 100_000_000
_BLOCK_PAIRS = 16_000_000

# the distance buffers one thread's searches share inside search_workspace() (None outside it), for searches of
# _WORKSPACE_MIN to _WORKSPACE_MAX distances per block: smaller buffers come from the allocator's heap without page
# faults, and holding them would only push the alignment's later temporaries out of it; larger ones (the 50,000-landmark
# pair's 64 MB blocks) held through the alignment would raise its peak memory (304 -> 375 MB), for little
_WORKSPACE = threading.local()
_WORKSPACE_MIN, _WORKSPACE_MAX = 262_144, 4_194_304
_CLIP_BY_MASK = 1 << 20
# AlignmentConfig.ratio_sides: whose ratio test a mutual best match must pass (map 1's landmark: the robust preset's
# one-sided test, distinctive_correspondences; both landmarks', or either's: symmetric_correspondences)
RATIO_SIDES = ("map1", "both", "either")


@contextmanager
def search_workspace() -> Iterator[None]:
    """Inside it, this thread's descriptor searches reuse one pair of distance buffers, freed on leaving.

    An alignment searches three times (the pair, then each map against itself); buffers of a map of 1,000 landmarks
    hold 4 MB each, above the allocator's mmap threshold, so each fresh pair costs ~2,000 page faults (1.5-2.5 ms).
    Only searches of 262,144 to 4,194,304 distances per block use it (see _WORKSPACE_MIN).  Nested use keeps the outer
    workspace.  The values computed are the same either way: every element a search reads it has written."""
    if getattr(_WORKSPACE, "buffers", None) is not None:
        yield
        return
    _WORKSPACE.buffers = []
    try:
        yield
    finally:
        _WORKSPACE.buffers = None


def _distance_buffers(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Two float32 arrays of ``shape`` (C order): the workspace's, grown when too small, or fresh outside one."""
    store = getattr(_WORKSPACE, "buffers", None)
    n = shape[0] * shape[1]
    if store is None or not _WORKSPACE_MIN <= n <= _WORKSPACE_MAX:
        return np.empty(shape, np.float32), np.empty(shape, np.float32)
    if not store or store[0].size < n:
        store[:] = [np.empty(n, np.float32), np.empty(n, np.float32)]
    return store[0][:n].reshape(shape), store[1][:n].reshape(shape)


def _two_nearest_exact(queries: np.ndarray, base: np.ndarray, exclude: np.ndarray | None = None,
                       back_matches: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Indices and distances of the two nearest ``base`` rows for every query, and every base row's
    nearest query (one pass over the distance matrix, in blocks of rows).

    queries (Q, D), base (B, D) -> index (Q, 2), distance (Q, 2) (second column -1 / inf when B < 2),
    back (B,) index of the nearest query of each base row. ``exclude`` (Q,): a base row each query may not
    match (a map searched against itself: the query's own row).  ``back_matches=False``: ``back`` is left zero
    (only the mutual-match test needs it; it costs two more passes over every block).
    """
    q = queries.astype(np.float32, copy=False)
    b = base.astype(np.float32, copy=False)
    b_sq = np.einsum("ij,ij->i", b, b)
    index = np.full((len(q), 2), -1, np.int64)
    dist = np.full((len(q), 2), np.inf)
    back = np.zeros(len(b), np.int64)
    back_d2 = np.full(len(b), np.inf, np.float32)
    block_rows = int(np.clip(_BLOCK_PAIRS // max(len(b), 1), 64, 4096))
    rows = np.arange(block_rows)
    # two (block, B) arrays for all blocks (and, inside search_workspace(), for the alignment's other searches):
    # fresh arrays of this size cost their pages every time
    d2_buffer, ab_buffer = _distance_buffers((min(block_rows, len(q)), len(b)))
    for start in range(0, len(q), block_rows):
        block = q[start:start + block_rows]
        r = rows[: len(block)]
        d2, ab = d2_buffer[: len(block)], ab_buffer[: len(block)]
        # |a - b|² = (|a|² + |b|²) - 2 a·b, clipped at zero against round-off (the same operations as the
        # expression written out, in place; on blocks of up to 2^20 distances the clip sets the few negatives to +0.0
        # as np.maximum(d2, 0.0) does, in a quarter of its time: a comparison and a scan -- larger blocks keep
        # np.maximum, whose bytes of comparison would add 16 MB to the 50,000-landmark search's peak)
        np.add(np.einsum("ij,ij->i", block, block)[:, None], b_sq[None, :], out=d2)
        np.matmul(block, b.T, out=ab)
        ab *= 2.0
        d2 -= ab
        if d2.size > _CLIP_BY_MASK:
            np.maximum(d2, 0.0, out=d2)
        else:
            negative = d2 < 0.0
            if negative.any():
                d2[negative] = 0.0
        if exclude is not None:
            d2[r, exclude[start:start + len(block)]] = np.inf
        # each base row's nearest query: the first row that reaches the column's minimum (argmin along the columns
        # copies the block, and its copy falls into the cache's sets when B is a power of two: 6-8 ms against 1.6 ms
        # for 1,024 x 1,024; the minimum and a byte-wide comparison do not)
        if back_matches:
            col_min = d2.min(axis=0)
            better = col_min < back_d2
            if better.any():
                col_best = np.argmax(d2 == col_min[None, :], axis=0)
                back[better] = start + col_best[better]
                back_d2[better] = col_min[better]
        first = np.argmin(d2, axis=1)
        index[start:start + len(block), 0] = first
        dist[start:start + len(block), 0] = np.sqrt(d2[r, first])
        if len(b) > 1:
            d2[r, first] = np.inf
            second = np.argmin(d2, axis=1)
            index[start:start + len(block), 1] = second
            dist[start:start + len(block), 1] = np.sqrt(d2[r, second])
    return index, dist, back


def two_nearest(queries: np.ndarray, base: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest and second-nearest ``base`` descriptor of every query: index (Q, 2), distance (Q, 2)."""
    return _two_nearest_exact(queries, base, back_matches=False)[:2]


def query_subset(n1: int, n2: int, rng: np.random.Generator) -> np.ndarray | None:
    """Rows of map 1 to search with when n1·n2 exceeds the search budget (None: search with all rows).

    Exact search costs n1·n2 descriptor distances; above ``SEARCH_BUDGET_PAIRS`` a random subset of map 1
    is matched (RANSAC needs a sample of correct correspondences, not all of them); the robust preset then
    gathers the remaining supports by guided matching once the transform is known.
    """
    if n1 * n2 <= SEARCH_BUDGET_PAIRS:
        return None
    size = max(64, SEARCH_BUDGET_PAIRS // max(n2, 1))
    return np.sort(rng.choice(n1, min(n1, size), replace=False))


def nearest_correspondences(desc1: np.ndarray, desc2: np.ndarray, max_distance: float
                            ) -> tuple[np.ndarray, np.ndarray]:
    """The paper's step 1: each map-1 landmark with its nearest map-2 descriptor, if nearer than th0.

    desc1 (N1, D), desc2 (N2, D) -> pairs (K, 2) int64 rows (i in map 1, j in map 2), distances (K,).
    """
    if len(desc1) == 0 or len(desc2) == 0:
        return np.zeros((0, 2), np.int64), np.zeros(0)
    index, dist = two_nearest(desc1, desc2)
    keep = dist[:, 0] < max_distance
    pairs = np.stack([np.flatnonzero(keep), index[keep, 0]], axis=1).astype(np.int64)
    return pairs, dist[keep, 0]


def distinctive_correspondences(desc1: np.ndarray, desc2: np.ndarray, max_distance: float, ratio: float
                                ) -> tuple[np.ndarray, np.ndarray]:
    """Mutual best matches that pass the ratio test and an absolute distance gate.

    desc1 (N1, D), desc2 (N2, D) -> pairs (K, 2) int64 (i, j), distances (K,).  A match i -> j is kept when
    d1 < max_distance, d1 < ratio · d2 (d2: distance to i's second-nearest map-2 descriptor), and i is
    also j's nearest descriptor among the queries.
    """
    if len(desc1) == 0 or len(desc2) == 0:
        return np.zeros((0, 2), np.int64), np.zeros(0)
    fwd, fwd_d, back = _two_nearest_exact(desc1, desc2)
    # d1 < ratio · d2; a lone map-2 landmark (d2 = inf) passes
    keep = (fwd_d[:, 0] < max_distance) & (fwd_d[:, 0] < ratio * fwd_d[:, 1])
    i = np.flatnonzero(keep)
    j = fwd[keep, 0]
    d = fwd_d[keep, 0]
    mutual = back[j] == i
    pairs = np.stack([i[mutual], j[mutual]], axis=1).astype(np.int64)
    return pairs, d[mutual]


def symmetric_correspondences(desc1: np.ndarray, desc2: np.ndarray, max_distance: float, ratio: float,
                              sides: str = "both") -> tuple[np.ndarray, np.ndarray]:
    """:func:`distinctive_correspondences` with the ratio test on both sides of a match.

    A mutual best match i <-> j within ``max_distance`` has two ratio tests: i's (its nearest map-2 descriptor
    ``ratio`` times nearer than its second) and j's (its nearest map-1 descriptor ``ratio`` times nearer than its
    second).  ``sides="both"`` keeps the matches that pass both; ``"either"`` those that pass one or the other.
    desc1 (N1, D), desc2 (N2, D) -> pairs (K, 2) int64 (i, j) sorted by i, distances (K,).

    The result is made of the two one-sided searches, (desc1, desc2) and (desc2, desc1), so ``symmetric_
    correspondences(desc2, desc1)`` gives exactly the same pairs swapped, whatever the float32 round-off of either
    search (the distances agree to that round-off): with "both" a pair one search keeps and the other does not is
    dropped; with "either" a landmark the two searches pair with different partners (a near tie) takes part in
    neither.  Costs a second search (map 2 against map 1)."""
    if sides not in RATIO_SIDES[1:]:
        raise ValueError(f"sides must be one of {RATIO_SIDES[1:]}, not {sides!r}")
    forward, d_forward = distinctive_correspondences(desc1, desc2, max_distance, ratio)
    backward, d_backward = distinctive_correspondences(desc2, desc1, max_distance, ratio)
    backward = backward[:, ::-1]
    if sides == "both":
        # both are one-to-one (mutual best): a pair is kept when map-1 landmark i has the same partner both ways
        partner = np.full(len(desc1), -1, np.int64)
        partner[backward[:, 0]] = backward[:, 1]
        keep = partner[forward[:, 0]] == forward[:, 1]
        return forward[keep], d_forward[keep]
    pairs = np.concatenate([forward, backward])
    dist = np.concatenate([d_forward, d_backward])
    pairs, first = np.unique(pairs, axis=0, return_index=True)    # sorted by i, then j
    dist = dist[first]
    once = (np.bincount(pairs[:, 0], minlength=len(desc1))[pairs[:, 0]] == 1) & (
        np.bincount(pairs[:, 1], minlength=len(desc2))[pairs[:, 1]] == 1)
    return pairs[once].astype(np.int64), dist[once]


def self_correspondences(desc: np.ndarray, max_distance: float, ratio: float, rows: np.ndarray | None = None
                         ) -> np.ndarray:
    """Pairs of *different* landmarks of one map whose descriptors match distinctively: repeated structure
    (look-alike corners, identical doors) or duplicates.

    desc (N, D); ``rows`` (Q,) optional subset of queries (very large maps).  A query i takes its nearest other
    landmark j if d(i, j) < max_distance and d(i, j) < ratio · d(i, next other).  Returns pairs (K, 2) int64.
    """
    n = len(desc)
    if n < 3:
        return np.zeros((0, 2), np.int64)
    queries = np.arange(n) if rows is None else np.asarray(rows, np.int64)
    index, dist, _ = _two_nearest_exact(desc[queries], desc, exclude=queries, back_matches=False)
    keep = (dist[:, 0] < max_distance) & (dist[:, 0] < ratio * dist[:, 1])
    return np.column_stack([queries[keep], index[keep, 0]]).astype(np.int64)
