"""Full-trajectory smoothing of a planar range-bearing landmark log (known associations), after the filter.

FastSLAM estimates online: each particle's landmarks are conditioned on that particle's trajectory, and the
filter keeps a few hundred trajectory hypotheses whose diversity resampling erodes (Bailey, Nieto & Nebot 2006).
Once a log is over, the question "which trajectory and which map explain all of it" has a direct answer: the
maximum a-posteriori estimate of every pose and every landmark together (full SLAM; Thrun & Montemerlo's
GraphSLAM, Dellaert & Kaess's square-root SAM). This module computes it, starting from the filter's best
particle, for logs whose sightings name their landmark (fiducials, barcodes: ``association="id"``).

The problem, in the map's frame (pose 0 is the frame's origin and is held fixed: the gauge):

- odometry factors: between(x_k, x_{k+1}) − δ_k with covariance diag(σ_xy², σ_xy², σ_θ²), the same random-walk
  increment model the filter samples from (``estimation.fastslam.motion.increment_variance``);
- sighting factors: (‖m − t_k‖ − r, atan2(m − t_k) − θ_k − φ) with the sensor's (σ_r, σ_φ), the variances
  inflated for correlated sightings as the filter's are.

Solved by Gauss–Newton with Levenberg damping on the sparse normal equations. Outliers: the sightings are first
weighted by Huber's function (k = 2.45, χ²₂ 70 %), then every sighting whose squared normalised residual exceeds
χ²₂ 99 % is dropped and the problem solved again without weights; the dropped ones are reported. The covariances
are the inverse of the information matrix JᵀJ at the solution (the Laplace approximation), its landmark blocks
and a sample of its pose blocks, from one factorisation that follows the problem's structure (`NormalFactor`).

Option (``sighting_offset``, off by default): a systematic offset per group of sightings (:class:`SightingOffset`:
a post seen from one side, one visit's sightings sharing that error), so that no number of sightings of one group
makes its landmark more certain than the offset's σ.

Option (the problem's ``image_bearing_sigmas``, empty by default): one bearing error shared by all the sightings
taken at one pose (one image), of σ τ_k at pose k: the bearings of an image then have the joint covariance
diag(σ_φ²) + τ_k² 11ᵀ, and the smoother whitens them with it (:func:`image_whitening`). Why: an image's time stamp
is uncertain, and a robot turning at ω while its camera exposes δ s away from the stamp sees every landmark of that
image turned by the same ω δ (:mod:`estimation.image_timing` gives τ_k = |ω_k| σ_t).

What it is not: an association method. A sighting is given its landmark; a wrong identity that stays within the
χ²₂ 99 % bound moves the solution. And the covariances are as honest as the noise model: if consecutive
sightings share their error beyond the model's inflation, the smoother, like the filter, is overconfident; the
solution's χ² per degree of freedom (``Smoothed.chi2_per_dof``) says how far the data are from the model.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import scipy.linalg
import scipy.sparse as sp

from .geometry import between, wrap_angle

HUBER_K = 2.45                    # σ: Huber's threshold on a sighting's normalised residual norm (χ²₂ 70 %)
OUTLIER_CHI2 = 9.21               # χ²₂ 99 %: a sighting beyond it after the robust solve is dropped
MAX_ITERATIONS = 60
MIN_DRIFT_STEP_S = 1e-3           # s: the heading drift's factors take at least this long between two increments
IN_PLACE_M_PER_RAD = 0.1          # m/rad: an increment travelling less than this per radian it turns, turns on the spot
_STEP_TOLERANCE = 1e-7            # stop when no variable moves more than this (m or rad)
MAX_DENSE_ENTRIES = 50_000_000    # the Schur elimination holds H_pp⁻¹ H_pl, 3T × 2L dense: 400 MB at most
_COLUMN_BLOCK_ENTRIES = 4_000_000 # pose covariances are solved for in blocks of columns this size (32 MB)


class SmoothingError(ValueError):
    """The smoothing problem is malformed (shapes, indices, variances)."""


@dataclass(frozen=True)
class HeadingLoss:
    """A heavy-tailed loss on each odometry increment's heading residual, an option of :func:`smooth` (the default,
    ``None``, is the Gaussian of the random-walk variances).

    In units of the increment's own σ_θ (r = (Δθ_smoothed − Δθ_odometry) / σ_θ), the negative log-likelihood ρ(r),
    scaled so that ρ ≈ r² near 0:

    - ``"student-t"``: ρ = (ν + 1) log(1 + r²/(ν + 1)), ``dof`` ν (a t density whose scale is chosen so that its
      curvature at 0 is the Gaussian's: the same information for a residual that fits, less in the tails);
    - ``"mixture"``: a stall model, ρ = −2 log[(1 − π) e^{−r²/2} + (π/κ) e^{−r²/(2κ²)}] + const, π
      ``stall_probability`` (per increment), κ² = 1 + s²/σ_θ² with s ``stall_sigma_rad`` (the size of a stall).

    Solved by iteratively reweighted least squares: each Gauss–Newton step weights a heading residual by
    w(r) = ρ'(r)/(2r) (Student-t: (ν + 1)/(ν + 1 + r²); mixture: γ + (1 − γ)/κ², γ the narrow component's
    responsibility). The covariances are the inverse of JᵀWJ at the solution with these weights: a heading increment
    the loss has taken as an outlier gives the solution that much less information, so the poses and landmarks it
    held get wider covariances. (The exact Hessian of ρ is smaller still in the tail, and negative beyond the
    inflection, so it is not a covariance; W is the Gauss–Newton information, the usual choice.)

    Measured on MRCLAM (docs/fastslam-history.md, "Session 16 … (P)"): no gain (robot 1's start frame stays at 13 %
    within the bound with every loss: the stall it was built for lies in the increments that fix the frame, where it
    leaves no residual). Kept, off, for logs whose stalls fall where sightings can show them.
    """

    kind: str = "student-t"
    dof: float = 3.0
    stall_probability: float = 0.01
    stall_sigma_rad: float = 0.12

    def __post_init__(self) -> None:
        if self.kind not in ("student-t", "mixture"):
            raise SmoothingError(f"heading loss must be 'student-t' or 'mixture', not {self.kind!r}")
        if not self.dof > 0 or not 0 < self.stall_probability < 1 or not self.stall_sigma_rad > 0:
            raise SmoothingError("heading loss: dof and stall σ must be positive, the stall probability in (0, 1)")

    def _kappa2(self, sigma: np.ndarray) -> np.ndarray:
        return 1.0 + (self.stall_sigma_rad / sigma) ** 2

    def rho(self, r: np.ndarray, sigma: np.ndarray) -> np.ndarray:
        """ρ(r) (≥ 0, 0 at r = 0) of normalised heading residuals r with their σ_θ."""
        if self.kind == "student-t":
            return (self.dof + 1.0) * np.log1p(r ** 2 / (self.dof + 1.0))
        k2, p = self._kappa2(sigma), self.stall_probability
        at_zero = (1 - p) + p / np.sqrt(k2)
        mix = (1 - p) * np.exp(-0.5 * r ** 2) + p / np.sqrt(k2) * np.exp(-0.5 * r ** 2 / k2)
        return -2.0 * np.log(np.maximum(mix, 1e-300) / at_zero)

    def weight(self, r: np.ndarray, sigma: np.ndarray) -> np.ndarray:
        """The IRLS weight w(r) = ρ'(r)/(2r) in (0, 1]."""
        if self.kind == "student-t":
            return (self.dof + 1.0) / (self.dof + 1.0 + r ** 2)
        k2, p = self._kappa2(sigma), self.stall_probability
        narrow = (1 - p) * np.exp(-0.5 * r ** 2)
        wide = p / np.sqrt(k2) * np.exp(-0.5 * r ** 2 / k2)
        gamma = narrow / np.maximum(narrow + wide, 1e-300)
        return gamma + (1.0 - gamma) / k2


@dataclass(frozen=True)
class HeadingDrift:
    """A drifting heading bias per metre of odometry, an option of :func:`smooth` (the default, ``None``, is the
    white random walk alone).

    Each increment k carries a bias b_k (rad/m) that turns its heading by b_k × its distance d_k (the odometry's
    translation): the odometry factor's heading residual is Δθ_smoothed − Δθ_odometry − b_k d_k. The biases are a
    first-order Gauss–Markov process of stationary σ ``sigma_per_m`` and correlation time ``tau_s``: a prior
    b_0 ~ N(0, σ²) and factors b_{k+1} − e^(−Δ/τ) b_k of variance σ²(1 − e^(−2Δ/τ)), Δ the time between the
    increments' middles (floored at ``MIN_DRIFT_STEP_S``; the problem's ``increment_seconds`` give it). This is the
    error structure measured on MRCLAM's odometry in session 22 (O): honest at every horizon 5–600 s with σ 0.12–0.16
    rad/m, τ 10–30 s, where the white random walk is overconfident from a minute on. ``sigma_per_m`` 0 is off: the
    solution is then exactly the one without the option.

    ``sigma_per_rad`` (rad/rad, default 0: none): a second process of the same kind and τ, a heading slip c_k per
    radian the odometry turns *on the spot* (|Δθ_k| of an increment travelling less than ``IN_PLACE_M_PER_RAD`` per
    radian, either direction; 0 for the others): the heading residual also loses c_k |Δθ_k|. Why: a turn on the spot
    travels ~0 m, so the bias per metre adds nothing there, and MRCLAM's commanded-velocity odometry in place turns
    0.6–0.9 of what it reports and is 2–4× overdispersed, in runs of one sign (robot 2's wiggle at 779–817 s: +0.8 rad
    at a σ of 0.19), while in arcs it is within its model (benchmarks/mrclam_heading_slip.py, session 29 (C)). Its
    states follow the per-metre one's.
    """

    sigma_per_m: float
    tau_s: float
    sigma_per_rad: float = 0.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.sigma_per_m) and self.sigma_per_m >= 0):
            raise SmoothingError(f"heading drift σ must be finite and ≥ 0 rad/m, not {self.sigma_per_m}")
        if not (np.isfinite(self.tau_s) and self.tau_s > 0):
            raise SmoothingError(f"heading drift τ must be finite and > 0 s, not {self.tau_s}")
        if not (np.isfinite(self.sigma_per_rad) and self.sigma_per_rad >= 0):
            raise SmoothingError(f"heading slip σ must be finite and ≥ 0 rad/rad, not {self.sigma_per_rad}")

    @property
    def on(self) -> bool:
        return self.sigma_per_m > 0 or self.sigma_per_rad > 0


