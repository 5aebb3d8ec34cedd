"""Map alignment: the transformation between two landmark maps by RANSAC (Section 3.1 of the ISR 2009 paper).

Convention.  The result ``pose = (tx, ty, θ)`` is the pose of map 2's frame (robot 2's start) in map 1's
frame, REP-103, θ counter-clockwise: a map-2 point p' lies at ``p = R(θ) p' + t`` in map 1 (z unchanged),
so ``pose`` composes with :mod:`estimation.geometry` and equals ``between(start1, start2)`` for true start
poses in a common world frame.  ``Alignment.matrix`` is the 4×4 homogeneous transform of eq. 5 in the
column-vector convention (``p_h = T @ p'_h``; rotation block ``[[c, -s], [s, c]]``, translation in the
last column).

Where the code departs from the text, and why:

* Eq. 1 compares the wrong sums ((A² + C²) vs (B² + D²) mixes the two maps' x and y differences).  The
  intended rigid-motion check is that the distance between the two landmarks is preserved:
  ``|d'² − d²| < th1`` with ``d'² = A² + B²`` (map 2) and ``d² = C² + D²`` (map 1).  Note that th1 = 2 "m"
  in the text is then a tolerance on squared distances (m²); the paper preset keeps the number.
* Eqs. 2–4 are consistent with each other only for θ measured the other way round (the text's matrix of
  eq. 5, written for row vectors, rotates by −θ).  We report θ = −θ_text so that (tx, ty, θ) is a pose;
  tx, ty are unchanged.  Eq. 4 uses the quadrant-safe ``atan2(AD − BC, AC + BD)`` — a plain arctangent
  of the ratio loses half the circle.
* Step 1 with th0 = 2: descriptors are unit vectors, so descriptor distances lie in [0, 2] and th0 = 2
  accepts every nearest neighbour; the paper preset keeps it (the text's behaviour) and the robust preset
  replaces it with a ratio test, mutual best matches and a real distance gate.

The ``robust`` preset further adapts the iteration count to the inlier ratio and the desired confidence,
refines the winning hypothesis by weighted least squares (Gauss–Newton) on all supports using their
covariances, re-gates the supports with a Mahalanobis test, reports the alignment's 3×3 covariance, and
decides that the maps do not overlap unless (a) there are at least ``min_supports`` supports, (b) they
are spread out in space (a bunch of supports in one spot fixes no angle), and (c) that many supports are
very unlikely by chance: against a binomial model of how many correspondences a wrong transform would
put inside the gate (the chance rate is measured on the maps themselves, at the found transform), with a
Bonferroni correction for the number of hypotheses tried.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree
from scipy.special import bdtrc

from estimation.geometry import between, inverse, pose_to_matrix, rot_z, transform_points, wrap_angle
from estimation.landmark_map import LandmarkMap

from .errors import IncompatibleMapsError, NoOverlapError
from .matching import distinctive_correspondences, nearest_correspondences, query_subset
from .pose_covariance import inverse_with_covariance

# χ² quantiles at 0.999 for 1, 2 and 3 degrees of freedom (gates that keep 99.9 % of true supports).
CHI2_999 = {1: 10.828, 2: 13.816, 3: 16.266}


@dataclass(frozen=True)
class AlignmentConfig:
    """Parameters of the RANSAC alignment.  ``paper`` and ``robust`` are the two presets."""

    name: str
    descriptor_threshold: float          # th0: largest accepted descriptor distance
    ratio: float | None                  # Lowe ratio test + mutual matches; None = the paper's nearest match
    pair_tolerance: float                # paper: th1 on |d'² − d²| (m²); robust: in σ of |d' − d|
    min_pair_separation: float           # metres; shorter pairs fix no angle
    support_threshold: float             # th2, metres (Euclidean 3-D; robust: largest gate radius)
    min_supports: int                    # `min`
    iterations: int                      # M (paper) or the cap of the adaptive count (robust)
    adaptive: bool = False               # iteration count from the inlier ratio and `confidence`
    confidence: float = 0.999
    min_iterations: int = 32
    covariance_gating: bool = False      # gates from the landmark covariances instead of th2
    refine: bool = False                 # weighted least squares on all supports + covariance
    significance: float | None = None    # largest accepted chance probability of the supports
    min_spread: float = 0.0              # metres, principal standard deviation of the supports (xy)
    position_floor: float = 0.02         # metres, added in quadrature to every landmark's std

    def to_dict(self) -> dict:
        return asdict(self)


PAPER = AlignmentConfig(
    name="paper", descriptor_threshold=2.0, ratio=None, pair_tolerance=2.0, min_pair_separation=0.0,
    support_threshold=0.2, min_supports=20, iterations=70,
)
# min_supports 15: on maps built from rendered frames, the building's repeated structure (door frames, symmetric
# corridor) let a wrong transform gather 11–13 supports that the binomial chance test, which assumes independent
# correspondences, passed; true overlaps that fix a transform well have far more.
ROBUST = AlignmentConfig(
    name="robust", descriptor_threshold=0.8, ratio=0.8, pair_tolerance=3.0, min_pair_separation=0.5,
    support_threshold=1.0, min_supports=15, iterations=2000, adaptive=True, confidence=0.9999,
    covariance_gating=True, refine=True, significance=1e-6, min_spread=0.3,
)
PRESETS: dict[str, AlignmentConfig] = {"paper": PAPER, "robust": ROBUST}


@dataclass(frozen=True)
class AlignmentStatistics:
    """How the alignment was reached (all counts refer to the putative correspondences)."""

    correspondences: int = 0             # putative descriptor correspondences
    iterations: int = 0                  # hypotheses evaluated
    supports: int = 0
    inlier_ratio: float = 0.0            # supports / correspondences
    residual_rms: float = float("nan")   # metres, 3-D, over the supports
    expected_chance_supports: float = float("nan")  # what a wrong transform would gather
    log10_chance_probability: float = float("nan")  # Bonferroni-corrected, log10
    support_spread: float = 0.0          # metres, principal std of the supports in map 1 (xy)

    def to_dict(self) -> dict:
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in asdict(self).items()}


@dataclass(frozen=True)
class Alignment:
    """Result of aligning map 2 to map 1.

    found: whether the maps overlap (if False, ``pose`` and ``covariance`` are None, ``reason`` says why and
    ``supports`` holds the best rejected hypothesis' supports, for diagnostics);
    pose (3,) (tx, ty, θ) of map 2's frame in map 1's frame; covariance (3, 3) or None (paper preset);
    supports (S, 2) int64 rows (landmark index in map 1, landmark index in map 2).
    """

    found: bool
    preset: str
    pose: np.ndarray | None
    covariance: np.ndarray | None
    supports: np.ndarray
    statistics: AlignmentStatistics = field(default_factory=AlignmentStatistics)
    reason: str = ""

    @classmethod
    def from_pose(cls, pose, covariance=None, supports=None, preset: str = "given") -> Alignment:
        """An alignment known from elsewhere (e.g. calibrated start poses); supports (S, 2) optional."""
        sup = np.zeros((0, 2), np.int64) if supports is None else np.asarray(supports, np.int64).reshape(-1, 2)
        cov = None if covariance is None else np.asarray(covariance, float).reshape(3, 3)
        return cls(True, preset, np.asarray(pose, float).reshape(3), cov, sup,
                   AlignmentStatistics(supports=len(sup)))

    @property
    def matrix(self) -> np.ndarray:
        """The 4×4 transform of eq. 5 in column-vector form: map-1 point = T @ map-2 point (homogeneous)."""
        return pose_to_matrix(self.require().pose)

    @property
    def tx(self) -> float:
        return float(self.require().pose[0])

    @property
    def ty(self) -> float:
        return float(self.require().pose[1])

    @property
    def theta(self) -> float:
        return float(self.require().pose[2])

    def require(self) -> Alignment:
        """This alignment, or :class:`NoOverlapError` if none was found."""
        if not self.found:
            raise NoOverlapError(f"the maps do not overlap: {self.reason}")
        return self

    def inverse(self) -> Alignment:
        """The alignment of map 1 to map 2 (pose inverted, covariance propagated, support columns swapped)."""
        if not self.found:
            return replace(self, supports=self.supports[:, ::-1].copy())
        cov = self.covariance
        if cov is None:
            pose = inverse(self.pose)
        else:
            pose, cov = inverse_with_covariance(self.pose, cov)
        return replace(self, pose=pose, covariance=cov, supports=self.supports[:, ::-1].copy())

    def to_dict(self) -> dict:
        """JSON-friendly summary (supports as a list of index pairs)."""
        return {
            "found": self.found, "preset": self.preset, "reason": self.reason,
            "pose": None if self.pose is None else [float(v) for v in self.pose],
            "covariance": None if self.covariance is None else self.covariance.tolist(),
            "supports": self.supports.tolist(), "statistics": self.statistics.to_dict(),
        }


# -- ground truth ----------------------------------------------------------------------------------------
def true_relative_pose(map1: LandmarkMap, map2: LandmarkMap) -> np.ndarray | None:
    """between(true start 1, true start 2) from ``metadata["true_start_pose"]``, or None if either lacks it."""
    try:
        start1 = np.asarray(map1.metadata["true_start_pose"], float).reshape(3)
        start2 = np.asarray(map2.metadata["true_start_pose"], float).reshape(3)
    except (KeyError, TypeError, ValueError):
        return None
    return between(start1, start2)


def alignment_error(pose, true_pose) -> np.ndarray:
    """|Δtx|, |Δty|, |Δθ| (θ wrapped) of an estimated (tx, ty, θ) against the truth -> (3,)."""
    d = np.asarray(pose, float) - np.asarray(true_pose, float)
    return np.abs(np.array([d[0], d[1], wrap_angle(d[2])]))


# -- the algorithm -----------------------------------------------------------------------------------------
def _rotations_2d(theta: np.ndarray) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


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
    R = _rotations_2d(theta)
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
class _Problem:
    """Correspondence geometry: positions (K, 3), covariances (K, 3, 3) of both sides, gates (K,)."""

    p1: np.ndarray
    p2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    gate_xy_sq: np.ndarray
    gate_z_sq: np.ndarray
    pair_sigma_sq: np.ndarray


def _problem(map1: LandmarkMap, map2: LandmarkMap, pairs: np.ndarray, config: AlignmentConfig) -> _Problem:
    p1, p2 = map1.positions[pairs[:, 0]], map2.positions[pairs[:, 1]]
    P1, P2 = map1.covariances[pairs[:, 0]], map2.covariances[pairs[:, 1]]
    floor_sq = config.position_floor ** 2
    # rotation-invariant per-landmark variance in the plane (mean of the xy eigenvalues) and along z
    var_xy = 0.5 * (np.trace(P1[:, :2, :2], axis1=1, axis2=2) + np.trace(P2[:, :2, :2], axis1=1, axis2=2))
    var_z = P1[:, 2, 2] + P2[:, 2, 2]
    if config.covariance_gating:
        cap = config.support_threshold ** 2
        gate_xy = np.minimum(CHI2_999[2] * (var_xy + 2 * floor_sq), cap)
        gate_z = np.minimum(CHI2_999[1] * (var_z + 2 * floor_sq), cap)
    else:
        gate_xy = gate_z = np.full(len(pairs), config.support_threshold ** 2)
    return _Problem(p1, p2, P1, P2, gate_xy, gate_z, var_xy + 2 * floor_sq)


def _support_masks(problem: _Problem, poses: np.ndarray, config: AlignmentConfig) -> np.ndarray:
    """(H, K) bool: which correspondences support each hypothesis."""
    c, s = np.cos(poses[:, 2:3]), np.sin(poses[:, 2:3])
    x, y = problem.p2[None, :, 0], problem.p2[None, :, 1]
    rx = problem.p1[None, :, 0] - (c * x - s * y + poses[:, 0:1])
    ry = problem.p1[None, :, 1] - (s * x + c * y + poses[:, 1:2])
    r_xy_sq = rx * rx + ry * ry
    dz_sq = (problem.p1[:, 2] - problem.p2[:, 2]) ** 2
    if config.covariance_gating:
        return (r_xy_sq < problem.gate_xy_sq) & (dz_sq < problem.gate_z_sq)[None, :]
    return r_xy_sq + dz_sq[None, :] < config.support_threshold ** 2


def _pair_check(problem: _Problem, a: np.ndarray, b: np.ndarray, config: AlignmentConfig) -> np.ndarray:
    """The corrected eq. 1: is the landmark-to-landmark distance preserved between the maps?"""
    d1_sq = np.sum((problem.p1[a, :2] - problem.p1[b, :2]) ** 2, axis=1)
    d2_sq = np.sum((problem.p2[a, :2] - problem.p2[b, :2]) ** 2, axis=1)
    if not config.covariance_gating:
        return np.abs(d2_sq - d1_sq) < config.pair_tolerance          # |d'² − d²| < th1 (m²)
    sigma_sq = problem.pair_sigma_sq[a] + problem.pair_sigma_sq[b]
    return np.abs(np.sqrt(d2_sq) - np.sqrt(d1_sq)) < config.pair_tolerance * np.sqrt(sigma_sq)


def _required_iterations(inlier_ratio: float, config: AlignmentConfig) -> int:
    """RANSAC's N = log(1 − confidence) / log(1 − w²) for a two-correspondence sample."""
    w2 = min(max(inlier_ratio, 0.0), 1.0) ** 2
    if w2 >= 1.0:
        return config.min_iterations
    if w2 <= 0.0:
        return config.iterations
    n = np.log(1.0 - config.confidence) / np.log(1.0 - w2)
    return int(np.clip(np.ceil(n), config.min_iterations, config.iterations))


def _ransac(problem: _Problem, pairs: np.ndarray, config: AlignmentConfig, rng: np.random.Generator
            ) -> tuple[np.ndarray | None, np.ndarray, int]:
    """Steps 2–3 repeated: best pose (3,) or None, its support mask (K,), hypotheses evaluated."""
    k = len(pairs)
    best_pose, best_mask, best_count = None, np.zeros(k, bool), -1
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
        ok = (pairs[a, 0] != pairs[b, 0]) & (pairs[a, 1] != pairs[b, 1])
        ok &= _pair_check(problem, a, b, config)
        poses, valid = pair_hypotheses(problem.p1, problem.p2, a, b, config)
        keep = np.flatnonzero(ok & valid)[: min(batch, target - evaluated)]
        if len(keep) == 0:
            continue
        masks = _support_masks(problem, poses[keep], config)
        counts = masks.sum(axis=1)
        evaluated += len(keep)
        h = int(np.argmax(counts))
        if counts[h] > best_count:
            best_pose, best_mask, best_count = poses[keep[h]], masks[h], int(counts[h])
            if config.adaptive:
                target = _required_iterations(best_count / k, config)
    return best_pose, best_mask, evaluated


def refine_pose(p1: np.ndarray, P1: np.ndarray, p2: np.ndarray, P2: np.ndarray, pose, floor: float = 0.02,
                iterations: int = 10) -> tuple[np.ndarray, np.ndarray, float]:
    """Weighted least-squares (tx, ty, θ) from corresponding points by Gauss–Newton.

    Minimises Σ rᵢᵀ Sᵢ⁻¹ rᵢ, rᵢ = p1ᵢ − (R(θ) p2ᵢ + t) in the plane, Sᵢ = P1ᵢ + R P2ᵢ Rᵀ + floor² I (xy blocks).
    p1, p2 (K, 3); P1, P2 (K, 3, 3); pose (3,) the start.  Returns pose (3,), covariance (3, 3) = (Jᵀ W J)⁻¹
    inflated by the reduced χ² when that exceeds 1, and the χ² of the fit.
    """
    pose = np.asarray(pose, float).copy()
    xy1, xy2 = p1[:, :2], p2[:, :2]
    H = np.eye(3)
    chi2 = 0.0
    for _ in range(iterations):
        R = _rotations_2d(pose[2])
        q = xy2 @ R.T                                              # map-2 points rotated into map 1
        r = xy1 - (q + pose[:2])                                   # residuals (K, 2)
        S = P1[:, :2, :2] + R @ P2[:, :2, :2] @ R.T + floor ** 2 * np.eye(2)
        det = S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] * S[:, 1, 0]
        W = np.empty_like(S)                                       # weights S⁻¹ (K, 2, 2), closed form
        W[:, 0, 0], W[:, 1, 1] = S[:, 1, 1] / det, S[:, 0, 0] / det
        W[:, 0, 1], W[:, 1, 0] = -S[:, 0, 1] / det, -S[:, 1, 0] / det
        J = np.zeros((len(q), 2, 3))                               # ∂(R p2 + t)/∂(tx, ty, θ)
        J[:, 0, 0] = J[:, 1, 1] = 1.0
        J[:, 0, 2], J[:, 1, 2] = -q[:, 1], q[:, 0]
        JtW = np.einsum("kji,kjl->kil", J, W)                      # Jᵀ W (K, 3, 2)
        H = np.einsum("kil,klm->im", JtW, J)                       # normal matrix (3, 3)
        g = np.einsum("kil,kl->i", JtW, r)
        chi2 = float(np.einsum("ki,kij,kj->", r, W, r))
        step = np.linalg.solve(H, g)
        pose += step
        pose[2] = wrap_angle(pose[2])
        if np.max(np.abs(step)) < 1e-10:
            break
    cov = np.linalg.inv(H)
    dof = 2 * len(p1) - 3
    if dof > 0:
        cov *= max(1.0, chi2 / dof)
    return pose, 0.5 * (cov + cov.T), chi2


