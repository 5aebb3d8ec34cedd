"""Time one match of two 180-point scans, eICP vs ICP vs PL-ICP (goal: eICP <= 2 ms on one core).

    .venv/bin/python benchmarks/bench_scanmatch.py

Uses consecutive scans of the aces log (180 beams) from the reference pose perturbed by (0.2 m, ±5°) when
../shared/data is present, otherwise a synthetic room.  The process is pinned to one CPU and BLAS to one thread;
the best of several repeats is taken per pair, as process CPU time (the build machine is shared, wall time is
noise), and the mean and median over the pairs are reported.  Every match builds its reference curve and k-d
tree: that is its cost in scan-to-scan odometry, where each scan is a reference once.
"""
from __future__ import annotations

import os

for variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(variable, "1")
if hasattr(os, "sched_setaffinity"):   # one core
    os.sched_setaffinity(0, {max(os.sched_getaffinity(0))})

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import timeit  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from estimation.geometry import between, compose  # noqa: E402
from estimation.scanmatch import METHODS, Polyline, laser_scan, match_scans, read_laser_log  # noqa: E402
from estimation.scanmatch.common import apply_pose  # noqa: E402
from estimation.scanmatch.evaluate import perturbed_guesses  # noqa: E402
from estimation.scanmatch.polyline import NearestVertexCache  # noqa: E402

LOG = ROOT / ".." / "shared" / "data" / "laser" / "aces-corrected.log.gz"


def synthetic_pairs(count: int):
    room = np.array([[-3.0, -2.5], [4.0, -2.5], [4.0, 0.5], [2.5, 0.5], [2.5, 3.0], [-3.0, 3.0]])
    edges_a, edges_b = room, np.roll(room, -1, axis=0)

    def ranges(pose):
        bearings = pose[2] + np.linspace(-np.pi / 2, np.pi / 2, 180)
        d = np.column_stack([np.cos(bearings), np.sin(bearings)])
        e, w = edges_b - edges_a, edges_a - pose[:2]
        den = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (w[None, :, 0] * e[None, :, 1] - w[None, :, 1] * e[None, :, 0]) / den
            u = (w[None, :, 0] * d[:, None, 1] - w[None, :, 1] * d[:, None, 0]) / den
        return np.min(np.where((t > 0) & (u >= 0) & (u <= 1), t, np.inf), axis=1)

    rng = np.random.default_rng(0)
    pairs = []
    for _ in range(count):
        a = np.array([rng.uniform(-1, 1), rng.uniform(-1, 0), rng.uniform(-np.pi, np.pi)])
        b = compose(a, [0.3, 0.05, 0.1])
        pairs.append((laser_scan(ranges(a)), laser_scan(ranges(b)), compose(between(a, b), [0.1, -0.1, 0.05])))
    return pairs, "synthetic room (180 beams)"


def log_pairs(count: int):
    readings = read_laser_log(LOG)
    scans = [r.scan() for r in readings]
    poses = np.array([r.pose for r in readings])
    index = [(i, i + 1) for i in np.linspace(0, len(scans) - 2, count).astype(int)]
    guesses = perturbed_guesses(poses, index, 0.2, np.radians(5.0), np.random.default_rng(0))
    return [(scans[i], scans[j], g) for (i, j), g in zip(index, guesses, strict=True)], "aces k=1 (180 beams)"


def main(argv: list[str] | None = None) -> int:
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args(argv)  # no options: --help
    pairs, source = log_pairs(20) if LOG.is_file() else synthetic_pairs(20)
    print(f"scan pairs: {source}, {len(pairs)} pairs, median {np.median([len(b) for _, b, _ in pairs]):.0f} points")
    print(f"one CPU ({sorted(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') else '?'}), "
          f"OPENBLAS_NUM_THREADS={os.environ['OPENBLAS_NUM_THREADS']}; process CPU time, best of 5 per pair")
    print(f"{'method':10s} {'ms/match':>9s} {'median':>7s} {'iterations':>11s} {'ms/iteration':>13s}")
    for method in METHODS:
        repeat = 2 if method == "eicp-mesh" else 5
        times, iterations = [], []
        for reference, current, guess in pairs:
            times.append(min(timeit.repeat(lambda r=reference, c=current, g=guess, m=method: match_scans(r, c, m, g),
                                           number=1, repeat=repeat, timer=time.process_time)))
            iterations.append(match_scans(reference, current, method, guess).iterations)
        ms = 1e3 * np.mean(times)
        print(f"{method:10s} {ms:9.2f} {1e3 * np.median(times):7.2f} {np.mean(iterations):11.1f} "
              f"{ms / np.mean(iterations):13.3f}")
    reference, current, guess = pairs[0]
    curve = Polyline(reference, 0.5)
    moved = apply_pose(guess, current.points)
    warm = NearestVertexCache()
    curve.project(moved, warm)   # what the last iterations see: points that barely moved (no tree query)
    parts = (("polyline build", lambda: Polyline(reference, 0.5)), ("projection", lambda: curve.project(moved)),
             ("projection warm", lambda: curve.project(moved, warm)))
    for name, call in parts:
        best = min(timeit.repeat(call, number=200, repeat=5, timer=time.process_time))
        print(f"{name:15s} {1e3 * best / 200:.3f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
