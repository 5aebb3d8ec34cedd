"""Does an odometry noise model hold beyond the window it was fitted on? NEES of dead reckoning per horizon.

A noise model's odometry is a random walk (``estimation.fastslam.motion.increment_variance``): each increment's
variance grows with its distance and turn, so the dead-reckoned pose's covariance grows linearly with the path. It is
fitted on short windows (``estimate_noise``: 5 s). Errors that are correlated in time (a scale or heading-rate bias
that stays for minutes) grow with the square of the path instead, so a model honest at 5 s can be far too confident
over hundreds of seconds, which is what a loop closure or a landmark re-seen after a long open path relies on.

:func:`odometry_consistency` measures it from any odometry and ground truth (arrays of rows (t, x, y, θ)): for each
horizon H, windows of H seconds starting every ``stride_s``; in each the model's calibrated increments (every
``step_s``: the filter's frame interval) are dead-reckoned from the window's start and their covariance propagated as
the filter propagates it (``propagate_covariance`` with ``increment_variance``, the model's turn inflation included);
the window's NEES is eᵀP⁻¹e, e the true end pose (in the window's start frame) minus the dead-reckoned one. A
consistent model gives NEES ~ χ²₃: median 2.37 and 95 % of windows below 7.81 at every horizon.

The noise model's stalls after the command's dips (``[odometry] stall_sigma_s``, :mod:`estimation.odometry_stall`)
are in the windows' covariance when the command is given (``command``: the log's velocity rows (t, v, w),
``RangeBearingLog.velocities``, where the dips are found; odometry and truth rows do not hold it): each step that holds
a dip gets the variance the filter gives the increment that holds it
(:func:`~estimation.odometry_stall.command_stall_variance`). Without the command, or with σ_s = 0, the covariance is
the random walk's alone, bit for bit as before the term. MRCLAM (in-sample models with σ_s 0.08-0.12 s, robots 1, 2,
3, 5): a window that holds a dip was not overconfident without it (5 s median 1.5-2.1), and with it the medians per
horizon fall 1-6 %, the share within the bound rises 0-3 points. :func:`fit_heading_drift` takes no command: the drift
is fitted on the random walk's windows, as the drifts in use were (with the stall in them it moves by a grid step or
two at the same cost: robot 2 σ_b 0.13 → 0.11 rad/m, τ 10 → 20 s; robot 5 0.17 → 0.16; robots 1 and 3 the same).

Windows in which the odometry hardly moves (path < ``min_path_m`` and turn < ``min_turn_rad``) are left out: there the
model's covariance is its variance floor, and the ground truth's own jitter (millimetres) is no odometry error.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from . import chi2
from .fastslam.config import FastSLAMConfig
from .fastslam.motion import increment_variance
from .geometry import between, compose, interpolate_poses, wrap_angle
from .odometry_stall import command_stall_variance

if TYPE_CHECKING:
    from .noise_model import NoiseModel

HORIZONS_S = (5.0, 15.0, 30.0, 60.0, 120.0, 300.0, 600.0)
STEP_S = 0.25            # the increments' interval (MRCLAM's frames come at ~4 Hz)
STRIDE_S = 5.0           # a new window starts every this many seconds (windows of a long horizon overlap)
MIN_PATH_M = 0.1         # a window whose odometry moves less than this ...
MIN_TURN_RAD = 0.1       # ... and turns less than this is left out (the robot at rest: see the module's doc)
CHI2_3_95 = float(chi2.ppf(0.95, 3))      # 7.815
CHI2_3_MEDIAN = float(chi2.ppf(0.5, 3))   # 2.366
HONEST_WITHIN = 0.9      # a horizon is called honest with this share of windows within the bound (0.95 expected:
#                          overlapping windows of a log make the share a few per cent noisy)


@dataclass(frozen=True)
class HorizonConsistency:
    """The NEES of the dead-reckoned end pose over windows of one horizon."""

    horizon_s: float
    windows: int            # windows scored (overlapping when the horizon is longer than the stride)
    independent: int        # how many of them do not overlap: what the figures' precision rests on
    nees_median: float      # χ²₃: 2.37
    within_chi2_95: float   # fraction of windows with NEES below χ²₃'s 95 % bound (7.81): 0.95 if consistent
    variance_ratio: float   # nees_median / 2.37: roughly how many times the model's variance the errors need

    @property
    def verdict(self) -> str:
        """"honest" (≥ HONEST_WITHIN of the windows within the bound), else "overconfident" (the median above χ²₃'s:
        the errors outgrow the covariance) or "heavy-tailed" (the bulk within, too many far outside)."""
        if self.within_chi2_95 >= HONEST_WITHIN:
            return "honest"
        return "overconfident" if self.nees_median > CHI2_3_MEDIAN else "heavy-tailed"

    def as_dict(self) -> dict:
        return {"horizon_s": self.horizon_s, "windows": self.windows, "independent": self.independent,
                "nees_median": self.nees_median, "within_chi2_95": self.within_chi2_95,
                "variance_ratio": self.variance_ratio, "verdict": self.verdict}


@dataclass(frozen=True)
class DeadReckonedWindows:
    """Per window (W,): start time, the dead-reckoned end pose e_u (W, 3) and the true one g (W, 3) in the window's
    start frame (θ wrapped), the model's covariance P (W, 3, 3), and the Jacobians of the end pose
    (W, 3) by a scale on every translation (``by_scale``), a heading change per metre driven (``by_heading_per_m``),
    a scale on every turn (``by_turn_scale``) and a heading change per second (``by_heading_per_s``): what a
    systematic error constant over the window moves."""

    start: np.ndarray
    estimate: np.ndarray
    truth: np.ndarray
    covariance: np.ndarray
    by_scale: np.ndarray
    by_heading_per_m: np.ndarray
    by_turn_scale: np.ndarray
    by_heading_per_s: np.ndarray

    @property
    def error(self) -> np.ndarray:
        e = self.truth - self.estimate
        e[:, 2] = wrap_angle(e[:, 2])
        return e


def _check_rows(name: str, rows) -> np.ndarray:
    rows = np.asarray(rows, float)
    if rows.ndim != 2 or rows.shape[1] != 4 or len(rows) < 2:
        raise ValueError(f"{name} must be rows (t, x, y, θ), at least 2, not an array of shape {rows.shape}")
    if not np.all(np.isfinite(rows)) or np.any(np.diff(rows[:, 0]) < 0):
        raise ValueError(f"{name} must be finite with non-decreasing times")
    return rows


def dead_reckoned_windows(odometry, truth, model: NoiseModel, horizon_s: float, *, step_s: float = STEP_S,
                          stride_s: float = STRIDE_S, min_path_m: float = MIN_PATH_M,
                          min_turn_rad: float = MIN_TURN_RAD, heading_drift: tuple[float, float] | None = None,
                          command=None) -> DeadReckonedWindows:
    """Windows of ``horizon_s`` (see the module's doc) of odometry rows (K, 4) (t, x, y, θ: the dead-reckoned pose in
    the odometry's frame, as ``RangeBearingLog.odometry``) against ground-truth rows (M, 4), under ``model``'s
    calibration (its lag, scales, biases) and random walk.

    ``heading_drift`` (σ rad/m, τ s): the covariance also carries a heading bias per metre of odometry that the
    model's calibration does not know, a first-order Gauss–Markov process (stationary σ, correlation time τ: b ←
    e^(−Δt/τ) b + noise), as a filter would with a bias state: the pose's covariance is propagated jointly with it
    None: the model's own (``OdometryNoise.heading_drift``, none when its σ is 0), as the filter carries it;
    (0, τ) for none whatever the model says (docs/fastslam-history.md, Session 22 (O), Session 23 (D)).

    ``command`` (V, 3) rows (t, v, w): the log's commanded velocity (``RangeBearingLog.velocities``); with it, the
    model's stall term (if σ_s > 0) adds its variance to the steps that hold a dip of the command, as the filter adds
    it to its increments (the module's doc). None: no stall variance."""
    odometry, truth = _check_rows("odometry", odometry), _check_rows("ground truth", truth)
    if heading_drift is None:
        heading_drift = model.odometry.heading_drift
    if not (horizon_s > 0 and step_s > 0 and stride_s > 0):
        raise ValueError("horizon_s, step_s and stride_s must be > 0")
    lag = model.odometry.lag_s
    lo = max(truth[0, 0], odometry[0, 0] + lag)
    hi = min(truth[-1, 0], odometry[-1, 0] + lag)
    n = max(1, int(round(horizon_s / step_s)))
    times = lo + step_s * np.arange(max(int(np.floor((hi - lo) / step_s)) + 1, 0))
    empty = np.zeros((0, 3))
    if len(times) <= n:
        return DeadReckonedWindows(np.zeros(0), empty, empty, np.zeros((0, 3, 3)), empty, empty, empty, empty)
    odo = interpolate_poses(odometry, model.odometry_times(times))
    raw = between(odo[:-1], odo[1:])
    steps = model.calibrate_increments(raw)
    config = replace(FastSLAMConfig(), **{k: v for k, v in model.fastslam_overrides().items() if k.startswith("odom")})
    variance = increment_variance(steps, config, np.diff(times))
    if command is not None and (stalls := command_stall_variance(command, model, times)) is not None:
        variance = variance + stalls     # the stalls after the command's dips, on the steps that hold one
    distance = np.hypot(steps[:, 0], steps[:, 1])
    raw_distance = np.hypot(raw[:, 0], raw[:, 1])
    every = max(1, int(round(stride_s / step_s)))
    starts = np.arange(0, len(steps) - n + 1, every)
    path = np.concatenate([[0.0], np.cumsum(distance)])
    turned = np.concatenate([[0.0], np.cumsum(np.abs(steps[:, 2]))])
    moved = (path[starts + n] - path[starts] >= min_path_m) | (turned[starts + n] - turned[starts] >= min_turn_rad)
    starts = starts[moved]
    w = len(starts)
    pose = np.zeros((w, 3))
    # the pose's covariance with the heading drift's state as a 4th row and column (its variance 0 without a drift)
    drift_var, drift_tau = (float(heading_drift[0]) ** 2, float(heading_drift[1])) if heading_drift else (0.0, 1.0)
    if not (drift_var >= 0 and drift_tau > 0 and np.isfinite(drift_var)):
        raise ValueError(f"heading_drift must be (σ ≥ 0, τ > 0), not {heading_drift}")
    decay = float(np.exp(-step_s / drift_tau))
    cov = np.zeros((w, 4, 4))
    cov[:, 3, 3] = drift_var
    # for the systematic errors' Jacobians: Σ over steps of the step's weight times v_j = (−(y_end − y_j),
    # x_end − x_j, 1) (a heading change at step j swings the rest of the path about the pose after it), collected as
    # Σ a_j (−(y_end), x_end, 1) − Σ a_j (−y_j, x_j, 0) with the end known only at the end
    weight_sums = np.zeros((w, 3))          # Σ d_j, Σ Δθ_j and Σ Δt_j
    moment_sums = np.zeros((w, 3, 2))       # Σ d_j (x_j, y_j), Σ Δθ_j (x_j, y_j), Σ Δt_j (x_j, y_j) after each step
    for j in range(n):
        delta, var = steps[starts + j], variance[starts + j]
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        ja = np.tile(np.eye(4), (w, 1, 1))
        ja[:, 0, 2] = -s * delta[:, 0] - c * delta[:, 1]
        ja[:, 1, 2] = c * delta[:, 0] - s * delta[:, 1]
        ja[:, 2, 3] = raw_distance[starts + j]          # the drift turns the heading by b per metre driven
        ja[:, 3, 3] = decay
        jb = np.zeros((w, 4, 3))
        jb[:, 0, 0], jb[:, 0, 1], jb[:, 1, 0], jb[:, 1, 1], jb[:, 2, 2] = c, -s, s, c, 1.0
        cov = ja @ cov @ np.swapaxes(ja, 1, 2) + (jb * var[:, None, :]) @ np.swapaxes(jb, 1, 2)
        cov[:, 3, 3] += drift_var * (1.0 - decay ** 2)
        pose = compose(pose, delta)
        a = np.column_stack([raw_distance[starts + j], delta[:, 2], np.full(w, step_s)])
        weight_sums += a
        moment_sums += a[:, :, None] * pose[:, None, :2]
    end = pose
    lever = np.column_stack([-end[:, 1], end[:, 0], np.ones(w)])

    def swing(k: int) -> np.ndarray:
        out = weight_sums[:, k:k + 1] * lever
        out[:, 0] += moment_sums[:, k, 1]
        out[:, 1] -= moment_sums[:, k, 0]
        return out

    by_scale = np.column_stack([end[:, :2], np.zeros(w)])
    true_start, true_end = interpolate_poses(truth, times[starts]), interpolate_poses(truth, times[starts + n])
    g = between(true_start, true_end)
    g[:, 2] = end[:, 2] + wrap_angle(g[:, 2] - end[:, 2])
    return DeadReckonedWindows(times[starts], end, g, np.ascontiguousarray(cov[:, :3, :3]), by_scale, swing(0),
                               swing(1), swing(2))


def nees(windows: DeadReckonedWindows, covariance: np.ndarray | None = None) -> np.ndarray:
    """(W,) eᵀP⁻¹e of the windows' end-pose errors under their covariance (or ``covariance`` (W, 3, 3))."""
    p = windows.covariance if covariance is None else covariance
    e = windows.error
    if len(e) == 0:
        return np.zeros(0)
    return np.einsum("wi,wi->w", e, np.linalg.solve(p, e[:, :, None])[:, :, 0])


def summarize(horizon_s: float, values: np.ndarray, span_s: float) -> HorizonConsistency:
    """The figures of one horizon from its windows' NEES (W,) over logs spanning ``span_s`` seconds in all."""
    values = np.asarray(values, float)
    if len(values) == 0:
        return HorizonConsistency(float(horizon_s), 0, 0, float("nan"), float("nan"), float("nan"))
    median = float(np.median(values))
    independent = int(min(max(span_s // horizon_s, 1), len(values)))
    return HorizonConsistency(float(horizon_s), int(len(values)), independent, median,
                              float(np.mean(values < CHI2_3_95)), median / CHI2_3_MEDIAN)


def odometry_consistency(pairs: Sequence[tuple[np.ndarray, np.ndarray]], model: NoiseModel,
                         horizons: Sequence[float] = HORIZONS_S, *, step_s: float = STEP_S,
                         stride_s: float = STRIDE_S, heading_drift: tuple[float, float] | None = None,
                         commands: Sequence[np.ndarray | None] | None = None) -> list[HorizonConsistency]:
    """Per horizon, the NEES of ``model``'s dead reckoning over windows of (odometry rows, ground-truth rows) pairs
    (one per log, pooled; see :func:`dead_reckoned_windows`, also for ``heading_drift``). ``commands``: per pair, the
    log's command rows (t, v, w) or None, for the model's stall term (``dead_reckoned_windows``' ``command``); None:
    none for any pair. Horizons with no window (longer than every log, or the robot never moving) are left out."""
    if commands is None:
        commands = [None] * len(pairs)
    if len(commands) != len(pairs):
        raise ValueError(f"odometry_consistency: {len(commands)} commands for {len(pairs)} (odometry, truth) pairs")
    out = []
    span = sum(max(min(t[-1, 0], o[-1, 0]) - max(t[0, 0], o[0, 0]), 0.0)
               for o, t in ((np.asarray(o, float), np.asarray(t, float)) for o, t in pairs))
    for horizon in horizons:
        values = [nees(dead_reckoned_windows(o, t, model, horizon, step_s=step_s, stride_s=stride_s,
                                             heading_drift=heading_drift, command=c))
                  for (o, t), c in zip(pairs, commands, strict=True)]
        row = summarize(horizon, np.concatenate(values) if values else np.zeros(0), span)
        if row.windows:
            out.append(row)
    return out


def fit_keys(report: Sequence[HorizonConsistency]) -> dict:
    """The report as flat keys of a noise model's informational [fit] table (``odometry_nees_median_300s`` ...)."""
    out = {}
    for row in report:
        if row.windows == 0:
            continue
        label = f"{row.horizon_s:g}s".replace(".", "_")      # a dot in a TOML key would nest a table
        out[f"odometry_nees_windows_{label}"] = row.windows
        out[f"odometry_nees_median_{label}"] = row.nees_median
        out[f"odometry_nees_within_chi2_95_{label}"] = row.within_chi2_95
    return out


# -- fitting the drifting heading bias (σ_b, τ) -----------------------------------------------------------------
DRIFT_TAUS_S = (5.0, 10.0, 20.0, 30.0, 60.0, 100.0, 300.0)          # the correlation times tried
DRIFT_SIGMAS_PER_M = tuple(round(0.01 * k, 2) for k in range(41))   # 0 (none) to 0.4 rad/m by 0.01


@dataclass(frozen=True)
class HeadingDriftFit:
    """The (σ_b rad/m, τ s) whose dead reckoning looks most like χ²₃ at every horizon (``cost``: the sum over
    horizons of log(median / 2.37)² + ((share within the 95 % bound − 0.95) / 0.05)²), and the same cost without a
    drift. σ_b = 0: no drift did better than none."""

    sigma_per_m: float
    tau_s: float
    cost: float
    cost_without: float

    @property
    def heading_drift(self) -> tuple[float, float] | None:
        return (self.sigma_per_m, self.tau_s) if self.sigma_per_m > 0 else None


def _drift_cost(windows_by_horizon, white, unit, sigma: float) -> float:
    total = 0.0
    for ws, p0, p1 in zip(windows_by_horizon, white, unit, strict=True):
        values = np.concatenate([nees(w, a + sigma * sigma * (b - a)) for w, a, b in zip(ws, p0, p1, strict=True)])
        if len(values):
            total += float(np.log(np.median(values) / CHI2_3_MEDIAN) ** 2
                           + ((np.mean(values < CHI2_3_95) - 0.95) / 0.05) ** 2)
    return total


def fit_heading_drift(pairs: Sequence[tuple[np.ndarray, np.ndarray]], model: NoiseModel,
                      horizons: Sequence[float] = HORIZONS_S, *, taus: Sequence[float] = DRIFT_TAUS_S,
                      sigmas: Sequence[float] = DRIFT_SIGMAS_PER_M, step_s: float = STEP_S,
                      stride_s: float = STRIDE_S) -> HeadingDriftFit:
    """(σ_b, τ) of a Gauss–Markov heading bias per metre for ``model``'s odometry on (odometry rows, ground-truth
    rows) pairs, on the grid ``taus`` × ``sigmas`` (see :class:`HeadingDriftFit` for the criterion: session 22 (O)'s,
    which on MRCLAM's first halves chose σ_b 0.16 rad/m, τ 10 s). The model's own drift, if any, is ignored.

    Every σ_b of one τ costs one propagation: the covariance is linear in σ_b² (P = P_white + σ_b² (P₁ − P_white),
    P₁ with σ_b = 1), since the drift's initial variance and its driving noise both scale with it."""
    if not taus or not sigmas or any(not (t > 0 and np.isfinite(t)) for t in taus) \
            or any(not (0 <= s <= 1 and np.isfinite(s)) for s in sigmas):
        raise ValueError("fit_heading_drift needs correlation times > 0 and σ_b in [0, 1] rad/m")
    pairs = [(np.asarray(o, float), np.asarray(t, float)) for o, t in pairs]

    def windows(drift):
        return [[dead_reckoned_windows(o, t, model, h, step_s=step_s, stride_s=stride_s, heading_drift=drift)
                 for o, t in pairs] for h in horizons]

    white_windows = windows((0.0, 1.0))
    white = [[w.covariance for w in ws] for ws in white_windows]
    cost_without = _drift_cost(white_windows, white, white, 0.0)
    best = (cost_without, 0.0, 0.0)
    for tau in taus:
        unit = [[w.covariance for w in ws] for ws in windows((1.0, float(tau)))]
        for sigma in sigmas:
            if sigma > 0:
                best = min(best, (_drift_cost(white_windows, white, unit, float(sigma)), float(sigma), float(tau)))
    cost, sigma, tau = best
    return HeadingDriftFit(sigma, tau, cost, cost_without)
