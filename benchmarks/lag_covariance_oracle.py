"""The along-track lag of rendered FastSLAM runs with the readings' covariances at the measured or the TRUE disparity.

The front end evaluates each reading's covariance at its own measured disparity (σ along the ray ∝ 1/d², weight ∝ d⁴),
so a reading that errs short weighs more and the fused landmark is short by ≈ 3σ_d²/d² (docs/fastslam-history.md,
"Session 20 ... (S)"). This replays a frames cache of ``benchmarks.eval_slam_rendered`` twice: as recorded ("measured"),
and with every reading's covariance recomputed by the front end's own ``triangulation_covariances`` at the true
disparity fB/Z of the renderer's point behind its pixel ("oracle": an upper bound on what a covariance at the predicted
point could give). It prints ATE and the signed error of the estimate along the direction of travel (negative: behind
the truth) after 3, 5, 8 and 10 m of travel and its median over the first 10 m.

Run from the repository root (caches made by eval_slam_rendered --frames-cache DIR, 3.75 Hz, default run):
    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.lag_covariance_oracle --cache DIR --robot robot1 --seed 0
        [--capped] [--json]
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
from estimation.fastslam import FastSLAMConfig
from estimation.frontend.triangulation import camera_to_base, triangulation_covariances
from estimation.observations import StereoObservations
from runtime.commands.options import non_negative_int

ROOT = Path(__file__).resolve().parents[1]
DISTANCES_M = (3.0, 5.0, 8.0, 10.0)


def oracle_observer(cache: Path, renderer, geometry, noise):
    """A ReplayObserver of ``cache`` whose readings carry covariances at the true disparity."""
    fb = geometry.fx * geometry.baseline

    class OracleReplay(esr.ReplayObserver):
        def observe(self, pose, timestamp: float = 0.0):
            obs, index = super().observe(pose, timestamp)
            if len(obs) == 0:
                return obs, index
            pose = np.asarray(pose, float)
            truth = renderer.true_points(pose, obs.pixels, "left", rectified=True)
            to_camera = np.linalg.inv(renderer.camera_pose_world(pose, "left", rectified=True))
            z = (truth @ to_camera[:3, :3].T + to_camera[:3, 3])[:, 2]
            ok = np.isfinite(z) & (z > 0)
            cov = np.array(obs.covariances, copy=True)
            if ok.any():
                camera = triangulation_covariances(np.asarray(obs.pixels, float)[ok], fb / z[ok], geometry, noise)
                cov[ok] = camera_to_base(np.zeros((int(ok.sum()), 3)), camera, geometry)[1].astype(cov.dtype)
            return StereoObservations(obs.points, cov, obs.descriptors, obs.pixels, obs.timestamp), index

    return OracleReplay(cache)


def along_track(true_trajectory: np.ndarray, estimated: np.ndarray) -> dict:
    """Signed error of the estimate along the true direction of travel (m) at DISTANCES_M and its median over 10 m."""
    n = min(len(true_trajectory), len(estimated))
    tt, et = true_trajectory[:n], estimated[:n]
    if not np.allclose(tt[:, 0], et[:, 0]):
        raise ValueError("the true and estimated trajectories are not at the same times")
    velocity = np.gradient(tt[:, 1:3], axis=0)
    speed = np.linalg.norm(velocity, axis=1)
    along = np.einsum("ij,ij->i", et[:, 1:3] - tt[:, 1:3], velocity / np.maximum(speed, 1e-12)[:, None])
    moving = speed > 1e-4
    travelled = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(tt[:, 1:3], axis=0), axis=1))])
    out = {}
    for d in DISTANCES_M:
        k = np.flatnonzero(moving & (travelled >= d))
        out[f"along_at_{d:g}m"] = float(along[k[0]]) if len(k) else None
    first = moving & (travelled < 10.0)
    out["along_median_0_10m"] = float(np.median(along[first])) if first.any() else None
    return out


def run(cache_dir: Path, robot: str, seed: int, capped: bool) -> dict:
    from drivers.videre import calibration
    from mocks.stereo_head.renderer import StereoRenderer
    from mocks.world import World
    from runtime.commands.features import front_end_from_calibration

    world = World.load()
    calib = calibration.load(ROOT / "mocks" / "stereo_head" / "data" / "sth_mdcs2_default.ini")
    renderer = StereoRenderer(world, calib)
    front_end = front_end_from_calibration(calib)
    config = FastSLAMConfig(n_particles=100, max_observations=40) if capped else esr.runtime_config()
    results = {}
    for mode in ("measured", "oracle"):
        observer, route, start = esr.replay_default_run(world, robot, seed, 3.75, cache_dir)
        if mode == "oracle":
            observer = oracle_observer(cache_dir / f"{robot}-seed{seed}-3.75hz-150c-0s-300s.npz", renderer,
                                       front_end.config.geometry, front_end.config.noise)
        result = slam_sim.simulate(esr._PointWorld(world, observer), start_pose=start, route=route, seconds=300.0,
                                   seed=seed, config=config, robot=robot, frame_rate=3.75, observer=observer)
        results[mode] = {"ate_m": result.metrics["ate_m"],
                         **along_track(result.true_trajectory, result.estimated_trajectory)}
    return {"robot": robot, "seed": seed, "capped": capped, **results}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cache", type=Path, required=True, help="eval_slam_rendered's --frames-cache directory")
    parser.add_argument("--robot", default="robot1")
    parser.add_argument("--seed", type=non_negative_int, default=0)
    parser.add_argument("--capped", action="store_true", help="FastSLAMConfig's cap of 40 readings a frame")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    out = run(args.cache, args.robot, args.seed, args.capped)
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"{out['robot']} seed {out['seed']} ({'capped' if out['capped'] else 'uncapped'})")
    for mode in ("measured", "oracle"):
        r = out[mode]
        cells = "  ".join(f"{k[len('along_'):]} {v:+.3f}" for k, v in r.items()
                          if k.startswith("along") and v is not None)
        print(f"  {mode:>8}: ATE {r['ate_m']:.3f} m  along-track (m): {cells}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