@dataclass(frozen=True)
class SightingOffset:
    """A systematic offset shared by all the sightings of one group, an option of :func:`smooth` (the default,
    ``None``, is none: every sighting's error is its own).

    A post is not a point: the camera sees one side of it, so the range to its surface and the bearing to its barcode
    depend on the side it is seen from, and the sightings of one visit share that error however many they are. Each
    group g (the problem's ``offset_index``: by default each landmark is its own group) gets an offset o_g (2,), in
    the map's frame, with the prior o_g ~ N(0, σ² I) (σ ``sigma_m``); a sighting of landmark l in group g sees
    m_l + o_g. So a landmark seen by one group has a covariance of at least σ² I however many sightings it has, and
    two groups of one landmark (two visits, two names of one post merged) may differ by ≈ σ√2 at the prior's cost
    (|o_g|²/σ²) instead of the sightings'. With one group per landmark the MAP poses and landmarks are exactly those
    without the option (the offsets are 0) and each landmark's covariance is larger by σ² I; with several groups of
    one landmark the solution moves. ``sigma_m`` 0 is off: the solution is then exactly the one without the option.
    """

    sigma_m: float

    def __post_init__(self) -> None:
        if not (np.isfinite(self.sigma_m) and self.sigma_m >= 0):
            raise SmoothingError(f"sighting offset σ must be finite and ≥ 0 m, not {self.sigma_m}")

    @property
    def on(self) -> bool:
        return self.sigma_m > 0


@dataclass(frozen=True)
class LandmarkLogProblem:
    """One robot's log as factors. Poses 0..T: pose 0 is the frame's origin (fixed); increment k (T, 3) leads from
    pose k to pose k + 1 with variances ``increment_variances[k]`` (3,). Sighting s (S,) was taken at pose
    ``pose_index[s]`` (1..T) of landmark ``landmark_index[s]`` (0..L−1) with range, bearing and their σ."""

    increments: np.ndarray
    increment_variances: np.ndarray
    pose_index: np.ndarray
    landmark_index: np.ndarray
    ranges: np.ndarray
    bearings: np.ndarray
    range_sigmas: np.ndarray
    bearing_sigmas: np.ndarray
    # (T,) each increment's duration (s), needed by a HeadingDrift; empty (the default): not known
    increment_seconds: np.ndarray = field(default_factory=lambda: np.zeros(0))
    # (S,) each sighting's offset group for a SightingOffset (0..G−1); empty (the default): its landmark's
    offset_index: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    # (T,) σ (rad) of one bearing error shared by all the sightings taken at pose k + 1 (one image: see
    # image_whitening); 0 at a pose: none there; empty (the default): none anywhere, every bearing's error its own
    image_bearing_sigmas: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        t = len(self.increments)
        if self.increments.shape != (t, 3) or self.increment_variances.shape != (t, 3):
            raise SmoothingError("increments and their variances must both be (T, 3)")
        if np.any(~np.isfinite(self.increment_variances)) or np.any(self.increment_variances <= 0):
            raise SmoothingError("increment variances must be finite and positive")
        s = len(self.ranges)
        for name in ("pose_index", "landmark_index", "bearings", "range_sigmas", "bearing_sigmas"):
            if getattr(self, name).shape != (s,):
                raise SmoothingError(f"{name} must be ({s},), like the ranges")
        if s and (self.pose_index.min() < 1 or self.pose_index.max() > t):
            raise SmoothingError(f"sightings must be taken at poses 1..{t}")
        if s and self.landmark_index.min() < 0:
            raise SmoothingError("landmark indices must be non-negative")
        if np.any(self.range_sigmas <= 0) or np.any(self.bearing_sigmas <= 0):
            raise SmoothingError("sighting σ must be positive")
        if np.shape(self.increment_seconds) not in ((0,), (t,)) or not np.all(np.isfinite(self.increment_seconds)) \
                or np.any(np.asarray(self.increment_seconds) < 0):
            raise SmoothingError(f"increment_seconds must be ({t},) (or empty: not known), finite and ≥ 0")
        if np.shape(self.offset_index) not in ((0,), (s,)) or (len(self.offset_index) and (
                not np.issubdtype(np.asarray(self.offset_index).dtype, np.integer) or np.min(self.offset_index) < 0)):
            raise SmoothingError(f"offset_index must be ({s},) non-negative integers (or empty: each landmark's own)")
        shared = np.asarray(self.image_bearing_sigmas, float)
        if shared.shape not in ((0,), (t,)) or not np.all(np.isfinite(shared)) or np.any(shared < 0):
            raise SmoothingError(f"image_bearing_sigmas must be ({t},) (or empty: none), finite and ≥ 0")

    @property
    def n_poses(self) -> int:
        return len(self.increments)

    @property
    def n_landmarks(self) -> int:
        return int(self.landmark_index.max()) + 1 if len(self.landmark_index) else 0

    # what depends on the odometry alone, computed once per problem (every iteration of a solve reads it; the
    # problem's arrays are taken as given, not changed in place: make a new problem with dataclasses.replace)
    @functools.cached_property
    def offset_groups(self) -> np.ndarray:
        """(S,) each sighting's offset group: ``offset_index``, or its landmark when that is empty."""
        return np.asarray(self.offset_index if len(self.offset_index) else self.landmark_index, int)

    @functools.cached_property
    def increment_sigmas(self) -> np.ndarray:
        """(T, 3) the increments' σ, √ of ``increment_variances``."""
        return np.sqrt(self.increment_variances)

    @functools.cached_property
    def increment_distances(self) -> np.ndarray:
        """(T,) each increment's distance (its chord), which a heading bias per metre multiplies."""
        return np.hypot(self.increments[:, 0], self.increments[:, 1])

    @functools.cached_property
    def in_place_turns(self) -> np.ndarray:
        """(T,) each increment's odometry turn |Δθ| (rad) if it turns on the spot (travels less than
        ``IN_PLACE_M_PER_RAD`` per radian), else 0: what a heading slip per radian multiplies."""
        turn = np.abs(self.increments[:, 2])
        return np.where(self.increment_distances < IN_PLACE_M_PER_RAD * turn, turn, 0.0)


@dataclass
class Smoothed:
    """The solution: poses (T + 1, 3) (row 0 the origin), landmarks (L, 2), their marginal covariances (L, 2, 2),
    pose covariances (P, 3, 3) at poses ``covariance_poses`` (P,), the sightings kept (S,) bool, and the fit; with a
    :class:`HeadingDrift`, the drift and each increment's heading bias (T,) (rad/m; None if its σ per metre is 0) and
    heading slip (T,) (rad/rad; None if its σ per radian is 0)."""

    poses: np.ndarray
    landmarks: np.ndarray
    landmark_covariances: np.ndarray
    covariance_poses: np.ndarray
    pose_covariances: np.ndarray
    inliers: np.ndarray
    chi2: float
    dof: int
    iterations: int
    converged: bool       # both solves did: the robust one, at whose end the outliers are cut, and the last
    heading_weights: np.ndarray | None = None     # (T,) the heading loss's IRLS weights at the solution, if any
    heading_drift: HeadingDrift | None = None     # the drift the solution carries (None: off)
    heading_biases: np.ndarray | None = None      # (T,) each increment's heading bias (rad/m) with the drift
    sighting_offset: SightingOffset | None = None  # the sighting offsets the solution carries (None: off)
    offsets: np.ndarray | None = None             # (G, 2) each offset group's offset (m) with them
    turn_biases: np.ndarray | None = None         # (T,) each increment's heading slip (rad/rad) with sigma_per_rad

    @property
    def chi2_per_dof(self) -> float:
        return self.chi2 / self.dof if self.dof > 0 else float("nan")


