"""A camera's calibration estimated from the robot's own log, without ground truth (self-calibration).

Why: a range-bearing camera has its own bias. MRCLAM's five cameras differ (range offsets −0.011 to −0.110 m, scales
0.950-1.005, b₁ −0.013 to +0.039 /rad, bearing offsets up to 0.012 rad, fitted against Vicon), and a calibration pooled
over other robots leaves each camera's bias in its residuals: the known-ID maps then miss issue 13's figures
(docs/fastslam-history.md, "Session 36 ... (B)"). A lab has ground truth rarely; it has fiducials (MRCLAM's barcodes:
each sighting names its landmark) and odometry: the calibration becomes four more unknowns of the smoothing problem.

The problem (:mod:`estimation.landmark_smoother`'s, with known association by barcode): the poses of every frame
(pose 0, the first sighting's, is the frame's origin), the landmarks, and the camera's calibration: a sighting's
measured (r, φ) is calibrated to r' = a + r·(b₀ + b₁φ + b₂φ²), φ' = φ − ψ
(:meth:`~estimation.noise_model.RangeBearingNoise.corrected`); a, b₀, b₁ and ψ are estimated, b₂ (the depth-against-
range curvature, ½ b₀ for an ideal camera) is the given model's (``estimate_shape=True`` estimates it too: on MRCLAM
it then came out 0.016-0.036 low on all five robots, b₀ with it, and the range calibration undetermined: not
supported by the data). Each sighting is a factor (‖m − t‖ − r', atan2(m − t) − θ − φ') with the given model's σ
(inflated for correlated sightings as the filter's; the range's σ scales with the calibration, see :class:`_Shape`);
the odometry factors are the model's random walk (with its stalls after the command's dips, if it has that term:
:func:`~estimation.noise_model.increment_variances`, as the filter and the data set's smoother have them). The
odometry gives the metric scale; the landmarks' positions are free. Solved jointly by the smoother's own
Levenberg–Marquardt, the calibration its extra unknowns (Huber weights first, then the sightings beyond χ²₂ 99 %
dropped, as :func:`~estimation.landmark_smoother.smooth` does), from the FastSLAM filter's map and trajectory (known
association) with the given model; each step's turn of the whole map about pose 0 is taken as a rotation (as the
smoother's solve takes every step: the first steps' jumps of ψ turn the map, and along a turn's tangent the loop
crawled: MRCLAM robot 1 stopped at the iteration cap from one filter seed and converged from another, with other
outliers, b₀ 2 standard errors apart); both solves must converge. The calibration's covariance is its block of the
inverse information (Laplace).

The joint MAP's b₀ is biased low: where the odometry is loose the poses absorb part of the range noise, and they
absorb more the smaller b₀ (the sightings then weigh more against the odometry), so the minimum of the squared
residuals favours a small b₀ (simulated: 2σ low with the odometry's noise as modelled, 3-4σ with a model looser than
the data; MRCLAM: 2.4-3.3 % low). The estimate therefore maximises the Laplace approximation of the marginal
likelihood of the calibration, χ²_min(c) + log det H_xx(c) (H_xx the poses' and landmarks' information), by one
Newton step from the MAP: c − ½ Σ_c ∇ log det H_xx. Simulated (six seeds), that leaves a, b₀ and ψ within 2.4
standard errors; on MRCLAM b₀ is then 1.0-2.3 % low (docs/fastslam-history.md, "Session 37: the camera calibrated
without ground truth (A)").

What it cannot see: the camera's scale relative to the odometry's. A map and its ranges scaled together fit the
sightings alike, so b₀ (and a) come out in the odometry's units: an odometry translation scale wrong by 1 % (the given
model's, fitted on other robots: MRCLAM's robots differ by up to 1.4 %) moves b₀ by 1 %. Only an outside length can
fix that (the truth, or one measured distance between two fiducials); the reported uncertainty does not include it,
nor the odometry model's own errors (MRCLAM's commanded-velocity odometry: b₀ 1-2 % low, 2-9 standard errors, with
the robot's own truth-fitted odometry calibration too).

A surveyed length (``known_distances``: the distance between two landmarks, taped, with its σ) is one more factor
of the smoothing, (‖m_i − m_j‖ − d)/σ_d on the two landmarks' positions: it gives the map, and so b₀ and a, a metric
scale of their own beside the odometry's (docs/fastslam-history.md, "Session 37: a taped length in the
self-calibration (D)"). With a length the odometry's translation scale s is one more unknown (:class:`_OdometryScale`:
its increments' translations and their σ's ∝ s): the odometry, whose model calls it unbiased, then no longer pulls the
map against the tape (MRCLAM: the map's taped distance 3.6-18 mm short and b₀ 0.1-0.7 % low with s held). Then the
estimate is the joint MAP, without the marginal likelihood's step: the whole solution and s scaled together change
only the tape's residual (and b₂'s term), while the marginal likelihood's −½ log det H_xx, a volume under a flat
prior on the poses and landmarks, grows with that scale to the power of their number: the step then follows the
prior, not the data (simulated: s 16-19 standard errors high, b₀ 4-8.5); the MAP's b₀ is unbiased there (simulated,
seeds 3-8: −0.6 to +0.7 standard errors; MRCLAM: −0.5 to +0.35 % of the in-sample fit; docs/fastslam-history.md,
"Session 39: the odometry's scale beside a taped length (B)"). s itself is a nuisance: see :class:`_OdometryScale`.
The robust solve frees s only from the solution it gives with s held at the model's: from the filter's start, with
gross errors in its path, the first steps traded them for s (MRCLAM robot 5 without a tenth of its sightings: s
1.5-1.8, the solve stopped at the iteration cap; session 39 (D)); the estimator is the same, only its start moves.

The sensor's noise (``noise_components``, off by default): the σ's, like the calibration, are the given model's
unless asked for; with ``("range", "bearing")`` the sightings' σ_r (its shape a + b r kept, one factor on it) and σ_φ
are estimated from the log's own residuals as variance components (:mod:`estimation.noise_components`: Helmert's
σ²_g ← v_gᵀW_g v_g / r_g with r_g the group's redundancy, REML's fixed point), each round the self-calibration's own
robust solve, outlier cut and solve at the σ's the last round gave (from a start with σ_φ 2.5× too small the first
solves cut good sightings and stopped in another solution: σ_φ 7-9 % low, 6 standard errors, when only the last solve
was redone; with the robust solve in every round the estimate is the one the right model's start gives).

What it recovers. The solve weighs a sighting with its variance inflated by f = (1 + ρ)/(1 − ρ) for the correlation
of consecutive sightings (ρ the given model's), as the filter does; the residuals, though, are spread as the errors
are, by their marginal σ (a pass's slow error is only partly taken by its landmark and the poses). So at a solution
weighted with the marginal σ² inflated by f the residuals' χ²_g / r_g is 1/f, not 1: that is the fixed point sought
(the variances' factor becomes f χ²_g / r_g each round), and the model's fields receive marginal σ's, the same
quantity a fit against truth writes; the correlations are kept (not estimated). Simulated with AR(1) errors of ρ 0.6
along each pass, the model told ρ: σ_r 0.98 and σ_φ 1.13-1.14 of the marginal σ's come back; the fixed point χ²/r = 1
(the inflated variance taken for the marginal one) gave 0.45-0.49 of them, which the filter's inflation would then
halve twice over. On MRCLAM the in-sample σ_φ (against Vicon) also holds the truth's own heading errors, which the
smoother's poses take: the estimate is smaller there (robot 1: 0.0072 rad against 0.0253 in sample). It is the σ the
whole-log smoother sees: the known-ID maps made with it keep their NEES (0/93/100/100/100 % within on MRCLAM robots
1-5, ATE 0.256/0.033/0.137/0.058/0.037 → 0.247/0.031/0.101/0.057/0.037 m), but the FastSLAM filter under them, with
100 particles to take the poses' errors, got worse on four robots (its own landmark error 187 → 698 mm on robot 3,
183 → 4572 on robot 4), and the unknown-association chain split robot 5's posts (27 names against 16): not for the
chain as it is (docs/fastslam-history.md, "Session 40: the sensor's noise from the robot's own log (A)").

The odometry's factor (``"odometry"``, on all its increments' variances, the stall's too: written as the random walk's
variances times it and σ_s times its root) is a third group that can be asked for: with white sightings it comes
back (1.02-1.06 ± 0.03), but with AR(1) sightings (ρ 0.6, told) it came out 0.65-0.75 and took σ_φ to 1.21-1.27 of the
marginal: the sightings' slow errors leak into the odometry's residuals. MRCLAM's sightings are correlated (ρ 0.4-0.8),
so it is not estimated by default.

The ground truth is not read: :func:`self_calibrate` drops the log's truth before anything else.
Whether the calibration is determined (:attr:`CameraCalibration.problem`): the solve must converge, and the
calibration must be known better than one sighting's own noise: for the range, the RMS over the kept sightings of
the calibrated range's own σ (√(∂r'ᵀ Σ ∂r'), ∂r' = (1, r, rφ, rφ²) over the estimated terms) below the RMS of their
σ_r, for the bearing σ_ψ < σ_φ, each σ as the solve weighs one sighting (inflated by √((1 + ρ)/(1 − ρ)) for
correlated sightings, as the calibration's covariance is: both in the solve's units; the model's σ's, or the
estimated ones). Else the estimate would add to every sighting an error larger than the sighting's own, and it is
reported as not found, with the reason. (Until session 40 the σ's were compared before inflation; no MRCLAM run
changed: all five passed either way with the given σ's. With the estimated marginal σ_φ and no inflation, robots 3
and 5 would not pass: σ_ψ 0.0069 and 0.0077 rad against σ_φ 0.0063 and 0.0069.)
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .dataset_slam import run_landmark_log
from .dataset_smoothing import _initial_landmarks
from .datasets import RangeBearingLog
from .fastslam import FastSLAMConfig
from .geometry import between
from .landmark_smoother import (
    OUTLIER_CHI2,
    LandmarkLogProblem,
    NormalFactor,
    _jacobian,
    _residuals,
    _solve,
    solve_with_outlier_cut,
)
from .noise_components import GROUPS, MIN_FACTOR, NoiseComponents, truncated_means, variance_factors
from .noise_model import NoiseModel, increment_variances, with_fastslam

SIGMAS = ("range_sigma_m", "range_sigma_per_m", "bearing_sigma_rad")   # what the noise's components rescale
ESTIMATED = ("range_offset_m", "range_scale", "range_scale_per_rad", "range_scale_per_rad2",
             "bearing_offset_rad")   # c = (a, b₀, b₁, b₂, ψ), in this order
FREE = np.array([0, 1, 2, 4])          # estimated by default: a, b₀, b₁, ψ (b₂ the model's)
FREE_WITH_SHAPE = np.arange(5)         # estimate_shape: all five
TRANSLATION_SCALE = 5                  # the solve's c has a sixth term: the odometry's translation scale s


@dataclass(frozen=True)
class KnownDistance:
    """A length measured outside the log (a tape between two posts): landmarks ``first`` and ``second`` (their ids)
    are ``metres`` apart, with standard deviation ``sigma_m``."""

    first: int
    second: int
    metres: float
    sigma_m: float

    def problem(self) -> str | None:
        """Why the length cannot be used, in one sentence (None: it can); the ids are checked against a log apart."""
        if self.first == self.second:
            return f"a known distance joins two landmarks, not landmark {self.first} to itself"
        if not (math.isfinite(self.metres) and self.metres > 0):
            return f"the known distance between {self.first} and {self.second} must be positive, not {self.metres:g} m"
        if not (math.isfinite(self.sigma_m) and self.sigma_m > 0):
            return (f"the known distance's sigma between {self.first} and {self.second} must be positive, not "
                    f"{self.sigma_m:g} m")
        return None


@dataclass(frozen=True, eq=False)
class CalibrationSolution:
    """The joint solve's state at the reported calibration: the problem before the calibration is applied, the
    calibration's effect on it (``shape``: its estimated terms' columns, the known distances' rows), the poses (T + 1,
    3), landmarks (L, 2), c (the solve's: five terms, the odometry's scale sixth when estimated), the sightings kept
    (S,), the landmarks with a kept sighting (L,), and each frame's time (T,: pose k + 1's)."""

    problem: LandmarkLogProblem
    shape: _Shape
    poses: np.ndarray
    landmarks: np.ndarray
    values: np.ndarray
    inliers: np.ndarray
    seen: np.ndarray
    frame_times: np.ndarray


@dataclass(frozen=True)
class CameraCalibration:
    """The estimate: ``values`` (5,) a (m), b₀, b₁ (1/rad), b₂ (1/rad²), ψ (rad) (:data:`ESTIMATED`'s order), their
    covariance (5, 5), the joint MAP's values before the marginal likelihood's correction (see
    :func:`self_calibrate`), and the fit's figures. ``problem``: why the calibration is not determined (None: it
    is); a caller must not use an estimate with a problem."""

    values: np.ndarray
    covariance: np.ndarray
    map_values: np.ndarray
    sightings: int
    outliers: int
    landmarks: int
    frames: int
    chi2_per_dof: float
    # every joint solve's iterations: the first solves' and, with the noise estimated, each of its rounds'
    iterations: int
    # the solves of the solution reported did: the first ones, or with the noise estimated its last round's (whether
    # the rounds reached their fixed point is the noise's: NoiseComponents.converged)
    converged: bool
    range_sd_rms_m: float                       # the calibration's own σ of r', RMS over the kept sightings
    range_sigma_rms_m: float                    # one sighting's σ_r, RMS over them (model or estimate; not inflated)
    bearing_sigma_rad: float                    # one sighting's σ_φ (model or estimate; not inflated)
    problem: str | None
    known_distances: tuple[KnownDistance, ...] = ()   # the surveyed lengths used
    fitted_distances_m: tuple[float, ...] = ()        # the map's distance between each pair, at the solution
    # the odometry's translation scale, when estimated (with a known distance; None: the model's, kept), its standard
    # error, the joint MAP's, and its correlation with b₀ (the rest of its covariance is not kept)
    translation_scale: float | None = None
    translation_scale_standard_error: float = math.nan
    translation_scale_joint_map: float = math.nan
    range_scale_translation_scale_correlation: float = math.nan
    # the noise's level estimated with the calibration (None: the given model's σ's, kept)
    noise_components: NoiseComponents | None = None
    # the joint solution the calibration was read from, kept only on request (self_calibrate(keep_solution=True)):
    # what estimation.calibration_uncertainty needs to weigh each residual's influence on the calibration
    solution: CalibrationSolution | None = dataclasses.field(default=None, repr=False, compare=False)

    @property
    def standard_errors(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance))

    def __getattr__(self, name: str):
        if name in ESTIMATED:
            return float(self.values[ESTIMATED.index(name)])
        raise AttributeError(name)

    def as_dict(self) -> dict:
        se = self.standard_errors
        return {**{name: float(v) for name, v in zip(ESTIMATED, self.values, strict=True)},
                **{f"{name}_standard_error": float(s) for name, s in zip(ESTIMATED, se, strict=True)},
                **{f"{name}_joint_map": float(v) for name, v in zip(ESTIMATED, self.map_values, strict=True)},
                "range_offset_scale_correlation": float(self.covariance[0, 1] / max(se[0] * se[1], 1e-300)),
                "sightings": self.sightings, "outliers": self.outliers, "landmarks": self.landmarks,
                "frames": self.frames, "chi2_per_dof": self.chi2_per_dof, "iterations": self.iterations,
                "converged": self.converged, "range_sd_rms_m": self.range_sd_rms_m,
                "range_sigma_rms_m": self.range_sigma_rms_m, "bearing_sigma_rad": self.bearing_sigma_rad,
                "problem": self.problem, **self._known_distances_dict(), **self._translation_scale_dict(),
                **self._noise_dict()}

    def _noise_dict(self) -> dict:
        if self.noise_components is None:   # not estimated: no key at all, a file as before
            return {}
        nc = self.noise_components
        se = nc.standard_errors
        return {"noise_groups": list(nc.estimated), "noise_rounds": nc.rounds,
                **{f"{g}_variance_factor": float(nc.factors[j]) for j, g in enumerate(GROUPS) if g in nc.estimated},
                **{f"{g}_variance_factor_standard_error": float(se[j]) for j, g in enumerate(GROUPS)
                   if g in nc.estimated},
                **{f"{g}_redundancy": float(nc.redundancies[j]) for j, g in enumerate(GROUPS) if g in nc.estimated}}

    def _translation_scale_dict(self) -> dict:
        if self.translation_scale is None:   # not estimated: no key at all, a file as before
            return {}
        return {"translation_scale": self.translation_scale,
                "translation_scale_standard_error": self.translation_scale_standard_error,
                "translation_scale_joint_map": self.translation_scale_joint_map,
                "range_scale_translation_scale_correlation": self.range_scale_translation_scale_correlation}

    def _known_distances_dict(self) -> dict:
        if not self.known_distances:   # no key at all: a file made without them is as before
            return {}
        k = self.known_distances
        return {"known_distance_first_ids": [int(x.first) for x in k],
                "known_distance_second_ids": [int(x.second) for x in k],
                "known_distance_m": [float(x.metres) for x in k],
                "known_distance_sigma_m": [float(x.sigma_m) for x in k],
                "known_distance_fitted_m": [float(x) for x in self.fitted_distances_m]}

    def applied(self, model: NoiseModel, robot: str, source: str) -> NoiseModel:
        """``model`` (its odometry, the sensor's σ's, correlations and footprint) with this calibration and its
        figures in [fit] (``self_calibration_*``; the model's own calibration as ``self_calibration_given_*``). An
        estimated odometry translation scale is a figure of [fit] (``self_calibration_translation_scale``, its standard
        error, ...), not the model's [odometry] ``translation_scale``, which is kept: see :class:`_OdometryScale`."""
        if self.problem is not None:
            raise ValueError(f"the camera's calibration is not determined: {self.problem}")
        rb = dataclasses.replace(model.range_bearing, **{k: float(v) for k, v in zip(ESTIMATED, self.values,
                                                                                      strict=True)})
        figures = {f"self_calibration_{k}": v for k, v in self.as_dict().items()
                   if k not in ESTIMATED and k != "problem"}
        given = {f"self_calibration_given_{k}": float(getattr(model.range_bearing, k)) for k in ESTIMATED}
        odometry = model.odometry
        if self.noise_components is not None:   # the estimated σ's (their shape and the correlations kept)
            rb, odometry, sigmas = _with_sigmas(rb, odometry, self.noise_components)
            given |= {f"self_calibration_given_{k}": float(getattr(model.range_bearing, k)) for k in SIGMAS}
            figures |= sigmas
        return dataclasses.replace(model, odometry=odometry, range_bearing=rb, robot=robot, source=source,
                                   fit={**model.fit, **given, **figures})


def without_truth(log: RangeBearingLog) -> RangeBearingLog:
    """``log`` with its ground truth (trajectory, landmark positions) removed: what a lab without Vicon has."""
    return dataclasses.replace(log, ground_truth=np.zeros((0, 4)), truth_ids=np.zeros(0, np.int64),
                               truth_positions=np.zeros((0, 2)))


def self_calibrate(log: RangeBearingLog, noise: NoiseModel, *, config: FastSLAMConfig | None = None,
                   seed: int = 0, estimate_shape: bool = False,
                   known_distances: tuple[KnownDistance, ...] | list[KnownDistance] = (),
                   translation_scale: bool | None = None, noise_components: tuple[str, ...] = (),
                   keep_solution: bool = False) -> CameraCalibration:
    """The camera calibration (a, b₀, ψ) of ``log``'s robot from its odometry and its sightings, associated by their
    landmark ids (barcodes, fiducials): see the module docstring. ``noise``: the odometry's model and calibration,
    the sensor's σ's and correlations, b₁ and b₂ (e.g. a model fitted on other robots with
    ``estimate_noise(..., calibration_per_log=True)``); its a, b₀, ψ only start the filter that gives the initial
    guess. The log's ground truth is not read (it is dropped first). ``known_distances``: surveyed lengths between
    landmarks the log sights (:class:`KnownDistance`), each a factor on the two landmarks' positions; ValueError if
    one names a landmark the log does not sight, or is not a length (:meth:`KnownDistance.problem`).
    ``translation_scale``: estimate the odometry's translation scale too (:class:`_OdometryScale`; the model's
    ``translation_scale`` only starts it; the estimate is the joint MAP, without the marginal likelihood's step: see
    the module docstring); None (the default): when a known distance is given (without one the odometry is the map's
    only metric, and its scale is not observable: ValueError if asked for). ``keep_solution``: the result's
    ``solution`` holds the joint solve's state (:class:`CalibrationSolution`; the estimate is the same either way)."""
    log = without_truth(log)
    if noise.range_bearing is None:
        raise ValueError(f"the noise model of {noise.robot!r} has no [range_bearing] section")
    if len(log) == 0:
        raise ValueError(f"{log.name}: no sightings to calibrate the camera with")
    known_distances = tuple(known_distances)
    translation_scale = bool(known_distances) if translation_scale is None else bool(translation_scale)
    if translation_scale and not known_distances:
        raise ValueError("the odometry's translation scale needs a known distance: without one the odometry is the "
                         "map's only metric")
    sighted = set(np.unique(log.landmark_ids).tolist())
    for known in known_distances:
        if (text := known.problem()) is not None:
            raise ValueError(text)
        missing = [i for i in (known.first, known.second) if i not in sighted]
        if missing:
            raise ValueError(f"{log.name} never sights landmark {missing[0]} (known distance {known.first}-"
                             f"{known.second}): a taped length must join two landmarks of the log")
    config = config or FastSLAMConfig()
    run = run_landmark_log(log, config, np.random.default_rng(seed), noise=noise, association="id")
    sensor = noise.range_bearing
    inflate_r, inflate_b = (math.sqrt(f) for f in sensor.variance_inflation())
    times = np.unique(log.sighting_times)
    t0 = float(times[0])
    frame_times = np.concatenate([[t0], times])
    odometry = log.odometry_pose(noise.odometry_times(frame_times))
    increments = noise.calibrate_increments(between(odometry[:-1], odometry[1:]))
    frame_of = np.searchsorted(times, log.sighting_times)
    landmark_ids, landmark_index = np.unique(log.landmark_ids, return_inverse=True)
    raw_r, raw_b = log.ranges, log.bearings
    given = np.array([getattr(sensor, k) for k in ESTIMATED])
    start_r, _ = sensor.corrected(raw_r, raw_b)
    plain_sigma_r = sensor.range_sigma(start_r)
    # the random walk and the stalls after the command's dips, as the filter above and dataset_smoothing have them
    variances = increment_variances(log, noise, with_fastslam(noise, config), frame_times, increments)
    problem = LandmarkLogProblem(increments, variances,
                                 frame_of + 1, landmark_index, start_r, raw_b - sensor.bearing_offset_rad,
                                 plain_sigma_r * inflate_r, np.full(len(log), sensor.bearing_sigma_rad * inflate_b))
    poses = np.vstack([np.zeros(3), run.estimated_trajectory[:, 1:]])
    landmarks = _initial_landmarks(run.map, landmark_ids, problem, poses)
    free = FREE_WITH_SHAPE if estimate_shape else FREE
    scale = _OdometryScale.of(problem, noise.odometry.translation_scale) if translation_scale else None
    if translation_scale:   # c's sixth term
        free, given = np.append(free, TRANSLATION_SCALE), np.append(given, noise.odometry.translation_scale)
    shape = _Shape(sensor, raw_r, raw_b, problem.range_sigmas, free, _Lengths.of(known_distances, landmark_ids),
                   scale)
    c = given.copy()
    inliers = np.ones(len(log), bool)
    iterations_held = 0
    if scale is not None:
        # the odometry's scale held (the model's) from the filter's start, freed from the solution that gives: from a
        # start with gross errors in its path the first steps trade them for s (its σ's ∝ s loosen every increment):
        # MRCLAM robot 5 without the jackknife's block 2 went to s 1.5-1.8 with a stretch of 50 poses 3 m off, and
        # the robust solve stopped at the cap in a slow valley (from there 115 more iterations to the solution that
        # the other blocks reach); with s held it converges there in 18. The estimator is unchanged: only its start
        held = _Shape(sensor, raw_r, raw_b, problem.range_sigmas, free[free != TRANSLATION_SCALE], shape.lengths)
        iterations_held, _ = _solve(problem, poses, landmarks, inliers, robust=True, extra=held,
                                    extra_values=c[:TRANSLATION_SCALE])   # a view: c's first five terms move
    # the steps' turns of the map taken as rotations (see _solve); the outliers are cut at the robust solution, so
    # an unfinished robust solve leaves them to the start, and the estimate is reported as not converged
    iterations, converged = solve_with_outlier_cut(problem, poses, landmarks, inliers, extra=shape, extra_values=c)
    iterations += iterations_held
    components = None
    if noise_components:
        def shaped(p: LandmarkLogProblem) -> _Shape:
            odometry_scale = _OdometryScale.of(p, noise.odometry.translation_scale) if translation_scale else None
            return _Shape(sensor, raw_r, raw_b, p.range_sigmas, free, shape.lengths, odometry_scale)

        problem, shape, inliers, components, rounds_iterations, converged = _noise_components(
            problem, shaped, poses, landmarks, c, tuple(noise_components),
            (1.0, *sensor.variance_inflation()),
            (0.0, max(sensor.range_correlation, 0.0), max(sensor.bearing_correlation, 0.0)))
        iterations += rounds_iterations
    odometry_r, sightings = _residuals(shape.applied(problem, c), poses, landmarks)
    chi2 = float(np.sum(odometry_r ** 2) + np.sum(sightings.reshape(-1, 2)[inliers] ** 2))
    if shape.lengths.count:
        chi2 += float(np.sum(shape.lengths.residuals(landmarks) ** 2))
    seen = np.zeros(len(landmark_ids), bool)
    seen[landmark_index[inliers]] = True
    dof = 2 * int(inliers.sum()) + shape.lengths.count - 2 * int(seen.sum()) - len(c)
    covariance = _calibration_covariance(problem, shape, poses, landmarks, c, inliers, seen)
    map_values = c.copy()
    solution = CalibrationSolution(problem, shape, poses.copy(), landmarks.copy(), c.copy(), inliers.copy(),
                                   seen.copy(), times) if keep_solution else None
    # ∂r'/∂(a, b) at the kept sightings
    design = np.column_stack([np.ones(int(inliers.sum())), raw_r[inliers, None] * shape.powers[inliers]])
    with np.errstate(invalid="ignore"):   # inf × 0 of the terms not estimated, in a singular covariance
        sd_rms = float(np.sqrt(np.mean(np.einsum("si,ij,sj->s", design, np.nan_to_num(covariance[:4, :4], posinf=1e300),
                                                  design))))
    scale = np.ones(3) if components is None else components.sigma_factors   # the estimated σ's, if any
    sigma_rms = float(np.sqrt(np.mean(plain_sigma_r[inliers] ** 2))) * float(scale[1])
    bearing_sigma = float(sensor.bearing_sigma_rad) * float(scale[2])
    # one sighting's σ's as the solve weighs them (inflated for correlated sightings, as the calibration's covariance
    # is): the calibration must be known better than that (see the module docstring)
    weighed = (sigma_rms * inflate_r, bearing_sigma * inflate_b)

    def problem_at(values: np.ndarray) -> str | None:
        return _problem(converged, iterations, values, covariance, sd_rms, *weighed) or (
            None if components is None else components.problem())

    problem_text = problem_at(c)
    # determined at the MAP: the marginal likelihood's correction (else the MAP, reported); none with the odometry's
    # scale estimated: the joint MAP is reported (see the module docstring)
    if problem_text is None and not translation_scale:
        c = c - 0.5 * covariance @ _log_det_gradient(problem, shape, poses, landmarks, c, inliers, seen, covariance)
        problem_text = problem_at(c)
    fitted = tuple(float(x) for x in shape.lengths.distances(landmarks))
    n = len(ESTIMATED)
    scale_figures = {}
    if translation_scale:
        se = np.sqrt(np.diag(covariance))
        scale_figures = dict(translation_scale=float(c[n]), translation_scale_standard_error=float(se[n]),
                             translation_scale_joint_map=float(map_values[n]),
                             range_scale_translation_scale_correlation=float(covariance[1, n]
                                                                             / max(se[1] * se[n], 1e-300)))
    return CameraCalibration(c[:n], covariance[:n, :n], map_values[:n], int(len(log)), int((~inliers).sum()),
                             int(seen.sum()), int(len(times)), chi2 / dof if dof > 0 else float("nan"),
                             iterations, converged, sd_rms, sigma_rms,
                             bearing_sigma, problem_text, known_distances, fitted, **scale_figures,
                             noise_components=components, solution=solution)


@dataclass(frozen=True)
class _Lengths:
    """The known distances as factors: landmark index pairs (K, 2) (into the problem's landmarks), lengths (K,) and
    σ's (K,); residual (‖m_i − m_j‖ − d)/σ_d."""

    pairs: np.ndarray
    metres: np.ndarray
    sigmas: np.ndarray

    @classmethod
    def of(cls, known: tuple[KnownDistance, ...], landmark_ids: np.ndarray) -> _Lengths:
        index = {int(i): k for k, i in enumerate(landmark_ids)}
        return cls(np.array([[index[k.first], index[k.second]] for k in known], int).reshape(-1, 2),
                   np.array([k.metres for k in known], float), np.array([k.sigma_m for k in known], float))

    @property
    def count(self) -> int:
        return len(self.metres)

    def distances(self, landmarks: np.ndarray) -> np.ndarray:
        d = landmarks[self.pairs[:, 0]] - landmarks[self.pairs[:, 1]]
        return np.hypot(d[:, 0], d[:, 1])

    def residuals(self, landmarks: np.ndarray) -> np.ndarray:
        return (self.distances(landmarks) - self.metres) / self.sigmas

    def jacobian(self, landmarks: np.ndarray, t: int, columns: int) -> sp.csr_matrix:
        """(K, columns): ∂/∂m_i = uᵀ/σ_d, ∂/∂m_j = −uᵀ/σ_d (u the unit vector from m_j to m_i), landmark k's
        columns at 3t + 2k."""
        d = landmarks[self.pairs[:, 0]] - landmarks[self.pairs[:, 1]]
        u = d / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)[:, None] / self.sigmas[:, None]
        rows = np.repeat(np.arange(self.count), 4)
        cols = (3 * t + 2 * self.pairs[:, [0, 0, 1, 1]] + [0, 1, 0, 1]).ravel()
        vals = np.column_stack([u, -u]).ravel()
        return sp.csr_matrix((vals, (rows, cols)), shape=(self.count, columns))


