"""Full-trajectory smoothing of a planar robot's stereo landmark log (given associations), after the filter.

The rendered demo's maps are FastSLAM's best particle: each landmark conditioned on that particle's trajectory,
made online. Once a log is over, the maximum a-posteriori estimate of every pose and every landmark together (full
SLAM; GraphSLAM, square-root SAM) is a direct answer to "which trajectory and map explain all of it". This module
computes it for 3-D point landmarks seen by a stereo head on a planar robot, given each observation's landmark
(from the filter: ``benchmarks/demo_smoothing.py`` re-associates a replayed log to the filter's final map). It is the
stereo counterpart of :mod:`estimation.landmark_smoother` (planar range-bearing sightings) and is used by no default.

The problem, in the map's frame (pose 0 is the frame's origin and is held fixed: the gauge), poses x_k = (x, y, θ),
landmarks m = (x, y, z):

- odometry factors: between(x_k, x_{k+1}) − δ_k, covariance diag of the increment's variances (the filter's random
  walk, :func:`estimation.fastslam.motion.increment_variance`);
- observation factors: (R(θ_k)ᵀ (m_xy − t_k), m_z) − z, covariance Q (3 × 3, base_link: the stereo triangulation's
  covariance with the filter's scale and floor).

Solved by Gauss–Newton with Levenberg damping; the landmarks are eliminated (Schur complement: each landmark is a
3 × 3 block), the poses' reduced system is dense (3T × 3T; T ~ 10³ frames is a few MB). Outliers: the observations
are first weighted by Cauchy's function (scale c = √7.815, χ²₃ 95 %: ρ = c² log(1 + χ²/c²)), then every observation
whose squared normalised
residual exceeds χ²₃ 99 % (11.345, the filter's gate) is dropped and the problem solved again without weights.

Covariances: the inverse of the information matrix JᵀJ at the solution (Laplace): the pose marginals are the inverse
of the reduced system, each landmark's marginal H_ll⁻¹ + H_ll⁻¹ H_lp Σ_pp H_pl H_ll⁻¹. They are as honest as the noise
model. Two errors a landmark's readings share are modelled on request:

- ``landmark_floor``: an offset common to all of a landmark's readings (the marginal gains it; nothing else moves);
- ``view_floor`` (m², per axis), ``view_change`` (rad) and ``range_change`` (ln of a range ratio): an error shared by
  the readings of one landmark taken from about the same view and range. A detector finds a textured corner at the
  same slightly wrong world point while the view hardly changes (consecutive frames; a robot standing still reads
  the same pixels again), and at another wrong point from another view or range. Taken as independent, n readings
  from one view pin the landmark to those poses n times too tightly, and a stretch of the path tied to the rest by
  few landmarks (after a turn) gets a confident wrong pose: session 50, rendered demo seed 9's robot 1, smoothed with
  the white model, 76 % of its landmarks and 24 % of its poses within χ²₃ 95 % (x off by 40–90 mm at σ 14–18 mm
  from 35 s on). Its readings replaced by their landmarks' rendered true points plus white noise of their own Q:
  100 % and 98 % (so the solver and the marginals are right); by each reading's own pixel's true point plus that
  noise: still 86 % and 35 % (the readings of one landmark land on different true points, by view); the odometry
  replaced by the truth plus white noise of its model: unchanged. Not an error shared by a frame's readings: each
  frame's pose fitted robustly to its readings' true landmark points scatters as their own noise says, in turns too
  (z rms 1.05 at 0.35–0.6 rad/s; image-to-truth timing −4 ms, 1.8 mrad at 0.4 rad/s). Measured (each reading
  against its landmark's true point at the true pose; seeds 0, 8, 9): two readings of one landmark share 1.1–2.8e-4
  m² per axis while their views differ by less than 0.2 rad and their ranges by less than 20 %, about half that at
  0.2–0.5 rad or 0.2–0.4 in ln range, nothing beyond 0.7 in ln range (a part common to all of a landmark's readings
  is not in these figures, the true point being their median: it is ``landmark_floor``'s). The design effect models
  it without new variables: reading i of landmark l counts with covariance Q_i + view_floor · Σ_{j≠i} ρ_ij · I,
  ρ_ij = max(0, 1 − Δφ_ij / view_change) · max(0, 1 − |ln(r_i / r_j)| / range_change), Δφ the angle between the
  directions from the landmark to the two robot positions and r their horizontal distances (at the robust
  solution), over the inlier readings of l. So n readings from one view weigh as (Q/n + view_floor)⁻¹, and views
  far enough apart count as independent. The Cauchy weights and the χ²₃ 99 % cut judge each reading by its own
  covariance Q_i (the shared error does not make a single reading less likely); the final solve and the marginals
  use the inflated ones. ``view_floor`` 0 (the default) is the white model: readings independent given their
  landmark.

``view_model`` says where ``view_floor``'s error enters. ``"design"`` (the default): the weights, as above; the
estimate moves, each view down-weighted rather than decorrelated (session 50: the rendered demo's final fusion within
0.05 m / 0.01 rad on 6 of 8 found seeds, the white model's maps 8 of 8). ``"sandwich"``: the white model's weights, cut
and estimate, to the bit, with that estimate's covariance under the correlated error.

*The sandwich.* The white estimate solves JᵀW r = 0 (W: the readings' Q_i⁻¹ and the odometry's inverse variances);
to first order its error is −H⁻¹ JᵀW ε with H = JᵀWJ, so if the errors ε have covariance Σ, its covariance is
H⁻¹ (JᵀW Σ W J) H⁻¹. Σ: Q_i on the diagonal (a reading's whole error), view_floor · ρ_ij · J_m,i J_m,jᵀ between two
inlier readings i ≠ j of one landmark (a world-frame offset of the point found, shared as ρ says; J_m,i the reading's
Jacobian by the landmark, a rotation), the odometry white. So JᵀWΣWJ = H + view_floor · Δ with
Δ = Σ_l Σ_{i≠j∈l} ρ_ij G_i G_jᵀ, G_i = J_iᵀ W_i J_m,i (non-zero on reading i's pose and landmark only), and the
covariance is H⁻¹ + view_floor · H⁻¹ Δ H⁻¹: the white one plus a term linear in view_floor. With the landmarks
eliminated as in the white marginals, the poses' part is S⁻¹ Δ_p S⁻¹ (S the reduced system, Δ_p = Σ_l Σ ρ_ij y_i y_jᵀ
with y_i reading i's G_i reduced, non-zero only on the poses that read l; one dense product); each landmark's 3 × 3
marginal gains the poses' part through H_ll⁻¹ H_lp (as S⁻¹ enters the white one) and terms local to the poses that
read it (:func:`_view_sandwich`). No readings × readings matrix is formed; on the rendered demo (session 51, 20 maps,
490–750 frames, 10–27 thousand inlier readings) the marginals take 1.0 s against the white model's 0.38 s (CPU, medians;
the whole smoothing 2.9 s). Σ is a covariance when view_floor ≤ each reading's smallest variance (the shared part of
a reading's error within its whole stated error; ρ, a product of triangle kernels, is positive semi-definite), so a
larger view_floor is refused: beyond it the sandwich can be indefinite (seen: negative pose NEES on the demo at
1.6e-3 m²). ``landmark_floor`` combines with it by addition: a common offset o_l of landmark l's readings enters
reading i as J_m,i o_l, its middle term is (H e_l) F (H e_l)ᵀ and its sandwich exactly F on l's marginal, which is
what the white model adds. Checked against the dense H⁻¹ JᵀWΣWJ H⁻¹ (to 4e-15), against the delta method through the
estimate and by Monte Carlo (tests/estimation/test_stereo_smoothing_sandwich.py).

Session 51, rendered demo seeds 0–9 (session 49's logs; white estimate, sandwich at view_floor 4e-4 m², the filter's
observation_var_floor, the rest as the white model): landmark NEES within χ²₃ 95 % ≥ 90 % on 18 of 20 maps as the white
model (seed 9's robot 1 76 → 85 %, seed 4's robot 1, which lost its frame, 78 %; every other map 97–99 %), pose NEES
≥ 90 % on 13 of 20 (white 7; median 94 %, white 82 %); the demo's final fusion found on 9 seeds, all within the goal,
as with the white covariances (two alignments lose one support; they move by ≤ 2.3 mm, 0.26 mrad). Seed 9's robot 1
stays overconfident: its x is 43–83 mm off from 37 s at σ 19–24 mm (white 14–18); view_floor 8e-4 would give 91 %
and 1.6e-3 98 %, more than each reading's own floor (4e-4), and wider view or range kernels do not help (85 %).
With :mod:`estimation.stereo_readings`' keyframes (fewer readings from one view) and the sandwich at 4e-4: 89.5 %
(0.1 m / 0.1 rad; keyframes alone 86 %) and 95 % (0.25 m / 0.2 rad; alone 91 %), the fusion within the goal on 9 of 9
found in each.

*Odometry scales* (``calibrate_odometry``, off by default; session 52). A wheel's distance and a skid-steer's turning
are wrong by a scale that persists through a run (worn tyres, the effective track; the demo's virtual robots:
``--odometry realistic``, distance 0.99 and turning 0.99 / 1.03 ≈ 0.961 of the truth), which independent increments
do not model. As Kümmerle et al. (IROS 2011, "Simultaneous calibration, localization, and mapping") do in graph SLAM,
two more unknowns, s_d and s_θ (measured / true), each with the prior N(1, 0.05²) (:data:`ODOMETRY_SCALE_SIGMA`: a
few per cent known before any calibration; not fitted to the demo): each odometry factor predicts
(s_d·bx, s_d·by, s_θ·bθ) with (bx, by, bθ) = between(x_k, x_{k+1}). For keyframes (increments composed of frames)
this is the composed measured increment to first order: within one increment the headings turned are ≤ ~0.1 rad, so
a turn scale moves its lateral part by (1 − s_θ) · by (0.2 mm at 4 % and 5 mm) against the increment's σ of ~1 cm.
The scales touch only the odometry factors and their prior: their two columns border the reduced pose system (3(T−1)
+ 2, solved and inverted as before), the bordered inverse's pose block is the poses' marginal with the scales unknown,
and as no reading sees the scales the landmarks' marginals and the sandwich's middle term use that block unchanged
(the scales' own sandwich term is their rows of S⁻¹ times Δ). Checked against a dense inverse of the documented
model's information matrix (white and sandwich), a Monte Carlo and the truth the odometry was drawn with
(tests/estimation/test_s52_odometry_calibration.py).

Session 52, rendered demo seeds 0–9 (the day's default demo: keyframes, sandwich; ``benchmarks.demo_odometry_
calibration``, which reads the truth only to score): s_d 0.9874–0.9972 (mean 0.9921, σ 0.006) and s_θ 0.9508–0.9635
(mean 0.9588, σ 0.009–0.010) on the 20 maps, against the mock's 0.99 and 0.961 ((estimate − mock) / σ rms 0.57 and
0.40: the motion model's variances are about twice the demo odometry's noise, see below). The keyframes' heading
error rms falls from 10.4 to 6.5 mrad (median of the maps; robot 2's 12.4 → 7.3: in turns on the spot, where few
landmarks hold the heading, the odometry's 4 % short turning was taken as the truth); landmark NEES ≥ 90 % on 19 of 20
maps (18 without: seed 9's robot 1 89.2 → 91.8 %; seed 4's robot 1, which lost its frame, 78 % either way), pose NEES
≥ 90 % on 14 of 20 either way (median 92 → 93 %), ATE median 0.028 m either way, the final fusion found on the same 9
seeds, none wrong, errors moved by −13 to +4 mm (seed 3: 0.049 → 0.051 m, just past the 0.05 m goal), smoothing time
unchanged. Not what makes seed 9's robot 1 overconfident: smoothed with the true odometry (exact keyframe increments)
its poses are as wrong (x off by up to 74 mm at σ 22 mm around 70 s, 73 % of the poses within χ²₃ 95 %; 70 % with the
measured odometry): the demo's keyframe increments differ from the true ones by 0.57 σ (x), 0.17 σ (y) and 0.62 σ (θ)
of the motion model, scale and all, so the 1 % and 4 % scales lie within the odometry's stated variance. The readings
do it: 13.5 % of its inlier readings see a physical point more than 5 cm from their landmark's (the median of its
readings' true points; 1 % beyond 0.69 m), most of them (70 %) with a χ² below 3 (no residual test finds them);
without them (an oracle) 99 % of its poses and 98 % of its landmarks are within χ²₃ 95 %, and with every reading
replaced by its landmark's true point plus white noise of its own covariance, 100 % and 99.9 %. So on all 20 maps
(``--diagnose``): poses within χ²₃ 95 % median 92 % as measured, 92 % with the true odometry (≥ 90 % on 15 of 20
against 14), 99 % with the off-point readings cut (≥ 90 % on 20 of 20; 10–15 % of each map's readings, 65–74 % of
them with χ² < 3); the heading error follows the odometry (keyframes' rms median 10.4 mrad, 5.3 with the true
odometry, 6.5 with the measured odometry divided by the mock's scales, which is what the estimated scales give).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse as sp

from .geometry import between, wrap_angle

CAUCHY_C = float(np.sqrt(7.815))  # σ: the Cauchy loss's scale on the whitened residual norm (χ²₃ 95 %). Not Huber's:
#                                   a wrong association costs Huber a constant pull, and 5 % of them (3-D points
#                                   given another landmark) moved synthetic poses further than dead reckoning
#                                   (tests/estimation/test_stereo_smoothing.py); Cauchy's pull fades with the residual
OUTLIER_CHI2 = 11.345             # χ²₃ 99 %: an observation beyond it after the robust solve is dropped
VIEW_CHANGE = 0.4                 # rad: ρ = 1 − Δφ/0.4 between two views of one landmark (session 50, rendered demo:
#                                   the shared error holds its size to 0.2 rad and halves by 0.2–0.5 rad)
RANGE_CHANGE = 0.7                # |ln(r_i / r_j)|: ρ falls as 1 − |Δ ln r|/0.7 with the range (measured: the same
#                                   size to 0.2, about 60 % at 0.2–0.4, 35 % at 0.4–0.7, none beyond)
VIEW_MODELS = ("design", "sandwich")  # where view_floor's error enters: the weights (design effect) or only the
#                                   covariances of the white model's estimate (sandwich)
MAX_ITERATIONS = 50
STEP_TOLERANCE = 1e-6             # stop when no variable moves more than this (m or rad)
COST_TOLERANCE = 1e-9             # ... or an accepted step lowers the cost by less than this fraction
ODOMETRY_SCALE_SIGMA = 0.05       # σ of the prior N(1, σ²) on each odometry scale (calibrate_odometry): a wheel's
#                                   distance and a skid-steer's turning are known to a few per cent before any
#                                   calibration (the P3-AT's tyre wear, its effective track); weak beside what a run
#                                   of metres and radians between landmark-held poses determines
_CHUNK = 256                      # landmarks per block of the marginals' dense product


class StereoSmoothingError(ValueError):
    """The problem is malformed (shapes, indices, covariances)."""


@dataclass
class StereoLogProblem:
    """T poses (frames), L landmarks, K observations.

    increments (T−1, 3): the odometry's (dx, dy, dθ) from pose k to k+1 in pose k's frame; increment_variances
    (T−1, 3) their variances; pose_index, landmark_index (K,): which pose saw which landmark; points (K, 3) the
    observed point in the robot's frame (base_link), covariances (K, 3, 3) its covariance.
    """

    increments: np.ndarray
    increment_variances: np.ndarray
    pose_index: np.ndarray
    landmark_index: np.ndarray
    points: np.ndarray
    covariances: np.ndarray
    n_landmarks: int

    def __post_init__(self) -> None:
        self.increments = np.asarray(self.increments, float).reshape(-1, 3)
        self.increment_variances = np.asarray(self.increment_variances, float).reshape(-1, 3)
        self.pose_index = np.asarray(self.pose_index, np.int64).reshape(-1)
        self.landmark_index = np.asarray(self.landmark_index, np.int64).reshape(-1)
        self.points = np.asarray(self.points, float).reshape(-1, 3)
        self.covariances = np.asarray(self.covariances, float).reshape(-1, 3, 3)
        k, t = len(self.pose_index), self.n_poses
        if self.increment_variances.shape != self.increments.shape:
            raise StereoSmoothingError(f"{len(self.increments)} increments but {len(self.increment_variances)} "
                                       "variance rows")
        if not (np.all(np.isfinite(self.increment_variances)) and np.all(self.increment_variances > 0)):
            raise StereoSmoothingError("increment variances must be finite and > 0")
        if not (len(self.landmark_index) == len(self.points) == len(self.covariances) == k):
            raise StereoSmoothingError("pose_index, landmark_index, points and covariances need one row each per "
                                       "observation")
        if k and (self.pose_index.min() < 0 or self.pose_index.max() >= t):
            raise StereoSmoothingError(f"pose_index outside 0..{t - 1}")
        if k and (self.landmark_index.min() < 0 or self.landmark_index.max() >= self.n_landmarks):
            raise StereoSmoothingError(f"landmark_index outside 0..{self.n_landmarks - 1}")
        if not (np.all(np.isfinite(self.points)) and np.all(np.isfinite(self.covariances))):
            raise StereoSmoothingError("observations hold non-finite points or covariances")

    @property
    def n_poses(self) -> int:
        return len(self.increments) + 1


@dataclass
class StereoSmoothed:
    """The solution: poses (T, 3), landmarks (L, 3), their marginal covariances (T, 3, 3) and (L, 3, 3) (pose 0's
    zero: the gauge; a landmark no inlier observation holds keeps its start and an infinite covariance), which
    observations were kept (``inliers``, (K,) bool), the final χ² and its degrees of freedom, iterations; with
    ``calibrate_odometry`` the odometry's estimated distance and turn scales (s_d, s_θ) and their 2 × 2 marginal
    covariance (None without)."""

    poses: np.ndarray
    landmarks: np.ndarray
    pose_covariances: np.ndarray
    landmark_covariances: np.ndarray
    inliers: np.ndarray
    chi2: float
    dof: int
    iterations: int
    odometry_scales: np.ndarray | None = None              # (2,) (s_d, s_θ) with calibrate_odometry, else None
    odometry_scale_covariance: np.ndarray | None = None    # (2, 2) their marginal covariance (as the poses')

    @property
    def chi2_per_dof(self) -> float:
        return self.chi2 / max(self.dof, 1)

    @property
    def held(self) -> np.ndarray:
        """(L,) bool: landmarks that some inlier observation holds (a finite covariance)."""
        return np.isfinite(self.landmark_covariances[:, 0, 0])


def smooth(problem: StereoLogProblem, initial_poses: np.ndarray, initial_landmarks: np.ndarray, *,
           robust: bool = True, max_iterations: int = MAX_ITERATIONS, landmark_floor=0.0, view_floor: float = 0.0,
           view_change: float = VIEW_CHANGE, range_change: float = RANGE_CHANGE,
           view_model: str = "design", calibrate_odometry: bool = False,
           odometry_scale_sigma: float = ODOMETRY_SCALE_SIGMA) -> StereoSmoothed:
    """The MAP poses and landmarks from the initial ones (pose 0 held where it is: the map frame); with ``robust``,
    Cauchy-weighted first, then without the observations beyond χ²₃ 99 % (module docstring).

    ``landmark_floor`` (m², a scalar × I or a 3 × 3 matrix): an error shared by all the readings of one landmark
    (a model error that repetition does not average away: the same corner found at the same wrong sub-pixel place
    from nearby views). Its offset o_l enters every reading of l as m_l + o_l, so m_l + o_l is what the readings
    determine: the poses and the estimates are unchanged and each held landmark's marginal covariance gains the
    floor (Σ_l + F). 0: the readings' errors are independent (the solution's own marginals).

    ``view_floor`` (m² per axis, ≥ 0), ``view_change`` (rad, > 0) and ``range_change`` (> 0, in ln range): an error
    shared by a landmark's readings taken from about the same view and range (module docstring): each inlier
    reading's covariance gains view_floor times the sum of its correlations with the landmark's other inlier
    readings, for the final solve and the marginals. Unlike ``landmark_floor`` it moves the poses: a stretch of the
    path that many readings from few views tie to the rest is held less tightly, and says so. 0 (the default):
    none, the estimates and covariances of the white model.

    ``view_model`` ("design", the default, or "sandwich"): where ``view_floor``'s error enters. "design": the
    weights, as just said. "sandwich": only the covariances: the white model's estimate, inliers and χ² to the bit,
    its pose and landmark marginals H⁻¹ (JᵀW Σ W J) H⁻¹ under readings of one landmark that share view_floor · ρ_ij
    (module docstring, *The sandwich*); view_floor must not exceed any reading's smallest variance; with 0 the white
    model's covariances exactly. ``landmark_floor`` adds to the landmarks' marginals in both.

    ``calibrate_odometry`` (False: the default, the odometry taken as unbiased): two more unknowns, the odometry's
    distance scale s_d and turn scale s_θ (measured / true; module docstring, *Odometry scales*), each with the prior
    N(1, ``odometry_scale_sigma``²); every odometry factor predicts (s_d·bx, s_d·by, s_θ·bθ) from
    (bx, by, bθ) = between(x_k, x_{k+1}). The poses', landmarks' and scales' covariances are then their marginals
    with the scales unknown (in every view_model)."""
    if not (np.isfinite(view_floor) and view_floor >= 0):
        raise StereoSmoothingError(f"view_floor must be a finite number ≥ 0 (m²), not {view_floor!r}")
    if not (np.isfinite(view_change) and view_change > 0):
        raise StereoSmoothingError(f"view_change must be a finite angle > 0 (rad), not {view_change!r}")
    if not (np.isfinite(range_change) and range_change > 0):
        raise StereoSmoothingError(f"range_change must be a finite number > 0 (ln of a range ratio), not "
                                   f"{range_change!r}")
    if view_model not in VIEW_MODELS:
        raise StereoSmoothingError(f"view_model must be one of {', '.join(VIEW_MODELS)}, not {view_model!r}")
    if not isinstance(calibrate_odometry, (bool, np.bool_)):
        raise StereoSmoothingError(f"calibrate_odometry must be True or False, not {calibrate_odometry!r}")
    if not (isinstance(odometry_scale_sigma, (int, float, np.floating, np.integer))
            and np.isfinite(odometry_scale_sigma) and odometry_scale_sigma > 0):
        raise StereoSmoothingError(f"odometry_scale_sigma must be a finite number > 0 (the scales' prior σ), not "
                                   f"{odometry_scale_sigma!r}")
    if view_model == "sandwich" and len(problem.covariances):
        smallest = np.linalg.eigvalsh(0.5 * (problem.covariances + np.swapaxes(problem.covariances, 1, 2)))[:, 0]
        k = int(np.argmin(smallest))
        if view_floor > smallest[k]:
            raise StereoSmoothingError(f"view_floor {view_floor:g} m² exceeds observation {k}'s smallest variance "
                                       f"{smallest[k]:.3g} m²: the view-shared part of a reading's error cannot be "
                                       "larger than its covariance (view_model 'sandwich')")
    floor = np.asarray(landmark_floor, float) * (np.eye(3) if np.ndim(landmark_floor) == 0 else 1.0)
    if floor.shape != (3, 3) or not np.all(np.isfinite(floor)) or np.any(np.linalg.eigvalsh(floor) < -1e-15):
        raise StereoSmoothingError("landmark_floor must be a finite scalar ≥ 0 or a 3 × 3 positive semi-definite "
                                   "matrix, m²")
    poses = np.array(initial_poses, float).reshape(-1, 3)
    landmarks = np.array(initial_landmarks, float).reshape(-1, 3)
    if len(poses) != problem.n_poses or len(landmarks) != problem.n_landmarks:
        raise StereoSmoothingError(f"{len(poses)} initial poses and {len(landmarks)} landmarks for a problem of "
                                   f"{problem.n_poses} and {problem.n_landmarks}")
    whiten = _whitening(problem.covariances)
    inliers = np.ones(len(problem.pose_index), bool)
    iterations = 0
    scales = _Scales(np.ones(2), float(odometry_scale_sigma)) if calibrate_odometry else None
    if robust:
        poses, landmarks, n = _solve(problem, whiten, poses, landmarks, inliers, True, max_iterations, scales)
        iterations += n
        inliers = _observation_chi2(problem, whiten, poses, landmarks) <= OUTLIER_CHI2
    if view_floor > 0 and view_model == "design":
        shared = view_floor * _view_correlation_sums(problem, poses, landmarks, inliers, view_change, range_change)
        whiten = _whitening(problem.covariances + shared[:, None, None] * np.eye(3))
    poses, landmarks, n = _solve(problem, whiten, poses, landmarks, inliers, False, max_iterations, scales)
    iterations += n
    pose_cov, landmark_cov, scale_cov = _marginals(
        problem, whiten, poses, landmarks, inliers,
        (view_floor, view_change, range_change) if view_model == "sandwich" else None, scales)
    landmark_cov = landmark_cov + floor
    # the cost without Cauchy's weights; with the scales, their prior rows pay for them: the degrees of freedom stay
    chi2 = _total_cost(problem, whiten, poses, landmarks, inliers, False, scales)
    held = np.isfinite(landmark_cov[:, 0, 0])
    dof = 3 * int(inliers.sum()) - 3 * int(held.sum())   # the odometry's 3(T−1) rows pay for the 3(T−1) poses
    return StereoSmoothed(poses, landmarks, pose_cov, landmark_cov, inliers, chi2, dof, iterations,
                          None if scales is None else scales.values.copy(), scale_cov)


def observation_chi2(problem: StereoLogProblem, poses: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """(K,) each observation's squared normalised residual at these poses and landmarks."""
    return _observation_chi2(problem, _whitening(problem.covariances), np.asarray(poses, float),
                             np.asarray(landmarks, float))


