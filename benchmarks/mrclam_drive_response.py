"""MRCLAM's drive response against Vicon: a pure delay, a first-order response (delay τ + time constant T) or a
second order, on the turn (ω) and on the travel (v).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.mrclam_drive_response [--robots 1 2 ...] [--json]

Sections (truth used throughout; the logs read with truth_heading="travel"):

1. grid: the commanded velocities through the response (estimation.odometry_response, T on a grid, order 1 and 2),
   integrated, read τ earlier; over consecutive windows of 0.25 s (the frame interval) and 1 s the RMS of the heading
   increments' residual after a least-squares turn scale, and of the forward increments' after a travel scale. Per
   robot the best (T, τ) of each criterion; pooled (the windows' squares summed over robots, each its own scales) the
   best; the per-robot optima's mean and spread.
2. scale: the least-squares turn scale on windows of 0.2 / 1 / 5 s at the pure delay's best and at the first order's
   (the short-window attenuation that kept session 43's truth-free heading calibration out).
3. impulse: the turn's empirical step response by regularised deconvolution (Vicon's turn rate on a 20 ms grid
   regressed on the command's 40 past samples, a second-difference ridge), beside the fitted models' step responses.
4. shape (``--section shape``, session 45 (B); ``--fit-window``): the shape of the response, on held-out halves of
   each log (windows starting before / after 950 s). Four families of ``estimation.odometry_response.ResponseShape``
   (each with a dead time on a 5 ms grid): a pure delay, one first order, a fast and a slow part in parallel (a jump
   or a fast rise, then a tail), two first orders in cascade (an S-shaped rise). Each fitted on one half, pooled over
   the robots (the windows' heading residual after each robot's least-squares turn scale, at ``--fit-window`` s), and
   scored on the other half with that half's scale, at 0.25 / 1 / 5 s, per robot. Then the travel (v), with the
   turn's fitted fast + slow shape fixed, the same way on the forward residual. The response is linear in the command
   and so are the windows' turns (and, the heading given, their forward travel): each window's increment under any
   mixture of parts is the mixture of the parts' increments, so the fit sums Gram matrices of the parts per robot,
   delay and half once and scores every mixture from them.

Sections 1-3: ``--section grid`` (2 min); all four: ``--section all``.
"""
from __future__ import annotations

import argparse
import itertools
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from estimation.datasets import read_mrclam  # noqa: E402
from estimation.geometry import between, wrap_angle  # noqa: E402
from estimation.odometry_response import (  # noqa: E402
    ResponseShape,
    first_order_response,
    fit_response,
    truth_glitched,
    with_drive_response,
)
from runtime.commands.options import positive_float, positive_int  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "mrclam" / "MRCLAM_Dataset2"
TIME_CONSTANTS = np.round(np.arange(0.0, 0.401, 0.025), 3)
DELAYS = np.round(np.arange(0.0, 0.301, 0.025), 3)
WINDOWS = (0.25, 1.0)
CRITERIA = [(f"heading_{w:g}s", w, "heading_rms") for w in WINDOWS] + [(f"forward_{w:g}s", w, "forward_rms")
                                                                        for w in WINDOWS]
IMPULSE_STEP_S, IMPULSE_TAPS, IMPULSE_RIDGE = 0.02, 40, 30.0


def grid(logs: dict, order: int) -> dict:
    """criterion -> (R, len(T), len(τ)) RMS per robot, and the windows (R,) per criterion."""
    out = {name: np.zeros((len(logs), len(TIME_CONSTANTS), len(DELAYS))) for name, _, _ in CRITERIA}
    windows = {}
    for i, T in enumerate(TIME_CONSTANTS):
        filtered = [with_drive_response(log, float(T), order) for log in logs.values()]
        for j, d in enumerate(DELAYS):
            for w in WINDOWS:
                f = fit_response(filtered, float(d), w)
                for name, ww, attr in CRITERIA:
                    if ww == w:
                        out[name][:, i, j] = getattr(f, attr)
                        windows[name] = f.windows
    return {"rms": out, "windows": windows}


def best(surface: np.ndarray) -> tuple[float, float, float]:
    i, j = np.unravel_index(np.argmin(surface), surface.shape)
    return float(TIME_CONSTANTS[i]), float(DELAYS[j]), float(surface[i, j])


