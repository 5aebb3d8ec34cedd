"""Time per FastSLAM update as particles (10–500) and map size (up to 10,000 landmarks) grow.

Workload: landmarks scattered at 1 per m² of floor (0.3–2.4 m high) over a square sized to the map, every
particle starting from the same prior map (``FastSLAM.load_prior_map``); the robot creeps across the middle
and each frame sees 50 of the landmarks in its stereo field of view (noisy, with noisy descriptors), after a
small odometry increment. One core (set OMP/BLAS threads to 1 before numpy loads).

Side by side, in the same run, the same workload through ``TextbookFastSLAM``: a plain per-particle,
per-observation Python loop in the way textbook implementations (PythonRobotics' fast_slam1.py) write it,
with each particle's map its own arrays (deep-copied on resampling), association by scanning the particle's
whole map (numpy over landmarks, Python over particles and observations).

    .venv/bin/python benchmarks/bench_fastslam.py            # full table (a few minutes)
    .venv/bin/python benchmarks/bench_fastslam.py --quick    # smaller sweep
    .venv/bin/python benchmarks/bench_fastslam.py --accuracy # the simulated runs' accuracy table instead
    .venv/bin/python benchmarks/bench_fastslam.py --nees     # pose NEES by time window on robot1's route
"""
from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from estimation.fastslam import FastSLAM, FastSLAMConfig, low_variance_resample, normalise_log_weights  # noqa: E402
from estimation.fastslam.config import _HFOV  # noqa: E402
from estimation.fastslam.motion import increment_variance, sample_motion  # noqa: E402
from estimation.geometry import compose, rot_z  # noqa: E402
from estimation.landmark_map import LandmarkMap  # noqa: E402
from estimation.observations import OdometryIncrement, StereoObservations  # noqa: E402
from runtime.commands.options import positive_int  # noqa: E402

N_OBS = 50


def make_world(n_landmarks: int, rng: np.random.Generator):
    side = np.sqrt(n_landmarks)  # 1 landmark per m²
    pos = np.column_stack([rng.uniform(-side / 2, side / 2, (n_landmarks, 2)), rng.uniform(0.3, 2.4, n_landmarks)])
    desc = rng.standard_normal((n_landmarks, 64))
    desc = (desc / np.linalg.norm(desc, axis=1, keepdims=True)).astype(np.float32)
    cov = np.tile(np.eye(3) * 0.05**2, (n_landmarks, 1, 1))
    return LandmarkMap(pos, cov, desc, counts=np.full(n_landmarks, 5)), pos, desc


def observe(pose, pos, desc, rng):
    """50 landmarks in the field of view of ``pose`` as base_link observations (σ 3 cm, descriptor noise)."""
    local = (pos - [pose[0], pose[1], 0.0]) @ rot_z(pose[2])
    rel = local - [0.12, 0.0, 0.5]
    depth = rel[:, 0]
    ok = (depth > 0.5) & (depth < 12.0) & (np.abs(np.arctan2(rel[:, 1], depth)) < 0.45 * _HFOV)
    ok &= np.abs(np.arctan2(rel[:, 2], np.maximum(depth, 1e-9))) < 0.4
    idx = np.flatnonzero(ok)
    idx = rng.choice(idx, min(N_OBS, len(idx)), replace=False)
    sigma = 0.03
    points = local[idx] + rng.normal(0, sigma, (len(idx), 3))
    d = desc[idx] + rng.normal(0, 0.02, (len(idx), desc.shape[1]))
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    return StereoObservations(points, np.tile(np.eye(3) * sigma**2, (len(idx), 1, 1)), d)


def frames(pos, desc, n_frames: int, seed: int):
    """(increment, observations) pairs of a robot creeping along +x through the middle of the field."""
    rng = np.random.default_rng(seed)
    pose = np.array([-3.0, 0.0, 0.0])
    out = []
    for _ in range(n_frames):
        step = np.array([0.05, 0.0, 0.002])
        pose = compose(pose, step)
        out.append((OdometryIncrement(*(step * 1.02)), observe(pose, pos, desc, rng)))
    return out, np.array([-3.0, 0.0, 0.0])