# -- internals ------------------------------------------------------------------------------------------------
def _whitening(covariances: np.ndarray) -> np.ndarray:
    """(K, 3, 3) A_k with A_kᵀ A_k = Q_k⁻¹ (upper: the transposed Cholesky factor of Q⁻¹)."""
    if not len(covariances):
        return np.zeros((0, 3, 3))
    sym = 0.5 * (covariances + np.swapaxes(covariances, 1, 2))
    try:
        lower = np.linalg.cholesky(np.linalg.inv(sym))
    except np.linalg.LinAlgError:
        raise StereoSmoothingError("an observation covariance is not positive definite") from None
    return np.swapaxes(lower, 1, 2)


def _view_groups(problem, poses, landmarks, inliers, view_change, range_change):
    """(landmark, rows, ρ) for each landmark with two or more inlier readings: ``rows`` its inlier readings (sorted by
    the direction from the landmark to the robot), ρ (n × n, ones on the diagonal) their correlations
    ρ_ij = max(0, 1 − Δφ_ij / view_change) · max(0, 1 − |ln(r_i / r_j)| / range_change), Δφ the angle between the
    directions from the landmark to the robot at the two readings, r the horizontal distances."""
    p = poses[problem.pose_index]
    m = landmarks[problem.landmark_index]
    phi = np.arctan2(p[:, 1] - m[:, 1], p[:, 0] - m[:, 0])
    log_r = np.log(np.maximum(np.hypot(p[:, 1] - m[:, 1], p[:, 0] - m[:, 0]), 1e-3))
    idx = np.flatnonzero(inliers)
    order = idx[np.lexsort((phi[idx], problem.landmark_index[idx]))]
    lms = problem.landmark_index[order]
    bounds = np.flatnonzero(np.r_[True, lms[1:] != lms[:-1], True])
    for a, b in zip(bounds[:-1], bounds[1:], strict=False):
        if b - a < 2:
            continue
        rows = order[a:b]
        d = np.abs(wrap_angle(phi[rows][:, None] - phi[rows][None, :]))
        dr = np.abs(log_r[rows][:, None] - log_r[rows][None, :])
        yield int(lms[a]), rows, np.maximum(0.0, 1.0 - d / view_change) * np.maximum(0.0, 1.0 - dr / range_change)


