"""FastSLAM on MRCLAM (real range-bearing data, Vicon truth), per robot, both association modes (prints figures).

    .venv/bin/python -m benchmarks.eval_fastslam_mrclam [--data ../shared/data/mrclam/MRCLAM_Dataset2]
        [--robots 1,2,3,4,5] [--association id,unknown] [--particles 100] [--seed 0] [--until S] [--json]
        [--set FIELD=VALUE ...]

The filter's own evaluation (B1's ``p3at slam dataset`` is the user's command): read with
``estimation.datasets.read_mrclam``; one frame per sighting time; odometry increments between frames; the
noise is estimated from this log against its truth the way a noise-model command would (median absolute
residuals of range and bearing; odometry residual variance per metre and radian over 1 s windows), so no
constant here is tuned to the filter. Field of view and range: the sightings' own extent.

Scores (map in the robot's start frame, mapped to the world through the true start pose): ATE against the
Vicon truth beside dead reckoning; landmarks, duplicates (landmarks beyond one per true landmark they stand
for: the nearest true landmark within 1 m); landmark error; landmark NEES < χ²₃ 95 %; pose NEES median.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

from benchmarks.config_overrides import config_overrides  # noqa: E402
from estimation.datasets import read_mrclam  # noqa: E402
from estimation.fastslam import FastSLAM, range_bearing_config, range_bearing_observations  # noqa: E402
from estimation.geometry import between, compose, wrap_angle  # noqa: E402
from estimation.observations import OdometryIncrement  # noqa: E402
from runtime.commands.options import non_negative_int, positive_float, positive_int  # noqa: E402

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "mrclam" / "MRCLAM_Dataset2"
CHI2_3_95 = 7.815


def estimate_noise(log) -> dict:
    """Range/bearing σ (robust) and odometry variance rates from the log's residuals against its truth."""
    poses = log.true_pose(log.sighting_times)
    truth = log.true_landmarks()
    known = np.array([int(i) in truth for i in log.landmark_ids])
    lm = np.array([truth[int(i)] for i in log.landmark_ids[known]])
    d = lm - poses[known, :2]
    r_res = log.ranges[known] - np.hypot(d[:, 0], d[:, 1])
    b_res = wrap_angle(log.bearings[known] - (np.arctan2(d[:, 1], d[:, 0]) - poses[known, 2]))
    mad = lambda x: 1.4826 * float(np.median(np.abs(x - np.median(x))))  # noqa: E731
    t = np.arange(log.odometry[0, 0], log.odometry[-1, 0], 1.0)
    odo, true = log.odometry_increments(t), between(log.true_pose(t)[:-1], log.true_pose(t)[1:])
    dist, turn = np.hypot(odo[:, 0], odo[:, 1]), np.abs(odo[:, 2])
    res = odo - true
    res[:, 2] = wrap_angle(res[:, 2])
    moving = dist > 0.01
    xy_per_m = float(np.mean(np.sum(res[moving, :2] ** 2, axis=1) / 2 / dist[moving]))
    # heading residual variance split between distance and turn by least squares (non-negative)
    a = np.column_stack([dist, turn])
    coef = np.maximum(np.linalg.lstsq(a, res[:, 2] ** 2, rcond=None)[0], 1e-6)
    range_max = float(np.percentile(log.ranges, 99.5))
    half_fov = float(np.percentile(np.abs(log.bearings), 99.5))
    # detection probability per frame (one frame per sighting time): of the true landmarks well inside the
    # view and range at the true pose, the share the frame reports
    times, first = np.unique(log.sighting_times, return_index=True)
    frame_poses = log.true_pose(times)
    ids = np.array(sorted(truth))
    xy = np.array([truth[i] for i in ids])
    d = xy[None] - frame_poses[:, None, :2]
    rng_, brg = np.hypot(d[..., 0], d[..., 1]), wrap_angle(np.arctan2(d[..., 1], d[..., 0]) - frame_poses[:, 2:3])
    in_view = (rng_ < 0.85 * range_max) & (np.abs(brg) < 0.85 * half_fov)
    frame_of = np.searchsorted(times, log.sighting_times)
    seen = np.zeros_like(in_view)
    col = np.searchsorted(ids, log.landmark_ids)
    valid = (col < len(ids)) & (ids[np.minimum(col, len(ids) - 1)] == log.landmark_ids)
    seen[frame_of[valid], col[valid]] = True
    p_detect = float((seen & in_view).sum() / max(in_view.sum(), 1))
    # false alarms: sightings farther than 5 robust σ from their landmark (misreadings, reflections)
    p_false = float(np.mean((np.abs(r_res) > 5 * mad(r_res)) | (np.abs(b_res) > 5 * mad(b_res))))
    return {"sigma_range": mad(r_res), "sigma_bearing": mad(b_res), "odom_xy_var_per_m": xy_per_m, "p_false": p_false,
            "odom_theta_var_per_m": float(coef[0]), "odom_theta_var_per_rad": float(coef[1]),
            "range_max": range_max, "half_fov": half_fov, "p_detect": p_detect}


