"""MRCLAM: the forward travel of the (calibrated, lagged) commanded-velocity odometry in turns, against Vicon — a
scale that falls with the turn rate, a deficit per radian turned, or a sideways component; and how much of the
odometry's position error the forward deficit per radian (``estimate_noise(turn_translation=True)``) explains.
docs/fastslam-history.md "Session 16: … (Q)".

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.mrclam_turn_translation [--data DIR] [--robots 1,2,3,4,5]
        [--json]

Per robot, its own noise model fitted with the heading bias and the odometry lag (``calibrated``: what
``eval_mrclam --heading-bias --odometry-lag`` fits; the range calibration does not touch the odometry), and the same
with ``turn_translation=True`` (``deficit``):

1. **bands**: steps of 0.25 s (the filter's frame interval) and windows of 1 s on a grid inside the ground truth, the
   odometry read ``lag_s`` earlier and calibrated exactly as the filter calibrates its increments
   (``NoiseModel.calibrate_increments``), classed by the commanded |ω| and speed v over the step (from the raw
   odometry increment). Per class: Σ true forward travel / Σ odometry forward travel (robot frame at the step's
   start), the least-squares true/odometry turn ratio, and the sideways error (true − odometry lateral travel,
   signed by the turn's direction) per radian turned (not for the straight class: its turns are noise). Steps
   whose heading error passes 0.5 rad (Vicon's lost tracks) are left out.
2. **forms**: on the 0.25 s steps that move (v ≥ 0.01 m/s), the true forward travel g_x fitted by least squares as
   k·s − c·|Δθ| (a deficit per radian turned, equivalently a scale 1 − (c/k)·κ falling with the curvature κ), as
   k·s − b·s·|ω| (a scale falling with the turn rate at any speed), and with both terms (s the raw odometry
   distance): coefficients and RMS; the two forms differ where the same |ω| comes at different speeds, so the
   ratios of |ω| 0.1–0.2 rad/s at v < 0.05 and v ≥ 0.05 m/s are printed with each form's prediction. Turns on the
   spot (v < 0.01, |ω| ≥ 0.1): the true travel per radian (the deficit form would predict −c; the calibration clips
   to zero).
3. **error explained**: the position error |g_xy − u_xy| RMS of 0.25 s steps, 1 s and 5 s windows with the
   ``calibrated`` and the ``deficit`` model, its share removed, and the random walk's fitted σ_xy per √m and σ_θ
   per √rad (``estimate_noise``'s 5 s windows), and the 5 s windows' displacement RMS the fit leaves.
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
from estimation.geometry import between, wrap_angle  # noqa: E402
from estimation.noise_estimation import estimate_noise  # noqa: E402
from estimation.noise_model import NoiseModel  # noqa: E402

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "mrclam" / "MRCLAM_Dataset2"
STEPS_S = (0.25, 1.0)
W_BANDS = (0.0, 0.02, 0.1, 0.2, 0.3, 0.5, np.inf)      # commanded |ω|, rad/s
V_BANDS = (("still", 0.0, 0.01), ("slow", 0.01, 0.05), ("cruise", 0.05, np.inf))   # commanded v, m/s
GLITCH_RAD = 0.5
MOVING = 0.01          # m/s
SPIN_W = 0.1           # rad/s: a turn on the spot turns at least this fast
ERROR_WINDOWS_S = (0.25, 1.0, 5.0)


def steps(log, noise: NoiseModel, step_s: float):
    """(raw odometry increments, calibrated ones, true ones) (T, 3) over a grid of ``step_s`` inside the ground
    truth, the odometry read ``lag_s`` earlier; Vicon's lost tracks (heading error > GLITCH_RAD) left out."""
    lag = noise.odometry.lag_s
    lo = max(log.ground_truth[0, 0], log.odometry[0, 0] + lag)
    hi = min(log.ground_truth[-1, 0], log.odometry[-1, 0] + lag)
    t = np.arange(lo, hi, step_s)
    raw = log.odometry_increments(noise.odometry_times(t))
    u = noise.calibrate_increments(raw)
    truth = log.true_pose(t)
    g = between(truth[:-1], truth[1:])
    g[:, 2] = u[:, 2] + wrap_angle(g[:, 2] - u[:, 2])
    keep = np.abs(g[:, 2] - u[:, 2]) < GLITCH_RAD
    return raw[keep], u[keep], g[keep]


