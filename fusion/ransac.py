"""Steps 1–3 of the map alignment (Section 3.1 of the ISR 2009 paper): putative correspondences, a transform
from each pair of them, the RANSAC search over those hypotheses, and the robust preset's weighted least-squares
refinement on the supports.

The conventions (``pose = (tx, ty, θ)``: map 2's frame in map 1's, REP-103) and where the code departs from the
paper's equations 1–4, and why, are in :mod:`fusion.alignment`'s docstring; :mod:`fusion.evidence` decides whether
the best hypothesis is trusted.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from estimation.geometry import transform_points, wrap_angle
from estimation.landmark_map import LandmarkMap

from .errors import IncompatibleMapsError
from .gate_scale import residual_gate_scale, settled_scale
from .matching import (
    RATIO_SIDES,
    distinctive_correspondences,
    nearest_correspondences,
    query_subset,
    symmetric_correspondences,
)

if TYPE_CHECKING:
    from .alignment_config import AlignmentConfig

# χ² quantiles at 0.999 for 1, 2 and 3 degrees of freedom (gates that keep 99.9 % of true supports).
CHI2_999 = {1: 10.828, 2: 13.816, 3: 16.266}
# Without descriptors every landmark pair is a candidate; beyond this many the search is not attempted.
MAX_GEOMETRIC_PAIRS = 40_000


# -- step 1: putative correspondences --------------------------------------------------------------------------
def has_descriptors(landmark_map: LandmarkMap) -> bool:
    """False when the map's descriptors cannot tell landmarks apart (none, or all the same)."""
    d = landmark_map.descriptors
    if d.shape[1] == 0:
        return False
    # (the second row alone usually tells: one row's comparison instead of the whole map's)
    return len(d) < 2 or bool(np.any(d[1] != d[0])) or bool(np.any(d != d[0]))


def landmark_identities(landmark_map: LandmarkMap) -> np.ndarray | None:
    """The landmarks' external identities (N,) int64 (fiducials, barcodes: ``metadata["external_ids"]``, one per
    row, -1 = none), or None when the map has none or they do not fit its rows."""
    ext = landmark_map.metadata.get("external_ids")
    if ext is None:
        return None
    try:
        ids = np.asarray(ext, dtype=np.int64).reshape(-1)
    except (TypeError, ValueError):
        return None
    return ids if len(ids) == len(landmark_map) else None


def identity_pairs(ids1: np.ndarray, ids2: np.ndarray) -> np.ndarray:
    """Every (i, j) with the same identity ≥ 0 (K, 2) int64; a duplicated identity gives several pairs."""
    order = np.argsort(ids2, kind="stable")
    sorted2 = ids2[order]
    lo = np.searchsorted(sorted2, ids1, "left")
    hi = np.searchsorted(sorted2, ids1, "right")
    valid = ids1 >= 0
    i = np.repeat(np.arange(len(ids1)), np.where(valid, hi - lo, 0))
    j = np.concatenate([order[a:b] for a, b, v in zip(lo, hi, valid, strict=True) if v] or [np.zeros(0, np.int64)])
    return np.column_stack([i, j]).astype(np.int64)


def putative_correspondences(map1: LandmarkMap, map2: LandmarkMap, config: AlignmentConfig, rng: np.random.Generator
                     ) -> tuple[np.ndarray, bool]:
    """Step 1: putative pairs (K, 2), and whether descriptors chose them (False: every pair, geometry alone).

    Maps that both carry external identities (known-ID maps: barcodes, fiducials) pair equal identities."""
    if config.ratio_sides not in RATIO_SIDES:
        raise IncompatibleMapsError(f"unknown ratio_sides {config.ratio_sides!r} "
                                    f"(choose from {', '.join(RATIO_SIDES)})")
    ids1, ids2 = landmark_identities(map1), landmark_identities(map2)
    if ids1 is not None and ids2 is not None:
        return identity_pairs(ids1, ids2), True
    if not (has_descriptors(map1) and has_descriptors(map2)) and len(map1) and len(map2):
        i, j = np.meshgrid(np.arange(len(map1)), np.arange(len(map2)), indexing="ij")
        return np.column_stack([i.ravel(), j.ravel()]).astype(np.int64), False
    # (very large maps: a random subset of map 1 searches; see matching.query_subset)
    rows = query_subset(len(map1), len(map2), rng)
    desc1 = map1.descriptors if rows is None else map1.descriptors[rows]
    if config.ratio is None:
        pairs, _ = nearest_correspondences(desc1, map2.descriptors, config.descriptor_threshold)
    elif config.ratio_sides == "map1":
        pairs, _ = distinctive_correspondences(desc1, map2.descriptors, config.descriptor_threshold, config.ratio)
    else:
        # (with a subset of map 1, a map-2 landmark's ratio test is among that subset)
        pairs, _ = symmetric_correspondences(desc1, map2.descriptors, config.descriptor_threshold, config.ratio,
                                             config.ratio_sides)
    if rows is not None:
        pairs[:, 0] = rows[pairs[:, 0]]
    return pairs, True