@dataclass(frozen=True)
class _OdometryScale:
    """The odometry's translation scale s as an unknown: increment k's translation is s·ũ_k (ũ (T, 2) the increments
    calibrated as the model does with a translation scale of 1: :meth:`~estimation.noise_model.NoiseModel.
    calibrate_increments` is linear in it) and its x, y σ's s·σ̃_k (σ̃ the model's σ's at its own scale s₀, over s₀);
    the heading's σ is kept. Why σ ∝ s, as the range's σ ∝ m in :class:`_Shape`: the odometry's noise is in its own
    units (wheel turns), so (δ̂ − s ũ)/(s σ̃) is the raw increment's residual; with σ held, scaling the whole solution
    (poses, landmarks, a, b₀ and s) by λ would scale the odometry's residuals by λ, and the least squares would buy a
    smaller χ² with a smaller map against the tape (simulated, σ held: the map's taped distance 5-9 mm short, s 1-4
    standard errors low). x, y residual e = (δ̂ − s ũ)/(s σ̃): ∂e/∂s = −(e + δ/σ)/s, δ and σ at s.

    What s is for: a nuisance unknown that frees the camera's scale from the odometry's, so that the tape alone gives
    the map its metric. It is not written to the model's [odometry] (only to [fit]): its joint MAP is biased high by
    the odometry's own noise (simulated, translations 3 % long: +0.2 % with the odometry's variance q 0.0003 per metre
    and radian, +0.9 to +2.2 % at 0.003, +5.6 to +8.1 % at 0.01; b₀ unbiased at all three), and on MRCLAM, whose
    odometry loses 0.09 m of travel per radian in arcs, it came out 1.011-1.033 against the robots' truth-fitted
    translation scales 0.920-0.939 (docs/fastslam-history.md, Session 39 (B))."""

    unit_increments: np.ndarray    # (T, 2) ũ
    unit_sigmas: np.ndarray        # (T, 2) σ̃

    @classmethod
    def of(cls, problem: LandmarkLogProblem, given: float) -> _OdometryScale:
        """From ``problem``'s increments and σ's, calibrated at the model's translation scale ``given``."""
        return cls(problem.increments[:, :2] / given, problem.increment_sigmas[:, :2] / given)

    def applied(self, problem: LandmarkLogProblem, s: float) -> LandmarkLogProblem:
        increments, variances = problem.increments.copy(), problem.increment_variances.copy()
        increments[:, :2] = s * self.unit_increments
        variances[:, :2] = (s * self.unit_sigmas) ** 2
        return dataclasses.replace(problem, increments=increments, increment_variances=variances)

    def columns(self, problem: LandmarkLogProblem, odometry: np.ndarray, s: float) -> tuple[np.ndarray, np.ndarray]:
        """(rows (2T,), values (2T,)): ∂e/∂s in the x and y rows of the odometry's normalised residuals ``odometry``
        (3T,) at ``problem`` (as s makes it)."""
        t = problem.n_poses
        e = odometry.reshape(t, 3)[:, :2]
        values = -(e + problem.increments[:, :2] / problem.increment_sigmas[:, :2]) / s
        return (3 * np.arange(t)[:, None] + np.arange(2)).ravel(), values.ravel()


