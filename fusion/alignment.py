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
* Maps whose landmarks carry external identities (``metadata["external_ids"]``: barcodes, fiducials, as
  known-ID FastSLAM writes them) pair equal identities in step 1; a duplicated identity gives several
  candidate pairs, and supports count one-to-one.
* Maps without descriptors (range-bearing landmark maps built without IDs): step 1 has nothing to compare,
  so every landmark of map 1 is a candidate for every landmark of map 2 (n1·n2 candidate pairs), and a
  support counts once per landmark (one-to-one), whatever the preset.

The ``robust`` preset further adapts the iteration count to the inlier ratio, refines the winning
hypothesis by weighted least squares (Gauss–Newton) on all supports, re-gates them, and reports the
alignment's 3×3 covariance.  Its support gate is the two landmarks' combined covariance, floored at
``min_gate`` and inflated by the supports' own residual scale (``gate_inflation``: the median normalised
squared residual over its χ²₂ median), because FastSLAM's per-particle landmark covariances leave the
robot's pose error out and can be ten times too small; with honest start-frame covariances, whose shared drift the
transform removes, the same scale narrows it (``gate_scale="residual"``, :mod:`fusion.gate_scale`).  It decides
that the maps overlap only on the alignment's own evidence (:func:`evidence`): the supports beyond the two that
define a hypothesis are compared with the number a wrong transform gathers by chance on *these* maps — measured
by scoring decoy transforms with the same gate (landmark density, clustering along walls, map sizes) and by the best
hypothesis distinct from the winner (repeated structure: a corridor of identical doors) — giving a
false-alarm probability, Bonferroni-corrected for the hypotheses tried; the supports must also be spread
out (a bunch in one spot fixes no angle).  The number of supports needed therefore adapts to the maps.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np
from scipy.sparse import csr_matrix
from scipy.special import gammaincinv, pdtrc

from estimation.geometry import between, inverse, pose_to_matrix, transform_points, wrap_angle
from estimation.landmark_map import LandmarkMap

from .cache import content_rng
from .colocation import colocation_test
from .errors import IncompatibleMapsError, NoOverlapError
from .frame_covariance import start_frame_covariance
from .gate_scale import residual_gate_scale, settled_scale
from .matching import distinctive_correspondences, nearest_correspondences, query_subset, self_correspondences
from .pose_covariance import inverse_with_covariance

if TYPE_CHECKING:
    from .cache import AlignmentCache
    from .prior import StartPrior

# χ² quantiles at 0.999 for 1, 2 and 3 degrees of freedom (gates that keep 99.9 % of true supports).
CHI2_999 = {1: 10.828, 2: 13.816, 3: 16.266}
CHI2_2_MEDIAN = 2.0 * np.log(2.0)        # median of χ²₂: scale of the normalised residuals
# Without descriptors every landmark pair is a candidate; beyond this many the search is not attempted.
MAX_GEOMETRIC_PAIRS = 40_000
# Descriptor distances computed at most when a map is matched against itself (self_structure).
SELF_SEARCH_PAIRS = 20_000_000
SELF_REPEAT_GATES = ("own", "pair")      # AlignmentConfig.self_repeat_gate


@dataclass(frozen=True)
class AlignmentConfig:
    """Parameters of the RANSAC alignment.  ``paper`` and ``robust`` are the two presets."""

    name: str
    descriptor_threshold: float          # th0: largest accepted descriptor distance
    ratio: float | None                  # Lowe ratio test + mutual matches; None = the paper's nearest match
    pair_tolerance: float                # paper: th1 on |d'² − d²| (m²); robust: in σ of |d' − d|
    min_pair_separation: float           # metres; shorter pairs fix no angle
    support_threshold: float             # th2, metres (Euclidean 3-D; robust: largest gate radius)
    min_supports: int                    # `min` (paper: the decision; robust: a floor, the evidence decides)
    iterations: int                      # M (paper) or the cap of the adaptive count (robust)
    adaptive: bool = False               # iteration count from the inlier ratio and `confidence`
    confidence: float = 0.999
    min_iterations: int = 32
    covariance_gating: bool = False      # gates from the landmark covariances instead of th2
    refine: bool = False                 # weighted least squares on all supports + covariance
    significance: float | None = None    # largest accepted false-alarm probability of the supports
    min_spread: float = 0.0              # metres, principal standard deviation of the supports (xy)
    position_floor: float = 0.02         # metres, added in quadrature to every landmark's std
    min_gate: float = 0.0                # metres, smallest support-gate radius in the plane
    inflate_gate: bool = False           # scale the gate by the supports' own residuals (see module doc)
    decoys: int = 1000                   # decoy transforms scored to measure the chance supports
    gate_scale: str = "inflate"          # "residual": the supports' residuals may also narrow it (fusion.gate_scale)
    # where a map's repeat of itself is counted: "own", in the gate its own covariances give (capped at
    # support_threshold); "pair", in the pair's final gate scale, as the decoys and the rival are (see self_structure)
    self_repeat_gate: str = "own"
    # two robots cannot be in one place at one time (fusion/colocation.py, session 12; option, off): an alignment that
    # puts the robots' bodies together at a common time is not found, and a rival that does is no rival
    colocation: bool = False

    def to_dict(self) -> dict:
        return asdict(self)


PAPER = AlignmentConfig(
    name="paper", descriptor_threshold=2.0, ratio=None, pair_tolerance=2.0, min_pair_separation=0.0,
    support_threshold=0.2, min_supports=20, iterations=70,
)
# min_supports 4: two supports define a hypothesis, two more are the least that can check it; above that
# the false-alarm probability decides (10⁻⁶, Bonferroni-corrected).  min_gate 0.3 m: a landmark's position
# in its robot's start frame is rarely better than a few decimetres once the robot's pose error is counted,
# which FastSLAM's per-particle covariances leave out (MRCLAM: 4–7 mm claimed, 0.04–0.27 m real).  gate_scale
# "residual": honest start-frame covariances hold drift the transform removes, so the supports' residuals may also
# narrow the gate to that floor (fusion/gate_scale.py; docs/fusion.md "Session 8: the alignment's gate").
ROBUST = AlignmentConfig(
    name="robust", descriptor_threshold=0.8, ratio=0.8, pair_tolerance=3.0, min_pair_separation=0.5,
    support_threshold=1.0, min_supports=4, iterations=2000, adaptive=True, confidence=0.9999,
    covariance_gating=True, refine=True, significance=1e-6, min_spread=0.3, min_gate=0.3, inflate_gate=True,
    gate_scale="residual", self_repeat_gate="pair",
)
PRESETS: dict[str, AlignmentConfig] = {"paper": PAPER, "robust": ROBUST}