def existence_from(noise: dict) -> dict:
    """Existence log-odds from the sensor's detection and false-alarm probabilities: a detection adds
    log(P_D / P_FA), a miss in view log(1 − P_D); a new landmark starts at one detection's worth."""
    hit = float(np.log(noise["p_detect"] / max(noise["p_false"], 1e-3)))
    return {"existence_hit": hit, "existence_initial": hit, "existence_max": 2 * hit,
            "existence_miss": float(np.log1p(-noise["p_detect"])), "existence_remove": -1.4}


def run(log, association: str, particles: int, seed: int, overrides: dict) -> dict:
    noise = estimate_noise(log)
    config = range_bearing_config(
        n_particles=particles, association=association, max_range=noise["range_max"],
        fov_horizontal=2 * noise["half_fov"], odom_xy_var_per_m=noise["odom_xy_var_per_m"],
        odom_theta_var_per_m=noise["odom_theta_var_per_m"], odom_theta_var_per_rad=noise["odom_theta_var_per_rad"],
        max_observations=0, **existence_from(noise))
    config = replace(config, **overrides)
    slam = FastSLAM(config, np.random.default_rng(seed))
    times, first = np.unique(log.sighting_times, return_index=True)
    bounds = np.append(first, len(log.sighting_times))
    # the map's frame is the robot's pose at its first sighting (before it nothing but odometry is known, and
    # a heading error made there would be a gauge no observation can correct); the truth is taken there too
    t0 = float(times[0])
    increments = np.vstack([np.zeros((1, 3)), log.odometry_increments(times)])
    nees, previous = [], t0
    start = log.true_pose([t0])[0]
    for i, t in enumerate(times):
        inc = increments[i]
        slam.predict(OdometryIncrement(*inc, previous, float(t)))
        previous = float(t)
        rows = slice(bounds[i], bounds[i + 1])
        ids = log.landmark_ids[rows] if association == "id" else None
        report = slam.update(range_bearing_observations(log.ranges[rows], log.bearings[rows], noise["sigma_range"],
                                                        noise["sigma_bearing"], timestamp=float(t), ids=ids))
        truth = between(start, log.true_pose([t])[0])
        err = report.pose_mean - truth
        err[2] = wrap_angle(err[2])
        cov = report.pose_covariance
        if np.linalg.cond(cov) < 1e12:
            nees.append(float(err @ np.linalg.solve(cov, err)))
    trajectory = slam.trajectory()[1:]
    truth_world = log.true_pose(trajectory[:, 0])
    est_world = compose(start, trajectory[:, 1:])
    dead = compose(start, between(log.odometry_pose([t0])[0], log.odometry_pose(trajectory[:, 0])))
    ate = float(np.sqrt(np.mean(np.sum((est_world[:, :2] - truth_world[:, :2]) ** 2, axis=1))))
    dr_ate = float(np.sqrt(np.mean(np.sum((dead[:, :2] - truth_world[:, :2]) ** 2, axis=1))))
    landmark_map = slam.best_map(robot=f"robot{log.name}")
    truth = log.true_landmarks()
    ids = np.array(sorted(truth))
    true_xy = np.array([truth[i] for i in ids])
    world_xy = compose(start, np.column_stack([landmark_map.positions[:, :2], np.zeros(len(landmark_map))]))[:, :2]
    if association == "id":
        ext = slam.external_ids(landmark_map.ids)
        nearest = np.array([int(np.flatnonzero(ids == e)[0]) if e in truth else -1 for e in ext])
    else:
        dist = np.linalg.norm(world_xy[:, None] - true_xy[None], axis=2)
        nearest = np.where(dist.min(axis=1) < 1.0, dist.argmin(axis=1), -1)
    ok = nearest >= 0
    err_world = world_xy[ok] - true_xy[nearest[ok]]
    c, s = np.cos(start[2]), np.sin(start[2])
    err_start = np.column_stack([c * err_world[:, 0] + s * err_world[:, 1], -s * err_world[:, 0] + c * err_world[:, 1]])
    cov2 = landmark_map.covariances[ok][:, :2, :2]
    lm_nees = np.einsum("ni,ni->n", err_start, np.linalg.solve(cov2, err_start[..., None])[..., 0])
    n = len(landmark_map)
    return {"robot": log.name, "association": association, "ate_m": ate, "dead_reckoning_ate_m": dr_ate,
            "landmarks": n, "true_landmarks": len(truth),
            "duplicate_fraction": float((ok.sum() - len(np.unique(nearest[ok]))) / n) if n else 0.0,
            "unmatched_landmarks": int((~ok).sum()),
            "landmark_error_median_m": float(np.median(np.linalg.norm(err_world, axis=1))) if ok.any() else None,
            # 2-D NEES against χ²₂? the landmarks are planar: the z row is pinned, so χ²₂ 95 % = 5.991
            "landmark_nees_within_bound": float(np.mean(lm_nees < 5.991)) if ok.any() else None,
            "landmark_nees_median": float(np.median(lm_nees)) if ok.any() else None,
            "pose_nees_median": float(np.median(nees)),
            "pose_nees_within_bound": float(np.mean(np.array(nees) < CHI2_3_95)),
            "stats": vars(slam.stats).copy(), "noise": noise}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(DATA))
    parser.add_argument("--robots", default="1,2,3,4,5")
    parser.add_argument("--association", default="id,unknown")
    parser.add_argument("--particles", type=positive_int, default=100)
    parser.add_argument("--seed", type=non_negative_int, default=0)
    parser.add_argument("--until", type=positive_float, default=None, help="seconds of the log to use (default: all)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    if not Path(args.data).exists():
        print(f"{args.data}: not found (MRCLAM dataset 2 is in ../shared/data/mrclam/)")
        return 2
    rows = []
    for robot in (int(r) for r in args.robots.split(",")):
        log = read_mrclam(args.data, robot, until=args.until)
        for association in args.association.split(","):
            row = run(log, association, args.particles, args.seed, config_overrides(args.set))
            rows.append(row)
            if args.json:
                print(json.dumps(row), flush=True)
            else:
                print(f"| {row['robot']} | {association} | {row['ate_m']:.3f} | {row['dead_reckoning_ate_m']:.3f} | "
                      f"{row['landmarks']} | {100 * row['duplicate_fraction']:.1f} % | "
                      f"{row['landmark_error_median_m']:.3f} | {100 * row['landmark_nees_within_bound']:.0f} % | "
                      f"{row['pose_nees_median']:.1f} | {row['stats']} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
