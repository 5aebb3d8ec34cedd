"""Putative landmark correspondences from descriptor similarity (step 1 of the paper's RANSAC).

Two strategies:

* ``nearest_correspondences`` — the paper: every landmark of map 1 is paired with the landmark of map 2
  whose descriptor is nearest (Euclidean), if that distance is below ``th0``.  Several map-1 landmarks may
  share one map-2 landmark.
* ``distinctive_correspondences`` — the robust preset: Lowe's ratio test (nearest / second nearest below
  ``ratio``) and mutual best matches, so that every landmark takes part in at most one correspondence and
  ambiguous (repeated-texture) landmarks are dropped before RANSAC ever sees them.

Descriptor search is exact (blocked matrix products) while ``n1·n2`` is moderate.  For large maps a
k-d tree on the raw 64-D descriptors is slower than brute force (the curse of dimensionality), so the
search projects the descriptors onto their leading principal axes, takes ``k`` candidates from a
``scipy.spatial.cKDTree`` in that low-dimensional space and re-ranks them exactly; mutuality is then
approximated by keeping, for each map-2 landmark, only the closest map-1 landmark that chose it.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

# Above this many descriptor pairs the exact search gives way to the approximate one.
EXACT_SEARCH_MAX_PAIRS = 25_000_000
_BLOCK_ROWS = 2048
_PROJECTION_DIM = 6
_CANDIDATES = 8


def _two_nearest_exact(queries: np.ndarray, base: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices and distances of the two nearest ``base`` rows for every query.

    queries (Q, D), base (B, D) -> index (Q, 2), distance (Q, 2); the second column is -1 / inf when B < 2.
    """
    q = queries.astype(np.float32, copy=False)
    b = base.astype(np.float32, copy=False)
    b_sq = np.einsum("ij,ij->i", b, b)
    index = np.full((len(q), 2), -1, np.int64)
    dist = np.full((len(q), 2), np.inf)
    k = min(2, len(b))
    for start in range(0, len(q), _BLOCK_ROWS):
        block = q[start:start + _BLOCK_ROWS]
        # |a - b|² = |a|² + |b|² - 2 a·b, clipped at zero against round-off
        d2 = np.einsum("ij,ij->i", block, block)[:, None] + b_sq[None, :] - 2.0 * (block @ b.T)
        np.maximum(d2, 0.0, out=d2)
        part = np.argpartition(d2, k - 1, axis=1)[:, :k] if len(b) > k else np.tile(np.arange(k), (len(block), 1))
        part_d = np.take_along_axis(d2, part, axis=1)
        order = np.argsort(part_d, axis=1)
        index[start:start + len(block), :k] = np.take_along_axis(part, order, axis=1)
        dist[start:start + len(block), :k] = np.sqrt(np.take_along_axis(part_d, order, axis=1))
    return index, dist


def _two_nearest_approximate(queries: np.ndarray, base: np.ndarray, rng: np.random.Generator
                             ) -> tuple[np.ndarray, np.ndarray]:
    """Like :func:`_two_nearest_exact` but through a k-d tree on a PCA projection, re-ranked exactly."""
    q = queries.astype(np.float32, copy=False)
    b = base.astype(np.float32, copy=False)
    sample = np.vstack([q[rng.choice(len(q), min(len(q), 2000), replace=False)],
                        b[rng.choice(len(b), min(len(b), 2000), replace=False)]])
    mean = sample.mean(axis=0)
    _, _, vt = np.linalg.svd(sample - mean, full_matrices=False)
    axes = vt[:_PROJECTION_DIM].T
    tree = cKDTree((b - mean) @ axes)
    k = min(_CANDIDATES, len(b))
    _, cand = tree.query((q - mean) @ axes, k=k, workers=-1)
    cand = cand.reshape(len(q), k)
    diff_sq = (np.einsum("nkd,nkd->nk", b[cand], b[cand]) - 2.0 * np.einsum("nkd,nd->nk", b[cand], q)
               + np.einsum("nd,nd->n", q, q)[:, None])
    order = np.argsort(diff_sq, axis=1)[:, :2]
    index = np.take_along_axis(cand, order, axis=1)
    dist = np.sqrt(np.maximum(np.take_along_axis(diff_sq, order, axis=1), 0.0))
    return index, dist


def two_nearest(queries: np.ndarray, base: np.ndarray, rng: np.random.Generator | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """Nearest and second-nearest ``base`` descriptor of every query: index (Q, 2), distance (Q, 2)."""
    if len(queries) * len(base) <= EXACT_SEARCH_MAX_PAIRS:
        return _two_nearest_exact(queries, base)
    return _two_nearest_approximate(queries, base, rng if rng is not None else np.random.default_rng(0))


def nearest_correspondences(desc1: np.ndarray, desc2: np.ndarray, max_distance: float,
                            rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The paper's step 1: each map-1 landmark with its nearest map-2 descriptor, if nearer than th0.

    desc1 (N1, D), desc2 (N2, D) -> pairs (K, 2) int64 rows (i in map 1, j in map 2), distances (K,).
    """
    if len(desc1) == 0 or len(desc2) == 0:
        return np.zeros((0, 2), np.int64), np.zeros(0)
    index, dist = two_nearest(desc1, desc2, rng)
    keep = dist[:, 0] < max_distance
    pairs = np.stack([np.flatnonzero(keep), index[keep, 0]], axis=1).astype(np.int64)
    return pairs, dist[keep, 0]


def distinctive_correspondences(desc1: np.ndarray, desc2: np.ndarray, max_distance: float, ratio: float,
                                rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Mutual best matches that pass the ratio test and an absolute distance gate.

    desc1 (N1, D), desc2 (N2, D) -> pairs (K, 2) int64 (i, j), distances (K,).  A match i -> j is kept when
    d1 < max_distance, d1 < ratio · d2 (d2: distance to i's second-nearest map-2 descriptor), and i is
    also j's nearest map-1 descriptor (exact search) or j's closest claimant (approximate search).
    """
    if len(desc1) == 0 or len(desc2) == 0:
        return np.zeros((0, 2), np.int64), np.zeros(0)
    exact = len(desc1) * len(desc2) <= EXACT_SEARCH_MAX_PAIRS
    fwd, fwd_d = two_nearest(desc1, desc2, rng)
    # d1 < ratio · d2; a lone map-2 landmark (d2 = inf) passes
    keep = (fwd_d[:, 0] < max_distance) & (fwd_d[:, 0] < ratio * fwd_d[:, 1])
    i = np.flatnonzero(keep)
    j = fwd[keep, 0]
    d = fwd_d[keep, 0]
    if exact:
        back, _ = two_nearest(desc2, desc1)
        mutual = back[j, 0] == i
    else:
        # keep the closest claimant of each j: sort by distance, first occurrence of each j wins
        order = np.argsort(d, kind="stable")
        _, first = np.unique(j[order], return_index=True)
        mutual = np.zeros(len(j), bool)
        mutual[order[first]] = True
    pairs = np.stack([i[mutual], j[mutual]], axis=1).astype(np.int64)
    return pairs, d[mutual]
