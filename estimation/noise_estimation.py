"""Estimating a noise model from logs with ground truth (``p3at slam noise``): :func:`estimate_noise` and its fits.

The odometry's calibration (rotation and translation scales, heading bias per metre, lag, forward deficit per radian
turned) and random-walk variances over windows (:func:`_odometry_windows`, :func:`_random_walk_fit`), the turns'
overdispersion, the drifting heading bias and the stall after the command's dips; the sensor's range calibration,
σ's, footprint, correlations and detection rates. :data:`DATASET_CALIBRATIONS` is what ``p3at slam dataset`` fits
when no model is given. The model these fits write, its TOML file, its checks and its defaults:
:mod:`estimation.noise_model`.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import minimize_scalar, nnls

from .datasets import RangeBearingLog
from .fastslam.config import FastSLAMConfig
from .fastslam.motion import increment_variance, turn_spans, turning
from .geometry import between, wrap_angle
from .noise_model import (
    DETECTION_BANDS,
    MAX_FORWARD_DEFICIT_PER_RAD,
    MAX_HEADING_BIAS_PER_M,
    MAX_TURN_XY_INFLATION,
    NoiseModel,
    OdometryNoise,
    RangeBearingNoise,
    _calibrated,
)
from .odometry_consistency import fit_heading_drift
from .odometry_stall import fit_stall

ODOMETRY_WINDOW_S = 5.0       # see estimate_noise: the errors are time-correlated, so the window matters
MAX_VARIANCE_INFLATION = 100.0  # turn and distance more collinear than this: no heading bias is fitted
OUTLIER_MADS = 4.0            # sensor residuals beyond this many robust σ are outliers (misreads, glitches)
TURN_STEP_S = 0.25                 # the increments on which a turn's overdispersion is measured (a frame interval)
TURN_MIN_INCREMENTS = 4            # a turn shorter than this says nothing of the errors' persistence
# The calibrations that together make MRCLAM's smoothed known-ID maps honest in their start frame
# (docs/fastslam-history.md, "Session 16: the odometry's variance in turns" and "Session 17: the data set's default"):
# what `p3at slam dataset` fits from the log's own ground truth when no noise model is given. Each is per robot (the
# cameras' range and bearing offsets differ by up to 10 cm and 0.012 rad), so a model fitted on other robots does not
# serve. The stall after the command's dips (session 41 (A)) is one since session 42: on MRCLAM (seed 0) it takes
# robot 1's known-ID map from 93 to 100 % within and leaves the other four's within as they were; the chain in sample
# keeps 15 names on all five robots with it (docs/fastslam-history.md, "Session 42: the stall after the command's
# dips made a default (lead)"). On a log without dips it fits 0: no term.
DATASET_CALIBRATIONS = {"range_calibration": True, "heading_bias": True, "odometry_lag": True, "turn_variance": True,
                        "command_stall": True}


@dataclass(frozen=True)
class NoiseEstimate:
    """A fitted model, and the odometry fit at other windows (rows: window_s, σ_xy/√m, σ_θ/√rad, σ_θ/√m)."""

    model: NoiseModel
    odometry_by_window: np.ndarray


def estimate_noise(logs: Sequence[RangeBearingLog], *, window_s: float = ODOMETRY_WINDOW_S,
                   robot: str | None = None, platform: str = "", heading_bias: bool = False,
                   sensor_correlation: str = "lag1", range_calibration: bool = False,
                   odometry_lag: bool = False, turn_translation: bool = False,
                   turn_variance: bool = False, heading_drift: bool = False,
                   time_variance: bool = False, calibration_per_log: bool = False,
                   command_stall: bool = False) -> NoiseEstimate:
    """Fit a noise model from logs with ground truth (one robot's, or several pooled).

    ``heading_drift=True``: also a drifting heading bias per metre (σ_b, τ; see :func:`_with_heading_drift`).

    Odometry. The log's span is cut into windows of ``window_s``; in each, the odometry increment u and the
    true increment g (from the ground truth) give the error e = g − u in the robot frame at the window's start.
    First the calibration: the rotation scale and the heading bias per metre by least squares
    (g_θ ≈ k_r u_θ + c·d, d the window's odometry distance) with ``heading_bias=True``; by default, or for a log
    whose turns and distances are proportional so that the two cannot be told apart, c = 0 (see
    _heading_calibration; off by default because on MRCLAM it did not improve the maps, docs/fastslam-history.md); then,
    the turns calibrated, the translation scale by least squares on the window's displacement vectors (which
    scale linearly with it). Then
    the random-walk variances q = (q_xy, q_θ/rad, q_θ/m) of the calibrated steps:
    the model's covariance of a window's error is linear in q (each step's noise, propagated to the window's end
    through the composition: a heading error also moves the end sideways), so q is the non-negative least
    squares fit of every window's e eᵀ to it (:func:`_random_walk_fit`). On MRCLAM the variance per metre still
    grows with the window (the odometry is commanded velocity, so its errors are correlated over seconds);
    the model is a random walk, so the window chosen is the time scale on which the filter must trust the
    odometry alone: the default 5 s is longer than the gaps between sightings, and the fits at other windows
    are returned beside it (``odometry_by_window``) so that the choice can be judged.

    Sensor. Each sighting is predicted from the true pose and the landmark's true position: residuals
    Δr = r − r̂, Δφ = φ − φ̂. The bearing offset is the residuals' median (the sensor's yaw on the robot);
    outliers (beyond OUTLIER_MADS robust σ: misread barcodes, sightings during Vicon glitches) are counted and
    set aside; σ_r(r) = a + b·r is fitted (non-negative least squares) to |Δr|·√(π/2) of the inliers — the
    mean absolute value of a zero-mean Gaussian is σ·√(2/π) — so the range's bias (the short-range bias the
    data set's authors report) counts as noise, not as a correction; σ_φ is the inliers' RMS about the offset.
    ``sensor_correlation``: how ``range_correlation`` / ``bearing_correlation`` are measured: ``"lag1"``
    (default) the lag-1 correlation of consecutive sightings of a landmark (an AR(1) assumed beyond it: on MRCLAM
    it understates the bearing's inflation 1.5-2x and overstates the range's 2-4x); ``"passes"`` the ρ whose
    AR(1) inflation (1 + ρ)/(1 − ρ) equals the measured one of whole passes (:func:`_pass_inflation`): what a
    filter taking a pass's sightings as independent needs over a pass. Not the default: on MRCLAM it improved
    known-ID maps on three seeds but made the leave-one-out and unknown-association runs worse
    (docs/fastslam-history.md). ``range_calibration``: first fit the range's calibration r_true ≈ a + r·(b₀ + b₁φ +
    b₂φ²) (measured r, φ; see :meth:`RangeBearingNoise.corrected`) by least squares, refitted three times on the
    sightings within OUTLIER_MADS robust σ, and take every range residual, σ_r and correlation after it; off: the
    identity. ``calibration_per_log`` (several logs pooled): the range calibration (with ``range_calibration``)
    and the bearing offset are fitted to each log on its own, and the σ's and correlations are measured on each
    log's residuals about its own calibration; the model carries the logs' mean calibration (the typical camera;
    its b₂ is what a self-calibration holds fixed), and [fit] each log's (``per_log_*``, in the logs' order). Why:
    cameras differ (MRCLAM's range offsets −0.011 to −0.110 m, scales 0.950-1.005); pooled residuals about one
    calibration hold each camera's bias, which reads as noise 4-9x too large and as a lag-1 correlation of 0.8-0.9
    (docs/fastslam-history.md, "Session 36 ... (B)"). The σ's of this fit are the ones to give a robot whose own
    calibration is estimated apart (:mod:`estimation.camera_calibration`). ``odometry_lag``: first fit the time by
    which the odometry leads the motion (:func:`_odometry_lag`: the
    lag that minimises the heading increments' error at the filter's frame interval) and fit everything else on the
    odometry read that much earlier; off: 0.
    ``turn_translation``: fit the translation scale k jointly with a forward deficit per radian turned c (each
    50 Hz step's distance d → max(d − c·|Δθ|, 0), then scaled by k; :func:`_calibrated`) on the same windows,
    c by a bounded search on [0, MAX_FORWARD_DEFICIT_PER_RAD] with k in closed form for each c, and c's standard
    error from the profile's curvature; off: c = 0 (one translation scale for all motion). Why: MRCLAM's robots
    cover 0.65 of the commanded distance in arcs and all of it straight (docs/fastslam-history.md "Session 16 (Q)").
    ``turn_variance``: fit ``turn_xy_inflation``, the turns' overdispersion (:func:`_turn_inflation`): on
    increments of TURN_STEP_S with everything above calibrated, z = (true − odometry forward travel) / σ_xy of the
    fitted random walk; over each turn (≥ TURN_MIN_INCREMENTS consecutive increments of
    ``estimation.fastslam.motion.turning``) Σz/√n is a unit normal if the increments' errors are independent; the
    inflation is its mean square over the turns (≥ 1; a mean error counts: a bias the calibration left is a
    persistent error too); off: 1. Why: the smoothed MRCLAM maps' start frames fail on the forward travel of the
    first turns, correlated through each turn (docs/fastslam-history.md "Session 16 (P)").
    ``time_variance``: fit a fourth random-walk variance, ``theta_var_per_s`` (rad² of heading per second, moving or
    not), in the same non-negative least squares (each step's heading noise q_θ/s × its duration, propagated like the
    others; :func:`_odometry_windows`' time column), and write the three-term fit's q_θ/rad and q_θ/m beside it in
    [fit]; off: 0. Why and what it does and does not explain: docs/fastslam-history.md "Session 35: a heading
    variance per second (A)".
    ``command_stall``: fit ``stall_sigma_s``, the σ of the random stall after a one-sample dip of the commanded
    velocity (:func:`estimation.odometry_stall.fit_stall`, on the odometry calibrated as above; needs the logs'
    velocity samples), its figures in [fit]; off: 0. Why: MRCLAM's robots stop for a random while after each such dip
    while their odometry goes on (docs/fastslam-history.md "Session 41 (A)").
    """
    if sensor_correlation not in ("lag1", "passes"):
        raise ValueError(f"sensor_correlation must be 'lag1' or 'passes', not {sensor_correlation!r}")
    logs = list(logs)
    if not logs:
        raise ValueError("estimate_noise needs at least one log")
    if not window_s > 0:
        raise ValueError(f"window_s must be > 0, not {window_s}")
    for log in logs:
        if not log.has_ground_truth:
            raise ValueError(f"{log.name}: noise estimation needs ground truth, and the log has none")

    lag, lag_fit = _odometry_lag(logs) if odometry_lag else (0.0, {})
    windows = [_odometry_windows(log, window_s, lag_s=lag) for log in logs]
    u = np.concatenate([w[0] for w in windows])
    g = np.concatenate([w[1] for w in windows])
    if len(u) < 10:
        raise ValueError(f"only {len(u)} odometry windows of {window_s} s: too short a log for a fit")
    distance = np.concatenate([w[2][:, 0, 0, 0] for w in windows])    # odometry metres per window
    rotation_scale, bias, bias_se = _heading_calibration(u[:, 2], distance if heading_bias else None, g[:, 2])
    bias_fit = {} if not heading_bias else {"heading_bias_per_m_standard_error": bias_se} if math.isfinite(bias_se) \
        else {"heading_bias_note": "not fitted: the windows' turns and distances are proportional (a bias per "
                                   "metre cannot be told from a rotation scale)"}
    # with the turns calibrated, the chain's positions scale linearly with the translation scale: regress on them
    translation_scale, deficit, deficit_fit = _translation_calibration(logs, window_s, rotation_scale, bias, lag,
                                                                       g, turn_translation)
    scales = np.array([translation_scale, translation_scale, rotation_scale])
    q_xy, q_theta_rad, q_theta_m, *q_theta_s = _random_walk_fit(
        [_odometry_windows(log, window_s, scales, bias, lag, deficit, time_variance) for log in logs])
    q_theta_s = q_theta_s[0] if q_theta_s else 0.0
    time_fit = {}
    if time_variance:   # the three-term fit beside it: what the time term took from the others
        without = _random_walk_fit([_odometry_windows(log, window_s, scales, bias, lag, deficit) for log in logs])
        time_fit = {"theta_var_per_rad_without_time": without[1], "theta_var_per_m_without_time": without[2]}
    inflation, turn_fit = (_turn_inflation(logs, scales, bias, lag, deficit, q_xy) if turn_variance
                           else (1.0, {}))
    stall, stall_fit = (fit_stall(logs, lag, lambda inc: _calibrated(inc, scales, bias, deficit)) if command_stall
                        else (0.0, {}))
    by_window = []
    for w in sorted({0.5, 1.0, 2.0, 5.0, 10.0, 20.0, float(window_s)}):
        other = [_odometry_windows(log, w, scales, bias, lag, deficit) for log in logs]
        if sum(len(o[0]) for o in other) >= 10:
            by_window.append((w, *np.sqrt(_random_walk_fit(other))))

    residual_r, residual_b, ranges, bearings, follows, true_ranges = [], [], [], [], [], []
    for log in logs:
        if len(log) == 0:
            continue
        pose = log.true_pose(log.sighting_times)
        known = np.isin(log.landmark_ids, log.truth_ids)
        target = log.truth_positions[np.searchsorted(log.truth_ids, log.landmark_ids[known])]
        d = target - pose[known, :2]
        true_ranges.append(np.hypot(d[:, 0], d[:, 1]))
        residual_r.append(log.ranges[known] - true_ranges[-1])
        residual_b.append(wrap_angle(log.bearings[known] - (np.arctan2(d[:, 1], d[:, 0]) - pose[known, 2])))
        ranges.append(log.ranges[known])
        bearings.append(log.bearings[known])
        follows.append(_consecutive(log.sighting_times[known], log.landmark_ids[known]))
    range_bearing = None
    range_fit = _NO_RANGE_CALIBRATION
    per_log_fit: dict = {}
    if range_calibration and residual_r and sum(len(r) for r in residual_r) >= 20:
        range_fit = _range_calibration(np.concatenate(ranges), np.concatenate(bearings), np.concatenate(true_ranges))
        own = [_range_calibration(r, b, t) if calibration_per_log else range_fit
               for r, b, t in zip(ranges, bearings, true_ranges, strict=True)]
        residual_r = [RangeBearingNoise(1.0, 0.0, 1.0, **dict(zip(_RANGE_CALIBRATION, f, strict=True)))
                      .corrected(r, b)[0] - t for f, r, b, t in zip(own, ranges, bearings, true_ranges, strict=True)]
        if calibration_per_log:   # the model's: the logs' mean (the typical camera)
            range_fit = tuple(float(v) for v in np.mean(own, axis=0))
            per_log_fit.update({f"per_log_{name}": [float(f[i]) for f in own]
                                for i, name in enumerate(_RANGE_CALIBRATION)})
    if calibration_per_log and residual_b:   # each log's bearing residuals about its own offset, moved to the
        own_offsets = [float(np.median(b)) if len(b) else 0.0 for b in residual_b]    # logs' mean offset
        per_log_fit["per_log_bearing_offset_rad"] = own_offsets
        typical = float(np.mean(own_offsets))
        residual_b = [wrap_angle(b - o + typical) for b, o in zip(residual_b, own_offsets, strict=True)]
    fit = {"odometry_window_s": float(window_s), "odometry_windows": int(len(u)),
           **bias_fit, **lag_fit, **deficit_fit, **turn_fit, **time_fit, **stall_fit, **per_log_fit,
           "odometry_max_gap_s": float(max(np.max(np.diff(log.odometry[:, 0])) for log in logs))}
    if residual_r and sum(len(r) for r in residual_r) >= 20:
        dr, db, r = np.concatenate(residual_r), np.concatenate(residual_b), np.concatenate(ranges)
        offset = float(np.median(db))
        db = wrap_angle(db - offset)
        inlier = (np.abs(dr - np.median(dr)) < OUTLIER_MADS * _robust_sigma(dr)) & \
                 (np.abs(db) < OUTLIER_MADS * _robust_sigma(db))
        coefficients, _ = nnls(np.column_stack([np.ones(inlier.sum()), r[inlier]]),
                               np.abs(dr[inlier]) * math.sqrt(math.pi / 2))
        a, b = (float(c) for c in coefficients)
        if a <= 0:   # a σ that vanishes at r = 0 would make close sightings infinitely precise
            a = float(np.min(np.abs(dr[inlier]) * math.sqrt(math.pi / 2)) + 1e-3)
        # the footprint: where the sensor reported anything (extreme 0.1 % of the sightings left out)
        fov = float(min(2.0 * np.percentile(np.abs(wrap_angle(np.concatenate(bearings) - offset)), 99.9), 2 * math.pi))
        min_range, max_range = (float(v) for v in np.percentile(r, [0.1, 99.9]))
        # sightings j and next[j] are consecutive sightings of one landmark (within CORRELATION_GAP_S)
        shift = np.cumsum([0] + [len(x) for x in residual_r[:-1]])
        nxt = np.concatenate([np.where(f >= 0, f + s0, -1) for f, s0 in zip(follows, shift, strict=True)])
        pair = np.flatnonzero((nxt >= 0) & inlier)
        pair = pair[inlier[nxt[pair]]]
        rho_r = _lag_correlation(dr / (a + b * r), pair, nxt)
        rho_b = _lag_correlation(db, pair, nxt)
        inflation_r = _pass_inflation(dr / (a + b * r), nxt, inlier)
        inflation_b = _pass_inflation(db / float(np.sqrt(np.mean(db[inlier] ** 2))), nxt, inlier)
        fit.update(range_lag1_correlation=rho_r, bearing_lag1_correlation=rho_b,
                   range_pass_inflation=inflation_r, bearing_pass_inflation=inflation_b)
        if sensor_correlation == "passes":
            rho_r, rho_b = (float(np.clip((f - 1.0) / (f + 1.0), 0.0, 0.95)) for f in (inflation_r, inflation_b))
        range_bearing = RangeBearingNoise(range_sigma_m=a, range_sigma_per_m=b,
                                          bearing_sigma_rad=float(np.sqrt(np.mean(db[inlier] ** 2))),
                                          bearing_offset_rad=offset, fov_rad=fov, min_range_m=min_range,
                                          max_range_m=max_range, range_correlation=rho_r, bearing_correlation=rho_b,
                                          **dict(zip(_RANGE_CALIBRATION, range_fit, strict=True)))
        edges = [0.0] + [edge for _, edge in DETECTION_BANDS]
        for (label, _), lo, hi in zip(DETECTION_BANDS, edges[:-1], edges[1:], strict=True):
            probability = _detection_probability(logs, fov, lo, hi)
            if math.isfinite(probability):
                fit[f"detection_probability_{label}"] = probability
        fit["detection_correlation"] = _detection_correlation(logs, fov)
        fit.update(sightings=int(len(dr)), sensor_outlier_fraction=float(1.0 - inlier.mean()),
                   range_bias_median_m=float(np.median(dr[inlier])),
                   range_bias_below_2m_m=float(np.median(dr[inlier & (r < 2.0)])) if np.any(inlier & (r < 2.0))
                   else float("nan"),
                   range_residual_rms_m=float(np.sqrt(np.mean(dr[inlier] ** 2))))
        fit = {k: v for k, v in fit.items() if not (isinstance(v, float) and not math.isfinite(v))}
    name = robot or (logs[0].name if len(logs) == 1 else "+".join(log.name for log in logs))
    model = NoiseModel(
        OdometryNoise(q_xy, q_theta_rad, q_theta_m, translation_scale, rotation_scale, bias, lag, deficit, inflation,
                      theta_var_per_s=q_theta_s, stall_sigma_s=stall),
        range_bearing, None,
        robot=name, platform=platform, fit=fit,
        source=f"estimated by p3at slam noise from {', '.join(log.name for log in logs)} against its ground "
               f"truth ({len(u)} odometry windows of {window_s:g} s)")
    if heading_drift:
        model = _with_heading_drift(model, logs)
    return NoiseEstimate(model, np.array(by_window, float).reshape(-1, 4))


def _with_heading_drift(model: NoiseModel, logs: Sequence[RangeBearingLog]) -> NoiseModel:
    """``model`` with a drifting heading bias per metre (σ_b, τ) fitted to its dead reckoning over 5-600 s
    (``odometry_consistency.fit_heading_drift``: the grid whose NEES per horizon looks most like χ²₃), and the fit's
    costs in [fit]. σ_b = 0 (none) if no drift does better than none."""
    drift = fit_heading_drift([(log.odometry, log.ground_truth) for log in logs], model)
    odometry = replace(model.odometry, heading_drift_sigma_per_m=drift.sigma_per_m, heading_drift_tau_s=drift.tau_s)
    fit = {**model.fit, "heading_drift_cost": drift.cost, "heading_drift_cost_without": drift.cost_without}
    return replace(model, odometry=odometry, fit=fit)


_RANGE_CALIBRATION = ("range_offset_m", "range_scale", "range_scale_per_rad", "range_scale_per_rad2")
_NO_RANGE_CALIBRATION = (0.0, 1.0, 0.0, 0.0)   # a, b₀, b₁, b₂ of the identity


def _range_calibration(ranges: np.ndarray, bearings: np.ndarray, true_ranges: np.ndarray) -> tuple[float, ...]:
    """(a, b₀, b₁, b₂) of r_true ≈ a + r·(b₀ + b₁φ + b₂φ²) (measured r, φ (N,); see RangeBearingNoise.corrected):
    least squares, refitted three times on the sightings within OUTLIER_MADS robust σ of the last fit (misread
    barcodes and Vicon glitches must not bend it). The identity if the fit leaves b₀ outside [0.5, 2]."""
    design = np.column_stack([np.ones_like(ranges), ranges, ranges * bearings, ranges * bearings ** 2])
    keep = np.ones(len(ranges), bool)
    coefficients = np.array(_NO_RANGE_CALIBRATION)
    for _ in range(3):
        if keep.sum() < design.shape[1] * 5:
            break
        coefficients, *_ = np.linalg.lstsq(design[keep], true_ranges[keep], rcond=None)
        error = true_ranges - design @ coefficients
        keep = np.abs(error - np.median(error)) < OUTLIER_MADS * _robust_sigma(error)
    if not 0.5 <= coefficients[1] <= 2.0:
        return _NO_RANGE_CALIBRATION
    return tuple(float(c) for c in coefficients)


LAG_GRID_S = np.arange(0.0, 0.505, 0.01)   # candidate lags of the odometry behind the motion
LAG_STEP_S = 0.25                           # the step the lag is judged at: MRCLAM's frame interval (~4 Hz)
LAG_MIN_GAIN = 0.01   # a lag must lower the squared heading error by this fraction, or there is none to see


def _odometry_lag(logs: Sequence[RangeBearingLog]) -> tuple[float, dict]:
    """The time (s, on LAG_GRID_S) by which the odometry leads the motion, and the fit's figures: the lag whose
    odometry turns over LAG_STEP_S steps, each scaled by the least-squares rotation scale of that lag, have the
    smallest squared error against the true turns (pooled over the logs). A commanded-velocity odometry leads by
    the drive's actuation lag (MRCLAM: 0.16-0.20 s by cross-correlating the turn rates); encoders lead by ~0.
    A lag that lowers the error by less than LAG_MIN_GAIN is not fitted (0): where the turn rate does not vary
    (a circle at constant speeds) every lag fits alike, and the grid's minimum is rounding noise that would
    shift the whole odometry in time (MRCLAM: 20 % lower, so unaffected)."""
    pairs = []
    for log in logs:
        lo, hi = log.ground_truth[0, 0] + LAG_GRID_S[-1], log.ground_truth[-1, 0]
        lo, hi = max(lo, log.odometry[0, 0] + LAG_GRID_S[-1]), min(hi, log.odometry[-1, 0])
        if hi - lo > 10 * LAG_STEP_S:
            pairs.append((log, np.arange(lo, hi, LAG_STEP_S)))
    if not pairs:
        return 0.0, {}
    true_turn = np.concatenate([wrap_angle(np.diff(log.true_pose(t)[:, 2])) for log, t in pairs])
    errors = []
    for lag in LAG_GRID_S:
        turn = np.concatenate([between(p[:-1], p[1:])[:, 2] for p in (log.odometry_pose(t - lag) for log, t in pairs)])
        k = float(true_turn @ turn / max(turn @ turn, 1e-12))
        errors.append(float(np.mean(wrap_angle(k * turn - true_turn) ** 2)))
    best = int(np.argmin(errors))
    if errors[best] > (1.0 - LAG_MIN_GAIN) * errors[0]:
        return 0.0, {"odometry_lag_note": "not fitted: no lag lowers the heading error by "
                                          f"{100 * LAG_MIN_GAIN:g} % (the turn rate hardly varies)",
                     "odometry_no_lag_heading_rms_rad": float(np.sqrt(errors[0]))}
    return float(LAG_GRID_S[best]), {"odometry_lag_heading_rms_rad": float(np.sqrt(errors[best])),
                                     "odometry_no_lag_heading_rms_rad": float(np.sqrt(errors[0]))}


def _translation_calibration(logs, window_s: float, rotation_scale: float, bias: float, lag: float,
                             g: np.ndarray, turn_translation: bool) -> tuple[float, float, dict]:
    """(translation scale k, forward deficit per radian c, the fit's figures): with the turns calibrated, the
    windows' calibrated displacements u(c) scale linearly with k, so k(c) = Σ g·u / Σ u² (g the true ones) and
    the squared error left, S(c), is minimised over c in [0, MAX_FORWARD_DEFICIT_PER_RAD] (c = 0 unless
    ``turn_translation``). c's standard error: √(2σ² / S''(c)), σ² = S / (2W − 2) (W windows, x and y each)."""
    def profile(c: float) -> tuple[float, float]:
        u = np.concatenate([_odometry_windows(log, window_s, (1.0, 1.0, rotation_scale), bias, lag, c)[0]
                            for log in logs])[:, :2]
        k = float(np.sum(g[:, :2] * u) / max(np.sum(u ** 2), 1e-12))
        return k, float(np.sum((g[:, :2] - k * u) ** 2))

    k0, s0 = profile(0.0)
    if not turn_translation:
        return k0, 0.0, {}
    best = minimize_scalar(lambda c: profile(c)[1], bounds=(0.0, MAX_FORWARD_DEFICIT_PER_RAD), method="bounded",
                           options={"xatol": 1e-4})
    c = float(best.x) if best.fun < s0 else 0.0
    k, s = profile(c)
    if not 0.5 <= k <= 2.0:
        return k0, 0.0, {"forward_deficit_note": f"not fitted: the translation scale with it would be {k:.3f}"}
    h = 0.005
    lo, hi = max(c - h, 0.0), min(c + h, MAX_FORWARD_DEFICIT_PER_RAD)
    mid = 0.5 * (lo + hi)
    curvature = (profile(hi)[1] - 2.0 * profile(mid)[1] + profile(lo)[1]) / (0.5 * (hi - lo)) ** 2
    sigma2 = s / max(2 * len(g) - 2, 1)
    se = float(np.sqrt(2.0 * sigma2 / curvature)) if curvature > 0 else float("nan")
    fit = {"forward_deficit_translation_scale_alone": k0,
           "forward_deficit_displacement_rms_m": float(np.sqrt(s / max(len(g), 1))),
           "forward_deficit_none_displacement_rms_m": float(np.sqrt(s0 / max(len(g), 1)))}
    if math.isfinite(se):
        fit["forward_deficit_per_rad_standard_error"] = se
    return k, c, fit


def _heading_calibration(turn: np.ndarray, distance: np.ndarray | None, true_turn: np.ndarray):
    """(rotation scale k_r, heading bias c rad/m, c's standard error) by least squares over windows, true_turn ≈
    k_r·turn + c·distance (all (W,)); ``distance`` None: c = 0 (the scale alone, as before the bias existed).

    A robot that turns in proportion to the distance it drives (a circle at constant speeds) cannot tell a bias
    per metre from a rotation scale: when the two regressors are that collinear (variance inflation factor
    1/(1 − cos²) > MAX_VARIANCE_INFLATION, cos their uncentred correlation), or the joint fit puts c beyond
    MAX_HEADING_BIAS_PER_M, c = 0 and its standard error is NaN."""
    scale_only = float(np.sum(true_turn * turn) / max(np.sum(turn ** 2), 1e-12)), 0.0, float("nan")
    if distance is None:
        return scale_only
    cos = float(turn @ distance) / max(float(np.sqrt((turn @ turn) * (distance @ distance))), 1e-300)
    if not 1.0 - cos ** 2 > 1.0 / MAX_VARIANCE_INFLATION:
        return scale_only
    design = np.column_stack([turn, distance])
    (k_r, c), *_ = np.linalg.lstsq(design, true_turn, rcond=None)
    residual = true_turn - design @ [k_r, c]
    dof = max(len(turn) - 2, 1)
    covariance = np.linalg.pinv(design.T @ design) * float(residual @ residual) / dof
    if not (abs(c) <= MAX_HEADING_BIAS_PER_M and 0.5 <= k_r <= 2.0):
        return scale_only
    return float(k_r), float(c), float(np.sqrt(covariance[1, 1]))


def _turn_inflation(logs, scales, heading_bias_per_m, lag_s, forward_deficit_per_rad, q_xy):
    """The turns' overdispersion (see estimate_noise's ``turn_variance``) and its figures for ``fit``."""
    per_turn, increments = [], 0
    for log in logs:
        u, g, _ = _odometry_windows(log, TURN_STEP_S, scales, heading_bias_per_m, lag_s, forward_deficit_per_rad)
        if len(u) == 0:
            continue
        # σ of each increment's forward travel under the fitted random walk, as the filter moves particles by it
        sigma = np.sqrt(increment_variance(u, replace(FastSLAMConfig(), odom_xy_var_per_m=q_xy))[:, 0])
        z = (g[:, 0] - u[:, 0]) / sigma
        for start, stop in turn_spans(turning(u), TURN_MIN_INCREMENTS):
            per_turn.append(float(z[start:stop].sum() / np.sqrt(stop - start)))
            increments += stop - start
    if len(per_turn) < 3:
        return 1.0, {"turn_xy_inflation_note": f"not fitted: {len(per_turn)} turns of ≥ {TURN_MIN_INCREMENTS} "
                                                f"increments of {TURN_STEP_S:g} s"}
    square = float(np.mean(np.square(per_turn)))
    inflation = float(np.clip(square, 1.0, MAX_TURN_XY_INFLATION))
    return inflation, {"turn_xy_inflation_turns": len(per_turn), "turn_xy_inflation_increments": increments,
                       "turn_xy_inflation_mean_z_sum": float(np.mean(per_turn)),
                       "turn_xy_inflation_measured": square}


def _odometry_windows(log: RangeBearingLog, window_s: float, scales=(1.0, 1.0, 1.0), heading_bias_per_m=0.0,
                      lag_s: float = 0.0, forward_deficit_per_rad: float = 0.0, time_column: bool = False):
    """Consecutive windows of odometry rows inside the ground truth: odometry increments u (W, 3) calibrated by
    ``scales``, the heading bias per odometry metre and the forward deficit per radian, true increments g (W, 3)
    (``lag_s`` later than the odometry rows' times: the odometry leads the motion), and the design (W, K, 3, 3):
    the error covariance of each window is Σ_k q_k · design[:, k] for the model's variances
    q = (q_xy, q_θ/rad, q_θ/m), K = 3, and with ``time_column`` also q_θ/s, K = 4: each step's heading noise of
    variance q_θ/s × its duration (the window's duration over its steps: MRCLAM's stamps are coarser than its rows)
    (see _random_walk_fit)."""
    rows = log.odometry
    rows = rows[(rows[:, 0] >= log.ground_truth[0, 0]) & (rows[:, 0] <= log.ground_truth[-1, 0])]
    columns = 4 if time_column else 3
    empty = np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, columns, 3, 3))
    if len(rows) < 3:
        return empty
    # the rows' interval: their median step, or, where most rows share a stamp (stamps coarser than the rows: MRCLAM's
    # copy stamps its 50 Hz rows to 0.1 s from t = 1000 s on, so the median step there is 0), the mean step
    step_s = float(np.median(np.diff(rows[:, 0])))
    if not step_s > 0:
        step_s = float(rows[-1, 0] - rows[0, 0]) / (len(rows) - 1)
    n = max(1, int(round(window_s / max(step_s, 1e-9))))
    k = (len(rows) - 1) // n
    if k < 1:
        return empty
    rows = rows[: k * n + 1]
    steps = _calibrated(between(rows[:-1, 1:], rows[1:, 1:]), scales, heading_bias_per_m,   # robot frame
                        forward_deficit_per_rad)
    # the calibrated chain, in closed form: heading before step j, then positions after each step
    heading = np.concatenate([[0.0], np.cumsum(steps[:, 2])])
    c, s = np.cos(heading[:-1]), np.sin(heading[:-1])
    xy = np.vstack([[0.0, 0.0], np.cumsum(np.column_stack([c * steps[:, 0] - s * steps[:, 1],
                                                             s * steps[:, 0] + c * steps[:, 1]]), axis=0)])
    chain = np.column_stack([xy, heading])                     # (k·n + 1, 3), θ unwrapped
    window = np.arange(k * n) // n
    starts = chain[0:k * n:n]
    u = between(starts, chain[n::n])
    u[:, 2] = chain[n::n, 2] - starts[:, 2]                    # the turn itself, not wrapped
    g = between(log.true_pose(rows[0:k * n:n, 0] + lag_s), log.true_pose(rows[n::n, 0] + lag_s))
    g[:, 2] = u[:, 2] + wrap_angle(g[:, 2] - u[:, 2])          # the true turn nearest the odometry's (no 2π jumps)
    # first-order effect on the window's end pose of a noise δ on step j (robot frame at the step's start):
    # the end moves by R(θ_{j-1}) δ_xy + δ_θ v_j, v_j = (−(y_end − y_j), x_end − x_j, 1) in the window's frame
    after = between(starts[window], chain[1:])
    end = u[window]
    v = np.column_stack([-(end[:, 1] - after[:, 1]), end[:, 0] - after[:, 0], np.ones(k * n)])
    distance = np.hypot(steps[:, 0], steps[:, 1])
    turn = np.abs(steps[:, 2])
    outer = v[:, :, None] * v[:, None, :]
    design = np.zeros((k, columns, 3, 3))
    seconds = ((rows[n::n, 0] - rows[0:k * n:n, 0]) / n)[window] if time_column else None
    for a in range(3):
        for b in range(3):
            design[:, 1, a, b] = np.bincount(window, turn * outer[:, a, b], minlength=k)
            design[:, 2, a, b] = np.bincount(window, distance * outer[:, a, b], minlength=k)
            if time_column:
                design[:, 3, a, b] = np.bincount(window, seconds * outer[:, a, b], minlength=k)
    design[:, 0, 0, 0] = design[:, 0, 1, 1] = np.bincount(window, distance, minlength=k)
    return u, g, design


def _random_walk_fit(windows) -> tuple[float, ...]:
    """(q_xy, q_θ/rad, q_θ/m) ≥ 0 (and q_θ/s, if the windows' design has the time column) matching each window's
    e eᵀ (e = g − u) to its modelled covariance, element by element (xx, yy, θθ, xy, xθ, yθ), by non-negative least
    squares with each element's equations scaled to unit spread (metres and radians mixed)."""
    e = np.concatenate([w[1] - w[0] for w in windows])
    design = np.concatenate([w[2] for w in windows])
    lhs, rhs = [], []
    for a, b in ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)):
        y = e[:, a] * e[:, b]
        spread = float(np.std(y)) or 1.0
        lhs.append(design[:, :, a, b] / spread)
        rhs.append(y / spread)
    q, _ = nnls(np.concatenate(lhs), np.concatenate(rhs))
    return tuple(float(v) for v in q)