class _Shape:
    """The calibration's effect on the sightings: r' = a + r·m(φ), m = b₀ + b₁φ + b₂φ², φ' = φ − ψ; c = (a, b₀, b₁,
    b₂, ψ): ∂r'/∂c = (1, r, rφ, rφ², 0), ∂φ'/∂ψ = −1. To the smoother (:func:`~estimation.landmark_smoother._solve`)
    c's estimated terms are extra unknowns (:class:`~estimation.landmark_smoother.ExtraUnknowns`): their columns
    after the landmarks', the known distances' factors their own rows. With ``scale`` (:class:`_OdometryScale`) c has
    a sixth term, the odometry's translation scale s, which changes the odometry's factors instead.

    The noise is the camera's, in its raw range r: a range residual is (r̂ − r')/(m σ_raw), σ_raw = σ_r / m₀ (σ_r the
    model's, measured in calibrated units at the given calibration's m₀), i.e. the problem's σ_r scaled by m/m₀. Why
    not the given σ_r as it is: then a smaller b₀ shrinks each sighting's noise with it, and the least squares buys
    that with a smaller map; on simulated logs with σ_r 0.02 m it took b₀ 6-7 % low, 9-11 of its standard errors."""

    def __init__(self, sensor, ranges: np.ndarray, bearings: np.ndarray, range_sigmas: np.ndarray,
                 free: np.ndarray, lengths: _Lengths | None = None, scale: _OdometryScale | None = None) -> None:
        self.free = np.asarray(free, int)                            # the indices of c that are estimated
        self.scale = scale                                           # the odometry's translation scale (c[5]), if any
        if (TRANSLATION_SCALE in self.free) != (scale is not None):
            raise ValueError("the odometry's translation scale is estimated with its increments, or not at all")
        self.lengths = lengths or _Lengths.of((), np.zeros(0, int))   # known distances: rows after the sightings'
        self.ranges, self.bearings = np.asarray(ranges, float), np.asarray(bearings, float)
        self.powers = np.column_stack([np.ones_like(self.bearings), self.bearings, self.bearings ** 2])   # 1, φ, φ²
        self.start = self.powers @ [sensor.range_scale, sensor.range_scale_per_rad, sensor.range_scale_per_rad2]
        self.sigmas = np.asarray(range_sigmas, float)               # σ_r at m₀ (inflated as the filter's)

    def multiplier(self, c: np.ndarray) -> np.ndarray:
        return self.powers @ c[1:4]

    def applied(self, problem: LandmarkLogProblem, c: np.ndarray) -> LandmarkLogProblem:
        m = self.multiplier(c)
        out = dataclasses.replace(problem, ranges=c[0] + self.ranges * m, bearings=self.bearings - c[4],
                                  range_sigmas=self.sigmas * m / self.start)
        return out if self.scale is None else self.scale.applied(out, c[TRANSLATION_SCALE])

    def columns(self, problem: LandmarkLogProblem, poses, landmarks, c, weights, residuals=None) -> sp.csr_matrix:
        """(3T + 2S, estimated terms) the odometry's and the sightings' derivatives in c's estimated terms, at
        ``problem`` (as c makes it; ``residuals`` its :func:`~estimation.landmark_smoother._residuals` there, if
        known: the solve has them already)."""
        odometry, sightings = _residuals(problem, poses, landmarks) if residuals is None else residuals
        e_r = sightings.reshape(-1, 2)[:, 0]                         # (r̂ − r')/σ
        s = np.arange(len(self.ranges))
        t = problem.n_poses
        m = self.multiplier(c)
        # e_r = (r̂ − r')/σ with σ ∝ m: ∂e_r/∂a = −1/σ, ∂e_r/∂b_j = −(r φʲ)/σ − e_r φʲ/m;
        # e_φ = wrap(φ̂ − φ + ψ)/σ_φ: ∂e_φ/∂ψ = 1/σ_φ
        columns = [-weights / problem.range_sigmas] + [
            -weights * self.powers[:, j] * (self.ranges / problem.range_sigmas + e_r / m) for j in range(3)]
        columns.append(weights / problem.bearing_sigmas)
        sighting_terms = [j for j in self.free if j != TRANSLATION_SCALE]
        rows = [3 * t + 2 * s + (1 if j == 4 else 0) for j in sighting_terms]
        cols = [np.full(len(s), k) for k, j in enumerate(self.free) if j != TRANSLATION_SCALE]
        vals = [columns[j] for j in sighting_terms]
        if TRANSLATION_SCALE in self.free:   # the odometry's x and y rows (the heading's does not depend on it)
            r, v = self.scale.columns(problem, odometry, c[TRANSLATION_SCALE])
            rows.append(r)
            cols.append(np.full(len(r), int(np.flatnonzero(self.free == TRANSLATION_SCALE)[0])))
            vals.append(v)
        return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(3 * t + 2 * len(s), len(self.free)))

    def residuals(self, landmarks, c) -> np.ndarray:
        return self.lengths.residuals(landmarks)

    def rows(self, problem: LandmarkLogProblem, landmarks, c, n_columns: int) -> sp.csr_matrix:
        return self.lengths.jacobian(landmarks, problem.n_poses, n_columns)

    def stepped(self, c: np.ndarray, step: np.ndarray) -> np.ndarray | None:
        out = c.copy()
        out[self.free] += step
        # a step that makes the range's multiplier m ≤ 0 anywhere is no camera (and no σ), an odometry scale ≤ 0 no
        # odometry: refused
        return out if np.all(self.multiplier(out) > 0) and (self.scale is None or out[TRANSLATION_SCALE] > 0) else None

    def jacobian(self, problem: LandmarkLogProblem, poses, landmarks, c, weights) -> sp.csr_matrix:
        """The smoother's Jacobian with the estimated calibration's columns after the landmarks' (and the known
        distances' rows after the sightings')."""
        return _jacobian(self.applied(problem, c), poses, landmarks, len(landmarks), weights, extra=self,
                         extra_values=c)


