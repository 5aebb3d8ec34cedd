"""The k nearest reference points of query points that move a little between calls, with few k-d tree queries.

An iterative matcher asks for the nearest reference points of the same N current-scan points at every iteration,
while they move by millimetres.  :class:`WarmNearest` remembers, per point, the position of its last tree query
(the anchor), the k nearest found there and the distances d_k of the k-th and d_{k+1} of the (k+1)-th: every
other reference point was at least d_{k+1} away.  After the point has moved by δ from its anchor, the k are at
most d_k + δ away and every other point at least d_{k+1} − δ, so while δ < (d_{k+1} − d_k) / 2 — the point's
*margin* — they are still exactly the k nearest, as a set.  Only the points past their margin are queried again,
so the answer is a fresh tree query's as a set (up to near-ties within rounding error).  The k are kept in the
order of their last tree query (closest first there); the order only matters to break exact ties, and for those
the first query can ask for as many neighbours as a caller's earlier, cold queries did (``first_query``).

Checking every point's margin is two array operations; a tree query costs a fixed ~15 µs plus ~0.5 µs a point.
Points near a tie (the k-th and (k+1)-th nearly equidistant) have a small margin and are queried again often, but
they are few once the pose has settled.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

_NO_ROWS = np.empty(0, dtype=np.intp)


class WarmNearest:
    """The k nearest of M reference points for N query points that keep their identity between calls.

    tree: a k-d tree over the M reference points.  After :meth:`update`, ``nearest`` (N, k) int holds each
    query's k nearest reference points, closest first as of their last tree query (k = min(k, M)).
    """

    def __init__(self, tree: cKDTree, k: int, first_query: int | None = None) -> None:
        self.tree = tree
        self.k = min(k, tree.n)
        self._query_k = min(k + 1, tree.n)   # one more than asked: its distance bounds every other point's
        # The first query may ask for a different count: a k-d tree orders exactly equidistant points differently for
        # different query sizes, and the first query (at the initial pose) is where such ties occur — identical
        # readings of two scans matched from the identity.  Asking what the earlier implementations asked (6 for
        # eICP's curve, 2 for a one-off projection, 1 for ICP and PL-ICP) keeps the results bit-identical.  With
        # only k, no margin is known yet.
        self._first_query_k = self._query_k if first_query is None else min(max(first_query, self.k), tree.n)
        self.nearest: np.ndarray | None = None   # (N, k) int
        self._anchor: np.ndarray | None = None   # (N,) complex x + iy of each point's last tree query
        self._margin: np.ndarray | None = None   # (N,) how far the point may move from its anchor (m)

    def update(self, queries: np.ndarray) -> np.ndarray:
        """Bring ``nearest`` up to date for the query points (N,) complex x + iy; returns the rows queried again
        (a superset of those whose k nearest changed)."""
        n = queries.shape[0]
        if self._anchor is None or self._anchor.shape[0] != n:
            self.nearest = np.empty((n, self.k), dtype=np.intp)
            self._anchor = np.empty(n, dtype=np.complex128)
            self._margin = np.empty(n)
            stale = np.arange(n)
            self._query(stale, queries, self._first_query_k)
            return stale
        stale = (np.abs(queries - self._anchor) >= self._margin).nonzero()[0]
        if stale.size == 0:
            return _NO_ROWS
        self._query(stale, queries[stale], self._query_k)
        return stale

    def _query(self, rows: np.ndarray, queries: np.ndarray, count: int) -> None:
        k = self.k
        points = np.ascontiguousarray(queries).view(np.float64).reshape(-1, 2)
        distance, index = self.tree.query(points, k=count)
        if count == 1:   # the tree drops the neighbour axis for k = 1
            distance, index = distance[:, None], index[:, None]
        self._anchor[rows] = queries
        if count > k:
            self._margin[rows] = 0.5 * (distance[:, k] - distance[:, k - 1])
        elif count >= self.tree.n:   # every reference point is among the k nearest: nothing can overtake them
            self._margin[rows] = np.inf
        else:                        # no bound known: query again next time
            self._margin[rows] = 0.0
        self.nearest[rows] = index[:, :k]


class NearestPoint:
    """The nearest reference point of each of N current points, warm-started between the iterations of a matcher.

    Called with the moved current points (N, 2) at every iteration; returns (distance (N,), index (N,) int), the
    same as ``cKDTree(points).query(moved)`` bit for bit — the distance is computed as the tree computes it,
    √(dx² + dy²), and the first query is the tree's default k = 1, whose order of exactly equidistant points the
    later queries (k = 2) might not share — while querying the tree only for the points whose nearest point may
    have changed.  points: (M, 2) reference points, M >= 1.
    """

    def __init__(self, points: np.ndarray) -> None:
        self._x, self._y = points[:, 0].copy(), points[:, 1].copy()
        self._warm = WarmNearest(cKDTree(points), 1, first_query=1)

    def __call__(self, moved: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        moved = np.ascontiguousarray(moved, dtype=float)
        self._warm.update(moved.view(np.complex128)[:, 0])
        index = self._warm.nearest[:, 0]
        dx = moved[:, 0] - self._x[index]
        dy = moved[:, 1] - self._y[index]
        return np.sqrt(dx * dx + dy * dy), index