def _view_correlation_sums(problem, poses, landmarks, inliers, view_change, range_change) -> np.ndarray:
    """(K,) Σ_{j≠i} ρ_ij over the inlier readings j of reading i's landmark (:func:`_view_groups`); 0 for an
    outlier."""
    out = np.zeros(len(problem.pose_index))
    for _, rows, rho in _view_groups(problem, poses, landmarks, inliers, view_change, range_change):
        out[rows] = rho.sum(axis=1) - 1.0
    return out


def _observation_terms(problem, whiten, poses, landmarks):
    """Whitened residuals (K, 3) and Jacobians by the pose (K, 3, 3) and the landmark (K, 3, 3)."""
    p = poses[problem.pose_index]
    m = landmarks[problem.landmark_index]
    c, s = np.cos(p[:, 2]), np.sin(p[:, 2])
    dx, dy = m[:, 0] - p[:, 0], m[:, 1] - p[:, 1]
    hx, hy = c * dx + s * dy, -s * dx + c * dy
    e = np.column_stack([hx, hy, m[:, 2]]) - problem.points
    k = len(p)
    jp = np.zeros((k, 3, 3))
    jp[:, 0, 0], jp[:, 0, 1], jp[:, 0, 2] = -c, -s, hy
    jp[:, 1, 0], jp[:, 1, 1], jp[:, 1, 2] = s, -c, -hx
    jl = np.zeros((k, 3, 3))
    jl[:, 0, 0], jl[:, 0, 1] = c, s
    jl[:, 1, 0], jl[:, 1, 1] = -s, c
    jl[:, 2, 2] = 1.0
    return (whiten @ e[:, :, None])[:, :, 0], whiten @ jp, whiten @ jl