def _calibration_covariance(problem, shape, poses, landmarks, c, inliers, seen) -> np.ndarray:
    """c's block (5, 5) of the inverse information at the solution (landmarks without a kept sighting left out; the
    terms not estimated 0)."""
    t, n = problem.n_poses, len(landmarks)
    jac = shape.jacobian(problem, poses, landmarks, c, inliers.astype(float))
    information = (jac.T @ jac).tocsc()
    free = np.ones(information.shape[0], bool)
    free[3 * t:3 * t + 2 * n] = np.repeat(seen, 2)
    out = np.zeros((len(c), len(c)))
    try:
        dense = NormalFactor(information[free][:, free], t, 3).landmark_covariance()
    except np.linalg.LinAlgError:   # singular: _problem says so
        out[np.ix_(shape.free, shape.free)] = np.inf
        return out
    out[np.ix_(shape.free, shape.free)] = dense[-len(shape.free):, -len(shape.free):]
    return out


def _log_det_gradient(problem, shape, poses, landmarks, c, inliers, seen, covariance) -> np.ndarray:
    """∇_c log det H_xx (5,) at the solution: H_xx the information of the poses and landmarks (c held), by central
    differences of one standard error. At fixed poses and landmarks H_xx depends on c only through the range σ's
    (∝ m = b₀ + b₁φ + b₂φ²), so the derivatives in a and ψ are 0. (Not used with the odometry's scale estimated:
    see the module docstring.)"""
    t, n = problem.n_poses, len(landmarks)
    free = np.ones(3 * t + 2 * n, bool)
    free[3 * t:] = np.repeat(seen, 2)

    def log_det(at: np.ndarray) -> float:
        jac = shape.jacobian(problem, poses, landmarks, at, inliers.astype(float))[:, :3 * t + 2 * n]
        information = (jac.T @ jac).tocsc()
        return NormalFactor(information[free][:, free], t, 3).log_determinant()

    gradient = np.zeros(len(c))
    for j in set(shape.free) & {1, 2, 3}:
        step = np.zeros(len(c))
        step[j] = float(np.sqrt(covariance[j, j]))
        gradient[j] = (log_det(c + step) - log_det(c - step)) / (2.0 * step[j])
    return gradient