@dataclass(frozen=True)
class AlignmentStatistics:
    """How the alignment was reached and how much it can be trusted (counts refer to the putative
    correspondences; supports are one-to-one)."""

    correspondences: int = 0             # putative correspondences (n1·n2 without descriptors)
    iterations: int = 0                  # hypotheses evaluated
    supports: int = 0
    inlier_ratio: float = 0.0            # supports / correspondences
    residual_rms: float = float("nan")   # metres, 3-D, over the supports
    expected_chance_supports: float = float("nan")  # supports a wrong hypothesis gathers (its 2 included)
    log10_chance_probability: float = float("nan")  # log10 false-alarm probability (Bonferroni-corrected)
    support_spread: float = 0.0          # metres, principal std of the supports in map 1 (xy), major axis
    support_spread_minor: float = 0.0    # metres, minor axis (≈ 0: the supports lie on a line)
    second_best_supports: int = 0        # best hypothesis distinct from the winner (repeated structure)
    self_repeat_supports: int = 0        # best non-identity transform of either map onto itself (self_structure)
    required_supports: int = 0           # fewest supports that would have been accepted on these maps
    # the second-best hypothesis against the winner: |Δθ| (rad), the RMS distance (m) by which it moves the winner's
    # supports, and the median descriptor distance of each one's supports (nan: none, or maps not matched by
    # descriptors) -- what a user needs to see why a pair is ambiguous
    second_best_turn: float = float("nan")
    second_best_shift: float = float("nan")
    support_descriptor_distance: float = float("nan")
    second_best_descriptor_distance: float = float("nan")
    gate_inflation: float = 1.0          # covariance scale the supports' residuals called for
    gate_radius: float = float("nan")    # metres, median support-gate radius in the plane
    descriptors: bool = True             # False: maps without descriptors, geometry alone
    second_best_pose: tuple = ()         # (tx, ty, θ) of the second-best hypothesis (empty: none)
    # with a start prior (fusion.prior): the winner's χ² against it, the hypotheses tried inside it (the Bonferroni
    # factor), and the supports of the best hypothesis outside it (not a rival; nan / 0 without a prior)
    prior_chi2: float = float("nan")
    prior_hypotheses: int = 0
    outside_prior_supports: int = 0
    # with AlignmentConfig.colocation (fusion.colocation): what the test did or why there was none ('' when off), and
    # the supports of the best distinct hypothesis it removed (0: none)
    colocation: str = ""
    colocation_removed_supports: int = 0

    @property
    def false_alarm_probability(self) -> float:
        """Probability that maps which do not overlap give this much support (nan if not evaluated)."""
        return float(10.0 ** self.log10_chance_probability) if np.isfinite(self.log10_chance_probability) \
            else float("nan")

    def to_dict(self) -> dict:
        out = {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in asdict(self).items()}
        p = self.false_alarm_probability
        out["false_alarm_probability"] = None if not np.isfinite(p) else p
        return out


