"""Where the rendered maps' along-track lag comes from (session 21, L): map scale, odometry, estimate, readings.

Robot 1's rendered runs fall behind the truth along the track (about −0.05 m after 10 m, every seed). This replays
the frames caches of ``benchmarks.eval_slam_rendered`` (3.75 Hz, default run) and prints, per seed and robot:

``map``: the map against the world and the estimate against the truth, as recorded.
  - ``scale``: the similarity (Umeyama, with scale) that best maps the map's landmarks (those within 0.3 m of the true
    point behind their first reading) onto those true points, in the plane, over the first 10 m of the route and over
    the whole map. A front-end scale error (baseline, focal length) would shrink the map: scale < 1.
  - ``odometry``: the synthetic odometry's drawn distance scale (``SyntheticOdometry``, the run's seed) and dead
    reckoning's along-track error. Dead reckoning runs ahead where the scale is > 1.
  - ``estimate``: the along-track error of ``slam.trajectory()`` (the final best particle's ancestry), of the
    per-frame weighted mean (``UpdateReport.pose_mean``) and of the per-frame best particle.
``readings`` (``--filter-seeds K`` filter draws per cache, paired against the recorded readings): the same frames with
  - ``exact``: every reading moved onto the true point behind its left pixel, covariance at the true disparity;
  - ``cov-true``: the readings as recorded, each covariance at the true disparity (session 20's oracle);
  - ``outliers-exact``: only the gross errors (|d − d_true| > 1 px) moved onto their true points;
  - ``beyond-max-depth-exact``: only the readings of points truly beyond the front end's max_depth (12 m) moved onto
    their true points (such a reading passes the depth cut only if it errs short);
  - ``cov-true+outliers-exact``: both of the first two changes;
  - ``perfect-odometry``: the readings as recorded, odometry without error.
``errors``: the recorded readings' disparity error e = d − d_true by true depth: the share of gross errors (|e| > 1 px)
  and how many of them are short (e > 0) or long; the mean of the rest. And whether repeated gross errors are phantoms
  that move along with the robot (``phantom_slopes``).
``synthetic``: a straight 10 m corridor of known features (tests/fastslam/test_along_track_lag.py's scene) with
  unbiased disparity noise and exact odometry: the covariances at the measured against at the true disparity.

Along-track error: negative is behind the truth (``benchmarks.lag_covariance_oracle.along_track``), after 10 m and
its median over the first 10 m of travel. True points: ``StereoRenderer.true_points`` of each reading's left pixel.

Run from the repository root (caches made by eval_slam_rendered --frames-cache DIR):
    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.lag_sources [--section map|readings|synthetic ...]
        [--caches /tmp/S20/cache-head-s{seed}-{robot}] [--seeds 0,1,2,3] [--robots robot1,robot2]
        [--filter-seeds 5] [--json]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

import benchmarks.eval_slam_rendered as esr
import runtime.slam_sim as slam_sim
from benchmarks.lag_covariance_oracle import along_track
from estimation.fastslam import FastSLAM
from estimation.frontend.triangulation import camera_to_base, triangulation_covariances
from estimation.geometry import compose, transform_points
from estimation.observations import StereoObservations
from mocks.synthetic_stereo import OdometryErrorModel, SyntheticOdometry
from runtime.commands.options import positive_int

ROOT = Path(__file__).resolve().parents[1]
CACHES = "/tmp/S20/cache-head-s{seed}-{robot}"
VARIANTS = ("exact", "cov-true", "outliers-exact", "beyond-max-depth-exact", "cov-true+outliers-exact",
            "perfect-odometry")
OUTLIER_PX = 1.0
EXACT_ODOMETRY = OdometryErrorModel(0.0, 0.0, 1e-12, 1e-12, 1e-12)


def _cache_file(pattern: str, seed: int, robot: str) -> Path:
    return Path(pattern.format(seed=seed, robot=robot)) / f"{robot}-seed{seed}-3.75hz-150c-0s-300s.npz"


def _stereo():
    from drivers.videre import calibration
    from mocks.stereo_head.renderer import StereoRenderer
    from mocks.world import World
    from runtime.commands.features import front_end_from_calibration

    world = World.load()
    calib = calibration.load(esr.CALIBRATION)
    config = front_end_from_calibration(calib).config
    return world, StereoRenderer(world, calib), config.geometry, config.noise


def true_readings(path: Path, renderer) -> tuple[np.ndarray, np.ndarray]:
    """The true point behind each cached reading's left pixel: (N,) depth in the left camera, (N, 3) in base_link."""
    with np.load(path) as a:
        t, poses, counts, pixels = a["t"], a["pose"], a["count"], a["pixels"]
    starts = np.concatenate([[0], np.cumsum(counts)])
    depth, base = np.full(len(pixels), np.nan), np.full((len(pixels), 3), np.nan)
    for i in range(len(t)):
        lo, hi = starts[i], starts[i + 1]
        if hi == lo:
            continue
        pose = poses[i]
        truth = renderer.true_points(pose, pixels[lo:hi], "left", rectified=True)
        to_camera = np.linalg.inv(renderer.camera_pose_world(pose, "left", rectified=True))
        depth[lo:hi] = (truth @ to_camera[:3, :3].T + to_camera[:3, 3])[:, 2]
        c, s = np.cos(pose[2]), np.sin(pose[2])
        d = truth - np.array([pose[0], pose[1], 0.0])
        base[lo:hi] = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]])
    return depth, base


