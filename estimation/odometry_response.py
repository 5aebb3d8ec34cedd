"""A drive that follows its command through a first-order response: the filter, the odometry it gives, its fit.

MRCLAM's odometry is the robots' commanded velocity (t, v, ω) at 50 Hz, integrated. The noise model treats the
drive's answer as a pure delay (``lag_s``); this module models it as a first-order response of time constant T on
both v and ω (the velocity the drive reaches, y, obeys T ẏ = u − y), the command u held between its samples, the
pure delay still ``lag_s`` (applied after, as today: :meth:`estimation.noise_model.NoiseModel.odometry_times`).

:func:`first_order_response` is exact for a held command: over a hold of length Δ from state y₀ under input u the
state ends at u + (y₀ − u) e^(−Δ/T) and its mean is u + (y₀ − u) (T/Δ)(1 − e^(−Δ/T)). :func:`respond` replaces each
sample by that mean over its hold, so :func:`~estimation.datasets.integrate_velocities` of the result has the
response's exact heading and exact path length at every sample (the position within a 20 ms hold follows an arc at
the mean rates: second order in the hold). T = 0 returns the command unchanged.

:func:`fit_response` measures it against the ground truth: over consecutive windows of ``window_s`` the increments
of the odometry (read ``delay_s`` earlier) against the truth's, a least-squares scale each (the turn's, the travel's:
calibrations the noise model fits anyway), the RMS of what is left. On MRCLAM dataset 2 see
``benchmarks/mrclam_drive_response.py``.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from .datasets import RangeBearingLog, integrate_velocities
from .geometry import between, wrap_angle

MAX_RESPONSE_TIME_S = 2.0     # s: a slower drive than this is not a calibration of a 50 Hz command
TRUTH_MAX_TURN_RATE = 4.0     # rad/s between consecutive truth rows: faster is the truth's glitch, not the robot's
TRUTH_MAX_SPEED = 2.0         # m/s, the same for the travel
TRUTH_MIN_STEP_S = 0.01       # s: the truth's row interval (100 Hz), the least time a step between rows is given


def first_order_response(times, command, time_constant_s: float, order: int = 1) -> np.ndarray:
    """The mean (K,) over each hold [t_k, t_{k+1}) of a first-order response of time constant ``time_constant_s`` to
    the ``command`` (K,) held from each of its ``times`` (K,) to the next (the last sample: its own value); the state
    starts at the first command. ``order`` 2: two such stages in cascade (a critically damped second order, each
    stage's held input its own previous stage's mean: exact for the first stage, a hold approximation for the
    second)."""
    t = np.asarray(times, float)
    u = np.asarray(command, float)
    if t.shape != u.shape or t.ndim != 1:
        raise ValueError(f"times and command must be (K,) alike, not {t.shape} and {u.shape}")
    if not (math.isfinite(time_constant_s) and 0.0 <= time_constant_s <= MAX_RESPONSE_TIME_S):
        raise ValueError(f"time constant must lie in [0, {MAX_RESPONSE_TIME_S}] s, not {time_constant_s}")
    if order not in (1, 2):
        raise ValueError(f"order must be 1 or 2, not {order}")
    if time_constant_s == 0.0 or len(u) == 0:
        return u.copy()
    dt = np.diff(t)
    if np.any(dt < 0):
        raise ValueError("times must not decrease")
    x = dt / time_constant_s
    a = np.exp(-x)
    # mean of e^(−s/T) over [0, Δ]: (1 − e^(−Δ/T)) T/Δ, → 1 as Δ → 0 (a zero-length hold keeps the state)
    gain = np.where(x > 1e-12, -np.expm1(-np.maximum(x, 1e-300)) / np.maximum(x, 1e-300), 1.0)
    out = np.empty_like(u)
    y = float(u[0])
    for k, (uk, ak, gk) in enumerate(zip(u[:-1].tolist(), a.tolist(), gain.tolist(), strict=True)):
        out[k] = uk + (y - uk) * gk
        y = uk + (y - uk) * ak
    out[-1] = y
    if order == 2:
        return first_order_response(t, out, time_constant_s)
    return out


def respond(velocities, time_constant_s: float, order: int = 1) -> np.ndarray:
    """Velocity rows (K, 3) (t, v, ω) -> the same times with v and ω replaced by the response's mean over each hold
    (:func:`first_order_response`); T = 0: a copy."""
    rows = np.asarray(velocities, float).reshape(-1, 3)
    return np.column_stack([rows[:, 0], first_order_response(rows[:, 0], rows[:, 1], time_constant_s, order),
                            first_order_response(rows[:, 0], rows[:, 2], time_constant_s, order)])


def with_drive_response(log: RangeBearingLog, time_constant_s: float, order: int = 1) -> RangeBearingLog:
    """``log`` whose odometry is its commanded velocities integrated through the response (the commands themselves,
    ``log.velocities``, unchanged: the stall's dips are the command's). T = 0: ``log`` itself. Needs the log's
    velocities (MRCLAM's reader keeps them)."""
    if time_constant_s == 0.0 and order == 1:
        return log
    return _with_commands_through(log, lambda rows: respond(rows, time_constant_s, order))


def _with_commands_through(log: RangeBearingLog, response) -> RangeBearingLog:
    """``log`` whose odometry is its commanded velocities (``log.velocities``, kept) through ``response`` (velocity
    rows (K, 3) -> the response's rows (M, 3)), integrated."""
    if len(log.velocities) < 2:
        raise ValueError(f"{log.name}: no commanded velocities to filter (the odometry is not a command)")
    rows = response(log.velocities)
    return replace(log, odometry=integrate_velocities(rows[:, 0], rows[:, 1], rows[:, 2]))


@dataclass(frozen=True)
class ResponseShape:
    """A drive's step response: nothing for ``dead_time_s``, then two first-order parts in parallel,
    1 − (1 − w) e^(−s/T_fast) − w e^(−s/T_slow) (s the time after the dead time, w = ``slow_weight``). w = 0: one first
    order (``fast_s``; 0: a pure delay). w in (0, 1]: a fast rise and a slow tail. w > 1 with T_fast = T_slow (w − 1)/w
    is two first orders in cascade (:meth:`cascade`: an S-shaped rise, no jump of the rate at the dead time's end).
    The response is linear in the command, so its mean over a hold is the parts' means weighted (exact for a held
    command, as :func:`first_order_response`)."""

    dead_time_s: float = 0.0
    fast_s: float = 0.0
    slow_s: float = 0.0
    slow_weight: float = 0.0

    def __post_init__(self) -> None:
        for name in ("dead_time_s", "fast_s", "slow_s"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and 0.0 <= value <= MAX_RESPONSE_TIME_S):
                raise ValueError(f"{name} must lie in [0, {MAX_RESPONSE_TIME_S}] s, not {value!r}")
        w = self.slow_weight
        if not (isinstance(w, int | float) and math.isfinite(w) and 0.0 <= w <= MAX_CASCADE_WEIGHT):
            raise ValueError(f"slow_weight must lie in [0, {MAX_CASCADE_WEIGHT:g}], not {w!r}")
        if w != 0.0 and self.slow_s == 0.0:
            raise ValueError("a slow part (slow_weight != 0) needs slow_s > 0")

    @classmethod
    def cascade(cls, dead_time_s: float, first_s: float, second_s: float) -> ResponseShape:
        """Two first orders of time constants ``first_s`` != ``second_s`` in cascade after a dead time: by partial
        fractions the step response is 1 − (T_s e^(−s/T_s) − T_f e^(−s/T_f)) / (T_s − T_f) (T_s the larger), i.e.
        weight T_s/(T_s − T_f) > 1 on the slow part and 1 minus that (negative) on the fast one."""
        slow, fast = max(first_s, second_s), min(first_s, second_s)
        if not slow > fast:
            raise ValueError(f"a cascade needs two different time constants, not {first_s} and {second_s}")
        return cls(dead_time_s, fast, slow, slow / (slow - fast))

    @property
    def mean_delay_s(self) -> float:
        """The response's mean delay ∫ (1 − step) ds: what a long window's increment lags the command by."""
        return self.dead_time_s + (1.0 - self.slow_weight) * self.fast_s + self.slow_weight * self.slow_s

    def step(self, lags) -> np.ndarray:
        """The step response (N,) at ``lags`` (N,) s after the command's step."""
        s = np.clip(np.asarray(lags, float) - self.dead_time_s, 0.0, None)

        def part(T):
            return np.exp(-s / T) if T > 0 else np.zeros_like(s)

        out = 1.0 - (1.0 - self.slow_weight) * part(self.fast_s) - self.slow_weight * part(self.slow_s)
        return np.where(s > 0, out, 0.0)

    def means(self, times, command) -> np.ndarray:
        """The response's mean (K,) over each hold of the command (before the dead time: the holds of ``times``)."""
        y = first_order_response(times, command, self.fast_s)
        if self.slow_weight == 0.0:
            return y
        return (1.0 - self.slow_weight) * y + self.slow_weight * first_order_response(times, command, self.slow_s)


MAX_CASCADE_WEIGHT = 10.0     # a cascade of T and 0.9 T has weight 10: closer to critically damped is not resolved


def shaped_velocities(velocities, turn: ResponseShape, travel: ResponseShape) -> np.ndarray:
    """Velocity rows (K, 3) (t, v, ω) -> rows (M, 3) of the response: v through ``travel``, ω through ``turn``, each
    delayed by its own dead time (the union of the two shifted grids, each channel held; before its first shifted
    sample a channel holds its first command)."""
    rows = np.asarray(velocities, float).reshape(-1, 3)
    t = rows[:, 0]
    v = travel.means(t, rows[:, 1])
    w = turn.means(t, rows[:, 2])
    if travel.dead_time_s == 0.0 and turn.dead_time_s == 0.0:
        return np.column_stack([t, v, w])
    tv, tw = t + travel.dead_time_s, t + turn.dead_time_s
    grid = np.concatenate([t[:1], np.sort(np.concatenate([tv, tw]), kind="stable")])

    def held(shifted, values):
        return values[np.clip(np.searchsorted(shifted, grid, side="right") - 1, 0, len(values) - 1)]

    return np.column_stack([grid, held(tv, v), held(tw, w)])


def with_drive_shape(log: RangeBearingLog, turn: ResponseShape, travel: ResponseShape | None = None
                     ) -> RangeBearingLog:
    """``log`` whose odometry is its commands integrated through the shaped responses (ω through ``turn``, v through
    ``travel``, by default the same); the commands (``log.velocities``) kept, as :func:`with_drive_response`. A pure
    zero shape on both (no delay, no lag): ``log`` itself."""
    travel = turn if travel is None else travel
    if turn == ResponseShape() and travel == ResponseShape():
        return log
    return _with_commands_through(log, lambda rows: shaped_velocities(rows, turn, travel))


@dataclass(frozen=True)
class ResponseFit:
    """Per log and in all, on windows of ``window_s``: the turn's least-squares scale and the RMS heading residual
    (rad), the travel's scale and the RMS forward residual (m), the windows counted, and of them those the turn and the
    travel were scored on."""

    window_s: float
    turn_scale: np.ndarray        # (L,)
    heading_rms: np.ndarray       # (L,)
    travel_scale: np.ndarray      # (L,)
    forward_rms: np.ndarray       # (L,)
    windows: np.ndarray           # (L,)
    turn_windows: np.ndarray      # (L,)
    travel_windows: np.ndarray    # (L,)

    @property
    def pooled_heading_rms(self) -> float:
        return float(np.sqrt(np.sum(self.heading_rms ** 2 * self.turn_windows) / np.sum(self.turn_windows)))

    @property
    def pooled_forward_rms(self) -> float:
        return float(np.sqrt(np.sum(self.forward_rms ** 2 * self.travel_windows) / np.sum(self.travel_windows)))


def window_increments(log: RangeBearingLog, delay_s: float, window_s: float, step_s: float = 0.05):
    """Odometry and true increments over consecutive windows of ``window_s`` on a grid of ``step_s`` inside the truth
    (the odometry read ``delay_s`` earlier): odometry (W, 3) and truth (W, 3) (x, y in the window's start frame, the
    turn unwrapped near the odometry's). The grid does not depend on ``delay_s`` (≤ 1 s), so every delay and response
    is scored on the same windows (:func:`window_grid`)."""
    grid = window_grid(log, window_s, step_s)
    keep = ~truth_glitched(log, grid)
    return _window_increments(log, delay_s, grid, keep)


def window_grid(log: RangeBearingLog, window_s: float, step_s: float = 0.05) -> np.ndarray:
    """The windows' ends (W + 1,): consecutive windows of ``window_s`` on a grid of ``step_s``, 1 s inside both the
    truth and the odometry (so a read up to 1 s earlier stays inside)."""
    lo = max(log.ground_truth[0, 0], log.odometry[0, 0]) + 1.0
    hi = min(log.ground_truth[-1, 0], log.odometry[-1, 0]) - 1.0
    n = max(1, int(round(window_s / step_s)))
    grid = np.arange(lo, hi, step_s)
    return grid[: (len(grid) - 1) // n * n + 1][::n]


def commanded_windows(log: RangeBearingLog, grid: np.ndarray, before_s: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """(W,) twice: whether the commanded turn rate, and the commanded speed, is not 0 somewhere in each window
    [grid_k − ``before_s``, grid_{k+1}] (the command the window's motion can answer). Without commands: all True."""
    rows = log.velocities
    if len(rows) < 2:
        every = np.ones(len(grid) - 1, bool)
        return every, every.copy()
    out = []
    for column in (2, 1):
        moving = np.concatenate([[0], np.cumsum(np.abs(rows[:, column]) > 1e-9)])
        out.append(moving[np.searchsorted(rows[:, 0], grid[1:], side="right")]
                   - moving[np.searchsorted(rows[:, 0], grid[:-1] - before_s)] > 0)
    return out[0], out[1]


def _window_increments(log: RangeBearingLog, delay_s: float, grid: np.ndarray, keep: np.ndarray):
    odo = log.odometry_pose(grid - delay_s)
    # the odometry's heading unwrapped along its rows, sampled at the grid (the turn of a window, not wrapped)
    rows = log.odometry
    theta = np.interp(grid - delay_s, rows[:, 0], np.unwrap(rows[:, 3]))
    u = between(odo[:-1], odo[1:])
    u[:, 2] = np.diff(theta)
    g = between(log.true_pose(grid[:-1]), log.true_pose(grid[1:]))
    g[:, 2] = u[:, 2] + wrap_angle(g[:, 2] - u[:, 2])
    return u[keep], g[keep]


def fast_truth_steps(truth: np.ndarray) -> np.ndarray:
    """(len(truth) − 1,) whether each step between consecutive truth rows (time, x, y, θ) is faster than
    TRUTH_MAX_TURN_RATE or TRUTH_MAX_SPEED over max(its time, TRUTH_MIN_STEP_S)."""
    dt = np.maximum(np.diff(truth[:, 0]), TRUTH_MIN_STEP_S)
    return ((np.abs(wrap_angle(np.diff(truth[:, 3]))) > TRUTH_MAX_TURN_RATE * dt)
            | (np.hypot(np.diff(truth[:, 1]), np.diff(truth[:, 2])) > TRUTH_MAX_SPEED * dt))


def truth_glitched(log: RangeBearingLog, grid: np.ndarray) -> np.ndarray:
    """(len(grid) − 1,) whether each window [grid_k, grid_{k+1}] overlaps a step between consecutive truth rows
    faster than TRUTH_MAX_TURN_RATE or TRUTH_MAX_SPEED over max(its time, TRUTH_MIN_STEP_S) (MRCLAM's Vicon jumps by
    up to 2.5 rad for a row now and then: one such window is worth the RMS of all the others; its rows at 100 Hz
    share stamps where the stamps are coarse, hence the floor)."""
    truth = log.ground_truth
    bad = fast_truth_steps(truth)
    if not bad.any():
        return np.zeros(len(grid) - 1, bool)
    starts, ends = truth[:-1, 0][bad], truth[1:, 0][bad]
    # a window [a, b] overlaps a bad step [s, e] if s <= b and e >= a
    first = np.searchsorted(ends, grid[:-1], side="left")      # the first bad step ending after a
    return (first < len(starts)) & (starts[np.minimum(first, len(starts) - 1)] <= grid[1:])


def fit_response(logs: Sequence[RangeBearingLog], delay_s: float, window_s: float,
                 min_turn_rad: float = 0.0, min_travel_m: float = 0.0) -> ResponseFit:
    """The odometry of each log (already through its response: :func:`with_drive_response`) read ``delay_s`` early,
    against its truth on windows of ``window_s``: the least-squares turn scale and heading RMS over the windows in
    which (or in the second before which) the log's command turns (:func:`commanded_windows`; with ``min_turn_rad``
    > 0, also turning more than that by the odometry), the travel scale and forward RMS over those in which it moves
    (with ``min_travel_m`` > 0: and moving more than that forward by the odometry).

    The windows are chosen by the command, not by each model's odometry (session 45 (B)): until then they were the
    windows whose odometry turn was not 0, so a pure delay was scored on the 4,628 of robot 1's 7,572 windows of
    0.25 s where its odometry turns, and a first-order response (whose odometry is almost never exactly still) on
    7,288: the still windows' small residuals made the response look 12 % better (19.28 against 16.94 mrad) where on
    all windows alike it was not (16.62 against 16.63; pure delay 0.175 s, response T 0.2 s read 0.075 s early)."""
    out = {k: [] for k in ("ks", "hr", "kv", "fr", "n", "nt", "nv")}
    for log in logs:
        grid = window_grid(log, window_s)
        keep = ~truth_glitched(log, grid)
        u, g = _window_increments(log, delay_s, grid, keep)
        turning, moving = (m[keep] for m in commanded_windows(log, grid))
        turn = turning & ((np.abs(u[:, 2]) > min_turn_rad) if min_turn_rad > 0 else True)
        k = float(np.dot(u[turn, 2], g[turn, 2]) / max(np.dot(u[turn, 2], u[turn, 2]), 1e-300))
        move = moving & ((np.abs(u[:, 0]) > min_travel_m) if min_travel_m > 0 else True)
        kv = float(np.dot(u[move, 0], g[move, 0]) / max(np.dot(u[move, 0], u[move, 0]), 1e-300))
        out["ks"].append(k)
        out["hr"].append(float(np.sqrt(np.mean((g[turn, 2] - k * u[turn, 2]) ** 2))) if turn.any() else math.nan)
        out["kv"].append(kv)
        out["fr"].append(float(np.sqrt(np.mean((g[move, 0] - kv * u[move, 0]) ** 2))) if move.any() else math.nan)
        out["n"].append(len(u))
        out["nt"].append(int(turn.sum()))
        out["nv"].append(int(move.sum()))
    return ResponseFit(window_s, *(np.asarray(out[k], float) for k in ("ks", "hr", "kv", "fr", "n", "nt", "nv")))