# -- steps 2–3: hypotheses, the search, the refinement -------------------------------------------------
# masks(): hypotheses × correspondences per block of its float work (8 bytes each: its arrays stay in cache); blocks
# of at least this many hypotheses are screened by one matrix product first, unless more than this fraction of
# the block passes the screen (a true hypothesis' batch: then the block is computed whole)
_MASK_BLOCK = 16_384
_SCREEN_BLOCK = 131_072
_SCREEN_MIN_HYPOTHESES = 16
_SCREEN_MAX_FRACTION = 0.25
# distinct_counts() counts from the supports' positions when at most one element in this many is a support
_SPARSE_COUNTS = 16


def _landmark_groups(rows: np.ndarray) -> tuple | None:
    """How the correspondences share landmarks (rows (K,): each one's landmark on one side): (the correspondences
    of landmarks in several, sorted by landmark; the start of each such landmark's group among them; the same
    correspondences in their own order; every correspondence's landmark as 0 … G−1; G); None when every landmark
    takes part once."""
    if len(rows) == 0:
        return None
    if rows.min() >= 0 and rows.max() < 8 * len(rows) + 64 and np.bincount(rows).max() == 1:
        return None                                   # (landmark rows: a count is cheaper than np.unique)
    _, inverse, size = np.unique(rows, return_inverse=True, return_counts=True)
    shared = size[inverse] > 1
    if not shared.any():
        return None
    columns = np.flatnonzero(shared)
    order = columns[np.argsort(rows[columns], kind="stable")]
    sorted_rows = rows[order]
    starts = np.flatnonzero(np.r_[True, sorted_rows[1:] != sorted_rows[:-1]])
    return order, starts, columns, inverse.reshape(-1), len(size)


def rotations_2d(theta: np.ndarray) -> np.ndarray:
    """(..., 2, 2) rotation matrices [[c, -s], [s, c]] of angles theta (...) (filled in place: np.stack's three calls
    cost more than the values)."""
    c, s = np.cos(theta), np.sin(theta)
    out = np.empty(np.shape(c) + (2, 2), np.result_type(c, s))
    out[..., 0, 0] = c
    out[..., 0, 1] = -s
    out[..., 1, 0] = s
    out[..., 1, 1] = c
    return out