def _problem(converged, iterations, c, covariance, sd_rms, sigma_rms, bearing_sigma) -> str | None:
    """Why the estimate is not to be used, in one sentence (None: it is determined)."""
    if not converged:
        return f"the joint solve did not converge ({iterations} iterations)"
    if not np.all(np.isfinite(covariance)) or np.any(np.diag(covariance)[FREE] <= 0):
        return "the information matrix is singular: the sightings do not determine the calibration"
    if not 0.5 <= c[1] <= 2.0:
        return f"the range scale came out {c[1]:.3f}, outside [0.5, 2] (a calibration, not a new sensor)"
    if len(c) > TRANSLATION_SCALE and not 0.5 <= c[TRANSLATION_SCALE] <= 2.0:
        return (f"the odometry's translation scale came out {c[TRANSLATION_SCALE]:.3f}, outside [0.5, 2] (a "
                "calibration, not a new robot)")
    if not sd_rms < sigma_rms:
        return (f"the range calibration is not known better than one sighting (± {sd_rms:.3f} m RMS over the "
                f"sightings' ranges against their σ_r {sigma_rms:.3f} m, as the solve weighs them): the log's ranges "
                "and odometry do not determine it")
    se_psi = float(np.sqrt(covariance[4, 4]))
    if not se_psi < bearing_sigma:
        return (f"the bearing offset is not known better than one sighting (± {se_psi:.4f} rad against σ_φ "
                f"{bearing_sigma:.4f} rad, as the solve weighs it)")
    return None


