"""The least-squares solvers' speed on fixed inputs: the landmark smoother (estimation/landmark_smoother.py) and the
camera's self-calibration solve (estimation/camera_calibration.py), here against another checkout of the code.

Run from the repository root:

    .venv/bin/python benchmarks/solver_speed.py [--baseline DIR] [--repeats 5] [--minutes 12]

Each case is one solve on a simulated log made from a fixed seed (a robot wandering among 15 posts for ``--minutes``,
a sighting frame every 0.24 s: about 3000 poses and 8000 sightings at 12 minutes), timed alone in a fresh process
(the log's making and the imports are not timed):

- ``smooth``: :func:`~estimation.landmark_smoother.smooth` (robust solve, outlier cut, solve, covariances) from dead
  reckoning;
- ``smooth-drift``: the same with a heading drift per metre and a slip per radian (5 variables a pose);
- ``self-calibration``: the joint solve of poses, landmarks and the camera's a, b₀, b₁, ψ
  (:func:`~estimation.landmark_smoother.solve_with_outlier_cut` with the calibration as extra unknowns) from the
  smoother's start, then the calibration's covariance and the marginal likelihood's gradient;
- ``self-calibration-tape``: the same with a taped length and the odometry's translation scale (six extra unknowns);
- ``filter-id``: the FastSLAM filter (100 particles, FastSLAM 2.0) over the log as a range-bearing log with known
  landmark ids (:func:`~estimation.dataset_slam.run_landmark_log`, ``association="id"``), what
  :func:`~estimation.camera_calibration.self_calibrate` runs first for its start;
- ``self-calibrate``: :func:`~estimation.camera_calibration.self_calibrate` whole (the filter, the joint solve, the
  outlier cut, the covariance), its bearing σ given 2.5 times too small and the range's and the bearing's variance
  components estimated (``noise_components``), as ``tests/estimation/test_camera_calibration.py`` runs it.

With ``--baseline DIR`` (a checkout of another commit, e.g. ``git worktree add /tmp/base d7e60e8``), every case runs
``--repeats`` times in both, alternately, so that the machine's load falls on both alike; the table gives the
median seconds of each (``--clock``: the timed process's CPU time by default; the wall clock of a shared machine is
mostly the waits for a core: at load 15 in session 50 the wall times were 4-10 times the CPU's, and a 2.1x ratio of
wall medians was 1.08x in CPU time), their ratio, and whether the two solutions agree: the largest relative
difference over every array of the solution (poses, landmarks, covariances, calibration; 0: to the bit) and the
iterations. Without it, the medians of this checkout alone.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
# a timed child process imports the checkout it is told to (this one, or the baseline), not necessarily this file's
CODE = os.environ.get("SOLVER_SPEED_CODE", str(ROOT))
sys.path.insert(0, CODE)

from runtime.commands.options import positive_float, positive_int  # noqa: E402

CASES = ("smooth", "smooth-drift", "self-calibration", "self-calibration-tape", "filter-id", "self-calibrate")
SEED = 3


def _wander(minutes: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(times (n,), true poses (n, 3)) every ``dt`` s: the robot of both simulated runs, turning at 0.25 + 0.4 sin(t/9)
    rad/s and driving at 0.25 + 0.1 sin(t/13) m/s from the origin."""
    n = int(minutes * 60 / dt) + 1
    t = np.arange(n) * dt
    heading = np.concatenate([[0.0], np.cumsum((0.25 + 0.4 * np.sin(t / 9.0))[:-1] * dt)])
    speed = 0.25 + 0.1 * np.sin(t / 13.0)
    x = np.concatenate([[0.0], np.cumsum(speed[:-1] * np.cos(heading[:-1]) * dt)])
    y = np.concatenate([[0.0], np.cumsum(speed[:-1] * np.sin(heading[:-1]) * dt)])
    return t, np.column_stack([x, y, heading])


