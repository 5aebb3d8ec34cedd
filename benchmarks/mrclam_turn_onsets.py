"""MRCLAM: where the (calibrated, lagged) commanded-velocity odometry loses heading, against Vicon — at changes of
the commanded turn rate (an acceleration limit: ω²/(2α) lost at each start, given back at the stop; or a first-order
response), or elsewhere. docs/fastslam-history.md "Session 15: … (M)".

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.mrclam_turn_onsets [--data DIR] [--robots 1,2,3,4,5]
        [--json]

Per robot, with its own noise model fitted with the three calibrations (scales, heading bias, lag):
1. windows of 0.5, 1 and 2 s (consecutive, inside the ground truth): the heading error e = Δθ_Vicon − Δθ_odometry
   of the calibrated odometry read lag_s earlier, by class of the commanded ω over the window (and the response
   time before it): steady (commanded ω within 0.02 rad/s), ``start`` (|ω| from < 0.02 to > 0.1), ``stop``
   (the reverse), ``dropout`` (a commanded zero of ≤ 0.1 s inside a turn: the log's own gaps), other changes. For
   each: windows, share of the windows, RMS e, share of Σe², and the mean e signed by the turn's direction.
   Also the share of Σe² that the random-walk model gives these windows (its θ variance, per radian and metre).
2. the event-averaged response (Vicon ω / commanded step, medians over events) 0..1 s after starts, stops and
   dropouts, at the commanded time shifted by lag_s: a ramp (acceleration limit), an exponential (first order) or
   something else.
3. fits: the heading increment RMS over 0.25 s steps (the filter's frame interval) of the odometry reconstructed
   with an acceleration limit α on ω (grid) or a first-order lag τ (grid), each with the delay refitted, against
   the pure delay.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from estimation.datasets import read_mrclam  # noqa: E402
from estimation.geometry import wrap_angle  # noqa: E402
from estimation.noise_estimation import estimate_noise  # noqa: E402

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "mrclam" / "MRCLAM_Dataset2"
STEADY = 0.02          # rad/s: commanded ω that moves less than this over a window is steady
TURNING = 0.1          # rad/s: a turn
DROPOUT_S = 0.1        # a commanded zero this short inside a turn is a dropout of the log, not a stop
RESPONSE_S = 0.5       # the window's class looks this far before it (the robot is still answering)
CLASSES = ("steady_still", "steady_turn", "start", "stop", "dropout", "other_change", "stall", "vicon_glitch")
LAG_GRID = np.arange(0.0, 0.405, 0.01)
ALPHA_GRID = (0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 1e9)     # rad/s²
TAU_GRID = (0.0, 0.02, 0.05, 0.08, 0.1, 0.15, 0.2, 0.3)              # s
STEP_S = 0.25
STALL_FRACTION = 0.3   # a stall: Vicon ω below this share of a steady commanded turn ...
STALL_S = 0.2          # ... for at least this long
GLITCH_RAD = 0.5       # a window's heading error beyond this is Vicon's (a lost track), not the odometry's
DROPOUT_LOOKBACK_S = 0.4   # a dropout this shortly before a stall's onset (lagged) is counted as announcing it


def commanded(log) -> tuple[np.ndarray, np.ndarray]:
    """(times (K-1,), ω (K-1,)): the commanded turn rate held from each odometry row to the next."""
    o = log.odometry
    return o[:-1, 0], np.diff(np.unwrap(o[:, 3])) / np.maximum(np.diff(o[:, 0]), 1e-9)


def dropouts(t, w) -> np.ndarray:
    """(K-1,) bool: samples of a commanded zero lasting ≤ DROPOUT_S between turns of the same sign."""
    zero = np.abs(w) < 1e-6
    out = np.zeros(len(w), bool)
    edges = np.flatnonzero(np.diff(np.r_[0, zero.astype(int), 0]))
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        if a > 0 and b < len(w) and t[min(b, len(t) - 1)] - t[a] <= DROPOUT_S and abs(w[a - 1]) > TURNING \
                and abs(w[b]) > TURNING and np.sign(w[a - 1]) == np.sign(w[b]):
            out[a:b] = True
    return out


def classify(t, w, drop, lo, hi) -> str:
    m = (t >= lo - RESPONSE_S) & (t <= hi)
    seg, d = w[m], drop[m]
    if len(seg) == 0:
        return "other_change"
    if d.any():
        return "dropout"
    if np.ptp(seg) < STEADY:
        return "steady_turn" if abs(seg.mean()) > TURNING else "steady_still"
    first, last = abs(seg[: max(1, len(seg) // 10)]).mean(), abs(seg[-max(1, len(seg) // 10):]).mean()
    if first < STEADY and last > TURNING:
        return "start"
    if first > TURNING and last < STEADY:
        return "stop"
    return "other_change"


def limited(t, w, alpha: float, tau: float) -> np.ndarray:
    """ω (K-1,) the robot would turn at: commanded ω through a rate limit α (rad/s²) or a first-order lag τ (s)."""
    out = np.empty_like(w)
    state = 0.0
    dt = np.diff(np.r_[t, t[-1] + 0.02])
    for k in range(len(w)):
        if tau > 0:
            state += (w[k] - state) * (1.0 - np.exp(-dt[k] / tau))
        else:
            step = alpha * dt[k]
            state += min(max(w[k] - state, -step), step)
        out[k] = state
    return out


def heading_at(t, w, times) -> np.ndarray:
    """∫ω up to ``times`` (rate held from each sample to the next)."""
    theta = np.r_[0.0, np.cumsum(w * np.diff(np.r_[t, t[-1] + 0.02]))]
    return np.interp(times, np.r_[t, t[-1] + 0.02], theta)


def analyse(log, robot: int) -> dict:
    noise = estimate_noise([log], heading_bias=True, range_calibration=True, odometry_lag=True).model
    o = noise.odometry
    t, w = commanded(log)
    drop = dropouts(t, w)
    wf = np.interp(np.arange(len(w)), np.flatnonzero(~drop), w[~drop]) if drop.any() else w   # dropouts filled
    true_theta = np.unwrap(log.ground_truth[:, 3])
    gt0, gt1 = log.ground_truth[0, 0], log.ground_truth[-1, 0]
    result = {"robot": robot, "lag_s": o.lag_s, "rotation_scale": o.rotation_scale,
              "heading_bias_per_m": o.heading_bias_per_m, "theta_var_per_rad": o.theta_var_per_rad,
              "theta_var_per_m": o.theta_var_per_m, "dropouts": int(np.sum(np.diff(np.r_[0, drop.astype(int)]) == 1)),
              "windows": {}}
    odo_theta = np.unwrap(log.odometry[:, 3])
    odo_dist = np.r_[0.0, np.cumsum(np.hypot(np.diff(log.odometry[:, 1]), np.diff(log.odometry[:, 2])))]
    # Vicon's turn rate
    gtt = log.ground_truth[:, 0]

    def true_rate(times):   # Vicon's turn rate over ±0.05 s (its time stamps repeat: no np.gradient)
        return (np.interp(times + 0.05, gtt, true_theta) - np.interp(times - 0.05, gtt, true_theta)) / 0.1

    # stalls: the robot stops turning (Vicon ω < STALL_FRACTION of the command) for ≥ STALL_S while the command
    # (dropouts filled) is a steady turn of |ω| > 0.3 rad/s, read lag_s earlier
    grid50 = np.arange(gt0 + 1.0, gt1 - 1.0, 0.02)
    cmd = np.interp(grid50 - o.lag_s, t, wf)
    steady = np.abs(cmd) > 0.3
    low = steady & (true_rate(grid50) * np.sign(cmd) < STALL_FRACTION * np.abs(cmd))
    edges = np.flatnonzero(np.diff(np.r_[0, low.astype(int), 0]))
    stalls = [(grid50[a], (b - a) * 0.02, float(np.sum(np.abs(cmd[a:b]) - true_rate(grid50[a:b]) * np.sign(cmd[a:b]))
                                               * 0.02)) for a, b in zip(edges[::2], edges[1::2], strict=True)
              if (b - a) * 0.02 >= STALL_S]
    stalls = [x for x in stalls if x[2] < GLITCH_RAD]   # more heading than that in a stall: Vicon lost its track
    first = float(log.sighting_times[0]) if len(log) else float("nan")
    # is a stall announced by a commanded-zero dropout just before it (read lag_s earlier)? against the rate at
    # random instants of the same steady turning
    drop_times = t[drop]

    def dropout_before(times):
        i = np.searchsorted(drop_times, times - o.lag_s)
        j = np.searchsorted(drop_times, times - o.lag_s - DROPOUT_LOOKBACK_S)
        return i > j

    random_instants = grid50[steady][::25]
    stall_dropout = float(np.mean(dropout_before(np.array([x[0] for x in stalls])))) if stalls else float("nan")
    result["stalls"] = {"count": len(stalls), "steady_turn_s": float(steady.sum() * 0.02),
                        "heading_lost_rad": float(sum(x[2] for x in stalls)),
                        "lost_median_rad": float(np.median([x[2] for x in stalls])) if stalls else 0.0,
                        "with_dropout_before": stall_dropout,
                        "random_with_dropout_before": float(np.mean(dropout_before(random_instants))),
                        "within_2s_of_first_sighting": [list(x) for x in stalls if abs(x[0] - first) < 2.0]}
    for width in (0.5, 1.0, 2.0):
        starts = np.arange(gt0 + 1.0, gt1 - width, width)
        ends = starts + width
        sa, sb = starts - o.lag_s, ends - o.lag_s
        turn = np.interp(sb, log.odometry[:, 0], odo_theta) - np.interp(sa, log.odometry[:, 0], odo_theta)
        dist = np.interp(sb, log.odometry[:, 0], odo_dist) - np.interp(sa, log.odometry[:, 0], odo_dist)
        predicted = o.rotation_scale * turn + o.heading_bias_per_m * dist
        true = np.interp(ends, log.ground_truth[:, 0], true_theta) - np.interp(starts, log.ground_truth[:, 0],
                                                                                true_theta)
        e = wrap_angle(true - predicted)
        model_var = o.theta_var_per_rad * np.abs(o.rotation_scale * turn) + o.theta_var_per_m * dist
        kind = np.array([classify(t, wf, drop, a, b) for a, b in zip(sa, sb, strict=True)], dtype="<U16")
        for onset, length, _ in stalls:   # a window a stall overlaps is a stall window, whatever its command
            kind[(starts < onset + length) & (ends > onset)] = "stall"
        kind[np.abs(e) > GLITCH_RAD] = "vicon_glitch"
        sign = np.sign(np.where(np.abs(turn) > 1e-6, turn, 1.0))
        clean = kind != "vicon_glitch"    # the shares are of the windows Vicon tracked
        total, total_model = float(np.sum(e[clean] ** 2)), float(np.sum(model_var[clean]))
        rows = {}
        for c in CLASSES:
            m = kind == c
            rows[c] = {"windows": int(m.sum()), "share_windows": float(m.mean()),
                       "rms_rad": float(np.sqrt(np.mean(e[m] ** 2))) if m.any() else float("nan"),
                       "share_sq_error": float(np.sum(e[m & clean] ** 2) / total),
                       "share_model_var": float(np.sum(model_var[m & clean]) / total_model),
                       "mean_signed_rad": float(np.mean(e[m] * sign[m])) if m.any() else float("nan")}
        result["windows"][str(width)] = rows
    offsets = np.arange(0.0, 1.0001, 0.05)
    events = {"start": [], "stop": [], "dropout": []}
    for k in range(1, len(w) - 60):
        if abs(wf[k - 1]) < 1e-6 and abs(wf[k]) > TURNING and np.ptp(wf[k:k + 50]) < STEADY:
            events["start"].append((t[k], wf[k]))
        if abs(wf[k - 1]) > TURNING and abs(wf[k]) < 1e-6 and np.all(np.abs(wf[k:k + 50]) < 1e-6) and \
                np.ptp(wf[max(k - 50, 0):k]) < STEADY:
            events["stop"].append((t[k], wf[k - 1]))
        if drop[k] and not drop[k - 1]:
            events["dropout"].append((t[k], w[k - 1]))
    result["response"] = {"offsets_s": offsets.tolist()}
    for name, ev in events.items():
        ev = [(a, b) for a, b in ev if gt0 + 1 < a < gt1 - 2]
        if not ev:
            result["response"][name] = {"events": 0}
            continue
        r = np.array([true_rate(a + o.lag_s + offsets - 0.1) / b for a, b in ev])
        result["response"][name] = {"events": len(ev), "median": np.median(r, axis=0).tolist(),
                                    "omega_median": float(np.median([abs(b) for _, b in ev]))}
    # fits at the filter's frame interval
    grid = np.arange(gt0 + 1.0, gt1 - 1.0, STEP_S)
    true_steps = np.diff(np.interp(grid, log.ground_truth[:, 0], true_theta))

    def best(wr):
        out = []
        for lag in LAG_GRID:
            steps = np.diff(heading_at(t, wr, grid - lag))
            k = float(steps @ true_steps / max(steps @ steps, 1e-12))
            out.append((float(np.sqrt(np.mean(wrap_angle(k * steps - true_steps) ** 2))), float(lag)))
        return min(out)

    result["fit_pure_delay"] = dict(zip(("rms_rad", "lag_s"), best(w), strict=True))
    result["fit_alpha"] = [dict(zip(("rms_rad", "lag_s"), best(limited(t, w, a, 0.0)), strict=True), alpha=a)
                           for a in ALPHA_GRID]
    result["fit_tau"] = [dict(zip(("rms_rad", "lag_s"), best(limited(t, w, 0.0, tau)), strict=True), tau=tau)
                         for tau in TAU_GRID if tau > 0]
    result["fit_dropouts_filled"] = dict(zip(("rms_rad", "lag_s"), best(wf), strict=True))
    return result


def report(r: dict) -> None:
    print(f"\nrobot {r['robot']}: lag {r['lag_s']:.2f} s, rotation scale {r['rotation_scale']:.3f}, heading bias "
          f"{r['heading_bias_per_m']:+.4f} rad/m, σθ {np.sqrt(r['theta_var_per_rad']):.3f}/√rad "
          f"{np.sqrt(r['theta_var_per_m']):.3f}/√m, commanded-zero dropouts in turns: {r['dropouts']}")
    for width, rows in r["windows"].items():
        print(f"  windows {width} s: class    n  share  rms(rad)  share Σe²  share model var  mean signed e(rad)")
        for c, v in rows.items():
            print(f"    {c:13s} {v['windows']:5d} {v['share_windows']:5.3f} {v['rms_rad']:8.4f} "
                  f"{v['share_sq_error']:8.3f} {v['share_model_var']:8.3f} {v['mean_signed_rad']:+8.4f}")
    resp = r["response"]
    print("  response (Vicon ω / commanded step, median) at commanded time + lag + offset − 0.1 s:")
    print("    offset  " + " ".join(f"{x - 0.1:5.2f}" for x in resp["offsets_s"][::2]))
    for name in ("start", "stop", "dropout"):
        v = resp[name]
        if v["events"]:
            print(f"    {name:8s}" + " ".join(f"{x:5.2f}" for x in v["median"][::2])
                  + f"   ({v['events']} events, |ω| {v['omega_median']:.2f})")
    print(f"  0.25 s heading steps, RMS (rad): pure delay {r['fit_pure_delay']['rms_rad']:.4f} "
          f"(lag {r['fit_pure_delay']['lag_s']:.2f}); dropouts filled {r['fit_dropouts_filled']['rms_rad']:.4f} "
          f"(lag {r['fit_dropouts_filled']['lag_s']:.2f})")
    st = r["stalls"]
    print(f"  stalls (Vicon ω < {STALL_FRACTION} of a steady commanded turn > 0.3 rad/s for ≥ {STALL_S} s): "
          f"{st['count']} in {st['steady_turn_s']:.0f} s of such turning, heading lost {st['heading_lost_rad']:.3f} "
          f"rad (median {st['lost_median_rad']:.3f} each); a dropout in the {DROPOUT_LOOKBACK_S} s before: "
          f"{st['with_dropout_before']:.2f} of stalls vs {st['random_with_dropout_before']:.2f} of random instants of "
          f"such turning; within 2 s of the first sighting (t, s, rad): "
          + (", ".join(f"({a:.2f}, {b:.2f}, {c:.3f})" for a, b, c in st["within_2s_of_first_sighting"]) or "none"))
    print("    α (rad/s²): " + "  ".join(f"{a['alpha']:g}:{a['rms_rad']:.4f}@{a['lag_s']:.2f}"
                                         for a in r["fit_alpha"]))
    print("    τ (s):      " + "  ".join(f"{a['tau']:g}:{a['rms_rad']:.4f}@{a['lag_s']:.2f}" for a in r["fit_tau"]))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--robots", default="1,2,3,4,5")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    if not args.data.is_dir():
        print(f"no MRCLAM data at {args.data}", file=sys.stderr)
        return 2
    results = [analyse(read_mrclam(args.data, int(r)), int(r)) for r in args.robots.split(",")]
    if args.json:
        print(json.dumps(results, indent=1))
    else:
        for r in results:
            report(r)
    return 0


if __name__ == "__main__":
    sys.exit(main())