class TextbookFastSLAM:
    """Reference: FastSLAM 1.0 the textbook way — Python loops over particles and observations, per-particle
    map arrays scanned whole for association, maps deep-copied on resampling. Same models and gates."""

    def __init__(self, config: FastSLAMConfig, rng: np.random.Generator, initial_pose) -> None:
        self.config, self.rng = config, rng
        m = config.n_particles
        self.poses = np.tile(np.asarray(initial_pose, float), (m, 1))
        self.log_weights = np.zeros(m)
        self.maps = [dict(mean=np.zeros((0, 3)), cov=np.zeros((0, 3, 3)), desc=np.zeros((0, 64), np.float32))
                     for _ in range(m)]

    def load_prior_map(self, landmark_map: LandmarkMap) -> None:
        for particle_map in self.maps:
            particle_map.update(mean=landmark_map.positions.copy(), cov=landmark_map.covariances.copy(),
                                desc=landmark_map.descriptors.copy())

    def predict(self, increment: OdometryIncrement) -> None:
        var = increment_variance(increment.delta, self.config)
        for m in range(len(self.poses)):
            self.poses[m] = sample_motion(self.poses[m:m + 1], increment.delta, var, self.rng)[0]

    def update(self, obs: StereoObservations) -> None:
        cfg = self.config
        q_all = obs.covariances + cfg.observation_var_floor * np.eye(3)
        for m in range(len(self.poses)):
            x, y, th = self.poses[m]
            rot = rot_z(th)
            t = np.array([x, y, 0.0])
            lm = self.maps[m]
            used = set()
            new_mean, new_cov, new_desc = [], [], []
            for j in range(len(obs)):
                z, q = obs.points[j], q_all[j]
                dd = np.linalg.norm(lm["desc"] - obs.descriptors[j], axis=1)
                best, best_d2 = -1, cfg.mahalanobis_gate
                for i in np.flatnonzero(dd < cfg.descriptor_threshold):
                    if i in used:
                        continue
                    z_hat = rot.T @ (lm["mean"][i] - t)
                    s = rot.T @ lm["cov"][i] @ rot + q
                    v = z - z_hat
                    d2 = v @ np.linalg.solve(s, v)
                    if d2 < best_d2:
                        best, best_d2 = i, d2
                if best < 0:
                    new_mean.append(rot @ z + t)
                    new_cov.append(rot @ q @ rot.T)
                    new_desc.append(obs.descriptors[j])
                    self.log_weights[m] -= 0.5 * cfg.mahalanobis_gate
                    continue
                used.add(best)
                sigma = lm["cov"][best]
                s = rot.T @ sigma @ rot + q
                k = sigma @ rot @ np.linalg.inv(s)
                lm["mean"][best] = lm["mean"][best] + k @ (z - rot.T @ (lm["mean"][best] - t))
                ikh = np.eye(3) - k @ rot.T
                lm["cov"][best] = ikh @ sigma @ ikh.T + k @ q @ k.T
                self.log_weights[m] -= 0.5 * best_d2
            if new_mean:
                lm["mean"] = np.vstack([lm["mean"], new_mean])
                lm["cov"] = np.concatenate([lm["cov"], np.array(new_cov)])
                lm["desc"] = np.vstack([lm["desc"], np.array(new_desc, np.float32)])
        w = normalise_log_weights(self.log_weights)
        if 1.0 / np.sum(w * w) < cfg.resample_threshold * len(w):
            idx = low_variance_resample(w, self.rng)
            self.poses = self.poses[idx]
            self.maps = [{k: v.copy() for k, v in self.maps[i].items()} for i in idx]
            self.log_weights = np.zeros(len(w))