def _simulated(minutes: float, seed: int = SEED):
    """(problem (raw ranges and bearings, the camera's given calibration the identity), the true range calibration's
    (a, b₀, ψ), true landmarks (15, 2), the sensor): a robot wandering among 15 posts; odometry a random walk of
    variance 0.003 per metre and per radian; the camera reports every post within 0.6-7 m and ±0.55 rad each 0.24 s,
    its range such that −0.08 + 0.97 r is the true one (σ 5 mm + 0.6 %), its bearing 0.01 rad off (σ 0.01 rad)."""
    from estimation.geometry import between, wrap_angle
    from estimation.landmark_smoother import LandmarkLogProblem
    from estimation.noise_model import RangeBearingNoise

    rng = np.random.default_rng(seed)
    dt, every = 0.02, 12
    truth = _wander(minutes, dt)[1][::every]
    steps = between(truth[:-1], truth[1:])
    d = np.hypot(steps[:, 0], steps[:, 1])
    q = 0.003
    measured = steps + rng.normal(0, 1, steps.shape) * np.sqrt(q * np.column_stack([d, d, np.abs(steps[:, 2]) + d]))
    variances = q * np.column_stack([d, d, np.abs(measured[:, 2]) + d]) + 1e-9
    posts = rng.uniform(-5, 5, (15, 2)) + truth[:, :2].mean(axis=0)
    delta = posts[None, :, :] - truth[1:, None, :2]
    r = np.hypot(delta[..., 0], delta[..., 1])
    phi = wrap_angle(np.arctan2(delta[..., 1], delta[..., 0]) - truth[1:, None, 2])
    frame, post = np.nonzero((np.abs(phi) < 0.55) & (r > 0.6) & (r < 7.0))
    sigma_r = 0.005 + 0.006 * r[frame, post]
    a, b0, psi = -0.08, 0.97, 0.01
    ranges = (r[frame, post] + rng.normal(0, 1, len(frame)) * sigma_r - a) / b0
    bearings = phi[frame, post] + rng.normal(0, 0.01, len(frame)) + psi
    sensor = RangeBearingNoise(0.005, 0.006, 0.01, fov_rad=1.2, max_range_m=8.0)
    problem = LandmarkLogProblem(measured, variances, frame + 1, post, ranges, bearings, sensor.range_sigma(ranges),
                                 np.full(len(frame), 0.01), increment_seconds=np.full(len(measured), dt * every))
    return problem, (a, b0, psi), posts, sensor


def _clocks() -> tuple[float, float]:
    """(wall, CPU) clocks now: a case's time is read on both (:func:`_since`)."""
    return time.perf_counter(), time.process_time()


def _since(began: tuple[float, float]) -> tuple[float, float]:
    """(wall seconds, CPU seconds of this process) since :func:`_clocks` gave ``began``."""
    return time.perf_counter() - began[0], time.process_time() - began[1]


def _simulated_log(minutes: float, seed: int = SEED):
    """(a range-bearing log, its noise model) of the same kind of run as :func:`_simulated`, with odometry at 50 Hz
    (the filter's and the self-calibration's input: they make their increments from it): a robot wandering among 15
    posts, its odometry a random walk of variance 0.003 per metre and per radian, the camera's range such that
    −0.08 + 0.97 r is the true one (σ 5 mm + 0.6 %), its bearing 0.01 rad off (σ 0.01 rad), a frame every 0.24 s."""
    from estimation.datasets import RangeBearingLog
    from estimation.geometry import between, dead_reckoning, wrap_angle
    from estimation.noise_model import NoiseModel, OdometryNoise, RangeBearingNoise

    rng = np.random.default_rng(seed)
    dt, every, q = 0.02, 12, 0.003
    t, truth = _wander(minutes, dt)
    n = len(t)
    steps = between(truth[:-1], truth[1:])
    d = np.hypot(steps[:, 0], steps[:, 1])
    steps = steps + rng.normal(0, 1, steps.shape) * np.sqrt(q * np.column_stack([d, d, np.abs(steps[:, 2]) + d]))
    posts = rng.uniform(-5, 5, (15, 2)) + truth[:, :2].mean(axis=0)
    frames = np.arange(0, n, every)
    delta = posts[None, :, :] - truth[frames, None, :2]
    r = np.hypot(delta[..., 0], delta[..., 1])
    phi = wrap_angle(np.arctan2(delta[..., 1], delta[..., 0]) - truth[frames, None, 2])
    frame, post = np.nonzero((np.abs(phi) < 0.55) & (r > 0.6) & (r < 7.0))
    sigma_r = 0.005 + 0.006 * r[frame, post]
    ranges = (r[frame, post] + rng.normal(0, 1, len(frame)) * sigma_r + 0.08) / 0.97
    bearings = phi[frame, post] + rng.normal(0, 0.01, len(frame)) + 0.01
    log = RangeBearingLog("simulated", np.column_stack([t, dead_reckoning(steps)]), t[frames[frame]], ranges,
                          bearings, (post + 1).astype(np.int64))
    model = NoiseModel(OdometryNoise(q, q, q), RangeBearingNoise(0.005, 0.006, 0.01, fov_rad=1.2, max_range_m=8.0))
    return log, model


