"""The continuous curve through a reference scan: a piecewise-linear polyline with breaks.

Consecutive points of the scan are joined by a segment unless they are farther apart than ``gap`` metres or
a reading between them is missing (a range dropout); each unbroken run is a *piece*.  A point on the curve
is addressed by its arc length λ (metres).  Arc length runs along each piece and jumps by ``_PIECE_SPACING``
between pieces, so λ is strictly increasing over the whole curve and never ambiguous at a break.

Projection (the closed-form optimum of λ for a given point) uses the 2 nearest vertices and the
segments adjacent to them.  That is exact whenever the closest segment has one of those vertices as an
end; with segments no longer than ``gap`` this holds for every point within the matcher's gate in practice.

Warm start.  An iterative matcher projects the same points again and again while they move by millimetres, and
the k-d tree query is half of a projection's cost.  :class:`NearestVertexCache` keeps, per point, the
``_CACHED_VERTICES`` nearest vertices found by the last tree query at an anchor position and the distance r to
the farthest of them (every other vertex is at least r from the anchor).  A point that has since moved by δ
has every other vertex at least r − δ away, so if its two nearest cached vertices are closer than that they
are exactly the two nearest vertices the tree would return; only the points failing that test are queried
again.  The result is the same as a fresh query (up to the order of exact ties).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from estimation.scanmatch.errors import ScanMatchError
from estimation.scanmatch.scan import Scan2D

_PIECE_SPACING = 1.0  # metres of arc length left empty between pieces (any positive value works)
_NEAREST_VERTICES = 2
_CACHED_VERTICES = 6  # vertices remembered per point by NearestVertexCache (>= _NEAREST_VERTICES)


@dataclass(frozen=True)
class Projection:
    """Closest curve points of N query points.

    point:    (N, 2) closest point on the curve
    arc:      (N,) its arc length λ
    distance: (N,) Euclidean distance from the query to it
    normal:   (N, 2) unit vector from the curve point to the query (± the segment normal when the foot is inside
              a segment, the radial direction at a curve end or convex vertex; the segment normal at distance 0)
    vertex:   (N,) int, index of the curve vertex nearest to the query (what point-to-point ICP pairs with)
    """

    point: np.ndarray
    arc: np.ndarray
    distance: np.ndarray
    normal: np.ndarray
    vertex: np.ndarray


class NearestVertexCache:
    """Per-point memory of the last k-d tree query, for :meth:`Polyline.project` (see the module docstring).

    Valid for one fixed set of N points (the i-th query is always the i-th point of the same scan) and one
    Polyline.  anchor: (N, 2) query position of the last tree query; candidates: (N, K) its K nearest vertices;
    radius: (N,) distance from the anchor to the K-th of them (∞ when the curve has no more than K vertices).
    """

    def __init__(self) -> None:
        self.anchor: np.ndarray | None = None
        self.candidates: np.ndarray | None = None
        self.radius: np.ndarray | None = None


class Polyline:
    """The curve through a scan's points.  Built once per reference scan; queries are vectorised.

    Internally every vertex v has a "segment slot" v+1 (slot 0 and slot M are padding): the segment from v to
    v+1 when it exists, otherwise a zero-length segment sitting on v.  A zero-length segment is still a point
    of the curve (the vertex), so projection needs no validity masks.
    """

    def __init__(self, scan: Scan2D, gap: float) -> None:
        if len(scan) < 2:
            raise ScanMatchError(f"a reference scan needs at least 2 points, got {len(scan)}")
        self.vertices = scan.points                                   # (M, 2)
        m = self.vertices.shape[0]
        step = np.diff(self.vertices, axis=0)                          # (M-1, 2)
        length = np.hypot(step[:, 0], step[:, 1])                      # (M-1,)
        # Segment k joins vertex k to k+1; it exists unless the pair is a gap or straddles a dropout.
        self.segment_valid = (length <= gap) & (np.diff(scan.beam_index) == 1) & (length > 0.0)
        direction = step / np.where(length > 0.0, length, 1.0)[:, None]
        arc_step = np.where(self.segment_valid, length, _PIECE_SPACING)
        self.arc = np.concatenate([[0.0], np.cumsum(arc_step)])        # (M,) λ of every vertex
        piece = np.concatenate([[0], np.cumsum(~self.segment_valid)])  # (M,) piece id of every vertex
        first = np.flatnonzero(np.r_[True, np.diff(piece) != 0])
        last = np.r_[first[1:] - 1, m - 1]
        self.piece_of_vertex = piece
        self.piece_start = self.arc[first]                              # (P,) λ range of each piece
        self.piece_end = self.arc[last]
        # Segment slots (M+1): slot v+1 starts at vertex v (slot 0 is padding on vertex 0).
        slot_start = np.concatenate([self.vertices[:1], self.vertices])
        valid = np.concatenate([[False], self.segment_valid, [False]])
        slot_direction = np.zeros((m + 1, 2))
        slot_direction[1:m] = direction
        self._slot_start = slot_start                                   # (M+1, 2)
        self._slot_length = np.where(valid, np.r_[0.0, length, 0.0], 0.0)
        self._slot_direction = np.where(valid[:, None], slot_direction, 0.0)
        self._slot_normal = np.column_stack([-slot_direction[:, 1], slot_direction[:, 0]])
        self._slot_arc = np.concatenate([self.arc[:1], self.arc])
        self._slot_start_complex = self._slot_start[:, 0] + 1j * self._slot_start[:, 1]              # (M+1,)
        self._slot_direction_complex = self._slot_direction[:, 0] + 1j * self._slot_direction[:, 1]  # (M+1,)
        self._tree = cKDTree(self.vertices)
        self._vertex_complex = np.ascontiguousarray(self.vertices, dtype=float).view(np.complex128)[:, 0]  # (M,)

    @property
    def n_segments(self) -> int:
        return int(np.count_nonzero(self.segment_valid))

    def project(self, queries: np.ndarray, cache: NearestVertexCache | None = None) -> Projection:
        """Closest curve point of each query.  queries: (N, 2); cache: warm start for repeated queries of the
        same N points (updated in place; the result is the same as without it)."""
        queries = np.asarray(queries, dtype=float)
        n = queries.shape[0]
        nearest = self._nearest_vertices(queries) if cache is None else self._nearest_cached(queries, cache)
        # Candidate slots: the segment ending at (slot v) and the one starting at (slot v+1) each near vertex.
        slot = np.concatenate([nearest, nearest + 1], axis=1)              # (N, 2k)
        # Points as complex x + iy: fewer (and bigger) array operations, which is what a projection costs.
        offset = np.ascontiguousarray(queries).view(np.complex128) - self._slot_start_complex[slot]  # (N, 2k)
        direction = self._slot_direction_complex[slot]
        along = np.clip((offset * direction.conjugate()).real, 0.0, self._slot_length[slot])
        offset -= along * direction                                         # query minus candidate foot
        dist = np.abs(offset)
        flat = np.arange(n) * slot.shape[1] + np.argmin(dist, axis=1)
        best_slot = slot.ravel()[flat]
        residual = offset.ravel()[flat].view(float).reshape(n, 2)
        distance = dist.ravel()[flat]
        # Unit direction from the curve to the query; on the curve itself, the segment normal.
        on_curve = distance <= 1e-12
        normal = residual / np.where(on_curve, 1.0, distance)[:, None]
        if on_curve.any():
            normal[on_curve] = self._slot_normal[best_slot[on_curve]]
        return Projection(queries - residual, self._slot_arc[best_slot] + along.ravel()[flat], distance, normal,
                          nearest[:, 0])

    def _nearest_vertices(self, queries: np.ndarray) -> np.ndarray:
        """The nearest vertices (N, k) of queries (N, 2), closest first, k = min(2, M)."""
        k = min(_NEAREST_VERTICES, self.vertices.shape[0])
        _, nearest = self._tree.query(queries, k=k)
        return nearest.reshape(queries.shape[0], k)

    def _nearest_cached(self, queries: np.ndarray, cache: NearestVertexCache) -> np.ndarray:
        """As :meth:`_nearest_vertices`, re-querying the tree only where the cache cannot vouch for the result."""
        m = self.vertices.shape[0]
        if m <= _NEAREST_VERTICES:
            return self._nearest_vertices(queries)
        n = queries.shape[0]
        if cache.anchor is None or cache.anchor.shape[0] != n:
            cache.anchor = queries.copy()
            cache.candidates = np.empty((n, min(_CACHED_VERTICES, m)), dtype=np.intp)
            cache.radius = np.empty(n)
            stale = np.arange(n)
        else:
            # Complex x + iy: one subtraction and one abs per distance instead of a handful of array ops.
            here = np.ascontiguousarray(queries).view(np.complex128)               # (N, 1)
            distance = np.abs(self._vertex_complex[cache.candidates] - here)      # (N, K)
            order = np.argpartition(distance, 1, axis=1)[:, :_NEAREST_VERTICES]  # two smallest, closest first
            rows = np.arange(n)[:, None]
            bound = cache.radius - np.abs(here[:, 0] - cache.anchor.view(np.complex128)[:, 0])
            # Strict: a vertex outside the cache at exactly the bound could tie with the second nearest.
            fresh = distance[rows[:, 0], order[:, 1]] < bound
            stale = np.flatnonzero(~fresh)
            nearest = cache.candidates[rows, order]
            if stale.size == 0:
                return nearest
        k = cache.candidates.shape[1]
        distance, index = self._tree.query(queries[stale], k=k)
        cache.anchor[stale] = queries[stale]
        cache.candidates[stale] = index
        cache.radius[stale] = distance[:, -1] if k < m else np.inf
        if stale.size == n:
            return index[:, :_NEAREST_VERTICES].copy()
        nearest[stale] = index[:, :_NEAREST_VERTICES]
        return nearest

    def clamp_to_piece(self, arc: np.ndarray, piece: np.ndarray) -> np.ndarray:
        """Arc lengths (N,) clamped to the λ range of the given pieces (N,) int."""
        return np.clip(arc, self.piece_start[piece], self.piece_end[piece])

    def piece_at(self, arc: np.ndarray) -> np.ndarray:
        """Piece id (N,) of curve points given by arc length (N,) (each λ must lie on the curve)."""
        vertex = np.clip(np.searchsorted(self.arc, arc, side="right") - 1, 0, len(self.arc) - 1)
        return self.piece_of_vertex[vertex]

    def evaluate(self, arc: np.ndarray) -> np.ndarray:
        """Curve points (N, 2) at arc lengths (N,) that lie on the curve (clamp first if unsure)."""
        arc = np.asarray(arc, dtype=float)
        vertex = np.clip(np.searchsorted(self.arc, arc, side="right") - 1, 0, len(self.arc) - 1)
        slot = vertex + 1
        along = np.clip(arc - self.arc[vertex], 0.0, self._slot_length[slot])
        # λ at the end of a piece lands on its last vertex, whose slot is zero-length: that is the end point.
        return self._slot_start[slot] + along[:, None] * self._slot_direction[slot]