def smooth(problem: LandmarkLogProblem, initial_poses: np.ndarray, initial_landmarks: np.ndarray, *,
           pose_covariance_stride: int = 10, heading_loss: HeadingLoss | None = None,
           heading_drift: HeadingDrift | None = None, sighting_offset: SightingOffset | None = None) -> Smoothed:
    """The MAP poses and landmarks of ``problem`` from an initial guess (poses (T + 1, 3), landmarks (L, 2); a
    landmark never sighted keeps its guess and gets an infinite covariance). Pose covariances at every
    ``pose_covariance_stride``-th pose (and the last). ``heading_loss``: a heavy-tailed loss on the odometry's
    heading residuals (:class:`HeadingLoss`; ``None``, the default: Gaussian). ``heading_drift``: a heading bias
    state per increment (:class:`HeadingDrift`, needs ``problem.increment_seconds``; ``None`` or σ 0: none, today's
    solution exactly); the biases start at 0. ``sighting_offset``: an offset per group of sightings
    (:class:`SightingOffset`, groups ``problem.offset_index``; ``None`` or σ 0: none, today's solution exactly); the
    offsets start at 0. ``chi2`` is Σ r² of the normalised residuals whatever the loss (the data's distance from the
    model's σ), the drift's and the offsets' factors included (they pay for their own states)."""
    t, n_landmarks = problem.n_poses, max(problem.n_landmarks, len(initial_landmarks))
    drift = _Drift(problem, heading_drift) if heading_drift is not None and heading_drift.on else None
    width = _width(drift)
    offset = _Offsets(problem, sighting_offset) if sighting_offset is not None and sighting_offset.on else None
    n_dense = n_landmarks + (offset.n_explicit if offset is not None else 0)
    if width * t * 2 * n_dense > MAX_DENSE_ENTRIES:
        what = f"{n_landmarks} landmarks" + ("" if offset is None else f" and {offset.n_explicit} sighting offsets")
        raise SmoothingError(f"{t} poses and {what} are too many to smooth here (a dense "
                             f"{width * t} × {2 * n_dense} block, over {MAX_DENSE_ENTRIES * 8 // 10 ** 6} MB)")
    poses = np.array(initial_poses, float).reshape(t + 1, 3)
    landmarks = np.array(initial_landmarks, float).reshape(-1, 2)
    if len(landmarks) < n_landmarks:
        raise SmoothingError(f"{n_landmarks} landmarks sighted but {len(landmarks)} initial positions")
    bias = None if drift is None else np.zeros((t, drift.n))
    offsets = None if offset is None else np.zeros((offset.count, 2))
    poses[0] = 0.0
    inliers = np.ones(len(problem.ranges), bool)
    iterations, converged = solve_with_outlier_cut(problem, poses, landmarks, inliers, heading_loss=heading_loss,
                                                   drift=drift, bias=bias, offset=offset, offsets=offsets)
    odometry, sightings = _residuals(problem, poses, landmarks, _shift(drift, bias), offsets, inliers)
    heading_weights = _heading_weights(problem, odometry, heading_loss)
    chi2 = float(np.sum(odometry ** 2) + np.sum(sightings.reshape(-1, 2)[inliers] ** 2))
    if drift is not None:
        chi2 += float(np.sum(drift.residuals(bias) ** 2))
    if offset is not None:
        chi2 += float(np.sum(offset.residuals(offsets) ** 2))
    seen = np.zeros(n_landmarks, bool)
    seen[problem.landmark_index[inliers]] = True
    # the odometry's 3T residuals pay for the 3T poses, the offsets' priors for the offsets
    dof = 2 * int(inliers.sum()) - 2 * int(seen.sum())
    information = _information(problem, poses, landmarks, inliers, n_landmarks, heading_weights, drift,
                               offset, offsets)
    stride = max(int(pose_covariance_stride), 1)
    covariance_poses = np.unique(np.append(np.arange(stride, t + 1, stride), t)) if t else np.zeros(0, int)
    landmark_cov, pose_cov = _marginals(information, t, n_landmarks, seen, covariance_poses, width)
    if offset is not None:
        landmark_cov[offset.sole_landmarks] += offset.sigma ** 2 * np.eye(2)
    return Smoothed(poses, landmarks[:n_landmarks], landmark_cov, covariance_poses, pose_cov, inliers, chi2,
                    dof, iterations, converged, heading_weights,
                    heading_drift if drift is not None else None, None if drift is None else drift.per_metre(bias),
                    sighting_offset if offset is not None else None, offsets,
                    None if drift is None else drift.per_radian(bias))


def solve_with_outlier_cut(problem: LandmarkLogProblem, poses: np.ndarray, landmarks: np.ndarray,
                           inliers: np.ndarray, *, heading_loss: HeadingLoss | None = None, drift: _Drift | None = None,
                           bias: np.ndarray | None = None, offset: _Offsets | None = None,
                           offsets: np.ndarray | None = None, extra: ExtraUnknowns | None = None,
                           extra_values: np.ndarray | None = None) -> tuple[int, bool]:
    """The solve with the outliers cut, in place from the values the arrays hold (:func:`_solve`'s unknowns: poses[1:],
    landmarks, and the drift's ``bias``, the ``offsets``, the ``extra_values`` with theirs): the robust (Huber) solve
    over every sighting, the cut of the sightings whose two normalised residuals then pass OUTLIER_CHI2, and the
    plain solve over the rest. ``inliers`` (S,) bool is written in place too: every sighting for the robust solve,
    the cut from then on. Returns (both solves' iterations, whether both converged: the cut is made where the robust
    solve stopped, so an unfinished one leaves the final solve an unfinished cut).

    A LinAlgError (an information matrix not positive definite, in either solve) propagates, and everything written
    stays as the solve that raised had it: the poses, landmarks and other unknowns at its last accepted step, and
    ``inliers`` at the sightings it weighed, so every sighting if the robust solve raised, the cut if the final one
    did. Why this rule: the unknowns are then a (partial) solution of the problem with exactly those sightings, so a
    caller that reports from them after the error (each round of the noise's variance components in
    :mod:`estimation.camera_calibration` does) counts the χ², the outliers and the covariance of one problem, not
    the poses solved on one set of sightings beside the count of another."""
    inliers[:] = True
    iterations_robust, robust_converged = _solve(problem, poses, landmarks, inliers, robust=True,
                                                 heading_loss=heading_loss, drift=drift, bias=bias, offset=offset,
                                                 offsets=offsets, extra=extra, extra_values=extra_values)
    at = problem if extra is None else extra.applied(problem, extra_values)
    _, sightings = _residuals(at, poses, landmarks, _shift(drift, bias), offsets, inliers)
    inliers[:] = np.sum(sightings.reshape(-1, 2) ** 2, axis=1) <= OUTLIER_CHI2
    iterations, converged = _solve(problem, poses, landmarks, inliers, robust=False, heading_loss=heading_loss,
                                   drift=drift, bias=bias, offset=offset, offsets=offsets, extra=extra,
                                   extra_values=extra_values)
    return iterations_robust + iterations, robust_converged and converged