def _filter_case(case: str, minutes: float) -> dict:
    """One timed run of ``filter-id`` or ``self-calibrate`` (see the module docstring)."""
    import dataclasses

    from estimation.camera_calibration import self_calibrate
    from estimation.dataset_slam import run_landmark_log
    from estimation.fastslam import FastSLAMConfig

    log, model = _simulated_log(minutes)
    if case == "filter-id":
        began = _clocks()
        run = run_landmark_log(log, FastSLAMConfig(), np.random.default_rng(0), noise=model, association="id")
        seconds, cpu = _since(began)
        return {"seconds": seconds, "cpu": cpu, "iterations": len(run.estimated_trajectory),
                "arrays": {"trajectory": run.estimated_trajectory, "positions": run.map.positions,
                           "covariances": run.map.covariances}}
    model = dataclasses.replace(model, range_bearing=dataclasses.replace(model.range_bearing,
                                                                         bearing_sigma_rad=0.01 / 2.5))
    began = _clocks()
    calibration = self_calibrate(log, model, noise_components=("range", "bearing"))
    seconds, cpu = _since(began)
    return {"seconds": seconds, "cpu": cpu, "iterations": calibration.iterations,
            "arrays": {"values": calibration.values, "covariance": calibration.covariance,
                       "map_values": calibration.map_values, "factors": calibration.noise_components.factors,
                       "standard_errors": calibration.noise_components.standard_errors}}


def _start(problem):
    from estimation.geometry import dead_reckoning
    from estimation.landmark_smoother import landmarks_from_first_sightings

    poses = dead_reckoning(problem.increments)
    return poses, landmarks_from_first_sightings(problem, poses)


def _arrays(solution) -> dict[str, np.ndarray]:
    return {k: np.asarray(v, float) for k, v in vars(solution).items()
            if isinstance(v, np.ndarray) and v.dtype.kind in "fb"}


def run_case(case: str, minutes: float) -> dict:
    """One timed solve of ``case`` in this process: {"seconds", "iterations", "arrays": path of an .npz}."""
    from estimation import camera_calibration as cc
    from estimation.landmark_smoother import HeadingDrift, smooth, solve_with_outlier_cut

    if case in ("filter-id", "self-calibrate"):
        return _filter_case(case, minutes)
    problem, _, posts, sensor = _simulated(minutes)
    poses, landmarks = _start(problem)
    if case in ("smooth", "smooth-drift"):
        drift = HeadingDrift(0.05, 20.0, 0.05) if case == "smooth-drift" else None
        began = _clocks()
        solution = smooth(problem, poses, landmarks, heading_drift=drift)
        seconds, cpu = _since(began)
        return {"seconds": seconds, "cpu": cpu, "iterations": solution.iterations, "arrays": _arrays(solution)}
    # the self-calibration's solve: from the plain smoother's solution, as self_calibrate starts from the filter's
    start = smooth(problem, poses, landmarks)
    poses, landmarks = start.poses.copy(), start.landmarks.copy()
    free, given = cc.FREE, np.array([0.0, 1.0, 0.0, 0.0, 0.0])
    lengths, scale = cc._Lengths.of((), np.arange(15)), None
    if case == "self-calibration-tape":
        taped = cc.KnownDistance(0, 1, float(np.hypot(*(posts[0] - posts[1]))), 0.005)
        lengths = cc._Lengths.of((taped,), np.arange(15))
        scale = cc._OdometryScale.of(problem, 1.0)
        free, given = np.append(free, cc.TRANSLATION_SCALE), np.append(given, 1.0)
    shape = cc._Shape(sensor, problem.ranges, problem.bearings, problem.range_sigmas, free, lengths, scale)
    c = given.copy()
    inliers = np.ones(len(problem.ranges), bool)
    began = _clocks()
    iterations, converged = solve_with_outlier_cut(problem, poses, landmarks, inliers, extra=shape, extra_values=c)
    seen = np.zeros(len(landmarks), bool)
    seen[problem.landmark_index[inliers]] = True
    covariance = cc._calibration_covariance(problem, shape, poses, landmarks, c, inliers, seen)
    gradient = cc._log_det_gradient(problem, shape, poses, landmarks, c, inliers, seen, covariance)
    seconds, cpu = _since(began)
    return {"seconds": seconds, "cpu": cpu, "iterations": iterations,
            "arrays": {"poses": poses, "landmarks": landmarks, "values": c, "covariance": covariance,
                       "gradient": gradient, "inliers": inliers.astype(float), "converged": np.array([converged])}}