def summarise(result: dict, robots: list[int]) -> dict:
    summary = {}
    for name, _, _ in CRITERIA:
        rms, n = result["rms"][name], result["windows"][name]
        per = [best(rms[r]) for r in range(len(robots))]
        pure = [(float(DELAYS[np.argmin(rms[r, 0])]), float(np.min(rms[r, 0]))) for r in range(len(robots))]
        pooled = np.sqrt(np.tensordot(n, rms ** 2, axes=1) / n.sum())
        pooled_best = best(pooled)
        pooled_pure = (float(DELAYS[np.argmin(pooled[0])]), float(np.min(pooled[0])))
        i, j = (list(TIME_CONSTANTS).index(pooled_best[0]), list(DELAYS).index(pooled_best[1]))
        ts, ds = np.array([p[0] for p in per]), np.array([p[1] for p in per])
        summary[name] = {
            "per_robot": [{"robot": r, "T_s": p[0], "delay_s": p[1], "rms": p[2], "pure_delay_s": q[0],
                           "pure_rms": q[1], "rms_at_pooled": float(rms[k, i, j])}
                          for k, (r, p, q) in enumerate(zip(robots, per, pure, strict=True))],
            "pooled": {"T_s": pooled_best[0], "delay_s": pooled_best[1], "rms": pooled_best[2],
                       "pure_delay_s": pooled_pure[0], "pure_rms": pooled_pure[1]},
            "T_mean_s": float(ts.mean()), "T_sd_s": float(ts.std(ddof=1)) if len(ts) > 1 else 0.0,
            "delay_mean_s": float(ds.mean()), "delay_sd_s": float(ds.std(ddof=1)) if len(ds) > 1 else 0.0,
        }
    return summary


def scales(logs: dict, T: float, delay: float) -> list[dict]:
    rows = []
    for r, log in logs.items():
        filtered = with_drive_response(log, T)
        fits = [fit_response([filtered], delay, w) for w in (0.2, 1.0, 5.0)]
        rows.append({"robot": r, "T_s": T, "delay_s": delay, "turn_scale": [float(f.turn_scale[0]) for f in fits],
                     "heading_rms": [float(f.heading_rms[0]) for f in fits],
                     "travel_scale": [float(f.travel_scale[0]) for f in fits]})
    return rows


def impulse(log) -> np.ndarray:
    """The turn's step response (IMPULSE_TAPS,) at lags 0, 20 ms, …: cumulative sum of the deconvolved impulse."""
    v = log.velocities
    lo, hi = max(v[0, 0], log.ground_truth[0, 0]) + 2.0, min(v[-1, 0], log.ground_truth[-1, 0]) - 2.0
    t = np.arange(lo, hi, IMPULSE_STEP_S)
    theta = np.unwrap(log.true_pose(t)[:, 2])
    y = np.diff(theta) / IMPULSE_STEP_S
    # the command held: the last sample at or before each time
    idx = np.clip(np.searchsorted(v[:, 0], t, side="right") - 1, 0, len(v) - 1)
    w = v[idx, 2]
    rows = np.arange(IMPULSE_TAPS, len(t) - 1)
    x = np.column_stack([w[rows - j] for j in range(IMPULSE_TAPS)])
    d = np.diff(np.eye(IMPULSE_TAPS), 2, axis=0)
    h = np.linalg.solve(x.T @ x + IMPULSE_RIDGE * len(rows) / 1000 * d.T @ d, x.T @ y[rows])
    return np.cumsum(h)


def model_step(T: float, delay: float, order: int = 1) -> np.ndarray:
    lags = np.arange(IMPULSE_TAPS) * IMPULSE_STEP_S + IMPULSE_STEP_S   # the response at the end of each tap's step
    s = np.clip(lags - delay, 0.0, None)
    if T == 0:
        return (s > 0).astype(float)
    return 1 - np.exp(-s / T) * (1 + s / T) if order == 2 else 1 - np.exp(-s / T)


SHAPE_TIME_CONSTANTS = (0.0, 0.02, 0.03, 0.04, 0.05, 0.06, 0.08, 0.1, 0.12, 0.15, 0.2, 0.25, 0.3, 0.4, 0.5, 0.6, 0.8,
                        1.0, 1.3, 1.6, 2.0)
