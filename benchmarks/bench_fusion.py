"""Speed of map alignment and merging (run by hand: ``.venv/bin/python benchmarks/bench_fusion.py``).

Goals (issue 6): two maps of the paper's size (263 and 364 landmarks) aligned in ≤ 5 ms; two maps of
50,000 landmarks each in ≤ 2 s.  Prints the median of several runs of align (both presets) and merge.
Set OPENBLAS_NUM_THREADS=1 on a loaded machine: OpenBLAS's thread pool makes small matrix products
erratic (tens of ms) when other processes hold the cores.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from fusion_sim import random_pair  # noqa: E402

from fusion import align, merge  # noqa: E402


def _median_ms(fn, repeats: int) -> tuple[float, float, object]:
    """Median wall and CPU (this process) milliseconds of ``fn()``, and its last result."""
    out = fn()                                                      # warm-up
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return 1000.0 * float(np.median(wall)), 1000.0 * float(np.median(cpu)), out


def run(label: str, n_common: int, n1: int, n2: int, repeats: int, goal_ms: float) -> None:
    pose = np.array([12.0, -3.0, 2.2])
    extent = (35.0, 10.0) if n1 < 5000 else (350.0, 100.0)
    map1, map2, _ = random_pair(n_common, n1 - n_common, n2 - n_common, pose, seed=1, extent=extent)
    print(f"{label}: maps of {len(map1)} and {len(map2)} landmarks, {n_common} common")
    for preset in ("paper", "robust"):
        ms, cpu, a = _median_ms(lambda preset=preset: align(map1, map2, preset, np.random.default_rng(0)), repeats)
        err = np.abs(a.pose - pose) if a.found else None
        verdict = "ok" if ms <= goal_ms else "over"
        print(f"  align [{preset:6s}] {ms:9.2f} ms wall, {cpu:9.2f} ms CPU (goal {goal_ms:.0f} ms: {verdict}); "
              f"supports {len(a.supports)}, {a.statistics.iterations} iterations, "
              f"error {np.array2string(err, precision=4)}")
        for method in (1, 2):
            ms_m, cpu_m, g = _median_ms(lambda a=a, method=method: merge(map1, map2, a, method),
                                        max(1, repeats // 2))
            print(f"    merge method {method}: {ms_m:9.2f} ms wall, {cpu_m:9.2f} ms CPU -> {len(g)} landmarks")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skip-large", action="store_true", help="only the paper-size maps")
    args = parser.parse_args()
    run("paper size", 150, 263, 364, repeats=30, goal_ms=5.0)
    if not args.skip_large:
        run("large", 20_000, 50_000, 50_000, repeats=3, goal_ms=2000.0)


if __name__ == "__main__":
    main()