def _observation_chi2(problem, whiten, poses, landmarks) -> np.ndarray:
    e, _, _ = _observation_terms(problem, whiten, poses, landmarks)
    return np.sum(e * e, axis=1)


@dataclass
class _Scales:
    """The odometry's distance and turn scales (s_d, s_θ) being estimated and their prior's σ (around 1)."""

    values: np.ndarray
    sigma: float

    def factor(self) -> np.ndarray:
        """(3,) what multiplies between(x_k, x_{k+1}) in an odometry factor: (s_d, s_d, s_θ)."""
        return self.values[[0, 0, 1]]

    def prior_residuals(self) -> np.ndarray:
        return (self.values - 1.0) / self.sigma


def _odometry_residuals(problem, poses, relative: np.ndarray | None = None, scales: _Scales | None = None
                        ) -> np.ndarray:
    """Whitened residuals (T−1, 3) of the odometry increments; ``relative``: between(pose k, pose k+1) if known;
    ``scales``: the factor predicts (s_d·bx, s_d·by, s_θ·bθ)."""
    predicted = between(poses[:-1], poses[1:]) if relative is None else relative
    e = (predicted if scales is None else predicted * scales.factor()) - problem.increments
    e[:, 2] = wrap_angle(e[:, 2])
    return e / np.sqrt(problem.increment_variances)


