"""A drive that stalls after a one-sample dip of its commanded velocity: the dips, the stall's fit, its variance.

MRCLAM's odometry is the robots' commanded velocity at 50 Hz, integrated. About once every 12 s of motion one sample
of the command is zero amid motion (dataset 2: 122-163 per robot over 1,900 s, every one at x.90 s of the log's
clock, on several robots at once: the commanding process's hiccup, written in the files, not the reader's). The
robot answers it: it stops for a while, ~0.2 s later (its lag), while the integrated command goes on. How long is
random: over 1 s around each dip, the turn and travel the robot missed, in seconds of its rate, have a mean near
zero and a long tail (quartiles about -0.05 / +0.15 s, a tenth beyond 0.3 s; docs/fastslam-history.md "Session 41
(A)"). So the model is a random stall of standard deviation σ_s (s) after each dip, no deterministic correction: the
increment that holds a dip gets the variance (ω σ_s)² on its heading and (v σ_s)² on x and y, ω and v the command
before the dip (calibrated by the model's scales); :func:`stall_variance`.

σ_s is fitted against the ground truth (:func:`fit_stall`, ``estimate_noise(command_stall=True)``): around each dip
the error e of a window of STALL_WINDOW_S against its two neighbours, D = e − (e₋ + e₊)/2, in seconds of the window's
rate; the same for windows without a dip near; σ_s² = mean D² of the dips − mean D² of the others (the neighbours
take out what a window shares with its surroundings: the scales, an arc's forward deficit). Its mean is reported, not
applied: it is small beside its spread.

The dips are found in the command (``RangeBearingLog.velocities``), not in the integrated odometry: where MRCLAM's
stamps are coarser than its rows (from t = 1000 s) the integration runs rows sharing a stamp over no time, and the
dips (the third row of five) vanish from it.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from .datasets import RangeBearingLog
from .geometry import between, wrap_angle

MAX_STALL_SIGMA_S = 1.0      # s: a drive whose every hiccup costs it seconds is not described by a variance
STALL_WINDOW_S = 1.0         # the windows the stall is measured on (a stall lasts up to ~0.5 s)
STALL_LEAD_S = 0.1           # each window starts this much before its dip (the dip's own samples inside it)
STALL_MIN_TURN_RAD = 0.1     # a window measures the heading's stall if it turns this much (rad), as do its neighbours
STALL_MIN_TRAVEL_M = 0.03    # ... and the travel's if it drives this far (m)
STALL_MIN_DIPS = 10          # fewer measured dips than this: no fit


@dataclass(frozen=True)
class CommandDips:
    """The isolated zero samples of a commanded velocity: their times (D,) s (as stamped) and the command before each,
    speed (D,) m/s and turn rate (D,) rad/s."""

    times: np.ndarray
    speeds: np.ndarray
    turn_rates: np.ndarray

    def __len__(self) -> int:
        return len(self.times)


def command_dips(velocities) -> CommandDips:
    """The dips of velocity samples (V, 3) rows (t, v, w): a sample with v = w = 0 between two that move. The command
    before it is the sample two before (one before is often cut short: MRCLAM's dips read 0.5, 0, 0.9 of the command),
    or one before at the log's start."""
    rows = np.asarray(velocities, float).reshape(-1, 3)
    if len(rows) < 3:
        return CommandDips(np.zeros(0), np.zeros(0), np.zeros(0))
    moving = (rows[:, 1] != 0.0) | (rows[:, 2] != 0.0)
    dips = np.flatnonzero(~moving[1:-1] & moving[:-2] & moving[2:]) + 1
    before = np.where(dips >= 2, dips - 2, dips - 1)
    return CommandDips(rows[dips, 0].copy(), rows[before, 1].copy(), rows[before, 2].copy())


def stall_variance(dips: CommandDips, times, sigma_s: float, scales=(1.0, 1.0)) -> np.ndarray:
    """Variances (T, 3) of (dx, dy, dθ) to add to the increments between consecutive odometry ``times`` (T + 1,) s:
    for each dip in [times[k], times[k+1]), (k_t v σ_s)² on x and y and (k_r ω σ_s)² on θ (v, ω its command, ``scales``
    (k_t, k_r) the model's translation and rotation scales). Zero where no dip falls, and everywhere for σ_s = 0."""
    times = np.asarray(times, float).reshape(-1)
    out = np.zeros((max(len(times) - 1, 0), 3))
    if sigma_s == 0.0 or len(dips) == 0 or len(out) == 0:
        return out
    k = np.searchsorted(times, dips.times, side="right") - 1
    inside = (k >= 0) & (k < len(out)) & (dips.times < times[-1])
    xy = (scales[0] * dips.speeds[inside] * sigma_s) ** 2
    theta = (scales[1] * dips.turn_rates[inside] * sigma_s) ** 2
    np.add.at(out, (k[inside], 0), xy)
    np.add.at(out, (k[inside], 1), xy)
    np.add.at(out, (k[inside], 2), theta)
    return out


def command_stall_variance(velocities, noise, frame_times) -> np.ndarray | None:
    """The variances (T, 3) the stall term of ``noise`` (an :class:`estimation.noise_model.NoiseModel`, duck-typed:
    that module imports this one) adds to a log's calibrated increments between consecutive log ``frame_times``
    (T + 1,), ``velocities`` (V, 3) the log's command rows (t, v, w) (``RangeBearingLog.velocities``):
    :func:`stall_variance` of the command's dips, the frames moved by the model's odometry lag, with the model's σ_s
    and scales; None when the model has no stall term. The one place the model's term meets a command: the data set's
    filter adds it to its predict (``estimation.dataset_slam``), every smoother of a log to its odometry factors'
    random-walk variances (:func:`estimation.noise_model.increment_variances`), the dead-reckoning windows to their
    steps (:func:`estimation.odometry_consistency.dead_reckoned_windows`, which noise_estimation imports: why this lives
    here and not there)."""
    o = noise.odometry
    if o.stall_sigma_s == 0.0:
        return None
    return stall_variance(command_dips(velocities), noise.odometry_times(frame_times), o.stall_sigma_s,
                          (o.translation_scale, o.rotation_scale))


def fit_stall(logs: Sequence[RangeBearingLog], lag_s: float,
              calibrate: Callable[[np.ndarray], np.ndarray]) -> tuple[float, dict]:
    """σ_s (s) of the stall after a dip, and the fit's figures for [fit] (see the module docstring), from logs with
    ground truth and their commands; the odometry read ``lag_s`` early and its increments (N, 3) calibrated by
    ``calibrate`` (the model's scales, heading bias, forward deficit). 0 and a note when fewer than STALL_MIN_DIPS
    dips can be measured (or a log has no velocity samples)."""
    dip_d: list[list[np.ndarray]] = [[], []]     # per channel (heading, travel): D of the dips' windows, s
    ref_d: list[list[np.ndarray]] = [[], []]
    found = 0
    for log in logs:
        dips = command_dips(log.velocities)
        found += len(dips)
        if not len(dips) or not log.has_ground_truth:
            continue
        lo = max(log.ground_truth[0, 0] - lag_s, log.odometry[0, 0]) + STALL_WINDOW_S + STALL_LEAD_S
        hi = min(log.ground_truth[-1, 0] - lag_s, log.odometry[-1, 0]) - 2 * STALL_WINDOW_S
        grid = np.arange(lo, hi, STALL_WINDOW_S)
        anchors = dips.times[(dips.times >= lo) & (dips.times < hi)]
        # a dip's windows must hold no other dip; a reference's none, nor a stall spilling in (half a window more)
        span = (-STALL_WINDOW_S - STALL_LEAD_S, 2 * STALL_WINDOW_S - STALL_LEAD_S)
        own = np.array([np.sum((dips.times >= a + span[0]) & (dips.times < a + span[1])) == 1 for a in anchors], bool)
        near = np.searchsorted(dips.times, grid + span[1] + 0.5 * STALL_WINDOW_S) \
            - np.searchsorted(dips.times, grid + span[0] - 0.5 * STALL_WINDOW_S)
        for group, points in ((dip_d, anchors[own]), (ref_d, grid[near == 0])):
            for channel, d in enumerate(_neighbour_differences(log, points, lag_s, calibrate)):
                group[channel].append(d)
    dip_c = [np.concatenate(c) if c else np.zeros(0) for c in dip_d]
    ref_c = [np.concatenate(c) if c else np.zeros(0) for c in ref_d]
    measured = [len(c) for c in dip_c]
    fit: dict = {"stall_dips": int(found), "stall_dips_measured_heading": measured[0],
                 "stall_dips_measured_travel": measured[1]}
    if sum(measured) < STALL_MIN_DIPS or any(len(r) < STALL_MIN_DIPS for r, n in zip(ref_c, measured, strict=True)
                                             if n):
        fit["stall_note"] = (f"not fitted: {sum(measured)} dips of the command measurable against the truth (at least "
                             f"{STALL_MIN_DIPS} are needed)")
        return 0.0, fit
    excess, weight, variance = 0.0, 0, 0.0
    for name, d, r in zip(("heading", "travel"), dip_c, ref_c, strict=True):
        if not len(d):
            continue
        e = float(np.mean(d ** 2) - np.mean(r ** 2))
        fit[f"stall_sigma_{name}_s"] = math.sqrt(max(e, 0.0))
        fit[f"stall_mean_{name}_s"] = float(np.mean(d) - np.mean(r))
        excess += len(d) * e
        weight += len(d)
        variance += len(d) ** 2 * (np.var(d ** 2) / len(d) + np.var(r ** 2) / len(r))
    sigma2 = excess / weight
    sigma = float(min(math.sqrt(max(sigma2, 0.0)), MAX_STALL_SIGMA_S))
    fit["stall_variance_s2"] = float(sigma2)
    fit["stall_variance_standard_error_s2"] = float(math.sqrt(variance) / weight)
    return sigma, fit


def _neighbour_differences(log: RangeBearingLog, anchors: np.ndarray, lag_s: float, calibrate):
    """(heading, travel) D's (each (n,), s) at ``anchors`` (A,) odometry times: the error of the window
    [a − STALL_LEAD_S, a − STALL_LEAD_S + STALL_WINDOW_S) (the truth ``lag_s`` later), less its two neighbours' mean,
    over the window's own odometry rate and sign-flipped (positive: motion the robot did not make); only where the
    window and both neighbours turn (drive) enough the same way."""
    if not len(anchors):
        return np.zeros(0), np.zeros(0)
    starts = anchors[:, None] - STALL_LEAD_S + STALL_WINDOW_S * np.array([-1.0, 0.0, 1.0])[None, :]
    t0, t1 = starts.ravel(), starts.ravel() + STALL_WINDOW_S
    u = calibrate(between(log.odometry_pose(t0), log.odometry_pose(t1))).reshape(-1, 3, 3)
    g = between(log.true_pose(t0 + lag_s), log.true_pose(t1 + lag_s)).reshape(-1, 3, 3)
    out = []
    for column, threshold in ((2, STALL_MIN_TURN_RAD), (0, STALL_MIN_TRAVEL_M)):
        rate = u[:, :, column]
        error = wrap_angle(g[:, :, 2] - rate) if column == 2 else g[:, :, 0] - rate
        ok = np.all(np.abs(rate) >= threshold, axis=1) & np.all(np.sign(rate) == np.sign(rate[:, 1:2]), axis=1)
        d = -(error[:, 1] - 0.5 * (error[:, 0] + error[:, 2])) / np.where(ok, rate[:, 1], 1.0) * STALL_WINDOW_S
        ok &= np.abs(d) < STALL_WINDOW_S      # beyond the window, a glitch of the truth, not a stall it can hold
        out.append(d[ok])
    return out[0], out[1]