def _mahalanobis_supports(problem: _Problem, pose: np.ndarray, config: AlignmentConfig) -> np.ndarray:
    """(K,) bool: 3-D Mahalanobis gate with the map-2 covariance rotated into map 1, capped by th2."""
    R3 = rot_z(pose[2])
    q = transform_points(pose, problem.p2)
    r = problem.p1 - q
    S = problem.P1 + R3 @ problem.P2 @ R3.T + config.position_floor ** 2 * np.eye(3)
    m_sq = np.einsum("ki,ki->k", r, np.linalg.solve(S, r[..., None])[..., 0])
    return (m_sq < CHI2_999[3]) & (np.einsum("ki,ki->k", r, r) < config.support_threshold ** 2)


def guided_supports(map1: LandmarkMap, map2: LandmarkMap, pose: np.ndarray, config: AlignmentConfig,
                    candidates: int = 4) -> np.ndarray:
    """All supports of a known transform: pairs (K, 2) near in position *and* in descriptor, one-to-one.

    Every map-1 landmark takes, among its ``candidates`` nearest transformed map-2 landmarks within th2
    (a k-d tree on positions) that pass the Mahalanobis gate, the one nearest in descriptor (below th0);
    a map-2 landmark claimed twice goes to the nearer descriptor.
    """
    R3 = rot_z(pose[2])
    x2 = transform_points(pose, map2.positions)
    k = min(candidates, len(map2))
    if k == 0 or len(map1) == 0:
        return np.zeros((0, 2), np.int64)
    dist, j = cKDTree(x2).query(map1.positions, k=k, distance_upper_bound=config.support_threshold)
    i, slot = np.nonzero(np.isfinite(dist.reshape(len(map1), k)))
    j = j.reshape(len(map1), k)[i, slot]
    r = map1.positions[i] - x2[j]
    S = map1.covariances[i] + R3 @ map2.covariances[j] @ R3.T + config.position_floor ** 2 * np.eye(3)
    gate = np.einsum("ki,ki->k", r, np.linalg.solve(S, r[..., None])[..., 0]) < CHI2_999[3]
    d_desc = np.linalg.norm(map1.descriptors[i].astype(np.float32) - map2.descriptors[j], axis=1)
    keep = gate & (d_desc < config.descriptor_threshold)
    i, j, d_desc = i[keep], j[keep], d_desc[keep]
    order = np.argsort(d_desc, kind="stable")
    i, j = i[order], j[order]
    _, first_i = np.unique(i, return_index=True)           # each map-1 landmark: its best candidate
    i, j = i[first_i], j[first_i]
    d_best = d_desc[order][first_i]
    order = np.argsort(d_best, kind="stable")
    _, first_j = np.unique(j[order], return_index=True)    # each map-2 landmark: its best claimant
    pick = np.sort(order[first_j])
    return np.column_stack([i[pick], j[pick]]).astype(np.int64)