def bands(raw, u, g, step_s: float) -> list[dict]:
    """The per-class ratios of section 1 (classes with ≥ 20 steps)."""
    v = np.hypot(raw[:, 0], raw[:, 1]) / step_s
    w = np.abs(raw[:, 2]) / step_s
    out = []
    for w_lo, w_hi in zip(W_BANDS[:-1], W_BANDS[1:], strict=True):
        for label, v_lo, v_hi in V_BANDS:
            sel = (w >= w_lo) & (w < w_hi) & (v >= v_lo) & (v < v_hi)
            if sel.sum() < 20:
                continue
            odometry, true = float(u[sel, 0].sum()), float(g[sel, 0].sum())
            turn = float(np.abs(raw[sel, 2]).sum())
            side = np.sign(raw[sel, 2]) * (g[sel, 1] - u[sel, 1])
            out.append({"w_from": w_lo, "w_to": w_hi, "v": label, "n": int(sel.sum()),
                        "mean_w": float(w[sel].mean()), "mean_v": float(v[sel].mean()),
                        "odometry_forward_m": odometry, "true_forward_m": true,
                        "forward_ratio": true / odometry if odometry > 0.05 else float("nan"),
                        "turn_ratio": float(g[sel, 2] @ u[sel, 2] / max(u[sel, 2] @ u[sel, 2], 1e-12)),
                        "sideways_m_per_rad": float(side.sum() / turn) if turn > 0.5 and w_lo > 0 else float("nan")})
    return out


def forms(raw, g, step_s: float) -> dict:
    """Section 2: the forward travel's least-squares forms on the moving 0.25 s steps, and turns on the spot."""
    s = np.hypot(raw[:, 0], raw[:, 1]) * np.sign(raw[:, 0])
    turn = np.abs(raw[:, 2])
    w = turn / step_s
    moving = np.abs(s) / step_s >= MOVING
    y = g[moving, 0]
    designs = {"scale": [s], "deficit_per_rad": [s, -turn], "scale_falling_with_w": [s, -s * w],
               "both": [s, -turn, -s * w]}
    out = {}
    for name, columns in designs.items():
        a = np.column_stack([c[moving] for c in columns])
        coefficients, *_ = np.linalg.lstsq(a, y, rcond=None)
        out[name] = {"coefficients": [float(c) for c in coefficients],
                     "rms_m": float(np.sqrt(np.mean((y - a @ coefficients) ** 2)))}
    k, c = out["deficit_per_rad"]["coefficients"]
    k2, b = out["scale_falling_with_w"]["coefficients"]
    speed = np.abs(s) / step_s
    mid = moving & (w >= 0.1) & (w < 0.2)
    split = {}
    for label, sel in (("slow", mid & (speed < 0.05)), ("cruise", mid & (speed >= 0.05))):
        if sel.sum() < 20:
            continue
        split[label] = {"n": int(sel.sum()), "true_over_odometry": float(g[sel, 0].sum() / s[sel].sum()),
                        "deficit_per_rad_predicts": float((k * s[sel] - c * turn[sel]).sum() / s[sel].sum()),
                        "scale_falling_with_w_predicts": float((k2 * s[sel] - b * s[sel] * w[sel]).sum()
                                                               / s[sel].sum())}
    out["w_0.1_to_0.2_by_speed"] = split
    spin = (np.abs(s) / step_s < MOVING) & (w >= SPIN_W)
    out["spin"] = {"n": int(spin.sum()), "turned_rad": float(turn[spin].sum()),
                   "true_forward_per_rad_m": float(g[spin, 0].sum() / max(turn[spin].sum(), 1e-12)),
                   "true_distance_per_rad_m": float(np.hypot(g[spin, 0], g[spin, 1]).sum()
                                                    / max(turn[spin].sum(), 1e-12))}
    return out


def position_error(log, noise: NoiseModel) -> dict:
    out = {}
    for window in ERROR_WINDOWS_S:
        _, u, g = steps(log, noise, window)
        e = g[:, :2] - u[:, :2]
        out[f"{window:g}"] = {"rms_m": float(np.sqrt(np.mean(np.sum(e ** 2, axis=1)))),
                              "forward_rms_m": float(np.sqrt(np.mean(e[:, 0] ** 2))),
                              "sideways_rms_m": float(np.sqrt(np.mean(e[:, 1] ** 2)))}
    return out


def measure(log) -> dict:
    calibrated = estimate_noise([log], heading_bias=True, odometry_lag=True).model
    deficit = estimate_noise([log], heading_bias=True, odometry_lag=True, turn_translation=True).model
    out = {"lag_s": calibrated.odometry.lag_s, "models": {}}
    for name, model in (("calibrated", calibrated), ("deficit", deficit)):
        o = model.odometry
        out["models"][name] = {
            "translation_scale": o.translation_scale, "rotation_scale": o.rotation_scale,
            "forward_deficit_per_rad": o.forward_deficit_per_rad,
            "forward_deficit_per_rad_standard_error": model.fit.get("forward_deficit_per_rad_standard_error"),
            "sigma_xy_per_sqrt_m": float(np.sqrt(o.xy_var_per_m)),
            "sigma_theta_per_sqrt_rad": float(np.sqrt(o.theta_var_per_rad)),
            "sigma_theta_per_sqrt_m": float(np.sqrt(o.theta_var_per_m)),
            "window_displacement_rms_m": model.fit.get("forward_deficit_displacement_rms_m"),
            "position_error": position_error(log, model),
            "bands": {f"{s:g}": bands(*steps(log, model, s), s) for s in STEPS_S}}
    raw, _, g = steps(log, calibrated, 0.25)
    out["forms"] = forms(raw, g, 0.25)
    out["window_displacement_rms_m_without"] = deficit.fit.get("forward_deficit_none_displacement_rms_m")
    return out