@dataclass(frozen=True)
class Alignment:
    """Result of aligning map 2 to map 1.

    found: whether the maps overlap (if False, ``pose`` and ``covariance`` are None, ``reason`` says why and
    ``supports`` holds the best rejected hypothesis' supports, for diagnostics);
    pose (3,) (tx, ty, θ) of map 2's frame in map 1's frame; covariance (3, 3) or None (paper preset): the
    alignment's own precision (placing one map on the other; what merging adds to map 2's landmarks);
    start_covariance (3, 3) or None: its uncertainty against the true relative pose of the two start frames,
    each map's landmark errors taken as possibly moving together at the overlap (``frame_covariance``);
    supports (S, 2) int64 rows (landmark index in map 1, landmark index in map 2).
    """

    found: bool
    preset: str
    pose: np.ndarray | None
    covariance: np.ndarray | None
    supports: np.ndarray
    statistics: AlignmentStatistics = field(default_factory=AlignmentStatistics)
    reason: str = ""
    start_covariance: np.ndarray | None = None
    prior: StartPrior | None = None      # the start prior the decision used (fusion.prior), or None

    @classmethod
    def from_pose(cls, pose, covariance=None, supports=None, preset: str = "given") -> Alignment:
        """An alignment known from elsewhere (e.g. calibrated start poses); supports (S, 2) optional."""
        sup = np.zeros((0, 2), np.int64) if supports is None else np.asarray(supports, np.int64).reshape(-1, 2)
        cov = None if covariance is None else np.asarray(covariance, float).reshape(3, 3)
        return cls(True, preset, np.asarray(pose, float).reshape(3), cov, sup,
                   AlignmentStatistics(supports=len(sup)), start_covariance=cov)

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
            return replace(self, supports=self.supports[:, ::-1].copy(),
                           prior=None if self.prior is None else self.prior.inverse())
        cov, start_cov = self.covariance, self.start_covariance
        pose = inverse(self.pose)
        if cov is not None:
            cov = inverse_with_covariance(self.pose, cov)[1]
        if start_cov is not None:
            start_cov = inverse_with_covariance(self.pose, start_cov)[1]
        return replace(self, pose=pose, covariance=cov, start_covariance=start_cov,
                       supports=self.supports[:, ::-1].copy(),
                       prior=None if self.prior is None else self.prior.inverse())

    def to_dict(self) -> dict:
        """JSON-friendly summary (supports as a list of index pairs)."""
        return {
            "found": self.found, "preset": self.preset, "reason": self.reason,
            "pose": None if self.pose is None else [float(v) for v in self.pose],
            "covariance": None if self.covariance is None else self.covariance.tolist(),
            "start_covariance": None if self.start_covariance is None else self.start_covariance.tolist(),
            "supports": self.supports.tolist(), "statistics": self.statistics.to_dict(),
            "prior": None if self.prior is None else self.prior.to_dict(),
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


def alignment_error_xy_theta(pose, true_pose) -> tuple[float, float]:
    """(error xy (m), error θ (rad)): the translation error's length and |Δθ| wrapped, the demo's columns."""
    e = alignment_error(pose, true_pose)
    return float(np.hypot(e[0], e[1])), float(e[2])


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

    def __post_init__(self) -> None:
        k = len(self.i)
        # mutual matches are one-to-one already: a plain count is the one-to-one count
        self._unique = len(np.unique(self.i)) == k and len(np.unique(self.j)) == k
        self._inc1 = self._inc2 = None
        if not self._unique:
            ones = np.ones(k, np.float32)
            self._inc1 = csr_matrix((ones, (self.i, np.arange(k))), shape=(int(self.i.max()) + 1, k))
            self._inc2 = csr_matrix((ones, (self.j, np.arange(k))), shape=(int(self.j.max()) + 1, k))
        self._set_gates()

    def _set_gates(self) -> None:
        c = self.config
        if c.covariance_gating:
            lo, hi = c.min_gate ** 2, c.support_threshold ** 2
            self.gate_xy_sq = np.clip(CHI2_999[2] * self.inflation * self.var_xy, lo, hi)
            self.gate_z_sq = np.clip(CHI2_999[1] * self.inflation * self.var_z, lo, hi)
        else:
            self.gate_xy_sq = self.gate_z_sq = np.full(len(self.i), c.support_threshold ** 2)

    def inflated(self, inflation: float) -> _Problem:
        """The same correspondences with the gate scaled by ``inflation`` (covariance scale, ≥ 1)."""
        return replace(self, inflation=float(inflation))

    @property
    def gate_radius(self) -> float:
        return float(np.sqrt(np.median(self.gate_xy_sq))) if len(self.i) else float("nan")

    def masks(self, poses: np.ndarray) -> np.ndarray:
        """(H, K) bool: which correspondences support each hypothesis poses (H, 3)."""
        c, s = np.cos(poses[:, 2:3]), np.sin(poses[:, 2:3])
        x, y = self.p2[None, :, 0], self.p2[None, :, 1]
        rx = self.p1[None, :, 0] - (c * x - s * y + poses[:, 0:1])
        ry = self.p1[None, :, 1] - (s * x + c * y + poses[:, 1:2])
        r_xy_sq = rx * rx + ry * ry
        dz_sq = (self.p1[:, 2] - self.p2[:, 2]) ** 2
        if self.config.covariance_gating:
            return (r_xy_sq < self.gate_xy_sq) & (dz_sq < self.gate_z_sq)[None, :]
        return r_xy_sq + dz_sq[None, :] < self.config.support_threshold ** 2

    def distinct_counts(self, masks: np.ndarray) -> np.ndarray:
        """(H,) one-to-one support counts: min(distinct map-1 landmarks, distinct map-2 landmarks) per row."""
        if masks.shape[1] == 0:
            return np.zeros(len(masks), np.int64)
        if self._unique:
            return masks.sum(axis=1)
        m = masks.T.astype(np.float32)
        n1 = np.count_nonzero(self._inc1 @ m, axis=0)
        n2 = np.count_nonzero(self._inc2 @ m, axis=0)
        return np.minimum(n1, n2).astype(np.int64)

    def counts(self, masks: np.ndarray) -> np.ndarray:
        return self.distinct_counts(masks) if self.distinct_scoring else masks.sum(axis=1)

    def one_to_one(self, mask: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """The supports of ``mask`` (K,) with each landmark used once, nearest in position first."""
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


def _problem(map1: LandmarkMap, map2: LandmarkMap, pairs: np.ndarray, config: AlignmentConfig,
             distinct_scoring: bool) -> _Problem:
    i, j = pairs[:, 0], pairs[:, 1]
    P1, P2 = map1.covariances[i], map2.covariances[j]
    floor_sq = config.position_floor ** 2
    # rotation-invariant per-axis variance of the difference in the plane (mean of the xy eigenvalues), and z
    var_xy = 0.5 * (np.trace(P1[:, :2, :2], axis1=1, axis2=2) + np.trace(P2[:, :2, :2], axis1=1, axis2=2))
    var_z = P1[:, 2, 2] + P2[:, 2, 2]
    return _Problem(map1.positions[i], map2.positions[j], P1, P2, i, j, var_xy + 2 * floor_sq,
                    var_z + 2 * floor_sq, config, distinct_scoring)


def _pair_check(problem: _Problem, a: np.ndarray, b: np.ndarray, config: AlignmentConfig) -> np.ndarray:
    """The corrected eq. 1: is the landmark-to-landmark distance preserved between the maps?"""
    d1_sq = np.sum((problem.p1[a, :2] - problem.p1[b, :2]) ** 2, axis=1)
    d2_sq = np.sum((problem.p2[a, :2] - problem.p2[b, :2]) ** 2, axis=1)
    if not config.covariance_gating:
        return np.abs(d2_sq - d1_sq) < config.pair_tolerance          # |d'² − d²| < th1 (m²)
    # the gate's own scale (min_gate, inflation) bounds how well a distance can be preserved
    sigma_sq = (problem.gate_xy_sq[a] + problem.gate_xy_sq[b]) / CHI2_999[2]
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


@dataclass
class _Search:
    """What RANSAC tried: the best pose (3,) or None, its support mask (K,), and every hypothesis
    evaluated with its support count (poses (E, 3), counts (E,))."""

    pose: np.ndarray | None
    mask: np.ndarray
    poses: np.ndarray
    counts: np.ndarray

    @property
    def evaluated(self) -> int:
        return len(self.counts)


def _ransac(problem: _Problem, config: AlignmentConfig, rng: np.random.Generator) -> _Search:
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
        ok &= _pair_check(problem, a, b, config)
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
                target = _required_iterations(best_count / k, config)
    poses = np.concatenate(tried_poses) if tried_poses else np.zeros((0, 3))
    counts = np.concatenate(tried_counts) if tried_counts else np.zeros(0, np.int64)
    return _Search(best_pose, best_mask, poses, counts)


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


def _residual_inflation(problem: _Problem, mask: np.ndarray, pose: np.ndarray, rule: str = "inflate") -> float:
    """Covariance scale the supports' residuals call for: median(|r_xy|² / var_xy) over the median of χ²₂,
    at least 1 unless ``rule`` (the polishing config's ``gate_scale``) is "residual" (:mod:`fusion.gate_scale`)."""
    idx = np.flatnonzero(mask)
    if len(idx) < 3:
        return problem.inflation
    r = problem.p1[idx, :2] - transform_points(pose, problem.p2[idx])[:, :2]
    return residual_gate_scale(r, problem.var_xy[idx], rule)


def _polish(problem: _Problem, pose: np.ndarray, mask: np.ndarray, config: AlignmentConfig, rounds: int = 6
            ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, _Problem]:
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
            kappa = _residual_inflation(problem, mask, pose, config.gate_scale)
            problem = problem.inflated(settled_scale(kappa, problem.inflation, step, config.gate_scale))
        new_mask = problem.one_to_one(problem.masks(pose[None])[0], pose)
        if new_mask.sum() < 2 or np.array_equal(new_mask, mask):
            break
        mask = new_mask
    else:
        if config.gate_scale == "residual":  # not settled: report the fit of the supports reported
            pose, covariance = _refit(problem, mask, pose, covariance, config)
    return pose, covariance, mask, problem


def _refit(problem: _Problem, mask: np.ndarray, pose: np.ndarray, covariance, config: AlignmentConfig):
    try:
        return refine_pose(problem.p1[mask], problem.P1[mask], problem.p2[mask], problem.P2[mask], pose,
                           config.position_floor)[:2]
    except np.linalg.LinAlgError:
        return pose, covariance


# -- the evidence --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Evidence:
    """How much a hypothesis with ``supports`` one-to-one supports can be trusted on these maps.

    chance_decoys: mean supports beyond its anchor that a decoy transform gathers (the chance rate);
    second_best: supports of the best hypothesis distinct from the winner (0 if none);
    chance_rate: the Poisson rate λ of chance supports beyond the two that define a hypothesis;
    hypotheses: how many were tried (the Bonferroni factor); log10_p: log10 of the false-alarm
    probability N · P(Poisson(λ) ≥ supports − 2); required: the fewest supports with p below ``significance``.
    """

    supports: int
    chance_decoys: float
    second_best: int
    chance_rate: float
    hypotheses: int
    log10_p: float
    required: int
    ambiguous: bool                       # the second-best hypothesis, not the decoys, set the chance rate
    self_repeat: int = 0                  # supports of the best repeat of either map onto itself (self_structure)
    rival_pose: np.ndarray | None = None  # (3,) the second-best hypothesis' pose, None if there is none
    rival_mask: np.ndarray | None = None  # (K,) its supports among the correspondences
    outside: int = 0                      # with a start prior: supports of the best distinct hypothesis outside it
    impossible: int = 0                   # with a co-location test: supports of the best distinct hypothesis it removed


def _log10_tail(excess: int, rate: float, hypotheses: int) -> float:
    """log10 min(1, N · P(Poisson(rate) ≥ excess))."""
    if excess <= 0:
        return 0.0
    tail = float(pdtrc(excess - 1, max(rate, 1e-12)))
    return min(0.0, float(np.log10(max(tail, 1e-300)) + np.log10(max(hypotheses, 1))))


def _rate_for_maximum(excess: int, hypotheses: int) -> float:
    """The Poisson rate at which the best of N wrong hypotheses reaches ``excess`` supports half the time:
    a null calibrated on the maps' own repeated structure."""
    if excess <= 0:
        return 0.0
    lo, hi = -12.0, 3.0                         # log10 λ
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if hypotheses * pdtrc(excess - 1, 10.0 ** mid) < 0.5:
            lo = mid
        else:
            hi = mid
    return 10.0 ** hi


def decoy_chance_supports(problem: _Problem, map1: LandmarkMap, map2: LandmarkMap, decoys: int,
                          rng: np.random.Generator) -> float:
    """Chance supports a wrong transform gathers beyond its anchor, scored with the same gates: the 95 %
    upper bound of their mean over the decoys.

    Each decoy puts a random map-2 landmark on a random map-1 landmark at a random angle (so the maps
    overlap as a RANSAC hypothesis makes them), then counts the correspondences inside the gate — the
    maps' density, their clustering along walls and their sizes all enter.
    """
    k = len(problem.i)
    if decoys <= 0 or k == 0 or len(map1) == 0 or len(map2) == 0:
        return 0.0
    theta = rng.uniform(-np.pi, np.pi, decoys)
    a = rng.integers(len(map1), size=decoys)
    b = rng.integers(len(map2), size=decoys)
    R = _rotations_2d(theta)
    t = map1.positions[a, :2] - np.einsum("hij,hj->hi", R, map2.positions[b, :2])
    poses = np.column_stack([t, theta])
    # the anchor itself supports a decoy only when (a, b) is a correspondence
    n2 = max(len(map2), int(problem.j.max()) + 1)
    keys = problem.i * n2 + problem.j
    order = np.argsort(keys)
    anchor = a * n2 + b
    pos = np.clip(np.searchsorted(keys[order], anchor), 0, k - 1)
    anchor_row = np.where(keys[order][pos] == anchor, order[pos], -1)
    total = 0.0
    batch = max(1, 4_000_000 // max(k, 1))
    for start in range(0, decoys, batch):
        sl = slice(start, start + batch)
        masks = problem.masks(poses[sl])
        counts = problem.distinct_counts(masks).astype(float)
        rows = anchor_row[sl]
        has = rows >= 0
        counts[has] -= masks[np.flatnonzero(has), rows[has]]
        total += counts.sum()
    # 95 % upper confidence bound of a Poisson rate from ``total`` events in ``decoys`` trials: a finite sample
    # of decoys that saw no chance support does not prove the rate is zero
    return float(gammaincinv(total + 1.0, 0.95)) / decoys


@dataclass(frozen=True)
class _Rival:
    """The best hypothesis distinct from the winner: its one-to-one supports (a repeated pair counted once when a
    map is matched against itself), pose (3,) and support mask (K,); None when there is none."""

    supports: int = 0
    pose: np.ndarray | None = None
    mask: np.ndarray | None = None


def _best_distinct(problem: _Problem, search: _Search, pose: np.ndarray, mask: np.ndarray,
                   config: AlignmentConfig, unordered: bool = False, admissible=None) -> _Rival:
    """The best hypothesis clearly distinct from ``pose``: it moves the winner's supports (or, without any, every
    correspondence) by more than two gate radii on average.  The three strongest candidates are re-scored with the
    final gate and polished like the winner.  ``admissible(poses (H, 3)) -> (H,) bool`` (a start prior) keeps only
    the hypotheses it admits, before and after polishing."""
    if search.evaluated == 0:
        return _Rival()
    pts = problem.p2[mask] if mask.sum() >= 2 else problem.p2
    ref = transform_points(pose, pts)[:, :2]
    far = 2.0 * problem.gate_radius

    def distinct(poses: np.ndarray) -> np.ndarray:
        R = _rotations_2d(poses[:, 2])
        moved = np.einsum("hij,kj->hki", R, pts[:, :2]) + poses[:, None, :2]
        return np.sqrt(np.mean(np.sum((moved - ref[None]) ** 2, axis=2), axis=1)) > far

    cand = np.flatnonzero(distinct(search.poses) & (True if admissible is None else admissible(search.poses)))
    if len(cand) == 0:
        return _Rival()
    best = _Rival()
    counts = np.zeros(len(cand), np.int64)
    for start in range(0, len(cand), 256):
        sl = cand[start:start + 256]
        counts[start:start + 256] = problem.distinct_counts(problem.masks(search.poses[sl]))
    # the rival is the null: with the residual rule it is also polished as the inflate rule polishes (the gate never
    # narrowed), and the stronger of the two counts (a rival polished in a narrowed gate can lose its own supports)
    polish_configs = [config] if config.gate_scale == "inflate" else [config, replace(config, gate_scale="inflate")]
    for c in cand[np.argsort(-counts, kind="stable")[:3]]:
        for polish_config in polish_configs:
            p = search.poses[c]
            m = problem.masks(p[None])[0]
            p, _, m, _ = _polish(replace(problem), p, m, polish_config)
            m = problem.one_to_one(problem.masks(p[None])[0], p)     # scored with the winner's gate
            if distinct(p[None])[0] and (admissible is None or admissible(p[None])[0]):
                # a map matched against itself: (i, j) and (j, i) are one repeated pair (a half turn maps both ways)
                n = (len({frozenset(e) for e in zip(problem.i[m], problem.j[m], strict=True)}) if unordered
                     else int(m.sum()))
                if n > best.supports:
                    best = _Rival(n, p, m)
    return best


def _second_best(problem: _Problem, search: _Search, pose: np.ndarray, mask: np.ndarray,
                 config: AlignmentConfig, unordered: bool = False) -> int:
    """Supports of the best hypothesis clearly distinct from ``pose`` (see :func:`_best_distinct`)."""
    return _best_distinct(problem, search, pose, mask, config, unordered).supports


def rival_offset(pose: np.ndarray, rival_pose: np.ndarray, points: np.ndarray) -> tuple[float, float]:
    """How far a rival hypothesis is from the winner: (RMS distance (m) by which it moves ``points`` (S, 2|3), map-2
    positions, against the winner; |Δθ| (rad)).  Frame-independent, unlike the difference of the poses' xy."""
    a = transform_points(pose, points)[:, :2]
    b = transform_points(rival_pose, points)[:, :2]
    shift = float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1)))) if len(points) else float("nan")
    return shift, float(abs(wrap_angle(rival_pose[2] - pose[2])))