SHAPE_TURN_DELAYS = np.round(np.arange(0.0, 0.3001, 0.005), 3)
SHAPE_TRAVEL_DELAYS = np.round(np.arange(0.0, 0.4001, 0.01), 3)
SHAPE_WEIGHTS = np.round(np.arange(0.05, 0.951, 0.05), 3)
SHAPE_WINDOWS = (0.25, 1.0, 5.0)
SHAPE_FAMILIES = ("delay", "first order", "fast + slow", "cascade")
HALF_S = 950.0       # the halves: windows starting before / after (MRCLAM dataset 2's logs run 0-1900 s)


class ShapeLog:
    """One log's windows (per length: start, end, true increment, half, and the half for the turn and for the travel,
    2 where that channel's command rests: not scored) and its commands through every part of
    SHAPE_TIME_CONSTANTS (the holds' exact means; the time constant 0 is the command itself)."""

    def __init__(self, log):
        rows = log.velocities
        self.t, self.dt = rows[:, 0], np.diff(rows[:, 0])
        self.windows = {}
        for w in SHAPE_WINDOWS:
            lo = max(log.ground_truth[0, 0], self.t[0]) + 1.0
            hi = min(log.ground_truth[-1, 0], self.t[-1]) - 1.0
            n = max(1, int(round(w / 0.05)))
            grid = np.arange(lo, hi, 0.05)
            grid = grid[: (len(grid) - 1) // n * n + 1][::n]
            keep = ~truth_glitched(log, grid)
            a, b = grid[:-1][keep], grid[1:][keep]
            half = (a >= HALF_S).astype(int)
            # the windows each channel is scored on: those in which (or in the second before which) its command is
            # not 0, for every model alike (where the command rests, every model predicts nothing and the residual
            # is the truth's jitter: those windows only dilute the differences; a model's own u ≠ 0 would select
            # different windows for different models)
            active = [self._active(rows[:, c], a - 1.0, b) for c in (2, 1)]
            self.windows[w] = (a, b, between(log.true_pose(a), log.true_pose(b)), half,
                               np.where(active[0], half, 2), np.where(active[1], half, 2))
        self.turn_parts = np.array([first_order_response(self.t, rows[:, 2], T) for T in SHAPE_TIME_CONSTANTS])
        self.travel_parts = np.array([first_order_response(self.t, rows[:, 1], T) for T in SHAPE_TIME_CONSTANTS])
        self.turn_integrals = np.column_stack([np.zeros(len(SHAPE_TIME_CONSTANTS)),
                                               np.cumsum(self.turn_parts[:, :-1] * self.dt, axis=1)])

    def _active(self, command: np.ndarray, start: np.ndarray, end: np.ndarray) -> np.ndarray:
        moving = np.concatenate([[0], np.cumsum(np.abs(command) > 1e-9)])
        return (moving[np.searchsorted(self.t, end, side="right")] - moving[np.searchsorted(self.t, start)]) > 0

    def turns(self, w: float, delay: float) -> np.ndarray:
        """(K, W) each part's turn over the windows, the command read ``delay`` earlier."""
        a, b = self.windows[w][:2]
        return np.array([np.interp(b - delay, self.t, c) - np.interp(a - delay, self.t, c)
                         for c in self.turn_integrals])

    def forwards(self, lengths, delay: float, heading: np.ndarray, heading_delay: float) -> dict:
        """{w: (K, W)} for each window length w of ``lengths``: each travel part's forward travel over the windows
        (read ``delay`` earlier), along ``heading`` (the turn's integral at the rows, read ``heading_delay`` earlier),
        in each window's start frame. Each part's path is integrated once for all the lengths (the windows only read
        it: the same arithmetic as integrating it per length; the shape fit 2.8x sooner)."""
        theta = np.interp(self.t + delay - heading_delay, self.t, heading)[:-1]
        cos, sin = np.cos(theta), np.sin(theta)
        shifted = self.t + delay
        paths = [(np.concatenate([[0.0], np.cumsum(part[:-1] * cos * self.dt)]),
                  np.concatenate([[0.0], np.cumsum(part[:-1] * sin * self.dt)])) for part in self.travel_parts]
        out = {}
        for w in lengths:
            a, b = self.windows[w][:2]
            start = np.interp(a - heading_delay, self.t, heading)
            rows = []
            for x, y in paths:
                dx = np.interp(b, shifted, x) - np.interp(a, shifted, x)
                dy = np.interp(b, shifted, y) - np.interp(a, shifted, y)
                rows.append(dx * np.cos(start) + dy * np.sin(start))
            out[w] = np.array(rows)
        return out


def _grams(units: np.ndarray, truth: np.ndarray, half: np.ndarray) -> list[tuple]:
    """Per half: (UUᵀ, U g, g·g, windows) of the parts' increments U (K, W) against the truth g (W,)."""
    out = []
    for h in (0, 1):
        u, g = units[:, half == h], truth[half == h]
        out.append((u @ u.T, u @ g, float(g @ g), int(len(g))))
    return out


def _mixtures() -> dict:
    """family -> [(ResponseShape without its delay, as (fast, slow, weight)), weights over the parts (K,)]."""
    k = len(SHAPE_TIME_CONSTANTS)
    unit = np.eye(k)
    out = {"delay": [((0.0, 0.0, 0.0), unit[0])],
           "first order": [((T, 0.0, 0.0), unit[i]) for i, T in enumerate(SHAPE_TIME_CONSTANTS) if T > 0],
           "fast + slow": [], "cascade": []}
    for i, j in itertools.combinations(range(k), 2):
        fast, slow = SHAPE_TIME_CONSTANTS[i], SHAPE_TIME_CONSTANTS[j]
        out["fast + slow"] += [((fast, slow, float(w)), (1 - w) * unit[i] + w * unit[j]) for w in SHAPE_WEIGHTS]
        weight = slow / (slow - fast)
        if fast > 0 and weight <= 10.0:
            out["cascade"].append(((fast, slow, weight), (1 - weight) * unit[i] + weight * unit[j]))
    return out


def _fit(stats: list, delays: np.ndarray, mixtures: list, train: int) -> tuple[int, int, float]:
    """The mixture and delay of least pooled training residual (after each robot's LS scale): (m, j, rms)."""
    weights = np.array([m[1] for m in mixtures])
    residual = np.zeros((len(weights), len(delays)))
    windows = 0
    for per_delay in stats:
        for j, halves in enumerate(per_delay):
            gram, cross, square, _ = halves[train]
            gw = np.einsum("mk,kl,ml->m", weights, gram, weights)
            residual[:, j] += square - (weights @ cross) ** 2 / np.maximum(gw, 1e-300)
        windows += per_delay[0][train][3]
    rms = np.sqrt(np.maximum(residual, 0) / windows)
    m, j = np.unravel_index(np.argmin(rms), rms.shape)
    return int(m), int(j), float(rms[m, j])


def _held_out(stats: list, weights: np.ndarray, j: int, train: int) -> list[float]:
    """Per robot: the other half's RMS with the training half's scale."""
    out = []
    for per_delay in stats:
        gram, cross, _, _ = per_delay[j][train]
        k = (weights @ cross) / (weights @ gram @ weights)
        gram_t, cross_t, square_t, n_t = per_delay[j][1 - train]
        out.append(float(np.sqrt(max(square_t - 2 * k * (weights @ cross_t) + k * k * (weights @ gram_t @ weights),
                                     0.0) / n_t)))
    return out


def _shape(args: tuple, delay: float) -> ResponseShape:
    fast, slow, weight = args
    if weight == 0.0:
        return ResponseShape(delay, fast)
    if weight > 1.0:
        return ResponseShape.cascade(delay, fast, slow)
    return ResponseShape(delay, fast, slow, weight)


def shape_fits(logs: dict, fit_window: float = 0.25) -> dict:
    """Section 4 (module docstring): per channel, training half and family, the fitted shape and its held-out RMS
    per robot and pooled at each of SHAPE_WINDOWS."""
    shaped = [ShapeLog(log) for log in logs.values()]
    mixtures = _mixtures()

    # the true turn unwrapped near the command's (a 5 s window may turn beyond ±π/2, never beyond ±π)
    turn_stats = {w: [[_grams(u := s.turns(w, d), u[0] + wrap_angle(s.windows[w][2][:, 2] - u[0]), s.windows[w][4])
                       for d in SHAPE_TURN_DELAYS] for s in shaped] for w in SHAPE_WINDOWS}
    out = {"robots": list(logs), "fit_window_s": fit_window, "turn": {}, "travel": {}}

    def record(channel, train, family, stats, delays):
        m, j, rms = _fit(stats[fit_window], delays, mixtures[family], train)
        args, weights = mixtures[family][m]
        shape = _shape(args, float(delays[j]))
        held = {w: _held_out(stats[w], weights, j, train) for w in SHAPE_WINDOWS}
        counts = [per_delay[j][1 - train][3] for per_delay in stats[SHAPE_WINDOWS[0]]]
        pooled = {w: float(np.sqrt(np.sum(np.square(held[w]) * [s[j][1 - train][3] for s in stats[w]])
                                   / np.sum([s[j][1 - train][3] for s in stats[w]]))) for w in SHAPE_WINDOWS}
        out[channel][f"{train}/{family}"] = {
            "train_half": train, "family": family, "train_rms": rms, "held_out": held, "held_out_pooled": pooled,
            "windows": counts, "shape": dataclasses_shape(shape), "mean_delay_s": shape.mean_delay_s}
        return shape

    turn_shapes = {}
    for train in (0, 1):
        for family in SHAPE_FAMILIES:
            shape = record("turn", train, family, turn_stats, SHAPE_TURN_DELAYS)
            if family == "fast + slow":
                turn_shapes[train] = shape
    for train in (0, 1):
        turn = turn_shapes[train]
        headings = [np.concatenate([[0.0], np.cumsum(turn.means(s.t, s.turn_parts[0])[:-1] * s.dt)]) for s in shaped]
        travel_stats = {w: [] for w in SHAPE_WINDOWS}        # per length, per log, per delay
        for s, h in zip(shaped, headings, strict=True):
            per_length = {w: [] for w in SHAPE_WINDOWS}
            for d in SHAPE_TRAVEL_DELAYS:
                moved = s.forwards(SHAPE_WINDOWS, d, h, turn.dead_time_s)
                for w in SHAPE_WINDOWS:
                    per_length[w].append(_grams(moved[w], s.windows[w][2][:, 0], s.windows[w][5]))
            for w in SHAPE_WINDOWS:
                travel_stats[w].append(per_length[w])
        for family in SHAPE_FAMILIES:
            record("travel", train, family, travel_stats, SHAPE_TRAVEL_DELAYS)
    return out


def dataclasses_shape(shape: ResponseShape) -> dict:
    return {"dead_time_s": shape.dead_time_s, "fast_s": shape.fast_s, "slow_s": shape.slow_s,
            "slow_weight": shape.slow_weight}


def print_shapes(result: dict) -> None:
    unit = {"turn": (1e3, "mrad"), "travel": (1e3, "mm")}
    for channel in ("turn", "travel"):
        scale, label = unit[channel]
        print(f"\n== shape of the {channel} (fitted on one half at {result['fit_window_s']:g} s, pooled; held-out "
              f"RMS {label} on the other half at " + " / ".join(f"{w:g}" for w in SHAPE_WINDOWS) + " s, pooled "
              f"[robots {' '.join(str(r) for r in result['robots'])}])")
        for row in result[channel].values():
            s = row["shape"]
            print(f"half {row['train_half']} {row['family']:>11}: dead {s['dead_time_s']:.3f} fast {s['fast_s']:.2f} "
                  f"slow {s['slow_s']:.2f} w {s['slow_weight']:.2f} (mean delay {row['mean_delay_s']:.3f} s); "
                  f"train {scale * row['train_rms']:.2f}; held out "
                  + "  ".join(f"{scale * row['held_out_pooled'][w]:.2f} ["
                              + " ".join(f"{scale * x:.1f}" for x in row["held_out"][w]) + "]" for w in SHAPE_WINDOWS))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--robots", type=positive_int, nargs="+", default=[1, 2, 3, 4, 5])
    parser.add_argument("--section", choices=("grid", "shape", "all"), default="grid",
                        help="grid: sections 1-3 (default); shape: section 4; all: both")
    parser.add_argument("--fit-window", type=positive_float, default=0.25, help="the windows (s) section 4 fits "
                        "the shapes on (the held-out scores are at 0.25, 1 and 5 s whatever it is)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    if not args.data.is_dir():
        print(f"mrclam_drive_response: no data set at {args.data}", file=sys.stderr)
        return 2
    logs = {r: read_mrclam(args.data, r, truth_heading="travel") for r in args.robots}
    shapes = shape_fits(logs, args.fit_window) if args.section in ("shape", "all") else None
    if args.section == "shape":
        if args.json:
            print(json.dumps({"shape": shapes}, indent=1))
        else:
            print_shapes(shapes)
        return 0
    result = {} if shapes is None else {"shape": shapes}
    for order in (1, 2):
        result[f"order{order}"] = summarise(grid(logs, order), args.robots)
    first = result["order1"]["heading_0.25s"]["pooled"]
    result["scale"] = {"pure_delay": scales(logs, 0.0, first["pure_delay_s"]),
                       "first_order": scales(logs, first["T_s"], first["delay_s"])}
    steps = {r: impulse(log) for r, log in logs.items()}
    result["impulse"] = {"lags_s": [float((k + 1) * IMPULSE_STEP_S) for k in range(IMPULSE_TAPS)],
                         "step": {r: s.tolist() for r, s in steps.items()}}
    if args.json:
        print(json.dumps(result, indent=1))
        return 0
    for order in (1, 2):
        print(f"\n== order {order}: best (T s, τ s) by robot and pooled; RMS mrad / mm (pure delay's best in brackets)")
        for name, _, _ in CRITERIA:
            s = result[f"order{order}"][name]
            unit = 1e3
            per = "  ".join(f"r{p['robot']} {p['T_s']:.3f},{p['delay_s']:.3f}: {unit * p['rms']:.2f} "
                            f"({unit * p['pure_rms']:.2f}@{p['pure_delay_s']:.3f})" for p in s["per_robot"])
            pooled = s["pooled"]
            print(f"{name:>14}: {per}")
            print(f"{'':>14}  pooled T {pooled['T_s']:.3f} τ {pooled['delay_s']:.3f}: {unit * pooled['rms']:.2f} "
                  f"(pure {unit * pooled['pure_rms']:.2f}@{pooled['pure_delay_s']:.3f}); per-robot T "
                  f"{s['T_mean_s']:.3f} ± {s['T_sd_s']:.3f}, τ {s['delay_mean_s']:.3f} ± {s['delay_sd_s']:.3f} (sd); "
                  f"at pooled " + " ".join(f"{unit * p['rms_at_pooled']:.2f}" for p in s["per_robot"]))
    print("\n== turn scale on windows of 0.2 / 1 / 5 s (heading RMS mrad)")
    for label, rows in result["scale"].items():
        for row in rows:
            print(f"{label:>11} r{row['robot']} T {row['T_s']:.3f} τ {row['delay_s']:.3f}: k "
                  + " / ".join(f"{k:.3f}" for k in row["turn_scale"]) + "   rms "
                  + " / ".join(f"{1e3 * e:.1f}" for e in row["heading_rms"]) + "   travel scale "
                  + " / ".join(f"{k:.3f}" for k in row["travel_scale"]))
    print("\n== the turn's step response (deconvolved, divided by its value at 0.8 s), lags 0.02..0.8 s every 0.04")
    sel = slice(0, IMPULSE_TAPS, 2)
    print("lag s      " + " ".join(f"{x:5.2f}" for x in result["impulse"]["lags_s"][sel]))
    for r, s in steps.items():
        print(f"robot {r}    " + " ".join(f"{x:5.2f}" for x in (s / s[-1])[sel]))
    o1 = result["order1"]["heading_0.25s"]["pooled"]
    o2 = result["order2"]["heading_0.25s"]["pooled"]
    for label, step in ((f"pure {o1['pure_delay_s']:.3f}", model_step(0.0, o1["pure_delay_s"])),
                        (f"1st {o1['T_s']:.3f},{o1['delay_s']:.3f}", model_step(o1["T_s"], o1["delay_s"])),
                        (f"2nd {o2['T_s']:.3f},{o2['delay_s']:.3f}", model_step(o2["T_s"], o2["delay_s"], 2))):
        print(f"{label:<11}" + " ".join(f"{x:5.2f}" for x in step[sel]))
    if shapes is not None:
        print_shapes(shapes)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
