"""The floor of MRCLAM known-ID FastSLAM: what the filter and its noise model reach when the map is not the problem,
and what the camera's residuals against Vicon say about the measurement model.

Run from the repository root:

    .venv/bin/python -m benchmarks.mrclam_floor [--data DIR] [--robots 1,2,3,4,5] [--particles 100] [--seed 0]
        [--residuals-only] [--json]

Every noise model here is fitted on the **first half** of the robot's own log (sightings before the median
sighting time, `read_mrclam(..., until=)`); the residual figures are taken on the **second half**, so nothing is
scored on the data it was fitted on.

1. Residuals (second half; range r and bearing φ predicted from the Vicon pose and the true landmark): the range
   residual's median at the image centre (|φ| < 0.15 rad) and at its edges (|φ| > 0.35 rad), its rms and
   median |Δr| (inliers within 4 robust σ) before and after the range calibration fitted on the first half
   (`estimate_noise(range_calibration=True)`, `RangeBearingNoise.corrected`), the calibration's coefficients,
   the bearing's rms; the time offset of the sightings against Vicon that minimises the bearing rms (scan of
   ±0.3 s) and the camera's position on the robot that minimises both (grid of ±0.15 m × ±0.09 m).
2. Localization only (`run_landmark_log(..., known_map=True)`: every particle starts with the true landmarks,
   σ 1 mm, none ever removed; association by id) over the whole log, without and with the range calibration:
   ATE, pose NEES median and the fraction of frames within χ²₃ 95 %.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from estimation.dataset_slam import run_landmark_log  # noqa: E402
from estimation.datasets import read_mrclam  # noqa: E402
from estimation.fastslam import range_bearing_config  # noqa: E402
from estimation.geometry import wrap_angle  # noqa: E402
from estimation.noise_estimation import estimate_noise  # noqa: E402
from estimation.noise_model import RangeBearingNoise  # noqa: E402
from runtime.commands.options import non_negative_int, positive_int  # noqa: E402

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "mrclam" / "MRCLAM_Dataset2"
CENTRE, EDGE = 0.15, 0.35                    # rad: |φ| of the image's centre and edges
TIME_OFFSETS = np.round(np.arange(-0.3, 0.301, 0.05), 3)
LEVER_X, LEVER_Y = np.arange(-0.15, 0.151, 0.03), np.arange(-0.09, 0.091, 0.03)


def sightings(log, offset_s: float = 0.0, lever=(0.0, 0.0)):
    """Measured (r, φ), predicted (r̂, φ̂) (N,) of the sightings of true landmarks, the sensor at ``lever`` (m, in
    the robot frame) and the Vicon pose taken ``offset_s`` after each sighting's time stamp; and the times."""
    known = np.isin(log.landmark_ids, log.truth_ids)
    t = log.sighting_times[known]
    target = log.truth_positions[np.searchsorted(log.truth_ids, log.landmark_ids[known])]
    pose = log.true_pose(t + offset_s)
    c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    sensor = pose[:, :2] + np.column_stack([c * lever[0] - s * lever[1], s * lever[0] + c * lever[1]])
    d = target - sensor
    return (log.ranges[known], log.bearings[known], np.hypot(d[:, 0], d[:, 1]),
            wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - pose[:, 2]), t)


def _inliers(x: np.ndarray) -> np.ndarray:
    centred = x - np.median(x)
    return np.abs(centred) < 4.0 * 1.4826 * np.median(np.abs(centred)) + 1e-12


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x ** 2)))


def residual_figures(log, half: float, sensor: RangeBearingNoise, calibrated: RangeBearingNoise) -> dict:
    """Section 1 of the module docstring for one robot (``half``: the time splitting fit and test)."""
    r, phi, r_hat, phi_hat, t = sightings(log)
    test = t >= half
    r, phi, r_hat, phi_hat = r[test], phi[test], r_hat[test], phi_hat[test]
    dr = r - r_hat
    dr_cal = calibrated.corrected(r, phi)[0] - r_hat
    db = wrap_angle(phi - phi_hat - sensor.bearing_offset_rad)
    keep, keep_cal = _inliers(dr) & _inliers(db), _inliers(dr_cal) & _inliers(db)
    centre, edge = keep & (np.abs(phi) < CENTRE), keep & (np.abs(phi) > EDGE)
    out = {"sightings_tested": int(test.sum()),
           "range_residual_centre_median_m": float(np.median(dr[centre])) if centre.any() else float("nan"),
           "range_residual_edge_median_m": float(np.median(dr[edge])) if edge.any() else float("nan"),
           "range_residual_rms_m": _rms(dr[keep]), "range_residual_mad_m": float(np.median(np.abs(dr))),
           "range_residual_rms_calibrated_m": _rms(dr_cal[keep_cal]),
           "range_residual_mad_calibrated_m": float(np.median(np.abs(dr_cal))),
           "calibrated_edge_minus_centre_m": float(np.median(dr_cal[keep_cal & (np.abs(phi) > EDGE)])
                                                   - np.median(dr_cal[keep_cal & (np.abs(phi) < CENTRE)])),
           "bearing_residual_rms_rad": _rms(db[keep] - np.median(db[keep])),
           "calibration": [calibrated.range_offset_m, calibrated.range_scale, calibrated.range_scale_per_rad,
                           calibrated.range_scale_per_rad2]}
    # timing and the camera's position: against the whole log's inliers (a look, not a fit used anywhere)
    r, phi, _, _, _ = sightings(log)
    bearing_rms = []
    for offset in TIME_OFFSETS:
        residual = wrap_angle(phi - sightings(log, offset)[3])
        bearing_rms.append(_rms(residual[_inliers(residual)] - np.median(residual[_inliers(residual)])))
    out["time_offset_best_s"] = float(TIME_OFFSETS[int(np.argmin(bearing_rms))])
    out["bearing_rms_at_offset_0_rad"] = float(bearing_rms[int(np.flatnonzero(TIME_OFFSETS == 0)[0])])
    out["bearing_rms_at_best_offset_rad"] = float(min(bearing_rms))
    best = None
    for x in LEVER_X:
        for y in LEVER_Y:
            _, _, r_hat, phi_hat, _ = sightings(log, 0.0, (x, y))
            dr_l, db_l = calibrated.corrected(r, phi)[0] - r_hat, wrap_angle(phi - phi_hat)
            ok = _inliers(dr_l) & _inliers(db_l)
            cost = _rms(dr_l[ok] - np.median(dr_l[ok])) / 0.02 + _rms(db_l[ok] - np.median(db_l[ok])) / 0.01
            if best is None or cost < best[0]:
                best = (cost, float(x), float(y))
    out["sensor_position_best_m"] = [round(best[1], 3), round(best[2], 3)]
    return out