def pair_hypotheses(p1: np.ndarray, p2: np.ndarray, a: np.ndarray, b: np.ndarray, config: AlignmentConfig
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Transforms from correspondence pairs (a, b) and whether each pair passes the distance check.

    p1, p2 (K, 3): corresponding landmark positions in map 1 and map 2; a, b (H,) indices into them.
    Returns poses (H, 3) and valid (H,) bool.  With A, B the x, y differences in map 2 and C, D in map 1:
    θ = atan2(AD − BC, AC + BD) (eq. 4, quadrant-safe, sign as in the module docstring); the paper's
    t = m_a − R(θ) m'_a (eqs. 2–3), the robust preset's t from the pair's midpoint (symmetric in a, b).
    """
    A = p2[a, 0] - p2[b, 0]
    B = p2[a, 1] - p2[b, 1]
    C = p1[a, 0] - p1[b, 0]
    D = p1[a, 1] - p1[b, 1]
    d2_sq = A * A + B * B
    d1_sq = C * C + D * D
    theta = np.arctan2(A * D - B * C, A * C + B * D)
    R = rotations_2d(theta)
    if config.covariance_gating:
        anchor1 = 0.5 * (p1[a, :2] + p1[b, :2])
        anchor2 = 0.5 * (p2[a, :2] + p2[b, :2])
    else:
        anchor1, anchor2 = p1[a, :2], p2[a, :2]
    t = anchor1 - np.einsum("hij,hj->hi", R, anchor2)
    sep = config.min_pair_separation
    valid = (d1_sq > max(sep, 1e-9) ** 2) & (d2_sq > max(sep, 1e-9) ** 2)
    return np.column_stack([t, theta]), valid


@dataclass
class CorrespondenceProblem:
    """Correspondence geometry: positions (K, 3), covariances (K, 3, 3) of both sides, landmark rows i, j (K,),
    per-axis combined variances var_xy, var_z (K,) (floors included), the gate scale ``inflation`` and the
    incidence matrices that count supports one-to-one."""

    p1: np.ndarray
    p2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    i: np.ndarray
    j: np.ndarray
    var_xy: np.ndarray
    var_z: np.ndarray
    config: AlignmentConfig
    distinct_scoring: bool               # RANSAC counts supports one-to-one (always so for the evidence)
    inflation: float = 1.0
    # what depends on the correspondences alone, shared by the copies replace() and inflated() make of them (each
    # polishing round, each re-scored rival): rebuilt only when a copy holds other arrays
    _geometry: dict | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        # what masks() and distinct_counts() reuse for every hypothesis: contiguous coordinates, the height
        # differences, and each side's grouping of correspondences by landmark (None: every landmark once, so a
        # plain count of a row is its distinct count -- mutual matches, the paper's one match per map-1 landmark)
        arrays = (self.p1, self.p2, self.i, self.j)
        g = self._geometry
        if g is None or any(a is not b for a, b in zip(g["arrays"], arrays, strict=True)):
            g = self._geometry = {
                "arrays": arrays,
                "xy": (np.ascontiguousarray(self.p1[:, 0]), np.ascontiguousarray(self.p1[:, 1]),
                       np.ascontiguousarray(self.p2[:, 0]), np.ascontiguousarray(self.p2[:, 1])),
                "dz_sq": (self.p1[:, 2] - self.p2[:, 2]) ** 2,
                "groups": [x for x in (_landmark_groups(self.i), _landmark_groups(self.j)) if x is not None]}
        self._x1, self._y1, self._x2, self._y2 = g["xy"]
        self._dz_sq = g["dz_sq"]
        self._groups = g["groups"]
        self._features = None
        self._set_gates()

    def _set_gates(self) -> None:
        c = self.config
        self._gate_radius = None
        if c.covariance_gating:
            lo, hi = c.min_gate ** 2, c.support_threshold ** 2
            self.gate_xy_sq = np.clip(CHI2_999[2] * self.inflation * self.var_xy, lo, hi)
            self.gate_z_sq = np.clip(CHI2_999[1] * self.inflation * self.var_z, lo, hi)
            # a correspondence whose heights differ beyond its gate supports no hypothesis: only the others are
            # computed (None: all of them)
            z_ok = self._dz_sq < self.gate_z_sq
            self._columns = None if z_ok.all() else np.flatnonzero(z_ok)
        else:
            self.gate_xy_sq = self.gate_z_sq = np.full(len(self.i), c.support_threshold ** 2)
            self._columns = None
        cols = slice(None) if self._columns is None else self._columns
        self._computed = (self._x1[cols], self._y1[cols], self._x2[cols], self._y2[cols], self.gate_xy_sq[cols])

    def inflated(self, inflation: float) -> CorrespondenceProblem:
        """The same correspondences with the gate scaled by ``inflation`` (covariance scale, ≥ 1)."""
        return replace(self, inflation=float(inflation))

    @property
    def gate_radius(self) -> float:
        """Median support-gate radius (m) in the plane (computed once per gate)."""
        if self._gate_radius is None:
            self._gate_radius = float(np.sqrt(np.median(self.gate_xy_sq))) if len(self.i) else float("nan")
        return self._gate_radius

    def masks(self, poses: np.ndarray) -> np.ndarray:
        """(H, K) bool: which correspondences support each hypothesis poses (H, 3).

        r = p1 − (R(θ) p2 + t) in the plane, |r|² against the gate (covariance gating: and the height difference
        against its own gate; else |r|² + dz² against th2²), each |r|² computed as the plain broadcast form computes
        it (the same floating-point operations in the same order; tests/fusion/test_fusion_exact_forms.py), only
        for the correspondences whose heights pass.  Many hypotheses (the decoys, RANSAC's batches) are screened
        first by |r|² expanded as one matrix product, with a margin far beyond its round-off; only those near or
        inside the gate are then computed exactly, so the screen changes no mask."""
        poses = np.asarray(poses, float)
        h, k = len(poses), len(self.i)
        cols = self._columns
        x1, y1, x2, y2, gate = self._computed
        n = len(x1)
        out = np.zeros((h, k), bool)
        if h == 0 or n == 0:
            return out
        limit = gate if self.config.covariance_gating else self.config.support_threshold ** 2
        cos, sin = np.cos(poses[:, 2:3]), np.sin(poses[:, 2:3])
        rows = max(1, _SCREEN_BLOCK // n) if h >= _SCREEN_MIN_HYPOTHESES else h
        for start in range(0, h, rows):
            p = poses[start:start + rows]
            c, s = cos[start:start + rows], sin[start:start + rows]
            screen = self._screen(p, c[:, 0], s[:, 0], limit) if len(p) >= _SCREEN_MIN_HYPOTHESES else None
            if screen is not None:
                hh, kk = np.divmod(np.flatnonzero(screen), n)
                if len(hh) <= _SCREEN_MAX_FRACTION * len(p) * n:
                    ok = self._exact(p[hh], c[hh, 0], s[hh, 0], kk)
                    hh, kk = hh[ok], kk[ok]
                    out[start + hh, kk if cols is None else cols[kk]] = True
                    continue
            step = max(1, _MASK_BLOCK // n)               # the broadcast form's temporaries, a block at a time
            for sub in range(0, len(p), step):
                block = self._exact_block(p[sub:sub + step], c[sub:sub + step], s[sub:sub + step])
                rows_out = slice(start + sub, start + sub + len(block))
                if cols is None:
                    out[rows_out] = block
                else:
                    out[rows_out, cols] = block
        return out

    def _residual_sq(self, p, c, s, kk):
        """|r|² of hypotheses p (N, 3) (cos c, sin s) and computed correspondences kk (N,) (or all of them, with p, c,
        s as (H, 1) columns): the broadcast form's operations, rx = x1 − ((c·x2 − s·y2) + tx), ry likewise."""
        x1, y1, x2, y2, _ = self._computed
        if kk is not None:
            x1, y1, x2, y2 = x1[kk], y1[kk], x2[kk], y2[kk]
        tx, ty = (p[:, 0], p[:, 1]) if kk is not None else (p[:, 0:1], p[:, 1:2])
        rx = x1 - (c * x2 - s * y2 + tx)
        ry = y1 - (s * x2 + c * y2 + ty)
        return rx * rx + ry * ry

    def _passes(self, r_xy_sq, kk):
        """The gate on |r|² (and the height difference) of computed correspondences kk (or all, as columns)."""
        sl = slice(None) if kk is None else kk
        if self.config.covariance_gating:
            return r_xy_sq < self._computed[4][sl]
        dz_sq = self._dz_sq if self._columns is None else self._dz_sq[self._columns]
        return r_xy_sq + dz_sq[sl] < self.config.support_threshold ** 2

    def _exact(self, p, c, s, kk):
        return self._passes(self._residual_sq(p, c, s, kk), kk)

    def _exact_block(self, p, c, s):
        return self._passes(self._residual_sq(p, c, s, None), None)

    def _screen(self, p, c, s, limit):
        """(H, n) bool, a superset of the supports (None: no screen possible): |r|² = |p1|² + |p2|² − 2c p1·p2
        − 2s (y1 x2 − x1 y2) − 2 p1·t + 2 x2 (c tx + s ty) + 2 y2 (c ty − s tx) + |t|², eight terms per hypothesis
        and correspondence, as one matrix product, against the gate plus 1e-9 of the coordinates' squared scale (its
        round-off is below 1e-13 of it, the plain form's too)."""
        if self._features is None:
            x1, y1, x2, y2, _ = self._computed
            self._features = np.stack([x1 * x1 + y1 * y1 + x2 * x2 + y2 * y2, -2.0 * (x1 * x2 + y1 * y2),
                                       -2.0 * (y1 * x2 - x1 * y2), -2.0 * x1, -2.0 * y1, 2.0 * x2, 2.0 * y2,
                                       np.ones_like(x1)])
            self._scale = float(max(np.max(np.abs(x1) + np.abs(y1)), np.max(np.abs(x2) + np.abs(y2))))
        tx, ty = p[:, 0], p[:, 1]
        fh = np.column_stack([np.ones_like(c), c, s, tx, ty, c * tx + s * ty, c * ty - s * tx, tx * tx + ty * ty])
        scale = max(self._scale, float(np.max(np.abs(tx) + np.abs(ty))), 1e-3)
        if not np.isfinite(scale):               # a coordinate not finite: no bound on the round-off, no screen
            return None
        approx = fh @ self._features
        return approx < np.add(limit, 1e-9 * scale * scale)

    def distinct_counts(self, masks: np.ndarray) -> np.ndarray:
        """(H,) one-to-one support counts: min(distinct map-1 landmarks, distinct map-2 landmarks) per row."""
        h, k = masks.shape
        if k == 0:
            return np.zeros(h, np.int64)
        hit = np.flatnonzero(masks)
        if len(hit) * _SPARSE_COUNTS <= h * k:
            # few supports (decoys, wrong hypotheses): from the supports themselves
            rows, cols = np.divmod(hit, k)
            counts = [np.bincount(rows, minlength=h)]
            for *_, landmark, n_landmarks in self._groups:
                seen = np.unique(rows * n_landmarks + landmark[cols])
                counts.append(np.bincount(seen // n_landmarks, minlength=h))
            return np.minimum.reduce(counts).astype(np.int64)
        total = np.count_nonzero(masks, axis=1)
        counts = [total]
        for order, starts, shared, *_ in self._groups:
            # the landmarks seen once count their column; a landmark in several correspondences counts once if any
            # of them supports
            any_hit = np.logical_or.reduceat(masks[:, order], starts, axis=1)
            counts.append(total - np.count_nonzero(masks[:, shared], axis=1) + np.count_nonzero(any_hit, axis=1))
        return np.minimum.reduce(counts).astype(np.int64)

    def counts(self, masks: np.ndarray) -> np.ndarray:
        return self.distinct_counts(masks) if self.distinct_scoring else masks.sum(axis=1)

    def one_to_one(self, mask: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """The supports of ``mask`` (K,) with each landmark used once, nearest in position first."""
        if not self._groups:
            # every landmark in one correspondence at most (mutual matches): every support is kept
            return mask.copy()
        idx = np.flatnonzero(mask)
        if len(idx) == 0:
            return mask
        r = self.p1[idx] - transform_points(pose, self.p2[idx])
        order = idx[np.argsort(np.einsum("ki,ki->k", r, r), kind="stable")]
        _, first_i = np.unique(self.i[order], return_index=True)
        order = order[np.sort(first_i)]
        _, first_j = np.unique(self.j[order], return_index=True)
        keep = np.zeros_like(mask)
        keep[order[first_j]] = True
        return keep


def correspondence_problem(map1: LandmarkMap, map2: LandmarkMap, pairs: np.ndarray, config: AlignmentConfig,
             distinct_scoring: bool) -> CorrespondenceProblem:
    i, j = pairs[:, 0], pairs[:, 1]
    P1, P2 = map1.covariances[i], map2.covariances[j]
    floor_sq = config.position_floor ** 2
    # rotation-invariant per-axis variance of the difference in the plane (mean of the xy eigenvalues), and z
    var_xy = 0.5 * (np.trace(P1[:, :2, :2], axis1=1, axis2=2) + np.trace(P2[:, :2, :2], axis1=1, axis2=2))
    var_z = P1[:, 2, 2] + P2[:, 2, 2]
    return CorrespondenceProblem(map1.positions[i], map2.positions[j], P1, P2, i, j, var_xy + 2 * floor_sq,
                    var_z + 2 * floor_sq, config, distinct_scoring)


def distance_preserved(problem: CorrespondenceProblem, a: np.ndarray, b: np.ndarray, config: AlignmentConfig
                       ) -> np.ndarray:
    """The corrected eq. 1: is the landmark-to-landmark distance preserved between the maps?"""
    d1_sq = np.sum((problem.p1[a, :2] - problem.p1[b, :2]) ** 2, axis=1)
    d2_sq = np.sum((problem.p2[a, :2] - problem.p2[b, :2]) ** 2, axis=1)
    if not config.covariance_gating:
        return np.abs(d2_sq - d1_sq) < config.pair_tolerance          # |d'² − d²| < th1 (m²)
    # the gate's own scale (min_gate, inflation) bounds how well a distance can be preserved
    sigma_sq = (problem.gate_xy_sq[a] + problem.gate_xy_sq[b]) / CHI2_999[2]
    return np.abs(np.sqrt(d2_sq) - np.sqrt(d1_sq)) < config.pair_tolerance * np.sqrt(sigma_sq)


def required_iterations(inlier_ratio: float, config: AlignmentConfig) -> int:
    """RANSAC's N = log(1 − confidence) / log(1 − w²) for a two-correspondence sample."""
    w2 = min(max(inlier_ratio, 0.0), 1.0) ** 2
    if w2 >= 1.0:
        return config.min_iterations
    if w2 <= 0.0:
        return config.iterations
    n = np.log(1.0 - config.confidence) / np.log(1.0 - w2)
    return int(np.clip(np.ceil(n), config.min_iterations, config.iterations))


@dataclass
class RansacSearch:
    """What RANSAC tried: the best pose (3,) or None, its support mask (K,), and every hypothesis
    evaluated with its support count (poses (E, 3), counts (E,))."""

    pose: np.ndarray | None
    mask: np.ndarray
    poses: np.ndarray
    counts: np.ndarray

    @property
    def evaluated(self) -> int:
        return len(self.counts)


def ransac(problem: CorrespondenceProblem, config: AlignmentConfig, rng: np.random.Generator) -> RansacSearch:
    """Steps 2–3 repeated (hypotheses from pairs of correspondences, scored by their supports)."""
    k = len(problem.i)
    best_pose, best_mask, best_count = None, np.zeros(k, bool), -1
    tried_poses, tried_counts = [], []
    evaluated, draws = 0, 0
    target = config.iterations if not config.adaptive else config.min_iterations
    batch = 64
    max_draws = 200 * config.iterations
    while evaluated < target and draws < max_draws:
        n = 4 * batch
        a = rng.integers(k, size=n)
        b = rng.integers(k - 1, size=n)
        b += b >= a
        draws += n
        # two distinct landmarks on each side, then the distance check (corrected eq. 1)
        ok = (problem.i[a] != problem.i[b]) & (problem.j[a] != problem.j[b])
        ok &= distance_preserved(problem, a, b, config)
        poses, valid = pair_hypotheses(problem.p1, problem.p2, a, b, config)
        keep = np.flatnonzero(ok & valid)[: min(batch, target - evaluated)]
        if len(keep) == 0:
            continue
        masks = problem.masks(poses[keep])
        counts = problem.counts(masks)
        tried_poses.append(poses[keep])
        tried_counts.append(counts)
        evaluated += len(keep)
        h = int(np.argmax(counts))
        if counts[h] > best_count:
            best_pose, best_mask, best_count = poses[keep[h]], masks[h], int(counts[h])
            if config.adaptive:
                target = required_iterations(best_count / k, config)
    poses = np.concatenate(tried_poses) if tried_poses else np.zeros((0, 3))
    counts = np.concatenate(tried_counts) if tried_counts else np.zeros(0, np.int64)
    return RansacSearch(best_pose, best_mask, poses, counts)


def refine_pose(p1: np.ndarray, P1: np.ndarray, p2: np.ndarray, P2: np.ndarray, pose, floor: float = 0.02,
                iterations: int = 10) -> tuple[np.ndarray, np.ndarray, float]:
    """Weighted least-squares (tx, ty, θ) from corresponding points by Gauss–Newton.

    Minimises Σ rᵢᵀ Sᵢ⁻¹ rᵢ, rᵢ = p1ᵢ − (R(θ) p2ᵢ + t) in the plane, Sᵢ = P1ᵢ + R P2ᵢ Rᵀ + floor² I (xy blocks).
    p1, p2 (K, 3); P1, P2 (K, 3, 3); pose (3,) the start.  Returns pose (3,), covariance (3, 3) = (Jᵀ W J)⁻¹
    inflated by the reduced χ² when that exceeds 1, and the χ² of the fit.
    """
    pose = np.asarray(pose, float).copy()
    xy1, xy2 = p1[:, :2], p2[:, :2]
    P1xy, P2xy, floor_sq = P1[:, :2, :2], P2[:, :2, :2], floor ** 2 * np.eye(2)
    J = np.zeros((len(p1), 2, 3))                                  # ∂(R p2 + t)/∂(tx, ty, θ)
    J[:, 0, 0] = J[:, 1, 1] = 1.0
    H = np.eye(3)
    r = W = None
    for _ in range(iterations):
        R = rotations_2d(pose[2])
        q = xy2 @ R.T                                              # map-2 points rotated into map 1
        r = xy1 - (q + pose[:2])                                   # residuals (K, 2)
        S = P1xy + R @ P2xy @ R.T + floor_sq
        det = S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] * S[:, 1, 0]
        W = np.empty_like(S)                                       # weights S⁻¹ (K, 2, 2), closed form
        W[:, 0, 0], W[:, 1, 1] = S[:, 1, 1] / det, S[:, 0, 0] / det
        W[:, 0, 1], W[:, 1, 0] = -S[:, 0, 1] / det, -S[:, 1, 0] / det
        J[:, 0, 2], J[:, 1, 2] = -q[:, 1], q[:, 0]
        JtW = np.einsum("kji,kjl->kil", J, W)                      # Jᵀ W (K, 3, 2)
        H = np.einsum("kil,klm->im", JtW, J)                       # normal matrix (3, 3)
        g = np.einsum("kil,kl->i", JtW, r)
        step = np.linalg.solve(H, g)
        pose += step
        pose[2] = wrap_angle(pose[2])
        if np.max(np.abs(step)) < 1e-10:
            break
    # the χ² of the last iteration's residuals and weights (only that one is reported)
    chi2 = 0.0 if r is None else float(np.einsum("ki,kij,kj->", r, W, r))
    cov = np.linalg.inv(H)
    dof = 2 * len(p1) - 3
    if dof > 0:
        cov *= max(1.0, chi2 / dof)
    return pose, 0.5 * (cov + cov.T), chi2


def residual_inflation(problem: CorrespondenceProblem, mask: np.ndarray, pose: np.ndarray, rule: str = "inflate"
                       ) -> float:
    """Covariance scale the supports' residuals call for: median(|r_xy|² / var_xy) over the median of χ²₂,
    at least 1 unless ``rule`` (the polishing config's ``gate_scale``) is "residual" (:mod:`fusion.gate_scale`)."""
    idx = np.flatnonzero(mask)
    if len(idx) < 3:
        return problem.inflation
    r = problem.p1[idx, :2] - transform_points(pose, problem.p2[idx])[:, :2]
    return residual_gate_scale(r, problem.var_xy[idx], rule)


def polish(problem: CorrespondenceProblem, pose: np.ndarray, mask: np.ndarray, config: AlignmentConfig, rounds: int = 6
            ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, CorrespondenceProblem]:
    """Refine a hypothesis on its supports, re-scale the gate to their residuals and re-gate, until the
    supports settle.  Returns pose (3,), covariance (3, 3) or None, one-to-one support mask (K,), problem."""
    covariance = None
    if problem.distinct_scoring or config.refine:
        mask = problem.one_to_one(mask, pose)
    if not config.refine:
        return pose, covariance, mask, problem
    for step in range(rounds):
        if mask.sum() < 2:
            break
        try:
            pose, covariance, _ = refine_pose(problem.p1[mask], problem.P1[mask], problem.p2[mask],
                                              problem.P2[mask], pose, config.position_floor)
        except np.linalg.LinAlgError:        # supports all in one spot: the spread check rejects them
            break
        if config.inflate_gate:
            kappa = residual_inflation(problem, mask, pose, config.gate_scale)
            problem = problem.inflated(settled_scale(kappa, problem.inflation, step, config.gate_scale))
        new_mask = problem.one_to_one(problem.masks(pose[None])[0], pose)
        if new_mask.sum() < 2 or np.array_equal(new_mask, mask):
            break
        mask = new_mask
    else:
        if config.gate_scale == "residual":  # not settled: report the fit of the supports reported
            pose, covariance = refit(problem, mask, pose, covariance, config)
    return pose, covariance, mask, problem


def refit(problem: CorrespondenceProblem, mask: np.ndarray, pose: np.ndarray, covariance, config: AlignmentConfig):
    try:
        return refine_pose(problem.p1[mask], problem.P1[mask], problem.p2[mask], problem.P2[mask], pose,
                           config.position_floor)[:2]
    except np.linalg.LinAlgError:
        return pose, covariance