def _odometry_terms(problem, poses, scales: _Scales | None = None):
    """Whitened residuals (T−1, 3) and Jacobians by pose k and pose k+1 (T−1, 3, 3); with ``scales`` also by
    (s_d, s_θ) (T−1, 3, 2)."""
    a = poses[:-1]
    relative = between(a, poses[1:])
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    bx, by = relative[:, 0], relative[:, 1]
    n = len(a)
    ja = np.zeros((n, 3, 3))
    ja[:, 0, 0], ja[:, 0, 1], ja[:, 0, 2] = -c, -s, by
    ja[:, 1, 0], ja[:, 1, 1], ja[:, 1, 2] = s, -c, -bx
    ja[:, 2, 2] = -1.0
    jb = np.zeros((n, 3, 3))
    jb[:, 0, 0], jb[:, 0, 1] = c, s
    jb[:, 1, 0], jb[:, 1, 1] = -s, c
    jb[:, 2, 2] = 1.0
    w = 1.0 / np.sqrt(problem.increment_variances)
    if scales is None:
        return _odometry_residuals(problem, poses, relative), ja * w[:, :, None], jb * w[:, :, None]
    f = scales.factor()[None, :, None] * w[:, :, None]
    js = np.zeros((n, 3, 2))
    js[:, 0, 0], js[:, 1, 0], js[:, 2, 1] = bx, by, relative[:, 2]
    return (_odometry_residuals(problem, poses, relative, scales), ja * f, jb * f, js * w[:, :, None])