def normalised_residuals(problem: LandmarkLogProblem, solution: Smoothed
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The solution's normalised residuals: odometry (T, 3), sightings (S, 2) (range, bearing; dropped ones too),
    and the extra factors: the heading drift's (T,) (and its slip's (T,) after them), then the explicit sighting
    offsets' priors (2E,) (empty without them; a sole group's offset is 0 and has none: :class:`_Offsets`)."""
    drift = _solution_drift(problem, solution)
    offset = _solution_offset(problem, solution)
    bias = None if drift is None else drift.stacked(solution)
    odometry, sightings = _residuals(problem, solution.poses, solution.landmarks, _shift(drift, bias),
                                     solution.offsets if offset is not None else None, solution.inliers)
    extra = drift.residuals(bias) if drift is not None else np.zeros(0)
    if offset is not None:
        extra = np.concatenate([extra, offset.residuals(solution.offsets)])
    return odometry.reshape(-1, 3), sightings.reshape(-1, 2), extra


def solution_jacobian(problem: LandmarkLogProblem, solution: Smoothed) -> tuple[sp.csr_matrix, int]:
    """The smoother's Jacobian at ``solution``, each heading row scaled by its loss weight, and the number of
    variables per pose (3, and one per heading drift process: the bias per metre, the slip per radian). Rows: the
    odometry's 3T, the kept sightings' 2S, then the priors; columns: the poses' width·T, the landmarks' 2L, then the
    sighting offsets'. Its JᵀJ is the normal matrix every covariance of the solution comes from (:class:`NormalFactor`
    factors it)."""
    drift = _solution_drift(problem, solution)
    offset = _solution_offset(problem, solution)
    jac = _jacobian(problem, solution.poses, solution.landmarks, len(solution.landmarks),
                    np.asarray(solution.inliers, float), drift, offset,
                    solution.offsets if offset is not None else None)
    return _row_scaled(jac, problem.n_poses, solution.heading_weights).tocsr(), _width(drift)


def joint_landmark_covariance(problem: LandmarkLogProblem, solution: Smoothed) -> np.ndarray:
    """The landmarks' joint marginal covariance (2L, 2L) at ``solution`` (the inverse information, its heading drift
    and loss weights included; rows of landmarks with no kept sighting: inf)."""
    t, n = problem.n_poses, len(solution.landmarks)
    jac, width = solution_jacobian(problem, solution)
    offset = _solution_offset(problem, solution)
    seen = np.zeros(n, bool)
    seen[problem.landmark_index[solution.inliers]] = True
    information = (jac.T @ jac).tocsc()
    free = np.ones(information.shape[0], bool)
    free[width * t:width * t + 2 * n] = np.repeat(seen, 2)
    factor = NormalFactor(information[free][:, free], t, width)
    out = np.full((2 * n, 2 * n), np.inf)
    keep = np.repeat(seen, 2)
    n_kept = 2 * int(seen.sum())
    out[np.ix_(keep, keep)] = factor.landmark_covariance()[:n_kept, :n_kept]
    if offset is not None:
        rows = 2 * offset.sole_landmarks
        out[rows, rows] += offset.sigma ** 2
        out[rows + 1, rows + 1] += offset.sigma ** 2
    return out


def _solution_drift(problem: LandmarkLogProblem, solution: Smoothed) -> _Drift | None:
    drift = solution.heading_drift
    return _Drift(problem, drift) if drift is not None and drift.on else None


def _solution_offset(problem: LandmarkLogProblem, solution: Smoothed) -> _Offsets | None:
    option = solution.sighting_offset
    return _Offsets(problem, option, len(solution.offsets)) if option is not None and option.on else None


def sole_offset_groups(problem: LandmarkLogProblem) -> np.ndarray:
    """(K, 2) the (landmark, group) of each *sole* offset group of ``problem``: a group that is its landmark's only
    group and holds no other landmark's sightings (every sighting counted, kept or not; every landmark's with the
    default grouping), in the order of the landmarks. The smoother marginalises its offset exactly (:class:`_Offsets`:
    no column, its σ² I added to the landmark's covariance after the solve), and so does every covariance taken from
    a solution (:func:`joint_landmark_covariance`, :func:`estimation.frame_reliability.frame_reliability`)."""
    pairs = np.unique(np.column_stack([problem.landmark_index, problem.offset_groups]).reshape(-1, 2), axis=0)
    if not len(pairs):
        return np.zeros((0, 2), int)
    per_landmark = np.bincount(pairs[:, 0])[pairs[:, 0]]
    per_group = np.bincount(pairs[:, 1])[pairs[:, 1]]
    return pairs[(per_landmark == 1) & (per_group == 1)]


class _Offsets:
    """A :class:`SightingOffset` on one problem: each sighting's group (S,), the number of groups G and σ.

    A group that is its landmark's only group and holds no other landmark's sightings (a *sole* group: every
    landmark's with the default grouping) is marginalised exactly instead of solved for: m + o enters the sightings
    only as a sum, so its offset stays 0, the MAP is the one without it and the landmark's covariance gains σ² I
    (added after the solve). The others (``explicit_groups``, E) are variables after the landmarks' (eliminated with
    them in the dense Schur block) and their priors o/σ are rows after the sightings' (and the drift's). The offsets
    array is (G, 2), the sole groups' rows 0."""

    def __init__(self, problem: LandmarkLogProblem, option: SightingOffset, count: int | None = None) -> None:
        self.index = problem.offset_groups
        self.count = int(self.index.max()) + 1 if count is None and len(self.index) else int(count or 0)
        self.sigma = float(option.sigma_m)
        sole = sole_offset_groups(problem)
        explicit = np.ones(self.count, bool)
        explicit[sole[:, 1]] = False
        self.explicit_groups = np.flatnonzero(explicit)
        self.n_explicit = len(self.explicit_groups)
        self.sole_landmarks = sole[:, 0]
        self.column = np.full(self.count, -1)                # each group's place among the explicit ones (−1: sole)
        self.column[self.explicit_groups] = np.arange(self.n_explicit)

    def residuals(self, offsets: np.ndarray) -> np.ndarray:
        """(2E,) normalised: the explicit offsets' priors o / σ (the sole ones are 0)."""
        return np.asarray(offsets, float)[self.explicit_groups].ravel() / self.sigma


class _Drift:
    """A :class:`HeadingDrift`'s factors on one problem: its n processes (1 or 2: the bias per metre if its σ is > 0,
    then the slip per radian if its σ is > 0), each with its multiplier (T,) of the increments (the distance d, the
    odometry turn on the spot |Δθ|), its prior's σ and its Gauss–Markov factors' σ (T − 1,); their decay a (T − 1,)
    is shared (one τ). The states (T, n) follow the poses' (x, y, θ) in the variables: pose j's block is
    (x_j, y_j, θ_j, b_{j−1}, c_{j−1}), so every factor still touches two consecutive blocks."""

    def __init__(self, problem: LandmarkLogProblem, drift: HeadingDrift) -> None:
        if len(problem.increment_seconds) != problem.n_poses:
            raise SmoothingError("a heading drift needs the problem's increment_seconds (each increment's duration)")
        seconds = np.asarray(problem.increment_seconds, float)
        gap = np.maximum(0.5 * (seconds[:-1] + seconds[1:]), MIN_DRIFT_STEP_S)
        self.decay = np.exp(-gap / drift.tau_s)
        unit_sd = np.sqrt(-np.expm1(-2.0 * gap / drift.tau_s))
        processes = [(drift.sigma_per_m, problem.increment_distances), (drift.sigma_per_rad, problem.in_place_turns)]
        self.has_metre, self.has_radian = drift.sigma_per_m > 0, drift.sigma_per_rad > 0
        kept = [(sigma, multiplier) for sigma, multiplier in processes if sigma > 0]
        self.n = len(kept)
        self.multipliers = [multiplier for _, multiplier in kept]
        self.prior_sds = [float(sigma) for sigma, _ in kept]
        self.sds = [sigma * unit_sd for sigma, _ in kept]

    def shift(self, bias: np.ndarray) -> np.ndarray:
        """(T,) the heading each increment loses to the states (T, n): b_k d_k (+ c_k |Δθ_k|)."""
        out = bias[:, 0] * self.multipliers[0]
        for j in range(1, self.n):
            out = out + bias[:, j] * self.multipliers[j]
        return out

    def residuals(self, bias: np.ndarray) -> np.ndarray:
        """(n·T,) normalised, process by process: b_0 / σ, then (b_{k+1} − a_k b_k) / σ_k."""
        return np.concatenate([np.concatenate([bias[:1, j] / self.prior_sds[j],
                                               (bias[1:, j] - self.decay * bias[:-1, j]) / self.sds[j]])
                               for j in range(self.n)])

    def per_metre(self, bias: np.ndarray) -> np.ndarray | None:
        return bias[:, 0].copy() if self.has_metre else None

    def per_radian(self, bias: np.ndarray) -> np.ndarray | None:
        return bias[:, self.n - 1].copy() if self.has_radian else None

    def stacked(self, solution: Smoothed) -> np.ndarray:
        """(T, n) a solution's states (a process the solution does not carry, e.g. a saved state's slip: 0)."""
        t = len(self.decay) + 1
        columns = [solution.heading_biases if self.has_metre else None,
                   solution.turn_biases if self.has_radian else None]
        return np.column_stack([np.zeros(t) if c is None else np.asarray(c, float)
                                for c, kept in zip(columns, (self.has_metre, self.has_radian), strict=True)
                                if kept])


def _shift(drift: _Drift | None, bias: np.ndarray | None) -> np.ndarray | None:
    return None if drift is None else drift.shift(bias)


def _width(drift: _Drift | None) -> int:
    """Variables per pose: (x, y, θ), and one per heading drift process."""
    return 3 if drift is None else 3 + drift.n


def _heading_weights(problem: LandmarkLogProblem, odometry: np.ndarray,
                     heading_loss: HeadingLoss | None) -> np.ndarray | None:
    """The heading loss's IRLS weights (T,) at normalised odometry residuals (T·3,); None without a loss."""
    if heading_loss is None:
        return None
    return heading_loss.weight(odometry.reshape(-1, 3)[:, 2], problem.increment_sigmas[:, 2])


def _row_scaled(jac: sp.csr_matrix, t: int, heading_weights: np.ndarray | None) -> sp.csr_matrix:
    """The Jacobian with each heading row (3k + 2) scaled by √w_k (unchanged without weights)."""
    if heading_weights is None:
        return jac
    scale = np.ones(jac.shape[0])
    scale[3 * np.arange(t) + 2] = np.sqrt(heading_weights)
    return sp.diags(scale, format="csr") @ jac


def _residuals(problem: LandmarkLogProblem, poses: np.ndarray, landmarks: np.ndarray,
               shift: np.ndarray | None = None, offsets: np.ndarray | None = None, inliers: np.ndarray | None = None):
    """Normalised residuals: odometry (T·3,) (the heading less the drift's shift (T,): b_k d_k, + c_k |Δθ_k|),
    sightings (S·2,) interleaved (range, bearing) (each of landmark + its group's offset, with offsets (G, 2)); with
    one error per image, the bearings whitened over each image's ``inliers`` (S,) (None: all;
    :func:`image_whitening`)."""
    odometry = between(poses[:-1], poses[1:]) - problem.increments
    if shift is not None:
        odometry[:, 2] -= shift
    odometry[:, 2] = wrap_angle(odometry[:, 2])
    odometry /= problem.increment_sigmas
    at = poses[problem.pose_index]
    d = landmarks[problem.landmark_index] - at[:, :2]
    if offsets is not None:
        d = d + offsets[problem.offset_groups]
    predicted_range = np.hypot(d[:, 0], d[:, 1])
    predicted_bearing = np.arctan2(d[:, 1], d[:, 0]) - at[:, 2]
    bearing = wrap_angle(predicted_bearing - problem.bearings) / problem.bearing_sigmas
    sightings = np.column_stack([(predicted_range - problem.ranges) / problem.range_sigmas,
                                 _whitened_bearings(problem, bearing, inliers)])
    return odometry.ravel(), sightings.ravel()