def time_updates(cls, n_particles: int, n_landmarks: int, n_frames: int, version: int = 1) -> float:
    """Median CPU time (ms) of predict + update over ``n_frames`` frames (after one warm-up frame).

    Process CPU time rather than wall time, so that other work on a shared machine does not inflate it.
    """
    rng = np.random.default_rng(0)
    prior, pos, desc = make_world(n_landmarks, rng)
    workload, start = frames(pos, desc, n_frames + 1, seed=1)
    slam = cls(FastSLAMConfig(n_particles=n_particles, version=version), np.random.default_rng(2), start)
    slam.load_prior_map(prior)
    times = []
    for increment, obs in workload:
        t0 = time.process_time()
        slam.predict(increment)
        slam.update(obs)
        times.append(time.process_time() - t0)
    return 1e3 * float(np.median(times[1:]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a smaller sweep")
    parser.add_argument("--accuracy", action="store_true", help="print the simulated runs' accuracy table")
    parser.add_argument("--seeds", type=positive_int, default=3, help="seeds per configuration for --accuracy (3)")
    parser.add_argument("--nees", action="store_true", help="print pose NEES by time window (robot1, seed 0)")
    args = parser.parse_args()
    if args.nees:
        nees_windows()
        return
    if args.accuracy:
        accuracy_table(args.seeds)
        return
    particles = [10, 100, 500] if args.quick else [10, 50, 100, 200, 500]
    sizes = [1000, 10000] if args.quick else [100, 1000, 3000, 10000]
    n_frames = 10 if args.quick else 20
    print(f"FastSLAM predict+update CPU time, median of {n_frames} frames, {N_OBS} observations per frame, one thread")
    print(f"{'particles':>9} {'landmarks':>9} {'1.0 ms':>8} {'2.0 ms':>8}")
    for m in particles:
        for n in sizes:
            v1 = time_updates(FastSLAM, m, n, n_frames, 1)
            v2 = time_updates(FastSLAM, m, n, n_frames, 2)
            print(f"{m:>9} {n:>9} {v1:>8.2f} {v2:>8.2f}", flush=True)
    print("\nSame workload, FastSLAM 1.0: vectorised vs the per-particle Python loop (textbook)")
    print(f"{'particles':>9} {'landmarks':>9} {'vectorised ms':>14} {'python loop ms':>15} {'ratio':>7}")
    for m, n in ([(10, 1000), (100, 1000)] if args.quick else [(10, 1000), (100, 1000), (100, 10000)]):
        fast = time_updates(FastSLAM, m, n, 5, 1)
        slow = time_updates(TextbookFastSLAM, m, n, 3, 1)
        print(f"{m:>9} {n:>9} {fast:>14.2f} {slow:>15.1f} {slow / fast:>7.0f}x", flush=True)


def accuracy_table(n_seeds: int) -> None:
    """Markdown table: both default routes of the building, FastSLAM 1.0 and 2.0, 100 particles, seeds 0..n-1
    (the same runs as ``p3at slam simulate --name R --seed S --fastslam V``), means over seeds; with the
    exported map's consistency (``benchmarks/slam_consistency.py``): duplicate fraction, landmark NEES."""
    import sys
    from pathlib import Path

    from mocks.synthetic_stereo import SyntheticStereo
    from mocks.world import World

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from slam_consistency import run_scored

    world = World.load()
    keys = ["ate_m", "dead_reckoning_ate_m", "final_position_error_m", "dead_reckoning_final_position_error_m",
            "landmark_median_error_m", "landmark_rms_error_m", "landmarks", "duplicate_fraction",
            "pose_nees_median", "pose_nees_within_chi2_95", "landmark_nees_median", "landmark_nees_within_bound"]
    print("| robot | FastSLAM | ATE (m) | dead-reckoning ATE (m) | final error (m) | dead-reckoning final (m) | "
          "landmark median / RMS error (m) | landmarks | duplicates | pose NEES median / < χ²₃ 95 % | "
          "landmark NEES median / < χ²₃ 95 % |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for robot in sorted(world.routes):
        for version in (1, 2):
            runs = []
            for seed in range(n_seeds):
                observer = SyntheticStereo.from_world(world, np.random.default_rng(seed).spawn(3)[0])  # as simulate
                runs.append(run_scored(world, robot=robot, seed=seed, observer=observer, route=world.routes[robot],
                                       seconds=300, config=FastSLAMConfig(n_particles=100, version=version)))
            m = {k: float(np.mean([r[k] for r in runs])) for k in keys}
            print(f"| {robot} | {version}.0 | {m['ate_m']:.3f} | {m['dead_reckoning_ate_m']:.3f} | "
                  f"{m['final_position_error_m']:.3f} | {m['dead_reckoning_final_position_error_m']:.3f} | "
                  f"{m['landmark_median_error_m']:.3f} / {m['landmark_rms_error_m']:.3f} | {m['landmarks']:.0f} | "
                  f"{100 * m['duplicate_fraction']:.1f} % | {m['pose_nees_median']:.0f} / "
                  f"{100 * m['pose_nees_within_chi2_95']:.0f} % | {m['landmark_nees_median']:.1f} / "
                  f"{100 * m['landmark_nees_within_bound']:.0f} % |", flush=True)


def nees_windows() -> None:
    """Markdown table: median pose NEES and χ²₃(95 %) coverage by time window, robot1's route, seed 0."""
    from mocks.world import World
    from runtime.slam_sim import simulate

    world = World.load()
    windows = [(0, 5), (5, 10), (10, 20), (20, 40), (40, 80)]
    print("| FastSLAM | " + " | ".join(f"{a}–{b} s" for a, b in windows) + " |")
    print("|---|" + "---|" * len(windows))
    for version in (1, 2):
        nees = simulate(world, start_pose=world.start_poses["robot1"], route=world.routes["robot1"], seconds=300,
                        seed=0, config=FastSLAMConfig(n_particles=100, version=version)).pose_nees
        cells = []
        for a, b in windows:
            sel = nees[(nees[:, 0] >= a) & (nees[:, 0] < b), 1]
            cells.append(f"{np.median(sel):.1f} ({100 * np.mean(sel < 7.815):.0f} %)" if len(sel) else "–")
        print(f"| {version}.0 | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