class VariantReplay(esr.ReplayObserver):
    """A frames cache replayed with readings changed as ``variant`` says (see the module)."""

    def __init__(self, path: Path, variant: str, depth: np.ndarray, base: np.ndarray, geometry, noise) -> None:
        super().__init__(path)
        self.variant, self.true_depth, self.true_base = variant, depth, base
        self.geometry, self.noise = geometry, noise
        self._to_camera = np.linalg.inv(geometry.left_camera_to_base())

    def observe(self, pose, timestamp: float = 0.0):
        lo, hi = self._starts[self._frame], self._starts[self._frame + 1]
        obs, index = super().observe(pose, timestamp)
        if len(obs) == 0 or self.variant in ("recorded", "perfect-odometry"):
            return obs, index
        g = self.geometry
        fb = g.fx * g.baseline
        points = np.asarray(obs.points, float)
        measured_z = (points @ self._to_camera[:3, :3].T + self._to_camera[:3, 3])[:, 2]
        true_d = fb / self.true_depth[lo:hi]
        ok = np.isfinite(true_d) & (true_d > 0)
        at_truth = camera_to_base(np.zeros((int(ok.sum()), 3)), triangulation_covariances(
            np.asarray(obs.pixels, float)[ok], true_d[ok], g, self.noise), g)[1]
        covariances = np.array(obs.covariances, float)
        move = np.zeros(len(obs), bool)
        if self.variant == "exact":
            move = ok.copy()
        if "outliers-exact" in self.variant:
            move = ok & (np.abs(fb / measured_z - np.where(ok, true_d, 0.0)) > OUTLIER_PX)
        if self.variant == "beyond-max-depth-exact":
            move = ok & (self.true_depth[lo:hi] > self.noise.max_depth)
        if self.variant in ("exact", "cov-true", "cov-true+outliers-exact"):
            covariances[ok] = at_truth
        else:
            covariances[move] = at_truth[move[ok]]
        points[move] = self.true_base[lo:hi][move]
        return StereoObservations(points.astype(obs.points.dtype), covariances.astype(obs.covariances.dtype),
                                  obs.descriptors, obs.pixels, obs.timestamp), index


class _Recording(FastSLAM):
    last: _Recording | None = None

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        _Recording.last = self
        self.reports, self.best_poses = [], []

    def update(self, observations):
        report = super().update(observations)
        self.reports.append(report)
        self.best_poses.append(self.best_pose())
        return report


def _simulate(world, observer, robot: str, seed: int, odometry: OdometryErrorModel | None = None):
    start = np.asarray(world.start_poses[robot], float)
    return slam_sim.simulate(esr._PointWorld(world, observer), start_pose=start,
                             route=esr.keep_right(np.asarray(world.routes[robot], float)), seconds=300.0, seed=seed,
                             config=esr.runtime_config(), robot=robot, frame_rate=3.75, observer=observer,
                             odometry_errors=odometry)