def image_whitening(problem: LandmarkLogProblem, inliers: np.ndarray | None = None) -> sp.csr_matrix | None:
    """(S, S) W, the whitening of the sightings' normalised bearing residuals z (S,) (z_i = e_i / σ_i) under one error
    per image; None when ``problem`` has none (``image_bearing_sigmas`` empty, or no kept sighting at a pose whose
    τ is > 0).

    The model: the kept sightings (``inliers`` (S,) bool; None: all) taken at pose k, one image, share a bearing error
    ε_k ~ N(0, τ_k²) (τ_k = ``image_bearing_sigmas[k − 1]``) beside their own errors of σ_i. In normalised units
    their covariance is I + u uᵀ, u_i = τ_k / σ_i, and W is its symmetric inverse square root on each image,
    W = I − c u uᵀ with c = 1 / (√(1 + a) (1 + √(1 + a))), a = uᵀu: (I − c uuᵀ)² (I + uuᵀ) = I because
    (1 − c a)² (1 + a) = 1. So |W z|² = zᵀ (I + uuᵀ)⁻¹ z is the image's exact χ² and W J the Jacobian whose JᵀJ is
    its information. The rows of sightings cut and of poses with τ 0 are left as they are (W's identity part).

    Where it comes from: an image's time stamp is known to within its timing uncertainty σ_t, and a robot turning at
    ω sees every landmark of that image turned by the same ω δ (δ the exposure's offset from the stamp), so the
    bearings share an error of σ |ω| σ_t (:mod:`estimation.image_timing`). On MRCLAM the camera also repeats a stale
    image while the robot turns (robot 5 at 13.16–13.46 s: three images 0.05–0.09 rad off together).

    Why whitened rather than an explicit unknown ε_k per image (its residual taken off the image's bearings, its prior
    ε_k / τ_k): the two give the same MAP and the same covariance of the poses and landmarks (ε_k marginalised exactly
    is this covariance), but ε_k would be one column per image, thousands on MRCLAM, in the dense block the landmarks
    are eliminated with, or a fourth column per pose that every frame figure's layout would have to know. Whitened,
    an image's rows touch only its pose and its landmarks, blocks the normal equations hold already. Why the
    symmetric root rather than a Cholesky factor: no sighting of an image comes first, an image of one sighting gets
    its bearing's σ √(σ² + τ²) exactly, and τ 0 leaves every row as it was. What reads the whitened residuals:
    Huber's weights and the outlier cut (per sighting, as before), and the frame reliability's per-sighting tests;
    a stale image's common error is shared among its sightings instead of being charged to each.

    The slip it corrects: the FastSLAM factorisation (Montemerlo et al. 2002, eq. 3) takes the sightings
    conditionally independent given the pose, and so did every variance in this package; session 41's scratch
    variant grew each bearing's variance by (ω · 0.065 s)² independently, which lets n sightings of one image
    average the common error away (the image's weight on the pose's heading n / (σ² + τ²), not at most 1 / τ²)."""
    sigmas = np.asarray(problem.image_bearing_sigmas, float)
    if not len(sigmas):
        return None
    n = len(problem.ranges)
    tau = sigmas[problem.pose_index - 1] if n else np.zeros(0)
    shared = (tau > 0) & (np.ones(n, bool) if inliers is None else np.asarray(inliers, bool))
    if not shared.any():    # nothing shared: every row as without the term, bit for bit
        return None
    u = np.where(shared, tau / problem.bearing_sigmas, 0.0)
    a = np.bincount(problem.pose_index, u ** 2, minlength=problem.n_poses + 1)
    root = np.sqrt(1.0 + a)
    c = 1.0 / (root * (1.0 + root))                       # per pose
    members = np.flatnonzero(shared)
    members = members[np.argsort(problem.pose_index[members], kind="stable")]
    pose = problem.pose_index[members]
    starts = np.flatnonzero(np.concatenate([[True], pose[1:] != pose[:-1]])) if len(members) else np.zeros(0, int)
    sizes = np.diff(np.append(starts, len(members)))
    group = np.repeat(np.arange(len(starts)), sizes)      # each member's image, in members' order
    # every ordered pair (i, j) of one image: member i repeated once per member of its image, j running over them
    rows = np.repeat(members, sizes[group])
    first = np.repeat(starts[group], sizes[group])
    within = np.arange(len(rows)) - np.repeat(np.cumsum(sizes[group]) - sizes[group], sizes[group])
    columns = members[first + within]
    values = -c[problem.pose_index[rows]] * u[rows] * u[columns]
    return (sp.identity(n, format="csr") + sp.csr_matrix((values, (rows, columns)), shape=(n, n))).tocsr()


def _whitened_bearings(problem: LandmarkLogProblem, bearings: np.ndarray, inliers: np.ndarray | None) -> np.ndarray:
    """Normalised bearing residuals (S,) whitened by :func:`image_whitening` (as they are without its term)."""
    whitening = image_whitening(problem, inliers)
    return bearings if whitening is None else whitening @ bearings


class _Rows:
    """A sparse Jacobian as blocks of rows, each row with at most W entries: columns (R, W) (−1: no entry) and values
    (R, W), the blocks in the matrix's row order (the odometry's first) and each row's columns ascending. Why not COO
    triplets: every factor type has a fixed shape of row, so the CSR arrays of any range of columns follow from these
    by one mask, without COO's conversion and the sparse stacking of the extra unknowns' columns and rows; and the
    solve takes the poses' columns and the others apart (:class:`_NormalEquations`)."""

    def __init__(self, n_columns: int) -> None:
        self.columns: list[np.ndarray] = []
        self.values: list[np.ndarray] = []
        self.n_columns = n_columns

    def add(self, columns: np.ndarray, values: np.ndarray) -> None:
        """Rows after the others: columns and values (..., W), the leading axes flattened in order."""
        shape = (int(np.prod(np.shape(columns)[:-1])), np.shape(columns)[-1])
        self.columns.append(np.asarray(columns, np.int64).reshape(shape))
        self.values.append(np.asarray(values, float).reshape(shape))

    def csr(self, first: int = 0, last: int | None = None) -> sp.csr_matrix:
        """The columns [first, last) as a CSR matrix (every row: stored entries as the rows hold them, zeros too)."""
        last = self.n_columns if last is None else last
        indices, data, counts = [], [], []
        for columns, values in zip(self.columns, self.values, strict=True):
            keep = (columns >= first) & (columns < last)
            indices.append(columns[keep] - first)
            data.append(values[keep])
            counts.append(keep.sum(axis=1))
        indptr = np.concatenate([[0], np.cumsum(np.concatenate(counts))]) if counts else np.zeros(1, np.int64)
        out = sp.csr_matrix((np.concatenate(data) if data else np.zeros(0),
                             np.concatenate(indices) if indices else np.zeros(0, np.int64), indptr),
                            shape=(len(indptr) - 1, last - first))
        out.has_sorted_indices = True      # ascending within each row, by construction
        return out