def _chance_rate(map1: LandmarkMap, map2: LandmarkMap, pose: np.ndarray, radius_xy: float, radius_z: float,
                 rng: np.random.Generator) -> float:
    """Fraction of all (map-1, map-2) landmark pairs that fall inside the support gate at ``pose``.

    This is the probability that a correspondence made by chance supports the transform.  Measured on the
    maps themselves (landmarks crowd along walls, so a uniform-area model would be optimistic); the
    gate's cylinder is replaced by its circumscribed ball in z-scaled space (conservative, ≤ 1.9×).
    """
    sample = rng.choice(len(map2), min(len(map2), 500), replace=False)
    scale = np.array([1.0, 1.0, radius_xy / max(radius_z, 1e-9)])
    q = transform_points(pose, map2.positions[sample])
    tree = cKDTree(map1.positions * scale)
    inside = np.sum(tree.query_ball_point(q * scale, r=np.sqrt(2.0) * radius_xy, return_length=True))
    return float(inside) / (len(sample) * len(map1))


def _spread(xy: np.ndarray) -> float:
    """Principal standard deviation (m) of points xy (S, 2)."""
    if len(xy) < 2:
        return 0.0
    return float(np.sqrt(max(np.linalg.eigvalsh(np.cov(xy.T))[-1], 0.0)))