def report(results: dict) -> None:
    for r, m in results.items():
        c, d = m["models"]["calibrated"], m["models"]["deficit"]
        print(f"robot {r}: lag {m['lag_s']:.2f} s; translation scale {c['translation_scale']:.3f} alone, "
              f"{d['translation_scale']:.3f} with a forward deficit of {d['forward_deficit_per_rad']:.4f} ± "
              f"{d['forward_deficit_per_rad_standard_error'] or float('nan'):.4f} m/rad; 5 s windows' displacement "
              f"RMS {m['window_displacement_rms_m_without']:.4f} -> {d['window_displacement_rms_m']:.4f} m")
        print(f"  random walk: σ_xy {c['sigma_xy_per_sqrt_m']:.4f} -> {d['sigma_xy_per_sqrt_m']:.4f} m/√m, "
              f"σ_θ {c['sigma_theta_per_sqrt_rad']:.4f} -> {d['sigma_theta_per_sqrt_rad']:.4f} rad/√rad, "
              f"{c['sigma_theta_per_sqrt_m']:.4f} -> {d['sigma_theta_per_sqrt_m']:.4f} rad/√m")
        for window, e in c["position_error"].items():
            e2 = d["position_error"][window]
            print(f"  position error over {window} s: RMS {e['rms_m'] * 1000:.1f} -> {e2['rms_m'] * 1000:.1f} mm "
                  f"(forward {e['forward_rms_m'] * 1000:.1f} -> {e2['forward_rms_m'] * 1000:.1f}, sideways "
                  f"{e['sideways_rms_m'] * 1000:.1f} -> {e2['sideways_rms_m'] * 1000:.1f}); "
                  f"{1 - (e2['rms_m'] / e['rms_m']) ** 2:.0%} of the squared error explained")
        for step in (f"{s:g}" for s in STEPS_S):
            print(f"  {step} s steps, |ω| band / speed: n, forward true/odometry (calibrated -> with the deficit), "
                  f"turn ratio, sideways error mm/rad (calibrated -> deficit)")
            for b, b2 in zip(c["bands"][step], d["bands"][step], strict=True):
                print(f"    |ω| {b['w_from']:.2f}-{b['w_to']:.2f} {b['v']:6s} n {b['n']:5d} (mean |ω| "
                      f"{b['mean_w']:.3f}, v {b['mean_v']:.3f}): {b['forward_ratio']:.3f} -> "
                      f"{b2['forward_ratio']:.3f}, turn {b['turn_ratio']:.3f}, sideways "
                      f"{b['sideways_m_per_rad'] * 1000:+.1f} -> {b2['sideways_m_per_rad'] * 1000:+.1f}")
        f = m["forms"]
        print("  forms on moving 0.25 s steps (g_x RMS mm): " + ", ".join(
            f"{name} {f[name]['rms_m'] * 1000:.2f} ({' '.join(f'{v:.4f}' for v in f[name]['coefficients'])})"
            for name in ("scale", "deficit_per_rad", "scale_falling_with_w", "both")))
        for label, s in f["w_0.1_to_0.2_by_speed"].items():
            print(f"  |ω| 0.1-0.2, {label}: n {s['n']}, true/odometry {s['true_over_odometry']:.3f}; deficit per rad "
                  f"predicts {s['deficit_per_rad_predicts']:.3f}, scale falling with |ω| "
                  f"{s['scale_falling_with_w_predicts']:.3f}")
        s = f["spin"]
        print(f"  turns on the spot: {s['n']} steps, {s['turned_rad']:.1f} rad, true forward "
              f"{s['true_forward_per_rad_m'] * 1000:+.1f} mm/rad, distance {s['true_distance_per_rad_m'] * 1000:.1f}"
              " mm/rad")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--robots", default="1,2,3,4,5")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    if not args.data.is_dir():
        print(f"mrclam_turn_translation: no data set at {args.data}", file=sys.stderr)
        return 2
    results = {int(r): measure(read_mrclam(args.data, int(r))) for r in args.robots.split(",")}
    if args.json:
        print(json.dumps(results))
    else:
        report(results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