def _padded(matrix: sp.spmatrix, column_offset: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(columns (R, W), values (R, W)) of ``matrix``'s stored entries row by row (columns shifted by
    ``column_offset``, ascending; −1 and 0 after a row's last), W its most entries in a row."""
    matrix = sp.csr_matrix(matrix)
    matrix.sort_indices()
    counts = np.diff(matrix.indptr)
    width = int(counts.max()) if len(counts) and matrix.nnz else 0
    columns = np.full((matrix.shape[0], width), -1, np.int64)
    values = np.zeros((matrix.shape[0], width))
    row = np.repeat(np.arange(matrix.shape[0]), counts)
    slot = np.arange(matrix.nnz) - np.repeat(matrix.indptr[:-1], counts)
    columns[row, slot] = matrix.indices + column_offset
    values[row, slot] = matrix.data
    return columns, values


def _jacobian(problem: LandmarkLogProblem, poses: np.ndarray, landmarks: np.ndarray, n_landmarks: int,
              sighting_weights: np.ndarray, drift: _Drift | None = None, offset: _Offsets | None = None,
              offsets: np.ndarray | None = None, extra: ExtraUnknowns | None = None,
              extra_values: np.ndarray | None = None) -> sp.csr_matrix:
    """∂(normalised residuals)/∂(poses 1..T, landmarks), sightings scaled by their weights (S,). With a drift, pose
    j's columns are (x, y, θ, b_{j−1}) and the drift's factors are rows after the sightings'. With sighting offsets
    (G, 2), their columns follow the landmarks' and their priors' rows follow the others. With extra unknowns
    (``problem``'s sightings as their values make them), their columns and their own factors' rows come last."""
    return _jacobian_rows(problem, poses, landmarks, n_landmarks, sighting_weights, drift, offset, offsets, extra,
                          extra_values).csr()


def _jacobian_rows(problem: LandmarkLogProblem, poses: np.ndarray, landmarks: np.ndarray, n_landmarks: int,
                   sighting_weights: np.ndarray, drift: _Drift | None = None, offset: _Offsets | None = None,
                   offsets: np.ndarray | None = None, extra: ExtraUnknowns | None = None,
                   extra_values: np.ndarray | None = None, residuals=None) -> _Rows:
    """:func:`_jacobian` as :class:`_Rows`: the odometry's rows (x, y, θ per increment), the sightings' (range,
    bearing), the drift's, the offsets' priors, the extra unknowns' own. ``residuals``: :func:`_residuals` at
    ``problem``, poses and landmarks if the caller has them (the extra unknowns' columns read them), else None."""
    t = problem.n_poses
    width = _width(drift)
    n_drift = 0 if drift is None else drift.n
    n_columns = width * t + 2 * n_landmarks + (0 if offset is None else 2 * offset.n_explicit)
    in_factors = None
    if extra is not None:
        # the extra values change the odometry's and the sightings' factors: their columns come after all the others
        derivatives = extra.columns(problem, poses, landmarks, extra_values, sighting_weights, residuals=residuals)
        in_factors = _padded(derivatives, n_columns)
    k = np.arange(t)
    a, b = poses[:-1], poses[1:]
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    sigma = problem.increment_sigmas
    col_a, col_b = width * (k - 1), width * k    # pose j's columns start at width·(j − 1); pose 0 has none
    # the odometry's rows: (x, y) (a_x, a_y, a_θ, b_x, b_y), θ (a_θ, b_θ, the drift's states of b)
    slots = max(5, 2 + n_drift)
    columns = np.full((t, 3, slots), -1, np.int64)
    values = np.zeros((t, 3, slots))
    # between: e_x = c dx + s dy, e_y = −s dx + c dy, e_θ = b_θ − a_θ
    for axis, (wx, wy, wth) in enumerate(((c, s, -s * dx + c * dy), (-s, c, -c * dx - s * dy))):
        w = 1.0 / sigma[:, axis]
        columns[:, axis, :5] = np.column_stack([col_a, col_a + 1, col_a + 2, col_b, col_b + 1])
        values[:, axis, :5] = np.column_stack([-wx * w, -wy * w, wth * w, wx * w, wy * w])
    columns[:, 2, :2] = np.column_stack([col_a + 2, col_b + 2])
    values[:, 2, :2] = np.column_stack([-1.0 / sigma[:, 2], 1.0 / sigma[:, 2]])
    if drift is not None:
        for j, multiplier in enumerate(drift.multipliers):     # the heading less b_k d_k (and c_k |Δθ_k|)
            columns[:, 2, 2 + j] = col_b + 3 + j
            values[:, 2, 2 + j] = -multiplier / sigma[:, 2]
    if t:                                         # pose 0 is fixed: no column
        columns[0, :2, :3] = -1
        columns[0, 2, 0] = -1
    rows = _Rows(n_columns + (0 if in_factors is None else derivatives.shape[1]))

    at = poses[problem.pose_index]
    d = landmarks[problem.landmark_index] - at[:, :2]
    if offset is not None:
        d = d + offsets[offset.index]
    q = np.maximum(d[:, 0] ** 2 + d[:, 1] ** 2, 1e-12)
    rng = np.sqrt(q)
    pose_col = width * (problem.pose_index - 1)
    landmark_col = width * t + 2 * problem.landmark_index
    wr = sighting_weights / problem.range_sigmas
    # one error per image: the bearing rows are whitened over each image's kept sightings (weight > 0) first, then
    # weighted as the residuals are (_solve: whitened, then Huber's weight of the whitened norm)
    whitening = image_whitening(problem, sighting_weights > 0)
    if whitening is not None and extra is not None:
        raise SmoothingError("one bearing error per image is not combined with extra unknowns")
    wb = (sighting_weights if whitening is None else (sighting_weights > 0).astype(float)) / problem.bearing_sigmas
    n_sightings = len(d)
    # the sightings' rows: range (p_x, p_y, −, m_x, m_y[, o_x, o_y]), bearing (p_x, p_y, p_θ, m_x, m_y[, o_x, o_y])
    sighting_columns = np.full((n_sightings, 2, 7 if offset is not None else 5), -1, np.int64)
    sighting_values = np.zeros(sighting_columns.shape)
    for col_offset, dr, db in ((0, d[:, 0] / rng, -d[:, 1] / q), (1, d[:, 1] / rng, d[:, 0] / q)):
        sighting_columns[:, :, 3 + col_offset] = (landmark_col + col_offset)[:, None]
        sighting_values[:, 0, 3 + col_offset] = dr * wr
        sighting_values[:, 1, 3 + col_offset] = db * wb
        sighting_columns[:, :, col_offset] = (pose_col + col_offset)[:, None]
        sighting_values[:, 0, col_offset] = -dr * wr
        sighting_values[:, 1, col_offset] = -db * wb
        if offset is not None:                                   # m + o: the same derivatives
            column = offset.column[offset.index]
            offset_col = np.where(column < 0, -1, width * t + 2 * n_landmarks + 2 * column + col_offset)
            sighting_columns[:, :, 5 + col_offset] = offset_col[:, None]
            sighting_values[:, 0, 5 + col_offset] = dr * wr
            sighting_values[:, 1, 5 + col_offset] = db * wb
    sighting_columns[:, 1, 2] = pose_col + 2
    sighting_values[:, 1, 2] = -wb
    if whitening is not None:
        sighting_columns, sighting_values = _whitened_rows(sighting_columns, sighting_values, whitening,
                                                           sighting_weights, rows.n_columns)
    if in_factors is None:
        rows.add(columns, values)
        rows.add(sighting_columns, sighting_values)
    else:
        extra_columns, extra_values_ = in_factors
        rows.add(np.concatenate([columns.reshape(3 * t, -1), extra_columns[:3 * t]], axis=1),
                 np.concatenate([values.reshape(3 * t, -1), extra_values_[:3 * t]], axis=1))
        rows.add(np.concatenate([sighting_columns.reshape(2 * n_sightings, -1), extra_columns[3 * t:]], axis=1),
                 np.concatenate([sighting_values.reshape(2 * n_sightings, -1), extra_values_[3 * t:]], axis=1))
    if drift is not None and t:
        # per process j: b_0 / σ, then (b_k − a b_{k−1}) / σ_k: b_k is column 3 + j of pose k + 1's block
        for j in range(drift.n):
            previous = np.concatenate([[-1], width * k[:-1] + 3 + j])
            rows.add(np.column_stack([previous, width * k + 3 + j]),
                     np.column_stack([np.concatenate([[0.0], -drift.decay / drift.sds[j]]),
                                      np.concatenate([[1.0 / drift.prior_sds[j]], 1.0 / drift.sds[j]])]))
    if offset is not None and offset.n_explicit:
        g = np.arange(2 * offset.n_explicit)
        rows.add((width * t + 2 * n_landmarks + g)[:, None], np.full((len(g), 1), 1.0 / offset.sigma))
    if extra is not None:   # their own factors' rows
        rows.add(*_padded(extra.rows(problem, landmarks, extra_values, rows.n_columns)))
    return rows


def _whitened_rows(columns: np.ndarray, values: np.ndarray, whitening: sp.csr_matrix, weights: np.ndarray,
                   n_columns: int) -> tuple[np.ndarray, np.ndarray]:
    """The sightings' rows (columns, values (S, 2, W)) with the bearing rows replaced by W J_b (``whitening`` W (S, S):
    an image's rows mixed, each then touching its pose and all its image's landmarks) and scaled by ``weights`` (S,);
    the range rows as they are. Padded to the wider of the two (−1, 0 after a row's last entry)."""
    n = len(columns)
    keep = columns[:, 1] >= 0
    bearing = sp.csr_matrix((values[:, 1][keep], (np.nonzero(keep)[0], columns[:, 1][keep])), shape=(n, n_columns))
    mixed_columns, mixed_values = _padded(whitening @ bearing)
    width = max(columns.shape[2], mixed_columns.shape[1])
    out_columns = np.full((n, 2, width), -1, np.int64)
    out_values = np.zeros((n, 2, width))
    out_columns[:, 0, :columns.shape[2]] = columns[:, 0]
    out_values[:, 0, :columns.shape[2]] = values[:, 0]
    out_columns[:, 1, :mixed_columns.shape[1]] = mixed_columns
    out_values[:, 1, :mixed_columns.shape[1]] = mixed_values * weights[:, None]
    return out_columns, out_values


def _sighting_weights(sightings: np.ndarray, inliers: np.ndarray, robust: bool) -> np.ndarray:
    """√(IRLS weight) per sighting: 0 for dropped ones, Huber's on the residual norm when ``robust``."""
    weights = inliers.astype(float)
    if robust:
        norm = np.sqrt(np.sum(sightings.reshape(-1, 2) ** 2, axis=1))
        weights *= np.sqrt(np.minimum(1.0, HUBER_K / np.maximum(norm, 1e-12)))
    return weights


class ExtraUnknowns(Protocol):
    """Unknowns of a caller's solved with the poses and landmarks (:func:`_solve`'s ``extra``; their values (k,),
    ``extra_values``, changed in place), as a camera's calibration and the odometry's translation scale are in
    :mod:`estimation.camera_calibration`. The values change what the sightings measured and what the odometry
    increments say (their values and σ's; not which poses and landmarks a factor joins); their k columns follow all the
    smoother's, and they may bring factors of their own, rows after all the smoother's. Not combined with a heading
    drift or sighting offsets (the columns are the odometry's and sightings' derivatives without them)."""

    def applied(self, problem: LandmarkLogProblem, values: np.ndarray) -> LandmarkLogProblem:
        """``problem`` with its increments and sightings (values, σ's) as ``values`` make them."""

    def columns(self, problem: LandmarkLogProblem, poses: np.ndarray, landmarks: np.ndarray, values: np.ndarray,
                weights: np.ndarray, residuals: tuple[np.ndarray, np.ndarray] | None = None) -> sp.csr_matrix:
        """(3T + 2S, k) ∂(the odometry's normalised residuals (x, y, θ per increment), then the sightings' ((range,
        bearing) interleaved, scaled by their weights (S,)))/∂values, at ``problem`` (as ``values`` make it).
        ``residuals``: :func:`_residuals` there (odometry, sightings), if the caller has them (None: computed)."""

    def residuals(self, landmarks: np.ndarray, values: np.ndarray) -> np.ndarray:
        """(K,) the own factors' normalised residuals (K may be 0)."""

    def rows(self, problem: LandmarkLogProblem, landmarks: np.ndarray, values: np.ndarray,
             n_columns: int) -> sp.csr_matrix:
        """(K, n_columns) their derivatives (the poses' columns 3T, the landmarks' 2L, ..., the values' k last)."""

    def stepped(self, values: np.ndarray, step: np.ndarray) -> np.ndarray | None:
        """``values`` moved by ``step`` (k,), or None if the result is not admissible (the step is then refused)."""


def _cost(problem, poses, landmarks, inliers, robust, heading_loss=None, drift=None, bias=None, offset=None,
          offsets=None, extra=None, extra_values=None) -> tuple[float, LandmarkLogProblem, tuple]:
    """(the cost, ``problem`` as the extra values make it, its residuals (odometry, sightings)): the solve's next
    iteration starts from the point a step was accepted at, and reads the last two from here instead of again."""
    if extra is not None:
        problem = extra.applied(problem, extra_values)
    residuals = _residuals(problem, poses, landmarks, _shift(drift, bias), offsets, inliers)
    odometry, sightings = residuals
    norm2 = np.sum(sightings.reshape(-1, 2) ** 2, axis=1)[inliers]
    if robust:
        norm = np.sqrt(norm2)
        rho = np.where(norm <= HUBER_K, norm2, 2 * HUBER_K * norm - HUBER_K ** 2)
    else:
        rho = norm2
    others = 0.0 if drift is None else float(np.sum(drift.residuals(bias) ** 2))
    if offset is not None:
        others += float(np.sum(offset.residuals(offsets) ** 2))
    if extra is not None:
        others += float(np.sum(extra.residuals(landmarks, extra_values) ** 2))
    if heading_loss is None:
        return float(np.sum(odometry ** 2) + np.sum(rho)) + others, problem, residuals
    odometry = odometry.reshape(-1, 3)
    heading = heading_loss.rho(odometry[:, 2], problem.increment_sigmas[:, 2])
    return float(np.sum(odometry[:, :2] ** 2) + np.sum(heading) + np.sum(rho)) + others, problem, residuals


def _solve(problem, poses, landmarks, inliers, robust, heading_loss=None, drift=None, bias=None, offset=None,
           offsets=None, extra=None, extra_values=None) -> tuple[int, bool]:
    """Levenberg–Marquardt (IRLS weights when ``robust``, and for ``heading_loss``) in place on poses[1:] and
    landmarks (and the biases (T, n) with a drift, the offsets (G, 2) with sighting offsets, the values (k,) of
    :class:`ExtraUnknowns`).

    Each step's turn of the whole solution about the frame's origin is taken as a rotation, not along its tangent
    (:func:`_rotation_correction`). Why: pose 0 alone fixes the frame, so turning every later pose and the map
    together changes only the first increments' residuals: the information in that direction is 10⁻¹¹-10⁻⁸ of the
    diagonal's (MRCLAM robot 1). A linear step along it by ω moves a point r from the origin ω²r/2 off the circle it
    turns on (0.15 rad at 5 m: 5.6 cm, two of a sighting's σ), so the loop must take short steps there and a start
    turned by a tenth of a radian from the solution takes more than the iteration cap. The self-calibration's first
    steps turn the map by the bearing offset's jumps (session 38 (E)); the smoother's robust solve on MRCLAM robot 1
    (30 particles, whole log) stopped at the cap of 60 with tangent steps and converges in 43 with rotations
    (session 39)."""
    t, n_landmarks = problem.n_poses, len(landmarks)
    width = _width(drift)
    landmarks_end = width * t + 2 * n_landmarks
    offsets_end = landmarks_end + (0 if offset is None else 2 * offset.n_explicit)
    damping = 1e-4
    cost, at, residuals = _cost(problem, poses, landmarks, inliers, robust, heading_loss, drift, bias, offset,
                                offsets, extra, extra_values)
    for iteration in range(1, MAX_ITERATIONS + 1):
        if residuals is None:   # no cost computed where the last step went (refused values): nothing to reuse
            at = problem if extra is None else extra.applied(problem, extra_values)
            residuals = _residuals(at, poses, landmarks, _shift(drift, bias), offsets, inliers)
        odometry, sightings = residuals
        weights = _sighting_weights(sightings, inliers, robust)
        heading_weights = _heading_weights(problem, odometry, heading_loss)
        rows = _jacobian_rows(at, poses, landmarks, n_landmarks, weights, drift, offset, offsets, extra, extra_values,
                              residuals)
        if heading_weights is not None:
            rows.values[0][2::3] *= np.sqrt(heading_weights)[:, None]   # the heading rows by √w, as _row_scaled
            odometry = odometry.copy()
            odometry[2::3] *= np.sqrt(heading_weights)
        parts = [odometry, (sightings.reshape(-1, 2) * weights[:, None]).ravel()]
        if drift is not None:
            parts.append(drift.residuals(bias))
        if offset is not None:
            parts.append(offset.residuals(offsets))
        if extra is not None:
            parts.append(extra.residuals(landmarks, extra_values))
        residual = np.concatenate(parts)
        normal = _NormalEquations(rows, residual, t, width)
        while True:
            step = -normal.damped(damping).solve(normal.gradient)
            trial_poses, trial_landmarks = poses.copy(), landmarks.copy()
            pose_step = step[:width * t].reshape(t, width)
            landmark_step = step[width * t:landmarks_end].reshape(n_landmarks, 2)
            trial_poses[1:] += pose_step[:, :3]
            trial_landmarks += landmark_step
            trial_bias = None if drift is None else bias + pose_step[:, 3:]
            trial_offsets = None
            if offset is not None:
                trial_offsets = offsets.copy()
                trial_offsets[offset.explicit_groups] += step[landmarks_end:offsets_end].reshape(-1, 2)
            omega = _step_rotation(np.vstack([poses[1:, :2], landmarks]), np.vstack([pose_step[:, :2], landmark_step]))
            trial_poses[1:, :2] += _rotation_correction(poses[1:, :2], omega)
            trial_landmarks += _rotation_correction(landmarks, omega)
            if offset is not None:   # vectors in the map's frame: they turn with it
                trial_offsets += _rotation_correction(offsets, omega)
            trial_poses[1:, 2] = wrap_angle(trial_poses[1:, 2])
            trial_values = None if extra is None else extra.stepped(extra_values, step[offsets_end:])
            if extra is not None and trial_values is None:   # values the extra unknowns do not admit: refused
                trial, trial_at, trial_residuals = np.inf, None, None
            else:
                trial, trial_at, trial_residuals = _cost(problem, trial_poses, trial_landmarks, inliers, robust,
                                                         heading_loss, drift, trial_bias, offset, trial_offsets,
                                                         extra, trial_values)
            if trial <= cost:
                break
            damping *= 10.0
            if damping > 1e8:
                return iteration, False
        poses[:], landmarks[:] = trial_poses, trial_landmarks
        if drift is not None:
            bias[:] = trial_bias
        if offset is not None:
            offsets[:] = trial_offsets
        if extra is not None:
            extra_values[:] = trial_values
        damping = max(damping / 10.0, 1e-9)
        improvement, cost = cost - trial, trial
        at, residuals = trial_at, trial_residuals
        if np.max(np.abs(step)) < _STEP_TOLERANCE or improvement < 1e-9 * max(cost, 1.0):
            return iteration, True
    return MAX_ITERATIONS, False


def _step_rotation(points: np.ndarray, step: np.ndarray) -> float:
    """ω (rad): the turn of the rigid motion (a turn and a shift) nearest, in least squares, to ``step`` (N, 2) at
    ``points`` (N, 2): Σ (p − p̄) × (δ − δ̄) / Σ |p − p̄|²."""
    centred, moved = points - points.mean(axis=0), step - step.mean(axis=0)
    return float(np.sum(centred[:, 0] * moved[:, 1] - centred[:, 1] * moved[:, 0])
                 / max(float(np.sum(centred ** 2)), 1e-300))


def _rotation_correction(points: np.ndarray, omega: float) -> np.ndarray:
    """(R(ω) − I − ω J) p for points p (N, 2), J the quarter turn: what turns p + (its step's tangent part ω J p)
    into R(ω) p, the rotation about the origin, exactly. Second order in ω: a step without a turn is unchanged."""
    cos, sin = np.cos(omega) - 1.0, np.sin(omega) - omega
    return np.column_stack([cos * points[:, 0] - sin * points[:, 1], sin * points[:, 0] + cos * points[:, 1]])


def _information(problem, poses, landmarks, inliers, n_landmarks, heading_weights=None, drift=None, offset=None,
                 offsets=None) -> sp.csc_matrix:
    jac = _row_scaled(_jacobian(problem, poses, landmarks, n_landmarks, inliers.astype(float), drift, offset,
                                offsets), problem.n_poses, heading_weights)
    return (jac.T @ jac).tocsc()


class NormalFactor:
    """The normal matrix H of poses 1..T (first ``width``·T variables: (x, y, θ) per pose, and a heading bias with a
    drift) and landmarks (the rest), factored by its structure.

    Every factor touches at most two consecutive poses, or one pose and one landmark, so the pose block H_pp is
    block-tridiagonal (a band of half-width 2·width − 1: 5, 7 with the drift's bias, 9 with its slip too): a banded
    Cholesky factors it in O(T). The landmarks are eliminated through their Schur complement
    S = H_ll − H_lp H_pp⁻¹ H_pl (2L × 2L, dense and small), whose inverse is exactly the landmarks' marginal
    covariance. A general sparse LU (SuperLU) did the same in 10–30× the time on MRCLAM.
    """

    def __init__(self, normal: sp.spmatrix, t: int, width: int = 3) -> None:
        normal = normal.tocsc()
        n = width * t
        self._factor(_upper_band(normal[:n, :n], width), normal[:n, n:].toarray(), normal[n:, n:].toarray(), t,
                     width)

    @classmethod
    def of_blocks(cls, band: np.ndarray, pl: np.ndarray, ll: np.ndarray, t: int, width: int = 3) -> NormalFactor:
        """The factor of H given as its blocks: H_pp's upper band (2·width, width·T) (row 2·width − 1 the diagonal,
        as :func:`scipy.linalg.cholesky_banded` reads it), H_pl (width·T, M) and H_ll (M, M), dense."""
        out = cls.__new__(cls)
        out._factor(band, pl, ll, t, width)
        return out

    def _factor(self, band: np.ndarray, pl: np.ndarray, ll: np.ndarray, t: int, width: int) -> None:
        self.t, self.width = t, width
        self.pl = pl
        self.band = scipy.linalg.cholesky_banded(band, lower=False)
        self.x = self._pose_solve(self.pl)                           # H_pp⁻¹ H_pl
        schur = ll - self.pl.T @ self.x
        self.schur = scipy.linalg.cho_factor(0.5 * (schur + schur.T)) if len(schur) else None

    def _pose_solve(self, rhs: np.ndarray) -> np.ndarray:
        return scipy.linalg.cho_solve_banded((self.band, False), rhs) if self.t else rhs

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        n = self.width * self.t
        rp, rl = rhs[:n], rhs[n:]
        dl = scipy.linalg.cho_solve(self.schur, rl - self.pl.T @ self._pose_solve(rp)) if self.schur else rl
        return np.concatenate([self._pose_solve(rp - self.pl @ dl), dl])

    def log_determinant(self) -> float:
        """log det H = log det H_pp + log det S (the Schur complement), from the two Cholesky factors."""
        pose_part = 2.0 * float(np.sum(np.log(self.band[-1]))) if self.t else 0.0
        rest = 2.0 * float(np.sum(np.log(np.diag(self.schur[0])))) if self.schur else 0.0
        return pose_part + rest

    def landmark_covariance(self) -> np.ndarray:
        n = len(self.pl.T)
        return scipy.linalg.cho_solve(self.schur, np.eye(n)) if self.schur else np.zeros((0, 0))

    def pose_covariance_blocks(self, poses: np.ndarray) -> np.ndarray:
        """(P, 3, 3) (x, y, θ) diagonal blocks of H⁻¹ at poses (P,) (1..T): (H_pp⁻¹ + X S⁻¹ Xᵀ) there,
        X = H_pp⁻¹ H_pl."""
        out = np.zeros((len(poses), 3, 3))
        landmark_cov = self.landmark_covariance()
        step = max(1, _COLUMN_BLOCK_ENTRIES // (9 * max(self.t, 1)))
        for chunk in range(0, len(poses), step):
            which = poses[chunk:chunk + step]
            columns = (self.width * (which[:, None] - 1) + np.arange(3)).ravel()
            # the rows before the chunk's first column stay exactly 0 in the forward pass Uᵀy = e, and the back
            # substitution U x = y finds the rows from that column on from the rows after them alone: solving with
            # the trailing block of the same factor gives those rows, with less work the later the chunk
            start = int(columns.min())
            unit = np.zeros((self.width * self.t - start, len(columns)))
            unit[columns - start, np.arange(len(columns))] = 1.0
            own = scipy.linalg.cho_solve_banded((self.band[:, start:], False), unit)[columns - start]
            own = own.reshape(len(which), 3, len(which), 3)
            blocks = own[np.arange(len(which)), :, np.arange(len(which)), :]
            x = self.x[columns].reshape(len(which), 3, -1)
            out[chunk:chunk + len(which)] = blocks + x @ landmark_cov @ x.transpose(0, 2, 1)
        return 0.5 * (out + out.transpose(0, 2, 1))


def _upper_band(pp: sp.spmatrix, width: int) -> np.ndarray:
    """H_pp (width·T, width·T) as the upper band :func:`scipy.linalg.cholesky_banded` reads (half-width 2·width − 1:
    every factor touches at most two consecutive poses)."""
    half = 2 * width - 1
    band = np.zeros((half + 1, pp.shape[0]))
    for offset in range(half + 1):
        band[half - offset, offset:] = pp.diagonal(offset)
    return band


class _NormalEquations:
    """One Gauss–Newton iteration's normal equations JᵀJ δ = −Jᵀr as :class:`NormalFactor` reads them: H_pp's band,
    H_pl and H_ll dense, and the gradient Jᵀr, from the Jacobian's pose columns and its others apart (J_pᵀJ_p,
    J_pᵀJ_r, J_rᵀJ_r). Every entry is the same sum as (JᵀJ)'s, Σ_k J_ki J_kj over the rows k in order (scipy's sparse
    products), so the blocks are JᵀJ's to the bit, without slicing the whole JᵀJ into them and adding the damping to
    it as a sparse sum at every damping step. Damping adds to the blocks' diagonals, the same single addition."""

    def __init__(self, rows: _Rows, residual: np.ndarray, t: int, width: int) -> None:
        n = width * t
        poses, others = rows.csr(0, n), rows.csr(n)
        self.t, self.width = t, width
        self.band = _upper_band(poses.T @ poses, width)
        self.pl = (poses.T @ others).toarray()
        self.ll = (others.T @ others).toarray()
        self.gradient = np.concatenate([poses.T @ residual, others.T @ residual])
        self.diagonal = np.concatenate([self.band[-1], np.diagonal(self.ll)])

    def damped(self, damping: float) -> NormalFactor:
        """The factor of H + damping·diag(max(diag H, 10⁻⁹)) (Levenberg's, scaled as Marquardt's)."""
        add = damping * np.maximum(self.diagonal, 1e-9)
        n = len(self.band[-1])
        band, ll = self.band.copy(), self.ll.copy()
        band[-1] += add[:n]
        ll[np.diag_indices_from(ll)] += add[n:]
        return NormalFactor.of_blocks(band, self.pl, ll, self.t, self.width)


def _marginals(information, t, n_landmarks, seen, covariance_poses, width=3):
    """Landmark (L, 2, 2) and pose (P, 3, 3) blocks of the information's inverse; a landmark never sighted (no
    information) gets an infinite covariance and is left out of the factorisation."""
    free = np.ones(information.shape[0], bool)
    free[width * t:width * t + 2 * n_landmarks] = np.repeat(seen, 2)     # offsets after them: all kept (priors)
    factor = NormalFactor(information[free][:, free], t, width)
    landmark_cov = np.full((n_landmarks, 2, 2), np.inf)
    n_seen = int(seen.sum())
    if n_seen:
        blocks = factor.landmark_covariance()[:2 * n_seen, :2 * n_seen].reshape(n_seen, 2, n_seen, 2)
        landmark_cov[seen] = blocks[np.arange(n_seen), :, np.arange(n_seen), :]
    return landmark_cov, factor.pose_covariance_blocks(covariance_poses)


def landmarks_from_first_sightings(problem: LandmarkLogProblem, poses: np.ndarray) -> np.ndarray:
    """Landmarks (L, 2), each placed by its first sighting from ``poses`` (T + 1, 3): an initial guess."""
    first = np.full(problem.n_landmarks, -1)
    order = np.arange(len(problem.landmark_index))[::-1]
    first[problem.landmark_index[order]] = order          # the last write of each index is its first sighting
    out = np.zeros((problem.n_landmarks, 2))                # an index never sighted stays at the origin
    seen = first >= 0
    at = poses[problem.pose_index[first[seen]]]
    angle = at[:, 2] + problem.bearings[first[seen]]
    out[seen] = at[:, :2] + problem.ranges[first[seen], None] * np.column_stack([np.cos(angle), np.sin(angle)])
    return out