def _child(case: str, minutes: float, out: Path) -> None:
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    result = run_case(case, minutes)
    np.savez(out, **result.pop("arrays"))
    print(json.dumps(result))


def _in_process(root: Path, case: str, minutes: float, folder: Path, clock: str = "cpu") -> tuple[float, int, dict]:
    """(seconds on ``clock``, iterations, arrays) of one run of ``case`` with the code of checkout ``root``, in a
    fresh process."""
    out = folder / f"{hashlib.sha1(f'{root}{case}'.encode()).hexdigest()[:12]}.npz"
    env = {**os.environ, "SOLVER_SPEED_CODE": str(root), "OPENBLAS_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--child", case, "--minutes", str(minutes),
                           "--child-out", str(out)], env=env, cwd=root, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"{case} in {root}: {done.stderr.strip().splitlines()[-1:]}")
    result = json.loads(done.stdout.strip().splitlines()[-1])
    with np.load(out) as arrays:
        return (result["cpu" if clock == "cpu" else "seconds"], result["iterations"],
                {k: arrays[k].astype(float) for k in arrays.files})


def _largest_difference(a: dict, b: dict) -> float:
    worst = 0.0
    for k in a:
        x, y = a[k], b.get(k)
        if y is None or x.shape != y.shape:
            return float("inf")
        finite = np.isfinite(x) & np.isfinite(y)
        if not np.array_equal(np.isfinite(x), np.isfinite(y)):
            return float("inf")
        if finite.any():
            worst = max(worst, float(np.max(np.abs(x[finite] - y[finite]) / np.maximum(np.abs(x[finite]), 1e-300))))
    return worst


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--baseline", type=Path, metavar="DIR",
                        help="another checkout of the repository to time against (e.g. a git worktree of an older "
                             "commit); default: this checkout alone")
    parser.add_argument("--repeats", type=positive_int, default=5, help="runs of each case in each checkout")
    parser.add_argument("--minutes", type=positive_float, default=12.0, metavar="MINUTES",
                        help="the simulated log's length (minutes of driving; a sighting frame every 0.24 s)")
    parser.add_argument("--cases", default=",".join(CASES), help=f"comma-separated, of {', '.join(CASES)}")
    parser.add_argument("--clock", choices=("cpu", "wall"), default="cpu",
                        help="the seconds compared: the timed process's CPU time (the default: one thread, and on a "
                             "shared machine the wall clock mostly times the waits for a core) or the wall clock")
    parser.add_argument("--child", choices=CASES, help=argparse.SUPPRESS)
    parser.add_argument("--child-out", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        _child(args.child, args.minutes, args.child_out)
        return 0
    cases = [c.strip() for c in args.cases.split(",") if c.strip()]
    unknown = [c for c in cases if c not in CASES]
    if unknown:
        parser.error(f"--cases: no case {unknown[0]!r} (the cases: {', '.join(CASES)})")
    if args.baseline is not None and not (args.baseline / "estimation" / "landmark_smoother.py").is_file():
        parser.error(f"--baseline: {args.baseline} is not a checkout of this repository")
    roots = [ROOT] + ([args.baseline.resolve()] if args.baseline is not None else [])
    print(f"{args.minutes:g}-minute simulated log, {args.repeats} runs of each case per checkout, medians "
          f"({'CPU' if args.clock == 'cpu' else 'wall'} s)")
    header = f"{'case':24s} {'this':>8s}"
    if len(roots) == 2:
        header += f" {'baseline':>9s} {'ratio':>6s}  {'iterations':>10s}  largest relative difference"
    print(header)
    with tempfile.TemporaryDirectory() as folder:
        for case in cases:
            times: dict[Path, list[float]] = {root: [] for root in roots}
            outputs: dict[Path, tuple[int, dict]] = {}
            for _ in range(args.repeats):
                for root in roots:
                    seconds, iterations, arrays = _in_process(root, case, args.minutes, Path(folder), args.clock)
                    times[root].append(seconds)
                    outputs[root] = (iterations, arrays)
            medians = [statistics.median(times[root]) for root in roots]
            line = f"{case:24s} {medians[0]:8.3f}"
            if len(roots) == 2:
                (it_new, new), (it_old, old) = outputs[roots[0]], outputs[roots[1]]
                line += (f" {medians[1]:9.3f} {medians[1] / medians[0]:6.2f}  {it_new:>4d} / {it_old:<4d}  "
                         f"{_largest_difference(old, new):.2g}")
            print(line, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