def similarity_2d(source: np.ndarray, target: np.ndarray) -> tuple[float, float]:
    """Umeyama's similarity source → target (K, 2): (scale, rotation in rad)."""
    a, b = source - source.mean(0), target - target.mean(0)
    u, s, vt = np.linalg.svd(b.T @ a / len(a))
    d = np.diag([1.0, np.sign(np.linalg.det(u @ vt))])
    rotation = u @ d @ vt
    return float(np.trace(np.diag(s) @ d) / np.mean(np.sum(a * a, axis=1))), float(np.arctan2(rotation[1, 0],
                                                                                               rotation[0, 0]))


def map_section(world, path: Path, robot: str, seed: int) -> dict:
    """Map scale, odometry and the three estimates of one recorded run."""
    observer = esr.ReplayObserver(path)
    original = slam_sim.FastSLAM
    slam_sim.FastSLAM = _Recording
    try:
        result = _simulate(world, observer, robot, seed)
    finally:
        slam_sim.FastSLAM = original
    slam = _Recording.last
    start = np.asarray(world.start_poses[robot], float)
    truth = result.true_trajectory
    t = truth[1:, 0]
    per_frame = {"weighted_mean": np.array([r.pose_mean for r in slam.reports]), "best_now": np.array(slam.best_poses)}
    out = {"robot": robot, "seed": seed, "ate_m": result.metrics["ate_m"],
           "odometry_distance_scale": SyntheticOdometry(np.random.default_rng(seed).spawn(3)[1]).distance_scale,
           "dead_reckoning": along_track(truth, result.dead_reckoning),
           "trajectory": along_track(truth, result.estimated_trajectory)}
    for name, poses in per_frame.items():
        out[name] = along_track(truth, np.vstack([truth[:1], np.column_stack([t, compose(start, poses)])]))
    created = {}
    for report, index in zip(slam.reports, observer.indices, strict=True):
        for j in np.flatnonzero(report.new_landmark_ids >= 0):
            created[int(report.new_landmark_ids[j])] = int(index[j])
    feature = np.array([created.get(int(i), -1) for i in result.map.ids], np.int64)
    known = feature >= 0
    estimated = transform_points(start, result.map.positions)[known]
    true = observer.points[feature[known]]
    good = np.linalg.norm(estimated - true, axis=1) < 0.3
    first_leg = good & (np.abs(true[:, 0] - start[0]) < 11.0) & (np.abs(true[:, 1] - start[1]) < 3.0)
    for name, keep in (("map_first_10m", first_leg), ("map_all", good)):
        scale, rotation = similarity_2d(estimated[keep, :2], true[keep, :2])
        out[name] = {"landmarks": int(keep.sum()), "scale": scale, "rotation_rad": rotation}
    return out


def readings_section(world, renderer, geometry, noise, path: Path, robot: str, seed: int, filter_seeds: int) -> dict:
    """Along-track error of the recorded readings and of each variant, ``filter_seeds`` filter draws each."""
    depth, base = true_readings(path, renderer)
    out = {"robot": robot, "seed": seed}
    for variant in ("recorded", *VARIANTS):
        rows = []
        for k in range(filter_seeds):
            observer = VariantReplay(path, variant, depth, base, geometry, noise)
            odometry = EXACT_ODOMETRY if variant == "perfect-odometry" else None
            result = _simulate(world, observer, robot, seed + 100 * k, odometry)
            rows.append({"ate_m": result.metrics["ate_m"],
                         **along_track(result.true_trajectory, result.estimated_trajectory)})
        out[variant] = rows
    return out


DEPTH_BANDS = ((0.0, 4.0), (4.0, 6.0), (6.0, 8.0), (8.0, 10.0), (10.0, 12.0), (12.0, np.inf))


