"""The full-trajectory smoother (estimation/landmark_smoother.py) on MRCLAM: its time, its memory, and where it
converges from two starts (the filter's best particle, which `--smooth` uses, and plain dead reckoning).

Run from the repository root:

    .venv/bin/python -m benchmarks.bench_smoother [--data DIR] [--robots 1,2,3,4,5] [--repeats 3]
        [--drift-sigma 0.16] [--drift-tau 10]

Per robot: poses, sightings, the median wall time of `smooth` over the repeats (and of the filter before it, one
run), the peak of Python-visible memory during one `smooth` (tracemalloc: numpy's arrays; SuperLU's factor is
C memory it does not see, so the process's peak RSS is printed too), and the ATE reached from each start. Then,
side by side on the same problem (the repeats interleaved, so the machine's load falls on both alike), the smoother
with a heading-bias state per frame (``HeadingDrift(--drift-sigma rad/m, --drift-tau s)``; σ 0 skips it): the
median times, their ratio, the iterations and the ATE of each.
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
from estimation.landmark_smoother import HeadingDrift, landmarks_from_first_sightings, smooth  # noqa: E402
from estimation.noise_estimation import estimate_noise  # noqa: E402
from runtime.commands.options import non_negative_float, positive_float, positive_int  # noqa: E402

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "mrclam" / "MRCLAM_Dataset2"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--robots", default="1,2,3,4,5")
    parser.add_argument("--repeats", type=positive_int, default=3)
    parser.add_argument("--drift-sigma", type=non_negative_float, default=0.16, metavar="RAD_PER_M",
                        help="the heading drift's stationary σ (rad/m) for the side-by-side timing; 0: none")
    parser.add_argument("--drift-tau", type=positive_float, default=10.0, metavar="S",
                        help="the heading drift's correlation time (s)")
    args = parser.parse_args(argv)
    if not args.data.is_dir():
        print(f"bench_smoother: no data set at {args.data}", file=sys.stderr)
        return 2
    print("robot  poses  sightings  filter s  smooth s (median)  peak numpy MB  ATE from filter  ATE from odometry")
    drift_rows = []
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
        if args.drift_sigma > 0:
            drift_rows.append(_side_by_side(robot, problem, poses, landmarks, start_pose, truth, args))
    print(f"peak RSS of the process: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")
    if drift_rows:
        print(f"\nheading drift σ {args.drift_sigma:g} rad/m, τ {args.drift_tau:g} s, side by side (medians of "
              f"{args.repeats}, interleaved)")
        print("robot  off s  drift s  ratio  iterations off/drift  ATE off  ATE drift")
        for row in drift_rows:
            print(row)
    return 0


def _side_by_side(robot, problem, poses, landmarks, start_pose, truth, args) -> str:
    """One row: the smoother without and with the heading drift on one problem, the repeats interleaved."""
    drift = HeadingDrift(args.drift_sigma, args.drift_tau)
    times: dict[bool, list[float]] = {False: [], True: []}
    solutions = {}
    for _ in range(args.repeats):
        for on in (False, True):
            start = time.perf_counter()
            solutions[on] = smooth(problem, poses, landmarks, heading_drift=drift if on else None)
            times[on].append(time.perf_counter() - start)
    off, on = statistics.median(times[False]), statistics.median(times[True])
    errors = [ate(compose(start_pose, solutions[k].poses[1:]), truth) for k in (False, True)]
    return (f"{robot:5d} {off:6.2f} {on:8.2f} {on / off:6.2f} {solutions[False].iterations:12d}/"
            f"{solutions[True].iterations:<9d} {errors[0]:7.3f} {errors[1]:10.3f}")


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