MAX_COMPONENT_ROUNDS = 40
COMPONENT_TOLERANCE = 1e-3   # the rounds stop when no variance factor moves by more than this (σ: 0.05 %)


def _noise_components(base: LandmarkLogProblem, shaped, poses, landmarks, c, estimated: tuple[str, ...],
                      inflation: tuple[float, float, float], correlations: tuple[float, float, float]):
    """The variance components of the groups ``estimated`` (of :data:`~estimation.noise_components.GROUPS`), each
    round the robust solve, the outlier cut and the solve at the σ's the last round gave (poses, landmarks and c in
    place), until no factor moves by COMPONENT_TOLERANCE: (problem, shape, inliers, NoiseComponents) there, the
    rounds' solves' iterations (a solve that raised counts none) and whether the last round's solves converged."""
    unknown = set(estimated) - set(GROUPS)
    if unknown:
        raise ValueError(f"no noise group {sorted(unknown)[0]!r}: the groups are {', '.join(GROUPS)}")
    t = base.n_poses
    # the fixed point: each group's normalised residuals at 1/inflation of the used variance (the sightings' marginal
    # variance, which the file's σ's are; see the module docstring)
    target = 1.0 / np.asarray(inflation, float)
    factors, on = np.ones(3), np.array([g in estimated for g in GROUPS])
    converged, redundancy, rows, rounds, iterations = False, np.zeros(3), np.zeros(3), 0, 0
    while rounds < MAX_COMPONENT_ROUNDS:
        rounds += 1
        problem = dataclasses.replace(base, increment_variances=base.increment_variances * factors[0],
                                      range_sigmas=base.range_sigmas * math.sqrt(factors[1]),
                                      bearing_sigmas=base.bearing_sigmas * math.sqrt(factors[2]))
        shape = shaped(problem)
        inliers, solved = np.ones(len(base.ranges), bool), False
        try:   # a LinAlgError leaves inliers as the solve that raised weighed them (see solve_with_outlier_cut)
            more, solved = solve_with_outlier_cut(problem, poses, landmarks, inliers, extra=shape, extra_values=c)
            iterations += more
            odometry, sightings = _residuals(shape.applied(problem, c), poses, landmarks)
            jac = shape.jacobian(problem, poses, landmarks, c, inliers.astype(float))
            residual = np.concatenate([odometry, sightings * np.repeat(inliers, 2), shape.residuals(landmarks, c)])
            kept = 3 * t + 2 * np.flatnonzero(inliers)
            seen = np.zeros(len(landmarks), bool)
            seen[problem.landmark_index[inliers]] = True
            free = np.ones(jac.shape[1], bool)
            free[3 * t:3 * t + 2 * len(landmarks)] = np.repeat(seen, 2)
            chi2, redundancy = variance_factors(jac, residual, [np.arange(3 * t), kept, kept + 1], t, free)
        except np.linalg.LinAlgError:   # the weights so far apart that the information is singular: no fixed point
            break
        rows = np.array([3 * t, len(kept), len(kept)], float)
        # the cut's share of the kept residuals' squares: their variances the target's times 1 − h, h on average
        # 1 − r/n (see estimation.noise_components)
        with np.errstate(divide="ignore", invalid="ignore"):
            spread = np.clip(redundancy / np.maximum(rows, 1.0), 1e-6, 1.0)
            means = np.concatenate([[1.0], truncated_means(OUTLIER_CHI2, target[1:] * spread[1:])])
            k = chi2 / (np.maximum(redundancy, 0.0) * means)
        update = np.where(on, k / target, 1.0)
        if not np.all(np.isfinite(update) & (update > 0)) or np.any(factors * update < MIN_FACTOR):
            factors = factors * np.where(np.isfinite(update), update, np.nan)   # not determined: see problem()
            break
        if np.max(np.abs(update - 1.0)) < COMPONENT_TOLERANCE:
            converged = bool(solved)   # the fixed point, where the robust and the final solve both converged
            break
        factors = factors * update
    components = NoiseComponents(tuple(g for g in GROUPS if g in estimated), factors, redundancy, rows,
                                 np.asarray(correlations, float), rounds, converged)
    return problem, shape, inliers, components, iterations, solved


