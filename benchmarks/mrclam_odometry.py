"""MRCLAM odometry against Vicon: is there a systematic heading error, is it stable, and is the rest a random walk?

Run from the repository root:

    .venv/bin/python -m benchmarks.mrclam_odometry [--data ../shared/data/mrclam/MRCLAM_Dataset2] [--window 10]

Prints, per robot (docs/fastslam-history.md, "Session 5"):
1. the heading bias per metre (UMBmark's type-A error: a curve on a straight run) fitted with the rotation scale
   (`estimate_noise(heading_bias=True)`, 5 s windows), on the whole log, its first half, and the other four robots;
2. whether a bias fitted on one part predicts another: the rms over 100 s blocks of the heading error left in the
   *second half* by (scale only | scale + bias) fitted on the first half, and over the whole log by a fit on the
   other robots (a stable bias lowers it);
3. the lag autocorrelation of the calibrated heading error per window (a slowly varying bias, the thing a bias
   state in the filter could track, shows as positive correlation over lags of 10-300 s);
4. the structure function: rms of the calibrated dead-reckoning heading error over horizons of 5-400 s against the
   fitted random walk's σ, without and with the bias (the model is consistent if the ratio stays near 1).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from estimation.datasets import read_mrclam
from estimation.geometry import wrap_angle
from estimation.noise_estimation import estimate_noise
from runtime.commands.options import positive_float

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "mrclam" / "MRCLAM_Dataset2"
GLITCH_RAD = 0.6          # a window whose heading error exceeds this is a Vicon glitch, not odometry
HORIZONS_S = (5, 10, 20, 50, 100, 200, 400)
LAGS = (1, 2, 3, 5, 10, 20, 30)


def _windows(log, window_s: float) -> dict:
    """Per window inside the ground truth: odometry turn u, true turn g, odometry distance d (all (W,))."""
    rows = log.odometry
    rows = rows[(rows[:, 0] >= log.ground_truth[0, 0]) & (rows[:, 0] <= log.ground_truth[-1, 0])]
    t = np.arange(rows[0, 0], rows[-1, 0], window_s)
    u = np.diff(np.interp(t, rows[:, 0], np.unwrap(rows[:, 3])))
    g = u + wrap_angle(np.diff(np.interp(t, log.ground_truth[:, 0], np.unwrap(log.ground_truth[:, 3]))) - u)
    path = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(rows[:, 1:3], axis=0).T))])
    d = np.diff(np.interp(t, rows[:, 0], path))
    ok = np.abs(g - u) < GLITCH_RAD
    return {"u": u[ok], "g": g[ok], "d": d[ok]}


def _fit(parts: list[dict], with_bias: bool) -> np.ndarray:
    x = np.vstack([np.column_stack([p["u"], p["d"]]) if with_bias else p["u"][:, None] for p in parts])
    return np.linalg.lstsq(x, np.concatenate([p["g"] for p in parts]), rcond=None)[0]


def _block_rms(part: dict, coef: np.ndarray, per_block: int) -> float:
    x = np.column_stack([part["u"], part["d"]])[:, :len(coef)]
    residual = part["g"] - x @ coef
    n = len(residual) // per_block * per_block
    return float(np.sqrt(np.mean(residual[:n].reshape(-1, per_block).sum(axis=1) ** 2)))


def _structure(log, model) -> list[tuple[float, float]]:
    """(rms heading error, model σ) of calibrated dead reckoning over each horizon in HORIZONS_S."""
    o = model.odometry
    rows = log.odometry
    rows = rows[(rows[:, 0] >= log.ground_truth[0, 0]) & (rows[:, 0] <= log.ground_truth[-1, 0])]
    step = np.hypot(*np.diff(rows[:, 1:3], axis=0).T)
    turn = np.diff(np.unwrap(rows[:, 3])) * o.rotation_scale + o.heading_bias_per_m * step
    heading = np.concatenate([[0.0], np.cumsum(turn)])
    turned = np.concatenate([[0.0], np.cumsum(np.abs(turn))])
    driven = np.concatenate([[0.0], np.cumsum(step * o.translation_scale)])
    truth = np.interp(rows[:, 0], log.ground_truth[:, 0], np.unwrap(log.ground_truth[:, 3]))
    error = truth - truth[0] - heading
    dt = float(np.median(np.diff(rows[:, 0])))
    out = []
    for horizon in HORIZONS_S:
        k = int(round(horizon / dt))
        i = np.arange(0, len(rows) - k, max(1, k // 4))
        change = wrap_angle(error[i + k] - error[i])
        variance = o.theta_var_per_rad * (turned[i + k] - turned[i]) + o.theta_var_per_m * (driven[i + k] - driven[i])
        out.append((float(np.sqrt(np.mean(change ** 2))), float(np.sqrt(np.mean(variance)))))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--window", type=positive_float, default=10.0,
                        help="window (s) of the prediction and lag tests")
    args = parser.parse_args(argv)
    if not args.data.is_dir():
        print(f"mrclam_odometry: no data set at {args.data}", file=sys.stderr)
        return 2
    logs = {r: read_mrclam(args.data, r) for r in range(1, 6)}
    half = {r: read_mrclam(args.data, r, until=float(log.ground_truth[0, 0] + log.ground_truth[-1, 0]) / 2)
            for r, log in logs.items()}

    print("1. heading bias per metre (5 s windows; mrad/m ± standard error)")
    for r in logs:
        fits = []
        for label, pool in (("whole log", [logs[r]]), ("first half", [half[r]]),
                            ("other robots", [logs[o] for o in logs if o != r])):
            model = estimate_noise(pool, heading_bias=True).model
            fits.append(f"{label} {1e3 * model.odometry.heading_bias_per_m:+6.1f} ± "
                        f"{1e3 * model.fit.get('heading_bias_per_m_standard_error', float('nan')):4.1f}")
        print(f"  robot {r}: " + ", ".join(fits))

    per_block = max(1, int(round(100.0 / args.window)))
    print(f"2. heading error left over 100 s blocks (rms rad; {args.window:g} s windows): scale only -> scale + bias")
    windows = {r: _windows(log, args.window) for r, log in logs.items()}
    for r, w in windows.items():
        h = len(w["u"]) // 2
        first, second = ({k: v[s] for k, v in w.items()} for s in (slice(0, h), slice(h, None)))
        others = [windows[o] for o in windows if o != r]
        split = [_block_rms(second, _fit([first], bias), per_block) for bias in (False, True)]
        pooled = [_block_rms(w, _fit(others, bias), per_block) for bias in (False, True)]
        print(f"  robot {r}: first half -> second half {split[0]:.3f} -> {split[1]:.3f}; "
              f"other robots -> whole log {pooled[0]:.3f} -> {pooled[1]:.3f}")

    print(f"3. autocorrelation of the calibrated heading error per {args.window:g} s window, lags "
          + ", ".join(f"{lag * args.window:g}" for lag in LAGS) + " s")
    for r, w in windows.items():
        e = w["g"] - w["u"] * _fit([w], False)[0]
        e = e - e.mean()
        acf = [float(np.sum(e[:-lag] * e[lag:]) / np.sum(e * e)) for lag in LAGS]
        print(f"  robot {r}: " + " ".join(f"{a:+.2f}" for a in acf) + f"   (±{2 / np.sqrt(len(e)):.2f} is noise)")

    print("4. dead reckoning's heading error over horizons " + ", ".join(f"{h} s" for h in HORIZONS_S)
          + ": measured rms / model σ (rotation scale | + heading bias)")
    for r, log in logs.items():
        plain = _structure(log, estimate_noise([log]).model)
        biased = _structure(log, estimate_noise([log], heading_bias=True).model)
        print(f"  robot {r}: " + "  ".join(f"{a:.2f}/{b:.2f}|{c:.2f}/{d:.2f}"
                                           for (a, b), (c, d) in zip(plain, biased, strict=True)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