def localization(log, noise, particles: int, seed: int) -> dict:
    start = time.process_time()
    run = run_landmark_log(log, range_bearing_config(n_particles=particles), np.random.default_rng(seed),
                           noise=noise, association="id", known_map=True)
    m = run.metrics
    return {"ate_m": m["ate_m"], "pose_nees_median": m["pose_nees_median"],
            "pose_nees_within_chi2_95": m["pose_nees_within_chi2_95"], "seconds_cpu": time.process_time() - start}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--robots", default="1,2,3,4,5")
    parser.add_argument("--particles", type=positive_int, default=100)
    parser.add_argument("--seed", type=non_negative_int, default=0)
    parser.add_argument("--residuals-only", action="store_true")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    if not args.data.is_dir():
        print(f"mrclam_floor: no data set at {args.data}", file=sys.stderr)
        return 2
    results = {}
    for robot in (int(r) for r in args.robots.split(",")):
        log = read_mrclam(args.data, robot)
        half = float(np.median(log.sighting_times))
        first = read_mrclam(args.data, robot, until=half)
        plain = estimate_noise([first]).model
        calibrated = estimate_noise([first], range_calibration=True).model
        figures = {"half_s": half, **residual_figures(log, half, plain.range_bearing, calibrated.range_bearing)}
        if not args.residuals_only:
            figures["floor"] = localization(log, plain, args.particles, args.seed)
            figures["floor_calibrated"] = localization(log, calibrated, args.particles, args.seed)
        results[robot] = figures
        if not args.json:
            print(f"  robot {robot} done", file=sys.stderr, flush=True)
    if args.json:
        print(json.dumps({"robots": results, "particles": args.particles, "seed": args.seed}))
        return 0
    print(f"MRCLAM {args.data.name}: models fitted on each log's first half, residuals on its second half")
    print("robot  Δr centre  Δr edge   rms Δr → calibrated   med|Δr| → cal.  edge−centre cal.  rms Δφ   "
          "best dt  (Δφ rms 0 → best)  sensor at (x, y)  calibration a, b0, b1, b2")
    for robot, f in results.items():
        print(f"{robot:5d}  {f['range_residual_centre_median_m']:+8.3f}  {f['range_residual_edge_median_m']:+7.3f}"
              f"   {f['range_residual_rms_m']:.3f} → {f['range_residual_rms_calibrated_m']:.3f}"
              f"        {f['range_residual_mad_m']:.3f} → {f['range_residual_mad_calibrated_m']:.3f}"
              f"     {f['calibrated_edge_minus_centre_m']:+.3f}        {f['bearing_residual_rms_rad']:.4f}"
              f"  {f['time_offset_best_s']:+.2f} s  ({f['bearing_rms_at_offset_0_rad']:.4f} → "
              f"{f['bearing_rms_at_best_offset_rad']:.4f})  {f['sensor_position_best_m']}  "
              + ", ".join(f"{c:+.3f}" for c in f["calibration"]))
    if not args.residuals_only:
        print("\nlocalization on the true landmarks (the floor), whole log, "
              f"{args.particles} particles, seed {args.seed}")
        print("robot  ATE m  pose NEES med  pose<χ²  |  calibrated: ATE m  pose NEES med  pose<χ²")
        for robot, f in results.items():
            a, b = f["floor"], f["floor_calibrated"]
            print(f"{robot:5d}  {a['ate_m']:.3f}  {a['pose_nees_median']:13.1f}  {a['pose_nees_within_chi2_95']:7.2f}"
                  f"  |              {b['ate_m']:.3f}  {b['pose_nees_median']:13.1f}  "
                  f"{b['pose_nees_within_chi2_95']:7.2f}")
        for key, label in (("floor", "plain"), ("floor_calibrated", "calibrated")):
            ate = [f[key]["ate_m"] for f in results.values()]
            print(f"{label}: median ATE {np.median(ate):.3f} m, max {np.max(ate):.3f} m")
    return 0


if __name__ == "__main__":
    sys.exit(main())