CORRELATION_GAP_S = 2.0     # consecutive sightings of one landmark further apart than this are not paired


def _consecutive(times: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """(N,) index of the next sighting of the same landmark within CORRELATION_GAP_S, or -1."""
    out = np.full(len(times), -1, np.int64)
    order = np.lexsort((times, ids))
    same = (ids[order][1:] == ids[order][:-1]) & (np.diff(times[order]) <= CORRELATION_GAP_S)
    out[order[:-1][same]] = order[1:][same]
    return out


def _pass_inflation(residuals: np.ndarray, nxt: np.ndarray, inlier: np.ndarray) -> float:
    """The variance inflation f a filter needs over whole passes, from residuals (N,) in units of their σ.

    A pass is a chain of consecutive sightings of one landmark (``nxt``: the next one within CORRELATION_GAP_S,
    -1 at a chain's end); its inliers' mean m over n sightings has the variance f/n if each sighting's variance
    is taken as f (σ² = 1) and the sightings as independent, which is what the filter does. So f is estimated as
    the mean of n·m² over the passes of at least 2 inliers (1 if there are fewer than 20 passes). Unlike the
    lag-1 correlation's AR(1), this also counts the error a pass shares throughout (a landmark's geometry).
    """
    has_previous = np.zeros(len(nxt), bool)
    has_previous[nxt[nxt >= 0]] = True
    values = []
    for start in np.flatnonzero(~has_previous):
        chain, j = [], int(start)
        while j >= 0:
            if inlier[j]:
                chain.append(j)
            j = int(nxt[j])
        if len(chain) >= 2:
            values.append(len(chain) * float(np.mean(residuals[chain])) ** 2)
    return float(max(np.mean(values), 1.0)) if len(values) >= 20 else 1.0


def _lag_correlation(residuals: np.ndarray, pair: np.ndarray, nxt: np.ndarray) -> float:
    """Correlation of residual j with residual next[j] over the pairs (0 if fewer than 20), clipped to [0, 0.95]."""
    if len(pair) < 20:
        return 0.0
    x, y = residuals[pair], residuals[nxt[pair]]
    x, y = x - residuals.mean(), y - residuals.mean()
    rho = float(np.sum(x * y) / max(np.sqrt(np.sum(x * x) * np.sum(y * y)), 1e-300))
    return float(np.clip(rho, 0.0, 0.95))


def _detection_frames(log: RangeBearingLog, fov: float, near: float, far: float, margin: float = 0.85):
    """Per frame (distinct sighting time) and true landmark: in view (``margin`` of the half field of view, range
    in [near, far)) at the true pose, and reported; both (F, L) bool, with the frame times (F,)."""
    times, frame = np.unique(log.sighting_times, return_inverse=True)
    pose = log.true_pose(times)
    d = log.truth_positions[None, :, :] - pose[:, None, :2]
    r = np.hypot(d[..., 0], d[..., 1])
    b = wrap_angle(np.arctan2(d[..., 1], d[..., 0]) - pose[:, 2:3])
    in_view = (np.abs(b) < margin * fov / 2) & (r >= near) & (r < far)
    seen = np.zeros_like(in_view)
    known = np.isin(log.landmark_ids, log.truth_ids)
    seen[frame[known], np.searchsorted(log.truth_ids, log.landmark_ids[known])] = True
    return in_view, seen, times


def _usable(log: RangeBearingLog) -> bool:
    return len(log) > 0 and len(log.truth_ids) > 0


def _detection_probability(logs: Sequence[RangeBearingLog], fov: float, near: float, far: float) -> float:
    """P(a landmark well inside the view at a range in [near, far) is reported in a frame), over the frames
    (distinct sighting times) of the logs, from the true poses."""
    hits = total = 0
    for log in filter(_usable, logs):
        in_view, seen, _ = _detection_frames(log, fov, near, far)
        hits += int((seen & in_view).sum())
        total += int(in_view.sum())
    return hits / total if total else float("nan")


def _detection_correlation(logs: Sequence[RangeBearingLog], fov: float) -> float:
    """Lag-1 correlation of a landmark's reported / not reported indicator over consecutive frames (at most
    CORRELATION_GAP_S apart) in which it is well in view at the true pose; clipped to [0, 0.95]."""
    x, y = [], []
    for log in filter(_usable, logs):
        in_view, seen, times = _detection_frames(log, fov, 0.0, math.inf)
        pair = (np.diff(times) <= CORRELATION_GAP_S)[:, None] & in_view[:-1] & in_view[1:]
        x.append(seen[:-1][pair])
        y.append(seen[1:][pair])
    x, y = (np.concatenate(v).astype(float) if v else np.zeros(0) for v in (x, y))
    if len(x) < 20 or x.std() == 0 or y.std() == 0:
        return 0.0
    return float(np.clip(np.corrcoef(x, y)[0, 1], 0.0, 0.95))


def _robust_sigma(x: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(x - np.median(x)))) + 1e-12