def errors_section(renderer, geometry, paths: list[Path]) -> list[dict]:
    """The disparity errors of all the caches' readings by true depth (see the module)."""
    fb = geometry.fx * geometry.baseline
    to_camera = np.linalg.inv(geometry.left_camera_to_base())
    errors, depths = [], []
    for path in paths:
        depth, _ = true_readings(path, renderer)
        with np.load(path) as a:
            measured = (a["points"].astype(float) @ to_camera[:3, :3].T + to_camera[:3, 3])[:, 2]
        errors.append(fb / measured - fb / depth)
        depths.append(depth)
    e, z = np.concatenate(errors), np.concatenate(depths)
    rows = [phantom_slopes(paths, errors, depths)]
    for lo, hi in DEPTH_BANDS:
        band = e[(z >= lo) & (z < hi)]
        gross = np.abs(band) > OUTLIER_PX
        rows.append({"depth_m": [lo, hi], "readings": int(len(band)), "gross_share": float(gross.mean()),
                     "gross_short": int((band > OUTLIER_PX).sum()), "gross_long": int((band < -OUTLIER_PX).sum()),
                     "inlier_mean_px": float(band[~gross].mean()),
                     "inlier_se_px": float(band[~gross].std() / np.sqrt(max(1, (~gross).sum())))})
    return rows


def phantom_slopes(paths: list[Path], errors: list[np.ndarray], depths: list[np.ndarray]) -> dict:
    """How the world position a reading implies (true pose ⊕ reading) moves along the first leg's direction per metre
    the robot travels, fitted per true point: over the short gross readings of points that have ≥ 5 of them (a
    repeated mismatch: 0 for a static point, > 0 for a phantom that moves along with the robot), and over the inlier
    readings of points beyond 6 m."""
    slopes: dict[str, list[float]] = {"gross_short": [], "inlier_far": []}
    for path, e, z in zip(paths, errors, depths, strict=True):
        with np.load(path) as a:
            frame = np.repeat(np.arange(len(a["count"])), a["count"])
            pose, points, index = a["pose"][frame], a["points"].astype(float), a["index"]
        heading = pose[0, 2]
        straight = np.abs(np.angle(np.exp(1j * (pose[:, 2] - heading)))) < 0.15   # the first leg's direction
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        world = pose[:, :2] + np.column_stack([c * points[:, 0] - s * points[:, 1],
                                               s * points[:, 0] + c * points[:, 1]])
        direction = np.array([np.cos(heading), np.sin(heading)])
        along_world, along_robot = world @ direction, pose[:, :2] @ direction
        for name, use in (("gross_short", straight & (e > OUTLIER_PX) & (index >= 0)),
                          ("inlier_far", straight & (np.abs(e) <= OUTLIER_PX) & (z > 6.0) & (index >= 0))):
            for k in np.unique(index[use]):
                sel = use & (index == k)
                if sel.sum() >= 5 and np.ptp(along_robot[sel]) > 0.5:
                    slopes[name].append(float(np.polyfit(along_robot[sel], along_world[sel], 1)[0]))
    return {"phantom_slopes": {k: {"points": len(v), "median": float(np.median(v)) if v else None}
                               for k, v in slopes.items()}}


def synthetic_section(seeds: int) -> dict:
    """The corridor of tests/fastslam/test_along_track_lag.py: along-track error at 10 m per seed."""
    from tests.fastslam.test_along_track_lag import along_track_at_10m

    return {"measured": [along_track_at_10m(s, at_truth=False) for s in range(seeds)],
            "truth": [along_track_at_10m(s, at_truth=True) for s in range(seeds)]}


def _mean_se(values) -> str:
    v = np.asarray([x for x in values if x is not None], float)
    if len(v) < 2:
        return f"{v.mean():+.3f}" if len(v) else "—"
    return f"{v.mean():+.3f} ± {v.std(ddof=1) / np.sqrt(len(v)):.3f}"


