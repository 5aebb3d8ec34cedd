"""The full-trajectory smoother (estimation/landmark_smoother.py) on MRCLAM: its time, its memory, and where it
converges from two starts (the filter's best particle, which `--smooth` uses, and plain dead reckoning).

Run from the repository root:

    .venv/bin/python -m benchmarks.bench_smoother [--data DIR] [--robots 1,2,3,4,5] [--repeats 3]

Per robot: poses, sightings, the median wall time of `smooth` over the repeats (and of the filter before it, one
run), the peak of Python-visible memory during one `smooth` (tracemalloc: numpy's arrays; SuperLU's factor is
C memory it does not see, so the process's peak RSS is printed too), and the ATE reached from each start.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import resource  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import tracemalloc  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

import estimation.dataset_smoothing as dataset_smoothing  # noqa: E402
from estimation.dataset_slam import run_landmark_log  # noqa: E402
from estimation.datasets import read_mrclam  # noqa: E402
from estimation.fastslam import range_bearing_config  # noqa: E402
from estimation.geometry import compose, dead_reckoning  # noqa: E402
from estimation.landmark_scores import ate  # noqa: E402
from estimation.landmark_smoother import landmarks_from_first_sightings, smooth  # noqa: E402
from estimation.noise_model import estimate_noise  # noqa: E402
from runtime.commands.options import positive_int  # noqa: E402

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "mrclam" / "MRCLAM_Dataset2"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--robots", default="1,2,3,4,5")
    parser.add_argument("--repeats", type=positive_int, default=3)
    args = parser.parse_args(argv)
    if not args.data.is_dir():
        print(f"bench_smoother: no data set at {args.data}", file=sys.stderr)
        return 2
    print("robot  poses  sightings  filter s  smooth s (median)  peak numpy MB  ATE from filter  ATE from odometry")
    for robot in (int(r) for r in args.robots.split(",")):
        log = read_mrclam(args.data, robot)
        start = time.perf_counter()
        run, captured = _smoothed_run(log)
        filter_and_smooth = time.perf_counter() - start
        problem, poses, landmarks = captured["problem"], captured["poses"], captured["landmarks"]
        seconds = []
        for _ in range(args.repeats):
            start = time.perf_counter()
            from_filter = smooth(problem, poses, landmarks)
            seconds.append(time.perf_counter() - start)
        tracemalloc.start()
        smooth(problem, poses, landmarks)
        peak = tracemalloc.get_traced_memory()[1] / 1e6
        tracemalloc.stop()
        odometry = dead_reckoning(problem.increments)
        from_odometry = smooth(problem, odometry, landmarks_from_first_sightings(problem, odometry))
        start_pose = np.array(run.metrics["true_start_pose"])
        truth = run.true_trajectory[:, 1:]
        errors = [ate(compose(start_pose, s.poses[1:]), truth) for s in (from_filter, from_odometry)]
        median = statistics.median(seconds)
        print(f"{robot:5d} {problem.n_poses:6d} {len(problem.ranges):10d} {filter_and_smooth - median:9.1f} "
              f"{median:18.2f} {peak:14.0f} {errors[0]:16.3f} {errors[1]:18.3f}"
              + ("" if from_odometry.converged else " (not converged)"), flush=True)
    print(f"peak RSS of the process: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")
    return 0


def _smoothed_run(log):
    """The run with --smooth, and the problem and starting point it smoothed (as run_landmark_log builds them)."""
    captured = {}

    def capture(problem, poses, landmarks, **kwargs):
        captured.update(problem=problem, poses=poses.copy(), landmarks=landmarks.copy())
        return smooth(problem, poses, landmarks, **kwargs)

    dataset_smoothing.smooth = capture
    try:
        run = run_landmark_log(log, range_bearing_config(n_particles=100), np.random.default_rng(0),
                               noise=estimate_noise([log]).model, association="id", smooth=True)
    finally:
        dataset_smoothing.smooth = smooth
    return run, captured


if __name__ == "__main__":
    sys.exit(main())
