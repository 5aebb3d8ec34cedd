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
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from estimation.datasets import read_mrclam  # noqa: E402
from estimation.odometry_response import fit_response, with_drive_response  # noqa: E402
from runtime.commands.options import positive_int  # noqa: E402

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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--robots", type=positive_int, nargs="+", default=[1, 2, 3, 4, 5])
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    if not args.data.is_dir():
        print(f"mrclam_drive_response: no data set at {args.data}", file=sys.stderr)
        return 2
    logs = {r: read_mrclam(args.data, r, truth_heading="travel") for r in args.robots}
    result = {}
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
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