def _print(out: dict) -> None:
    if out.get("map"):
        print("## map, odometry, estimate (recorded readings; along-track m at 10 m / median over 0-10 m)")
        print("| run | map scale first 10 m (landmarks) | map scale all | odometry scale | dead reckoning |"
              " trajectory() | weighted mean | best per frame |")
        print("|---|---|---|---|---|---|---|---|")
        for r in out["map"]:
            cells = [f"{r[k]['along_at_10m']:+.3f} / {r[k]['along_median_0_10m']:+.3f}"
                     if r[k]["along_at_10m"] is not None else "—"
                     for k in ("dead_reckoning", "trajectory", "weighted_mean", "best_now")]
            print(f"| {r['robot']} s{r['seed']} | {r['map_first_10m']['scale']:.4f} ({r['map_first_10m']['landmarks']})"
                  f" | {r['map_all']['scale']:.4f} | {r['odometry_distance_scale']:.3f} | " + " | ".join(cells) + " |")
    if out.get("readings"):
        print("\n## readings (mean ± s.e. over the filter draws of all seeds; paired difference to recorded)")
        for robot in sorted({r["robot"] for r in out["readings"]}):
            runs = [r for r in out["readings"] if r["robot"] == robot]
            print(f"\n{robot}, seeds {[r['seed'] for r in runs]}:")
            print("| readings | along at 10 m | minus recorded | median 0-10 m | ATE median |")
            print("|---|---|---|---|---|")
            for variant in ("recorded", *VARIANTS):
                rows = [(x, b) for r in runs for x, b in zip(r[variant], r["recorded"], strict=True)]
                at10 = [x["along_at_10m"] for x, _ in rows]
                diff = [x["along_at_10m"] - b["along_at_10m"] for x, b in rows
                        if x["along_at_10m"] is not None and b["along_at_10m"] is not None]
                print(f"| {variant} | {_mean_se(at10)} | {_mean_se(diff) if variant != 'recorded' else '—'} | "
                      f"{_mean_se([x['along_median_0_10m'] for x, _ in rows])} | "
                      f"{np.median([x['ate_m'] for x, _ in rows]):.3f} |")
    if out.get("errors"):
        print("\n## disparity errors of the recorded readings (e = d - d_true px; e > 0: short), by true depth")
        print("| true depth (m) | readings | gross (abs(e) > 1 px) | short : long | mean of the rest (px) |")
        print("|---|---|---|---|---|")
        for r in out["errors"][1:]:
            lo, hi = r["depth_m"]
            print(f"| {lo:g}-{hi:g} | {r['readings']} | {100 * r['gross_share']:.1f} % | {r['gross_short']} : "
                  f"{r['gross_long']} | {r['inlier_mean_px']:+.4f} ± {r['inlier_se_px']:.4f} |")
        slopes = out["errors"][0]["phantom_slopes"]
        print("\nImplied world position along the first leg per metre of travel, median over points: "
              f"repeated short gross errors {slopes['gross_short']['median']:+.3f} ({slopes['gross_short']['points']} "
              f"points), far inliers {slopes['inlier_far']['median']:+.3f} ({slopes['inlier_far']['points']} points)")
    if out.get("synthetic"):
        s = out["synthetic"]
        print("\n## synthetic corridor, 10 m, exact odometry: along-track at 10 m, mean ± s.e. (per seed)")
        for k, name in (("measured", "measured"), ("truth", "true")):
            per_seed = " ".join(f"{v:+.3f}" for v in s[k])
            print(f"- covariance at the {name} disparity: {_mean_se(s[k])} m ({per_seed})")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--section", action="append", choices=("map", "readings", "errors", "synthetic"), default=[])
    parser.add_argument("--caches", default=CACHES, help="cache directory pattern with {seed} and {robot}")
    parser.add_argument("--seeds", default="0,1,2,3")
    parser.add_argument("--robots", default="robot1,robot2")
    parser.add_argument("--filter-seeds", type=positive_int, default=5,
                        help="filter draws per cache in the readings section")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    sections = args.section or ["map", "readings", "errors", "synthetic"]
    seeds = [int(s) for s in args.seeds.split(",")]
    robots = args.robots.split(",")
    out: dict = {"map": [], "readings": []}
    world = renderer = geometry = noise = None
    if {"map", "readings", "errors"} & set(sections):
        world, renderer, geometry, noise = _stereo()
    for robot in robots:
        for seed in seeds:
            path = _cache_file(args.caches, seed, robot)
            if not path.exists():
                raise SystemExit(f"{path}: no frames cache (make it with eval_slam_rendered --frames-cache)")
            if "map" in sections:
                out["map"].append(map_section(world, path, robot, seed))
            if "readings" in sections:
                out["readings"].append(readings_section(world, renderer, geometry, noise, path, robot, seed,
                                                        args.filter_seeds))
    if "errors" in sections:
        out["errors"] = errors_section(renderer, geometry, [_cache_file(args.caches, seed, robot)
                                                            for robot in robots for seed in seeds])
    if "synthetic" in sections:
        out["synthetic"] = synthetic_section(8)
    if args.json:
        print(json.dumps(out))
    else:
        _print(out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