_ODOMETRY_VARIANCES = ("xy_var_per_m", "theta_var_per_rad", "theta_var_per_m", "theta_var_per_s")


def _with_sigmas(rb, odometry, components: NoiseComponents):
    """(range_bearing, odometry, [fit] figures): the sensor's σ's (a + b r scaled as one, σ_φ) and, if estimated,
    the odometry's variances scaled by the factors found; the σ's standard errors (σ √(2/r) ½, widened for ρ)."""
    root, relative = components.sigma_factors, components.sigma_relative_errors
    rb = dataclasses.replace(rb, range_sigma_m=rb.range_sigma_m * root[1], range_sigma_per_m=rb.range_sigma_per_m
                             * root[1], bearing_sigma_rad=rb.bearing_sigma_rad * root[2])
    figures = {}
    if "range" in components.estimated:
        figures |= {f"self_calibration_{k}_standard_error": float(getattr(rb, k) * relative[1])
                    for k in ("range_sigma_m", "range_sigma_per_m")}
    if "bearing" in components.estimated:
        figures["self_calibration_bearing_sigma_rad_standard_error"] = float(rb.bearing_sigma_rad * relative[2])
    if "odometry" in components.estimated:   # the factor was on every odometry variance, the stall's too (its σ_s)
        factor = float(components.factors[0])
        odometry = dataclasses.replace(odometry, **{k: getattr(odometry, k) * factor for k in _ODOMETRY_VARIANCES},
                                       stall_sigma_s=odometry.stall_sigma_s * math.sqrt(factor))
    return rb, odometry, figures