def self_structure(landmark_map: LandmarkMap, config: AlignmentConfig, rng: np.random.Generator,
                   inflation: float | None = None) -> int:
    """Supports of the best transform, other than the identity, that maps a map onto *itself* by its descriptors:
    the repeated structure inside one map (a building symmetric under a half turn whose corners look alike, a
    row of identical doors).  If one map repeats itself under T_s, a wrong cross-map alignment T_s ∘ T can
    gather about as many supports as the repeat holds, even when the true overlap T gathers few (a damaged
    map).  0 without descriptors.

    ``inflation`` (a pair's final gate scale, with ``config.self_repeat_gate == "pair"``): the repeat's supports are
    counted in the gate that scale gives, the gate every other count of the decision uses.  Without it they are
    counted in the map's own claimed covariances, which with honest start-frame covariances reach the 1 m cap
    (rendered demo seed 8, robot 2: 23 supports of a 1 m shift, 12 of them 0.44-0.96 m off it; 14 in the pair's
    gate)."""
    n = len(landmark_map)
    if not has_descriptors(landmark_map) or n < 4:
        return 0
    # very large maps: a random subset of queries (a repeat shows in any sizeable sample of the map)
    rows = None if n * n <= SELF_SEARCH_PAIRS else np.sort(rng.choice(n, max(64, SELF_SEARCH_PAIRS // n),
                                                                      replace=False))
    pairs = self_correspondences(landmark_map.descriptors, config.descriptor_threshold, config.ratio or 1.0, rows)
    if len(pairs) < 4:
        return 0
    problem = _problem(landmark_map, landmark_map, pairs, config, distinct_scoring=True)
    # a fixed number of hypotheses: the near-identity ones (duplicates side by side) must not stop the search
    search = _ransac(problem, replace(config, adaptive=False, iterations=min(config.iterations, 500)), rng)
    scored = problem if inflation is None else problem.inflated(inflation)
    return _second_best(scored, search, np.zeros(3), np.zeros(len(pairs), bool), config, unordered=True)


def evidence(problem: _Problem, search: _Search, pose: np.ndarray, mask: np.ndarray, map1: LandmarkMap,
             map2: LandmarkMap, config: AlignmentConfig, rng: np.random.Generator,
             repeats: bool = False, self_repeat=None, admissible=None, possible=None) -> Evidence:
    """The alignment's own evidence (see the module docstring): supports beyond the two that define a
    hypothesis against a Poisson null whose rate is the largest of the decoys', the one that makes the
    second-best distinct hypothesis a typical maximum and (``repeats``: maps matched by descriptors) the one
    that makes either map's repeat of itself (:func:`self_structure`) a typical maximum; Bonferroni over the
    hypotheses tried.  ``self_repeat(map) -> int`` gives a map's self-repeat count (default: :func:`self_structure`
    with a generator seeded by the map's content, so that the count is a property of the map alone); with
    ``config.self_repeat_gate == "pair"`` it is called as ``self_repeat(map, inflation)``, the pair's gate scale.

    ``admissible(poses) -> bool`` (a start prior, :mod:`fusion.prior`): only the hypotheses it admits are rivals and
    count in the Bonferroni factor (a false alarm needs the best hypothesis inside it); the best one outside it is
    reported (``outside``).  Each map's repeat of itself stays in the null whatever the prior: a wrong prior that
    agrees with a wrong winner (the truth damaged, its repeat winning) must not make it "found".

    ``possible(poses) -> bool`` (the co-location test, :mod:`fusion.colocation`) removes hypotheses as the prior does,
    from the rivals and the Bonferroni factor; the best one it removed is reported (``impossible``), not as outside the
    prior."""
    s = int(problem.distinct_counts(mask[None])[0])
    n_all = max(search.evaluated, 1)
    allowed = admissible
    if possible is not None:
        def allowed(poses: np.ndarray) -> np.ndarray:
            return possible(poses) & (True if admissible is None else admissible(poses))
    n = n_all if allowed is None else max(int(allowed(search.poses).sum()), 1)
    decoy_rate = decoy_chance_supports(problem, map1, map2, config.decoys, rng)
    rival = _best_distinct(problem, search, pose, mask, config, admissible=allowed)
    outside = 0 if admissible is None else _best_distinct(
        problem, search, pose, mask, config,
        admissible=lambda poses: ~admissible(poses) & (True if possible is None else possible(poses))).supports
    impossible = 0 if possible is None else _best_distinct(
        problem, search, pose, mask, config, admissible=lambda poses: ~possible(poses)).supports
    second = rival.supports
    if config.self_repeat_gate not in SELF_REPEAT_GATES:
        raise IncompatibleMapsError(f"unknown self_repeat_gate {config.self_repeat_gate!r} (choose from "
                                    f"{', '.join(SELF_REPEAT_GATES)})")
    pair_gate = config.self_repeat_gate == "pair"
    if self_repeat is None:
        def self_repeat(m: LandmarkMap, inflation: float | None = None) -> int:
            return self_structure(m, config, content_rng(m), inflation)
    repeat = 0
    if repeats:
        counts = [self_repeat(m, problem.inflation) if pair_gate else self_repeat(m) for m in (map1, map2)]
        repeat = max(counts)
    # the rival is the best of the n hypotheses inside the prior; the self-repeat was found without one, so its rate is
    # calibrated on all of them (a prior must not make the repeat's null stricter than it is without a prior)
    structure_rate = max(_rate_for_maximum(second - 2, n), _rate_for_maximum(repeat - 2, n_all))
    rate = max(decoy_rate, structure_rate, 1e-9)
    log10_p = _log10_tail(s - 2, rate, n)
    level = np.log10(config.significance) if config.significance is not None else -6.0
    required = max(config.min_supports, 3)
    while _log10_tail(required - 2, rate, n) > level and required < 100_000:
        required += 1
    return Evidence(s, decoy_rate, second, rate, n, log10_p, required, structure_rate > decoy_rate, repeat,
                    rival.pose, rival.mask, outside, impossible)


# -- what an ambiguous pair reports ----------------------------------------------------------------------------
# A rival turned by more than this is reported as a half turn (a building symmetric under a half turn).
HALF_TURN = 2.8
DISAMBIGUATION = ("to tell them apart: more common landmarks outside the repeated part (a longer shared route), "
                  "landmarks with identities (fiducials), or a rough relative start of the robots")


def _median_descriptor_distance(map1: LandmarkMap, map2: LandmarkMap, pairs: np.ndarray) -> float:
    if len(pairs) == 0:
        return float("nan")
    d = map1.descriptors[pairs[:, 0]].astype(np.float32) - map2.descriptors[pairs[:, 1]]
    return float(np.median(np.linalg.norm(d, axis=1)))


def _rival_figures(map1: LandmarkMap, map2: LandmarkMap, pairs: np.ndarray, pose: np.ndarray, mask: np.ndarray,
                   problem: _Problem, ev: Evidence, compare_descriptors: bool) -> dict:
    """The AlignmentStatistics fields that describe the second-best hypothesis against the winner."""
    out = {}
    if ev.rival_pose is not None:
        out["second_best_pose"] = tuple(float(v) for v in ev.rival_pose)
    if ev.rival_pose is not None and mask.any():
        out["second_best_shift"], out["second_best_turn"] = rival_offset(pose, ev.rival_pose, problem.p2[mask])
    if compare_descriptors and map1.descriptor_size:
        out["support_descriptor_distance"] = _median_descriptor_distance(map1, map2, pairs[mask])
        if ev.rival_mask is not None:
            out["second_best_descriptor_distance"] = _median_descriptor_distance(map1, map2, pairs[ev.rival_mask])
    return out


def rival_text(stats: AlignmentStatistics) -> str:
    """The second-best hypothesis in words ('' if none was measured): how far it turns and moves the winner's
    supports, and how closely each one's supports match in appearance."""
    parts = []
    if np.isfinite(stats.second_best_turn):
        half = " (a half turn)" if stats.second_best_turn > HALF_TURN else ""
        parts.append(f"turned {stats.second_best_turn:.2f} rad from the best one{half}, moving its supports "
                     f"{stats.second_best_shift:.1f} m")
    if np.isfinite(stats.second_best_descriptor_distance) and np.isfinite(stats.support_descriptor_distance):
        parts.append(f"median descriptor distance of its supports {stats.second_best_descriptor_distance:.3f}, "
                     f"the best one's {stats.support_descriptor_distance:.3f}")
    return "; ".join(parts)


# -- the entry point -----------------------------------------------------------------------------------------
def guided_supports(map1: LandmarkMap, map2: LandmarkMap, pose: np.ndarray, config: AlignmentConfig,
                    candidates: int = 4) -> np.ndarray:
    """All supports of a known transform: pairs (K, 2) near in position *and* in descriptor, one-to-one.

    Every map-1 landmark takes, among its ``candidates`` nearest transformed map-2 landmarks within th2
    (a k-d tree on positions) that pass the Mahalanobis gate, the one nearest in descriptor (below th0);
    a map-2 landmark claimed twice goes to the nearer descriptor.
    """
    from scipy.spatial import cKDTree

    from estimation.geometry import rot_z

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


def _spread(xy: np.ndarray) -> tuple[float, float]:
    """Principal standard deviations (m) of points xy (S, 2): major, minor axis."""
    if len(xy) < 2:
        return 0.0, 0.0
    ev = np.linalg.eigvalsh(np.cov(xy.T))
    return float(np.sqrt(max(ev[-1], 0.0))), float(np.sqrt(max(ev[0], 0.0)))


def _resolve(preset: str | AlignmentConfig) -> AlignmentConfig:
    if isinstance(preset, AlignmentConfig):
        return preset
    try:
        return PRESETS[preset]
    except KeyError:
        raise IncompatibleMapsError(f"unknown alignment preset {preset!r} (choose from {sorted(PRESETS)})") from None


def has_descriptors(landmark_map: LandmarkMap) -> bool:
    """False when the map's descriptors cannot tell landmarks apart (none, or all the same)."""
    d = landmark_map.descriptors
    if d.shape[1] == 0:
        return False
    return len(d) < 2 or bool(np.any(d != d[0]))


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


def _correspondences(map1: LandmarkMap, map2: LandmarkMap, config: AlignmentConfig, rng: np.random.Generator
                     ) -> tuple[np.ndarray, bool]:
    """Step 1: putative pairs (K, 2), and whether descriptors chose them (False: every pair, geometry alone).

    Maps that both carry external identities (known-ID maps: barcodes, fiducials) pair equal identities."""
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
    else:
        pairs, _ = distinctive_correspondences(desc1, map2.descriptors, config.descriptor_threshold, config.ratio)
    if rows is not None:
        pairs[:, 0] = rows[pairs[:, 0]]
    return pairs, True


def align(map1: LandmarkMap, map2: LandmarkMap, preset: str | AlignmentConfig = "robust",
          rng: np.random.Generator | None = None, cache: AlignmentCache | None = None,
          prior: StartPrior | None = None) -> Alignment:
    """Align map 2 to map 1 (RANSAC, see the module docstring); never raises for non-overlapping maps.

    Returns an :class:`Alignment` whose ``found`` says whether the maps overlap and whose ``statistics``
    carry the evidence (false-alarm probability, chance supports, second-best hypothesis, supports
    required on these maps).  Deterministic given the ``rng`` (None -> ``np.random.default_rng(0)``).
    Raises :class:`IncompatibleMapsError` when the descriptor sizes differ or the preset is unknown.
    ``cache`` (:class:`fusion.cache.AlignmentCache`) supplies each map's self-repeat count computed once per map
    content (use ``cache.align`` to reuse whole alignments of unchanged maps).
    ``prior`` (:class:`fusion.prior.StartPrior`): a rough relative start of the robots; hypotheses outside it are no
    rivals, and a best alignment outside it is "not found: ... contradicts the prior" (the prior removes hypotheses,
    it never adds support; see :mod:`fusion.prior`).
    """
    config = _resolve(preset)
    rng = np.random.default_rng(0) if rng is None else rng
    if map1.descriptor_size != map2.descriptor_size and len(map1) and len(map2):
        raise IncompatibleMapsError(f"descriptor sizes differ: {map1.descriptor_size} (map 1 of {map1.robot}) "
                                    f"vs {map2.descriptor_size} (map 2 of {map2.robot})")
    empty = np.zeros((0, 2), np.int64)

    def not_found(reason: str, stats: AlignmentStatistics, supports=empty) -> Alignment:
        return Alignment(False, config.name, None, None, supports, stats, reason, prior=prior)

    identities = landmark_identities(map1) is not None and landmark_identities(map2) is not None
    with_descriptors = identities or (has_descriptors(map1) and has_descriptors(map2))
    no_desc = "" if with_descriptors else (f"the maps carry no descriptors, so every landmark of one is a candidate "
                                           f"for every landmark of the other ({len(map1)} × {len(map2)} pairs); ")
    if not with_descriptors and len(map1) * len(map2) > MAX_GEOMETRIC_PAIRS:
        return not_found(f"{no_desc}more than {MAX_GEOMETRIC_PAIRS} candidate pairs are too many for a search by "
                         f"geometry alone", AlignmentStatistics(descriptors=False))
    if not with_descriptors and min(len(map1), len(map2)) < config.min_supports:
        return not_found(f"{no_desc}at most {min(len(map1), len(map2))} supports are possible, fewer than the "
                         f"{config.min_supports} this preset needs", AlignmentStatistics(descriptors=False))

    # step 1: putative correspondences (from descriptors, or every pair without them)
    pairs, _ = _correspondences(map1, map2, config, rng)
    subset_search = (not identities and with_descriptors
                     and query_subset(len(map1), len(map2), np.random.default_rng(0)) is not None)
    k = len(pairs)
    needed = max(2, config.min_supports)
    if k < needed:
        what = "identity" if identities else "descriptor"
        return not_found(f"only {k} {what} correspondences (at least {needed} needed)",
                         AlignmentStatistics(correspondences=k, descriptors=with_descriptors))
    problem = _problem(map1, map2, pairs, config, distinct_scoring=not with_descriptors or identities)

    # steps 2–3, repeated: hypotheses from pairs of correspondences, scored by their supports
    search = _ransac(problem, config, rng)
    if search.pose is None:
        return not_found(f"{no_desc}no pair of correspondences keeps its distance between the maps",
                         AlignmentStatistics(correspondences=k, iterations=search.evaluated,
                                             descriptors=with_descriptors))
    raw_count = int(search.mask.sum())
    pose, covariance, mask, problem = _polish(problem, search.pose, search.mask, config)
    inside, prior_chi2 = None, float("nan")
    # the prior and the co-location test are about the true starts: the winner's uncertainty against them widens them
    # (for every hypothesis)
    winner_start = (start_frame_covariance(problem.p1[mask], problem.P1[mask], problem.p2[mask], problem.P2[mask],
                                           pose, config.position_floor)
                    if (prior is not None or config.colocation) and covariance is not None and mask.sum() >= 2
                    else None)
    possible, colocation_note, colocation_failure = None, "", ""
    if config.colocation:
        test, why = colocation_test(map1, map2)
        if test is not None and winner_start is None:
            test, why = None, "the alignment has no covariance to carry to the robots"
        if test is None:
            colocation_note = f"no co-location test: {why}"
        else:
            colocation_note = test.text()
            colocation_failure = test.reason(pose, winner_start)

            def possible(poses: np.ndarray) -> np.ndarray:
                return test.admits(poses, winner_start)
    if prior is not None:
        prior_chi2 = float(prior.chi2(pose, winner_start))
        if prior_chi2 <= prior.bound:

            def inside(poses: np.ndarray) -> np.ndarray:
                return prior.admits(poses, winner_start)
    ev = evidence(problem, search, pose, mask, map1, map2, config, rng,
                  repeats=config.refine and with_descriptors and not identities,
                  self_repeat=None if cache is None else (
                      lambda m, *scale: cache.self_structure(m, config, *scale)),
                  admissible=inside, possible=possible)
    supports = pairs[mask] if (config.refine or not with_descriptors) else pairs[search.mask]
    s = ev.supports
    residual = problem.p1[mask] - transform_points(pose, problem.p2[mask])
    rms = float(np.sqrt(np.mean(np.sum(residual ** 2, axis=1)))) if s else float("nan")
    fit = (problem.p1[mask], problem.P1[mask], problem.p2[mask], problem.P2[mask])
    if subset_search and config.refine and s >= 2:
        # the subset fixed the transform; now every landmark's support, by guided matching
        guided = guided_supports(map1, map2, pose, config)
        if len(guided) >= max(s, 3):
            g_problem = _problem(map1, map2, guided, config, distinct_scoring=False)
            pose, covariance, _ = refine_pose(g_problem.p1, g_problem.P1, g_problem.p2, g_problem.P2, pose,
                                              config.position_floor)
            supports = guided
            residual = g_problem.p1 - transform_points(pose, g_problem.p2)
            rms = float(np.sqrt(np.mean(np.sum(residual ** 2, axis=1))))
            fit = (g_problem.p1, g_problem.P1, g_problem.p2, g_problem.P2)
    major, minor = _spread(problem.p1[mask, :2])
    rival = _rival_figures(map1, map2, pairs, pose, mask, problem, ev, compare_descriptors=with_descriptors
                           and not identities)
    stats = AlignmentStatistics(
        correspondences=k, iterations=search.evaluated, supports=len(supports), inlier_ratio=s / k,
        residual_rms=rms, expected_chance_supports=2.0 + ev.chance_rate, log10_chance_probability=ev.log10_p,
        support_spread=major, support_spread_minor=minor, second_best_supports=ev.second_best,
        self_repeat_supports=ev.self_repeat,
        required_supports=ev.required, gate_inflation=problem.inflation, gate_radius=problem.gate_radius,
        descriptors=with_descriptors, prior_chi2=prior_chi2,
        prior_hypotheses=ev.hypotheses if inside is not None else 0, outside_prior_supports=ev.outside,
        colocation=colocation_note, colocation_removed_supports=ev.impossible, **rival)

    counted = raw_count if not config.refine and with_descriptors else len(supports)
    if counted < config.min_supports:
        return not_found(f"{no_desc}only {counted} supports (at least {config.min_supports} needed)", stats, supports)
    if prior is not None and (inside is None or ev.outside > s):
        return not_found(_contradiction(prior, pose, s, prior_chi2, ev, config, major, inside is None), stats,
                         supports)
    if colocation_failure:
        return not_found(f"the maps' best alignment ({s} supports) contradicts co-location: {colocation_failure}",
                         stats, supports)
    if config.significance is not None and ev.log10_p > np.log10(config.significance):
        if ev.ambiguous and ev.self_repeat > ev.second_best:
            return not_found(
                f"ambiguous: one map repeats itself under a distinct transform with {ev.self_repeat} supports "
                f"(repeated structure), so a wrong alignment could gather as many as the best one's {s}; on these "
                f"maps {ev.required} would be needed (false-alarm probability 10^{ev.log10_p:.1f}); "
                f"{DISAMBIGUATION}", stats, supports)
        if ev.ambiguous:
            what = rival_text(stats)
            return not_found(
                f"ambiguous: a distinct transform gathers {ev.second_best} supports against the best one's {s} "
                f"(repeated structure{': ' + what if what else ''}); on these maps {ev.required} would be needed "
                f"(false-alarm probability 10^{ev.log10_p:.1f}); {DISAMBIGUATION}", stats, supports)
        return not_found(
            f"{no_desc}{s} supports are explainable by chance: a wrong transform gathers "
            f"{stats.expected_chance_supports:.1f} on these maps and the best of {ev.hypotheses} hypotheses more; "
            f"{ev.required} would be needed (false-alarm probability 10^{ev.log10_p:.1f})", stats, supports)
    if major < config.min_spread:
        return not_found(f"the {s} supports are bunched within {major:.2f} m (at least {config.min_spread} m "
                         f"spread needed to fix the angle)", stats, supports)
    start_cov = None
    if covariance is not None and len(fit[0]) >= 2:
        start_cov = start_frame_covariance(*fit, pose, config.position_floor)
    return Alignment(True, config.name, pose, covariance, supports, stats, "", start_cov, prior)


def _contradiction(prior: StartPrior, pose: np.ndarray, s: int, chi2: float, ev: Evidence, config: AlignmentConfig,
                   spread: float, winner_outside: bool) -> str:
    """Why a best alignment that contradicts the start prior is not found: how far, and what the evidence says."""
    if not winner_outside:
        return (f"the maps' best alignment contradicts the prior: a hypothesis outside it gathers {ev.outside} "
                f"supports against the best one inside's {s} ({prior.text()})")
    dxy, dth = prior.offset(pose)
    level = np.log10(config.significance) if config.significance is not None else -6.0
    alone = ("the evidence alone would find it" if ev.log10_p <= level and spread >= config.min_spread
             else f"the evidence alone would not find it either (false-alarm probability 10^{ev.log10_p:.1f}, "
                  f"{ev.required} supports needed)")
    return (f"the maps' best alignment contradicts the prior: {s} supports at tx={pose[0]:+.2f} m ty={pose[1]:+.2f} m "
            f"θ={pose[2]:+.3f} rad, {dxy:.2f} m / {dth:.3f} rad from the prior's mean (χ² {chi2:.1f} > "
            f"{prior.bound:.1f}); {alone}; {prior.text()}")


def align_at(map1: LandmarkMap, map2: LandmarkMap, pose, preset: str | AlignmentConfig = "robust",
             rng: np.random.Generator | None = None) -> Alignment:
    """Map 2 tested at one given transform ``pose`` (3,) (another part's alignment): the correspondences and gates
    of :func:`fusion.align`, the supports of ``pose`` polished as align polishes its winner, and its evidence
    without a search: one hypothesis given from outside, so no Bonferroni factor for hypotheses tried and no rival
    (the other part's alignment already chose among them). Found iff P(Poisson(λ_decoy) ≥ s − 2) is below the
    preset's significance, s ≥ its minimum and the supports spread out, as for align."""
    config = _resolve(preset)
    rng = np.random.default_rng(0) if rng is None else rng
    empty = np.zeros((0, 2), np.int64)
    identities = landmark_identities(map1) is not None and landmark_identities(map2) is not None
    with_descriptors = identities or (has_descriptors(map1) and has_descriptors(map2))
    if not with_descriptors and len(map1) * len(map2) > MAX_GEOMETRIC_PAIRS:
        return Alignment(False, config.name, None, None, empty, AlignmentStatistics(descriptors=False),
                         f"more than {MAX_GEOMETRIC_PAIRS} candidate pairs without descriptors")
    pairs, _ = _correspondences(map1, map2, config, rng)
    if len(pairs) < max(2, config.min_supports):
        return Alignment(False, config.name, None, None, empty, AlignmentStatistics(correspondences=len(pairs)),
                         f"only {len(pairs)} correspondences at the other part's transform")
    problem = _problem(map1, map2, pairs, config, distinct_scoring=not with_descriptors or identities)
    pose = np.asarray(pose, float).copy()
    pose, covariance, mask, problem = _polish(problem, pose, problem.masks(pose[None])[0], config)
    s = int(problem.distinct_counts(mask[None])[0])
    rate = max(decoy_chance_supports(problem, map1, map2, config.decoys, rng), 1e-9)
    log10_p = _log10_tail(s - 2, rate, 1)
    major, minor = _spread(problem.p1[mask, :2])
    residual = problem.p1[mask] - transform_points(pose, problem.p2[mask])
    stats = AlignmentStatistics(
        correspondences=len(pairs), iterations=1, supports=s, inlier_ratio=s / len(pairs),
        residual_rms=float(np.sqrt(np.mean(np.sum(residual ** 2, axis=1)))) if s else float("nan"),
        expected_chance_supports=2.0 + rate, log10_chance_probability=log10_p, support_spread=major,
        support_spread_minor=minor, gate_inflation=problem.inflation, gate_radius=problem.gate_radius,
        descriptors=with_descriptors)
    supports = pairs[mask]
    level = np.log10(config.significance) if config.significance is not None else -6.0
    if s < config.min_supports or log10_p > level or major < config.min_spread or covariance is None:
        return Alignment(False, config.name, None, None, supports, stats,
                         f"at the other part's transform {s} supports, where chance gives {rate:.1f} beyond 2 "
                         f"(false-alarm probability 10^{log10_p:.1f}), spread {major:.2f} m")
    start = start_frame_covariance(problem.p1[mask], problem.P1[mask], problem.p2[mask], problem.P2[mask], pose,
                                   config.position_floor)
    return Alignment(True, config.name, pose, covariance, supports, stats, "", start)
