"""The continuous curve through a reference scan: a piecewise-linear polyline with breaks.

Consecutive points of the scan are joined by a segment unless they are farther apart than ``gap`` metres or
a reading between them is missing (a range dropout); each unbroken run is a *piece*.  A point on the curve
is addressed by its arc length λ (metres).  Arc length runs along each piece and jumps by ``_PIECE_SPACING``
between pieces, so λ is strictly increasing over the whole curve and never ambiguous at a break.

Projection (the closed-form optimum of λ for a given point) uses the 2 nearest vertices and the
segments adjacent to them.  That is exact whenever the closest segment has one of those vertices as an
end; with segments no longer than ``gap`` this holds for every point within the matcher's gate in practice.

Warm start.  An iterative matcher projects the same points again and again while they move by millimetres.
:class:`NearestVertexCache` keeps, per point, the 2 nearest vertices and the data of their 4 candidate segments;
the nearest vertices are tracked by :class:`estimation.scanmatch.nearest.WarmNearest`, which re-queries the k-d
tree only for the points whose 2 nearest vertices could have changed, and only those points' segment data are
gathered again.  The result is that of a projection without the cache, up to exact distance ties: those are
decided by the candidates' order [v0, v1, v0+1, v1+1] (v0 the nearest vertex) and by the order in which the
k-d tree returns equidistant vertices, which the first tree query keeps as it always was (6 vertices for a
matcher's cache, 2 for a one-off projection; see WarmNearest).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from estimation.scanmatch.errors import ScanMatchError
from estimation.scanmatch.nearest import WarmNearest
from estimation.scanmatch.scan import Scan2D

_PIECE_SPACING = 1.0  # metres of arc length left empty between pieces (any positive value works)
_NEAREST_VERTICES = 2
_CANDIDATES = 2 * _NEAREST_VERTICES   # segment slots per query: before and after each nearest vertex
_FIRST_QUERY = 6  # vertices the first tree query asks for (see WarmNearest: the order of exact ties)


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
    """Warm start for repeated :meth:`Polyline.project` calls on the same N moving points (see the module docstring).

    Valid for one fixed set of N points (the i-th query is always the i-th point of the same scan) and one
    Polyline.  Per point: its 2 nearest vertices (``nearest.nearest``, (N, 2)) and the data of their 4 candidate
    segment slots (N, 2, 2, 4) complex (slot v or v+1, vertex v0 or v1, field): slot start x + iy, unit direction,
    its conjugate, length + i·slot index.
    """

    def __init__(self, first_query: int = _FIRST_QUERY) -> None:
        self.first_query = first_query   # vertices the first tree query asks for (the order of exact ties)
        self.nearest: WarmNearest | None = None
        self.candidates: np.ndarray | None = None     # (N, 2, 2, 4) complex: slot v or v+1, vertex v0 or v1
        self.first_of_row: np.ndarray | None = None   # (N,) int, 4 i: flat index of each row's first candidate


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
        vertex_complex = np.ascontiguousarray(self.vertices).view(np.complex128)[:, 0]  # (M,) x + iy
        step = np.diff(self.vertices, axis=0)                          # (M-1, 2)
        length = np.hypot(step[:, 0], step[:, 1])                      # (M-1,)
        # Unit direction to the next vertex, x + iy (float division: bit-identical to the earlier formulation).
        unit = (step / np.where(length > 0.0, length, 1.0)[:, None]).view(np.complex128)[:, 0]
        # Segment k joins vertex k to k+1; it exists unless the pair is a gap or straddles a dropout.
        self.segment_valid = (length <= gap) & (np.diff(scan.beam_index) == 1) & (length > 0.0)
        arc_step = np.where(self.segment_valid, length, _PIECE_SPACING)
        self.arc = np.zeros(m)                                         # (M,) λ of every vertex
        np.cumsum(arc_step, out=self.arc[1:])
        piece = np.zeros(m, dtype=np.intp)                             # (M,) piece id of every vertex
        np.cumsum(~self.segment_valid, out=piece[1:])
        first = np.concatenate([[0], np.flatnonzero(~self.segment_valid) + 1])
        last = np.concatenate([first[1:] - 1, [m - 1]])
        self.piece_of_vertex = piece
        self.piece_start = self.arc[first]                              # (P,) λ range of each piece
        self.piece_end = self.arc[last]
        # Segment slots (M+1): slot v+1 starts at vertex v (slot 0 is padding on vertex 0); invalid ones have
        # zero length and zero direction.
        valid_length = np.where(self.segment_valid, length, 0.0)
        self._slot_length = np.zeros(m + 1)
        self._slot_length[1:m] = valid_length
        self._slot_direction_complex = np.zeros(m + 1, dtype=np.complex128)
        self._slot_direction_complex[1:m] = np.where(self.segment_valid, unit, 0.0)
        self._slot_start_complex = np.empty(m + 1, dtype=np.complex128)
        self._slot_start_complex[0] = vertex_complex[0]
        self._slot_start_complex[1:] = vertex_complex
        # The normal of a slot is kept even where the segment is not valid (the direction to the next vertex).
        slot_unit = np.zeros(m + 1, dtype=np.complex128)
        slot_unit[1:m] = unit
        self._slot_normal = (1j * slot_unit).view(np.float64).reshape(m + 1, 2)  # (M+1, 2) direction turned +90°
        self._slot_arc = np.empty(m + 1)
        self._slot_arc[0] = 0.0
        self._slot_arc[1:] = self.arc
        self._tree = cKDTree(self.vertices)
        self._vertex_complex = vertex_complex
        # Per vertex v, its two candidate slots v and v+1 with what a projection needs of each: (M, 2, 4) complex
        # start, direction, conjugate direction, length + i·slot.  One gather fetches a point's candidates.
        table = np.empty((m + 1, 4), dtype=np.complex128)
        table[:, 0] = self._slot_start_complex
        table[:, 1] = self._slot_direction_complex
        np.conjugate(self._slot_direction_complex, out=table[:, 2])
        table[:, 3] = self._slot_length + 1j * np.arange(m + 1)
        self._candidate_table = np.empty((m, 2, 4), dtype=np.complex128)
        self._candidate_table[:, 0] = table[:-1]
        self._candidate_table[:, 1] = table[1:]

    @property
    def _slot_start(self) -> np.ndarray:
        return self._slot_start_complex.view(np.float64).reshape(-1, 2)

    @property
    def _slot_direction(self) -> np.ndarray:
        return self._slot_direction_complex.view(np.float64).reshape(-1, 2)

    @property
    def n_segments(self) -> int:
        return int(np.count_nonzero(self.segment_valid))

    def project(self, queries: np.ndarray, cache: NearestVertexCache | None = None) -> Projection:
        """Closest curve point of each query.  queries: (N, 2); cache: warm start for repeated queries of the
        same N points (updated in place; the result is the same as without it, up to exact ties)."""
        queries = np.ascontiguousarray(queries, dtype=float)
        n = queries.shape[0]
        # A one-off projection asks the tree for 2 vertices, as it always did: exact ties keep their order.
        cache = NearestVertexCache(first_query=_NEAREST_VERTICES) if cache is None else cache
        distance, offset, flat, along = self.project_complex(queries.view(np.complex128)[:, 0], cache)
        best_slot = cache.candidates[..., 3].imag.ravel()[flat].astype(np.intp)
        residual = offset.view(np.float64).reshape(n, 2)
        # Unit direction from the curve to the query; on the curve itself, the segment normal.
        on_curve = distance <= 1e-12
        normal = residual / np.where(on_curve, 1.0, distance)[:, None]
        if on_curve.any():
            normal[on_curve] = self._slot_normal[best_slot[on_curve]]
        pair = cache.nearest.nearest   # the 2 nearest vertices (a Polyline has at least 2)
        to_pair = np.abs(queries.view(np.complex128) - self._vertex_complex[pair])
        vertex = np.where(to_pair[:, 1] < to_pair[:, 0], pair[:, 1], pair[:, 0])
        return Projection(queries - residual, self._slot_arc[best_slot] + along.ravel()[flat], distance, normal,
                          vertex)

    def project_complex(self, queries: np.ndarray, cache: NearestVertexCache
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The lean projection an iterative matcher calls: queries (N,) complex x + iy, cache updated in place.

        Returns distance (N,), offset (N,) complex (query minus its closest curve point), flat (N,) int index of
        the chosen candidate among the (N, 4) candidates and along (N, 4) each candidate's foot (m from its start).
        """
        n = queries.shape[0]
        if cache.nearest is None or cache.nearest.tree is not self._tree or cache.candidates.shape[0] != n:
            cache.nearest = WarmNearest(self._tree, _NEAREST_VERTICES, first_query=cache.first_query)
            cache.candidates = np.empty((n, 2, _NEAREST_VERTICES, 4), dtype=np.complex128)   # slot, vertex
            cache.first_of_row = _CANDIDATES * np.arange(n)
        stale = cache.nearest.update(queries)
        if stale.size:   # candidates: the segment ending at (slot v) and the one starting at (slot v+1) each vertex
            # Ordered [v0, v1, v0+1, v1+1] (v0 the nearest): argmin breaks exact ties as a cold projection does.
            gathered = self._candidate_table[cache.nearest.nearest[stale]]                   # (s, vertex, slot, 4)
            cache.candidates[stale] = gathered.transpose(0, 2, 1, 3)
        candidates = cache.candidates.reshape(n, _CANDIDATES, 4)
        # Points as complex x + iy: fewer (and bigger) array operations, which is what a projection costs.
        offset = queries[:, None] - candidates[:, :, 0]                         # (N, 4)
        along = (offset * candidates[:, :, 2]).real                             # a view: clipped in place
        np.maximum(along, 0.0, out=along)
        np.minimum(along, candidates[:, :, 3].real, out=along)
        offset -= along * candidates[:, :, 1]                                   # query minus candidate foot
        dist = np.abs(offset)
        flat = cache.first_of_row + dist.argmin(axis=1)
        return dist.ravel()[flat], offset.ravel()[flat], flat, along

    def candidate_normal(self, cache: NearestVertexCache, flat: np.ndarray) -> np.ndarray:
        """Unit normals (n,) complex of the candidate segments at the flat indices (n,) :meth:`project_complex`
        returned: the direction from a curve point to a query that lies on the curve itself."""
        slot = cache.candidates[..., 3].imag.ravel()[flat].astype(np.intp)
        return self._slot_normal.view(np.complex128)[slot, 0]

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