def _resolve(preset: str | AlignmentConfig) -> AlignmentConfig:
    if isinstance(preset, AlignmentConfig):
        return preset
    try:
        return PRESETS[preset]
    except KeyError:
        raise IncompatibleMapsError(f"unknown alignment preset {preset!r} (choose from {sorted(PRESETS)})") from None


def align(map1: LandmarkMap, map2: LandmarkMap, preset: str | AlignmentConfig = "robust",
          rng: np.random.Generator | None = None) -> Alignment:
    """Align map 2 to map 1 (RANSAC, see the module docstring); never raises for non-overlapping maps.

    Returns an :class:`Alignment` whose ``found`` says whether the maps overlap.  Deterministic given the
    ``rng`` (None -> ``np.random.default_rng(0)``).  Raises :class:`IncompatibleMapsError` when the
    descriptor sizes differ or the preset is unknown.
    """
    config = _resolve(preset)
    rng = np.random.default_rng(0) if rng is None else rng
    if map1.descriptor_size != map2.descriptor_size and len(map1) and len(map2):
        raise IncompatibleMapsError(f"descriptor sizes differ: {map1.descriptor_size} (map 1 of {map1.robot}) "
                                    f"vs {map2.descriptor_size} (map 2 of {map2.robot})")
    empty = np.zeros((0, 2), np.int64)

    def not_found(reason: str, stats: AlignmentStatistics, supports=empty) -> Alignment:
        return Alignment(False, config.name, None, None, supports, stats, reason)

    # step 1: putative correspondences from descriptors
    # (very large maps: a random subset of map 1 searches; see matching.query_subset)
    rows = query_subset(len(map1), len(map2), rng)
    desc1 = map1.descriptors if rows is None else map1.descriptors[rows]
    if config.ratio is None:
        pairs, _ = nearest_correspondences(desc1, map2.descriptors, config.descriptor_threshold)
    else:
        pairs, _ = distinctive_correspondences(desc1, map2.descriptors, config.descriptor_threshold, config.ratio)
    if rows is not None:
        pairs[:, 0] = rows[pairs[:, 0]]
    k = len(pairs)
    if k < max(2, config.min_supports):
        return not_found(f"only {k} descriptor correspondences (at least {max(2, config.min_supports)} needed)",
                         AlignmentStatistics(correspondences=k))
    problem = _problem(map1, map2, pairs, config)

    # steps 2–3, repeated: hypotheses from pairs of correspondences, scored by their supports
    pose, mask, iterations = _ransac(problem, pairs, config, rng)
    if pose is None:
        return not_found("no pair of correspondences keeps its distance between the maps",
                         AlignmentStatistics(correspondences=k, iterations=iterations))
    covariance = None
    if config.refine and mask.sum() >= 2:
        for _ in range(4):
            try:
                pose, covariance, _ = refine_pose(problem.p1[mask], problem.P1[mask], problem.p2[mask],
                                                  problem.P2[mask], pose, config.position_floor)
            except np.linalg.LinAlgError:        # supports all in one spot: the spread check rejects them
                break
            new_mask = _mahalanobis_supports(problem, pose, config)
            if new_mask.sum() < 2 or np.array_equal(new_mask, mask):
                break
            mask = new_mask
    supports = pairs[mask]
    s = len(supports)
    residual = problem.p1[mask] - transform_points(pose, problem.p2[mask])
    rms = float(np.sqrt(np.mean(np.sum(residual ** 2, axis=1)))) if s else float("nan")

    # would a wrong transform gather that many supports by chance?
    radius_xy = float(np.sqrt(np.median(problem.gate_xy_sq)))
    radius_z = float(np.sqrt(np.median(problem.gate_z_sq)))
    p_chance = _chance_rate(map1, map2, pose, radius_xy, radius_z, rng)
    trials = k - 2                                               # the sampled pair supports itself
    # P(X ≥ s − 2) for X ~ Binomial(trials, p) = bdtrc(s − 3, ...); underflow is floored at 1e-300
    tail = float(bdtrc(s - 3, trials, min(max(p_chance, 1e-12), 1.0))) if s >= 3 else 1.0
    log10_p = float(np.log10(max(tail, 1e-300)) + np.log10(max(iterations, 1)))
    if rows is not None and config.refine and s >= 2:
        # the subset fixed the transform; now every landmark's support, by guided matching
        guided = guided_supports(map1, map2, pose, config)
        if len(guided) >= max(s, 3):
            g_problem = _problem(map1, map2, guided, config)
            pose, covariance, _ = refine_pose(g_problem.p1, g_problem.P1, g_problem.p2, g_problem.P2, pose,
                                              config.position_floor)
            supports, problem, mask = guided, g_problem, np.ones(len(guided), bool)
            residual = problem.p1 - transform_points(pose, problem.p2)
            rms = float(np.sqrt(np.mean(np.sum(residual ** 2, axis=1))))
    s_all = len(supports)
    spread = _spread(problem.p1[mask, :2])
    stats = AlignmentStatistics(k, iterations, s_all, s / k, rms, 2.0 + trials * p_chance, min(log10_p, 0.0),
                                spread)

    if s_all < config.min_supports:
        return not_found(f"only {s_all} supports (at least {config.min_supports} needed)", stats, supports)
    if config.significance is not None and log10_p > np.log10(config.significance):
        return not_found(f"{s} supports are explainable by chance (probability 10^{log10_p:.1f}, expected "
                         f"{stats.expected_chance_supports:.1f} chance supports)", stats, supports)
    if spread < config.min_spread:
        return not_found(f"the {s_all} supports are bunched within {spread:.2f} m (at least {config.min_spread} m "
                         f"spread needed to fix the angle)", stats, supports)
    return Alignment(True, config.name, pose, covariance, supports, stats, "")