def _tmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(K, 3, 3) aₖᵀ bₖ."""
    return np.swapaxes(a, 1, 2) @ b


def _tvec(a: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(K, 3) aₖᵀ vₖ."""
    return (np.swapaxes(a, 1, 2) @ v[:, :, None])[:, :, 0]


def _block_coo(rows: np.ndarray, cols: np.ndarray, blocks: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Entries of 3 × 3 blocks at block rows/cols."""
    r = (3 * rows[:, None, None] + np.arange(3)[None, :, None]).repeat(3, 2)
    c = (3 * cols[:, None, None] + np.arange(3)[None, None, :]).repeat(3, 1)
    return r.ravel(), c.ravel(), blocks.ravel()


class _System:
    """The normal equations at one linearisation, landmarks eliminated: S Δp = r (poses 1..T−1; with ``scales``
    bordered by the two odometry scales, which only the odometry factors and their prior see)."""

    def __init__(self, problem, whiten, poses, landmarks, inliers, weights, scales: _Scales | None = None):
        t, n_l = problem.n_poses, problem.n_landmarks
        e, jp, jl = _observation_terms(problem, whiten, poses, landmarks)
        keep = inliers & (weights > 0)
        e, jp, jl, w = e[keep], jp[keep], jl[keep], weights[keep]
        pi, li = problem.pose_index[keep], problem.landmark_index[keep]
        if scales is None:
            eo, ja, jb = _odometry_terms(problem, poses)
        else:
            eo, ja, jb, js = _odometry_terms(problem, poses, scales)
        wjp, wjl = jp * w[:, None, None], jl * w[:, None, None]
        # pose-pose (dense 3T × 3T), then the gauge's rows dropped
        hpp = np.zeros((3 * t, 3 * t))
        blocks = [(pi, pi, _tmul(wjp, jp))]
        k = np.arange(t - 1)
        blocks += [(k, k, _tmul(ja, ja)), (k + 1, k + 1, _tmul(jb, jb)),
                   (k, k + 1, _tmul(ja, jb)), (k + 1, k, _tmul(jb, ja))]
        for rows, cols, b in blocks:
            r, c, v = _block_coo(rows, cols, b)
            np.add.at(hpp, (r, c), v)
        gp = np.zeros(3 * t)
        np.add.at(gp, (3 * pi[:, None] + np.arange(3)).ravel(), _tvec(wjp, e).ravel())
        np.add.at(gp, (3 * k[:, None] + np.arange(3)).ravel(), _tvec(ja, eo).ravel())
        np.add.at(gp, (3 * (k + 1)[:, None] + np.arange(3)).ravel(), _tvec(jb, eo).ravel())
        # landmark blocks and pose-landmark coupling
        hll = np.zeros((n_l, 3, 3))
        np.add.at(hll, li, _tmul(wjl, jl))
        gl = np.zeros((n_l, 3))
        np.add.at(gl, li, _tvec(wjl, e))
        self.held = np.zeros(n_l, bool)
        self.held[li] = True
        hll[~self.held] = np.eye(3)           # no observation: no step (and no covariance, see _marginals)
        gl[~self.held] = 0.0
        r, c, v = _block_coo(pi, li, _tmul(wjp, jl))
        self.border = 0
        if scales is not None:      # the scales' two rows and columns after the poses' (a border)
            self.border = 2
            hps = np.zeros((t, 3, 2))
            np.add.at(hps, k, _tmul(ja, js))
            np.add.at(hps, k + 1, _tmul(jb, js))
            hss = np.einsum("kai,kaj->ij", js, js) + np.eye(2) / scales.sigma ** 2
            gs = np.einsum("kai,ka->i", js, eo) + scales.prior_residuals() / scales.sigma
            hpp = np.block([[hpp, hps.reshape(3 * t, 2)], [hps.reshape(3 * t, 2).T, hss]])
            gp = np.concatenate([gp, gs])
        self.w = sp.csr_matrix((v, (r, c)), shape=(3 * t + self.border, 3 * n_l))
        self.hpp, self.gp, self.hll, self.gl = hpp, gp, hll, gl
        self.n_poses, self.n_landmarks = t, n_l

    def step(self, damping: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(Δposes (T, 3), Δlandmarks (L, 3), Δscales (2,) or (0,)) of the damped Gauss–Newton step (pose 0
        held)."""
        hll = self.hll + damping * np.einsum("kii->ki", self.hll)[:, :, None] * np.eye(3)
        hll_inv = np.linalg.inv(hll)
        hinv = sp.block_diag(list(hll_inv), format="csr") if self.n_landmarks else sp.csr_matrix((0, 0))
        m = (hinv @ self.w.T).tocsr()                                  # H_ll⁻¹ H_lp (3L × 3T)
        s = self.hpp - (self.w @ m).toarray()
        s[np.diag_indices_from(s)] += damping * np.diag(self.hpp)
        rhs = -(self.gp - m.T @ self.gl.ravel())
        s, rhs = s[3:, 3:], rhs[3:]
        dp = np.zeros(3 * self.n_poses + self.border)
        dp[3:] = scipy.linalg.cho_solve(scipy.linalg.cho_factor(s), rhs)
        dl = -(hll_inv @ self.gl[:, :, None])[:, :, 0] - (m @ dp).reshape(-1, 3)
        dl[~self.held] = 0.0
        t3 = 3 * self.n_poses
        return dp[:t3].reshape(-1, 3), dl, dp[t3:]


def _robust_weights(chi2: np.ndarray, robust: bool) -> np.ndarray:
    """IRLS weights of Cauchy's loss (1 without ``robust``)."""
    return 1.0 / (1.0 + chi2 / CAUCHY_C ** 2) if robust else np.ones_like(chi2)


def _robust_rho(chi2: np.ndarray, robust: bool) -> np.ndarray:
    """Cauchy's ρ of the squared whitened residual, as a contribution to 2 × cost (χ² without ``robust``)."""
    return CAUCHY_C ** 2 * np.log1p(chi2 / CAUCHY_C ** 2) if robust else chi2


def _total_cost(problem, whiten, poses, landmarks, inliers, robust, scales: _Scales | None = None) -> float:
    """Twice the cost: the observations' (Cauchy's ρ when ``robust``, else χ²) over the inliers, the odometry's squared
    whitened residuals and, with ``scales``, their prior's."""
    chi2 = _observation_chi2(problem, whiten, poses, landmarks)[inliers]
    prior = 0.0 if scales is None else np.sum(scales.prior_residuals() ** 2)
    return float(np.sum(_robust_rho(chi2, robust)) + np.sum(_odometry_residuals(problem, poses, scales=scales) ** 2)
                 + prior)


def _solve(problem, whiten, poses, landmarks, inliers, robust, max_iterations, scales: _Scales | None = None):
    """Levenberg–Marquardt from (poses, landmarks); Cauchy's weights (IRLS) when ``robust``; ``scales`` (the odometry
    scales, when estimated) is updated in place."""
    cost = _total_cost(problem, whiten, poses, landmarks, inliers, robust, scales)
    damping = 0.0
    iterations = 0
    while iterations < max_iterations:
        iterations += 1
        weights = _robust_weights(_observation_chi2(problem, whiten, poses, landmarks), robust)
        system = _System(problem, whiten, poses, landmarks, inliers, weights, scales)
        while True:
            dp, dl, ds = system.step(damping)
            new_poses = poses + dp
            new_poses[:, 2] = wrap_angle(new_poses[:, 2])
            new_landmarks = landmarks + dl
            new_scales = None if scales is None else _Scales(scales.values + ds, scales.sigma)
            new_cost = _total_cost(problem, whiten, new_poses, new_landmarks, inliers, robust, new_scales)
            if new_cost <= cost * (1 + 1e-12) or damping > 1e6:
                break
            damping = max(1e-4, damping * 10)
        moved = max(float(np.abs(dp).max(initial=0.0)), float(np.abs(dl).max(initial=0.0)),
                    float(np.abs(ds).max(initial=0.0)))
        gain = cost - new_cost
        if new_cost <= cost * (1 + 1e-12):
            poses, landmarks, cost = new_poses, new_landmarks, new_cost
            if scales is not None:
                scales.values = new_scales.values
            damping = damping / 10 if damping > 1e-4 else 0.0
        if moved < STEP_TOLERANCE or damping > 1e6 or 0 <= gain < COST_TOLERANCE * cost:
            break
    return poses, landmarks, iterations


def _marginals(problem, whiten, poses, landmarks, inliers, view=None, scales: _Scales | None = None):
    """Pose marginals (T, 3, 3), landmark marginals (L, 3, 3) and, with ``scales``, the scales' (2, 2) (else None)
    from JᵀJ at the solution (unweighted); with ``view`` = (view_floor, view_change, range_change), the sandwich
    H⁻¹ JᵀW Σ W J H⁻¹ of :func:`_view_sandwich`. With the scales the reduced system is bordered by their two rows and
    columns; its inverse's pose block is the poses' marginal with the scales unknown, and as the readings do not see
    the scales, that block is all the landmarks' marginals and the sandwich's middle term need."""
    system = _System(problem, whiten, poses, landmarks, inliers, np.ones(len(problem.pose_index)), scales)
    t = problem.n_poses
    hll_inv = np.linalg.inv(system.hll)
    hinv = sp.block_diag(list(hll_inv), format="csr") if problem.n_landmarks else sp.csr_matrix((0, 0))
    m = (hinv @ system.w.T).tocsr()[:, 3:3 * t]                       # H_ll⁻¹ H_lp, the gauge's columns dropped
    s = (system.hpp - (system.w @ (hinv @ system.w.T)).toarray())[3:, 3:]
    cov_pp = scipy.linalg.cho_solve(scipy.linalg.cho_factor(s), np.eye(len(s)))
    scale_cov = border = None
    if scales is not None:
        free = 3 * (t - 1)
        scale_cov, border = cov_pp[free:, free:].copy(), cov_pp[free:, :free].copy()
        cov_pp = np.ascontiguousarray(cov_pp[:free, :free])
    landmark_extra = None
    if view is not None:
        pose_extra, landmark_extra, scale_extra = _view_sandwich(problem, whiten, poses, landmarks, inliers, hll_inv,
                                                                 cov_pp, *view[1:], border=border)
        cov_pp = cov_pp + view[0] * pose_extra
        if scale_cov is not None:
            scale_cov = scale_cov + view[0] * scale_extra
    pose_cov = np.zeros((t, 3, 3))
    idx = np.arange(t - 1)
    blocks = cov_pp.reshape(t - 1, 3, t - 1, 3)[idx, :, idx, :]
    pose_cov[1:] = blocks
    landmark_cov = hll_inv.copy()
    for a in range(0, problem.n_landmarks, _CHUNK):          # H_ll⁻¹ H_lp Σ_pp H_pl H_ll⁻¹, blocks of landmarks
        rows = m[3 * a:3 * min(a + _CHUNK, problem.n_landmarks)]
        ms, md = (rows @ cov_pp).reshape(-1, 3, 3 * (t - 1)), rows.toarray().reshape(-1, 3, 3 * (t - 1))
        landmark_cov[a:a + len(ms)] += np.einsum("lat,lbt->lab", ms, md)
    if landmark_extra is not None:
        landmark_cov = landmark_cov + view[0] * landmark_extra
    landmark_cov[~system.held] = np.inf
    if scale_cov is not None:
        scale_cov = 0.5 * (scale_cov + scale_cov.T)
    return pose_cov, landmark_cov, scale_cov


def _view_sandwich(problem, whiten, poses, landmarks, inliers, hll_inv, cov_pp, view_change, range_change,
                   border=None):
    """The view-shared error's part of the sandwich covariance, per unit of view_floor (module docstring, *The
    sandwich*): (the poses' (3(T−1))² correction C = S⁻¹ Δ S⁻¹, the gauge's rows dropped; (L, 3, 3) each landmark's
    own terms Λ_l; with ``border`` (the odometry scales' rows of the bordered S⁻¹ on the free poses, (2, 3(T−1))) the
    scales' (2, 2) correction border Δ borderᵀ, else None). The caller adds view_floor · C to S⁻¹ before the landmarks'
    H_ll⁻¹ H_lp Σ_pp H_pl H_ll⁻¹ and view_floor · Λ_l to each landmark's marginal. (The readings do not see the
    scales: Δ has no rows for them, and ``cov_pp`` is the bordered S⁻¹'s pose block.)

    Reading i of landmark l (pose k_i) carries d_i, a world-frame offset of the point it finds, cov(d_i, d_j) =
    view_floor · ρ_ij · I between two readings of l (i ≠ j; :func:`_view_groups`); d_i enters the reading as J_m,i d_i
    (J_m the reading's Jacobian by the landmark, a rotation). With C_i = J_p,iᵀ W_i J_m,i and D_i = J_m,iᵀ W_i J_m,i
    (W_i = Q_i⁻¹), P_l = H_ll,l⁻¹ and Z_l = Σ_{i∈l} E_{k_i} C_i (= H_pl's column of l), the reduced (landmarks
    eliminated) gradient of reading i's offset is y_i = E_{k_i} C_i − Z_l P_l D_i, supported on the poses that read
    l. With ρ̄ = ρ off its diagonal, U_i = Σ_j ρ̄_ij D_j:

    - Δ = Σ_l Σ_ij ρ̄_ij y_i y_jᵀ (the poses' middle term), C = S⁻¹ Δ S⁻¹;
    - Λ_l = P_l V_l P_l − P_l Ω_lᵀ S⁻¹ Z_l P_l − (the same)ᵀ, V_l = Σ_i D_i U_i, Ω_l = Σ_i y_i U_i, where S⁻¹
      is needed only on the poses that read l; the term P_l Z_lᵀ C Z_l P_l comes with the caller's product.
    """
    t = problem.n_poses
    _, a_p, a_m = _observation_terms(problem, whiten, poses, landmarks)
    c_all, d_all = _tmul(a_p, a_m), _tmul(a_m, a_m)                  # C_i, D_i
    delta = np.zeros((3 * (t - 1), 3 * (t - 1)))                      # Δ on the free poses (the gauge's dropped)
    landmark_extra = np.zeros((problem.n_landmarks, 3, 3))
    for lm, rows, rho in _view_groups(problem, poses, landmarks, inliers, view_change, range_change):
        n = len(rows)
        rbar = rho.copy()
        np.fill_diagonal(rbar, 0.0)
        if not rbar.any():
            continue
        cs, ds = c_all[rows], d_all[rows]
        uniq, u = np.unique(problem.pose_index[rows], return_inverse=True)
        nu = len(uniq)
        z = np.zeros((nu, 3, 3))
        np.add.at(z, u, cs)
        z = z.reshape(3 * nu, 3)                                      # Z_l on its poses
        p = hll_inv[lm]
        y = -np.einsum("ab,jbc->ajc", z, p @ ds).reshape(nu, 3, n, 3)  # y_j's columns on l's poses
        y[u, :, np.arange(n), :] += cs
        y = y.reshape(3 * nu, n, 3)
        yr = (y.transpose(0, 2, 1).reshape(3 * nu * 3, n) @ rbar).reshape(3 * nu, 3, n).transpose(0, 2, 1)
        flat = y.reshape(3 * nu, 3 * n)
        at = (3 * uniq[:, None] + np.arange(3)).ravel()
        free = at >= 3                                                # pose 0 is the gauge: no rows in S⁻¹ or Δ
        at_free = at[free] - 3
        delta[np.ix_(at_free, at_free)] += (flat @ yr.reshape(3 * nu, 3 * n).T)[np.ix_(free, free)]
        us = np.einsum("ij,jab->iab", rbar, ds)                       # U_i
        omega = flat @ us.reshape(3 * n, 3)
        v = np.einsum("iab,ibc->ac", ds, us)
        cov_at = np.zeros((len(at), len(at)))                         # S⁻¹ on l's poses, the gauge's rows zero
        cov_at[np.ix_(free, free)] = cov_pp[np.ix_(at_free, at_free)]
        cross = p @ omega.T @ cov_at @ z @ p
        landmark_extra[lm] = p @ v @ p - cross - cross.T
    delta = 0.5 * (delta + delta.T)
    pose_extra = cov_pp @ delta @ cov_pp
    scale_extra = None if border is None else border @ delta @ border.T
    return (0.5 * (pose_extra + pose_extra.T), 0.5 * (landmark_extra + np.swapaxes(landmark_extra, 1, 2)),
            scale_extra)


__all__ = ["CAUCHY_C", "ODOMETRY_SCALE_SIGMA", "OUTLIER_CHI2", "RANGE_CHANGE", "VIEW_CHANGE", "VIEW_MODELS",
           "StereoLogProblem", "StereoSmoothed", "StereoSmoothingError", "observation_chi2", "smooth"]
