"""Speed of map alignment and merging (run by hand: ``.venv/bin/python benchmarks/bench_fusion.py``).

Goals (issue 6): two maps of the paper's size (263 and 364 landmarks) aligned in ≤ 5 ms; two maps of
50,000 landmarks each in ≤ 2 s.  Prints the median of several runs of align (both presets) and merge, wall and CPU time;
the goal's verdict is on the CPU time, which the machine's other load does not count.
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
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

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
        verdict = "ok" if cpu <= goal_ms else "over"   # on CPU: the wall time of a shared machine counts its load
        print(f"  align [{preset:6s}] {ms:9.2f} ms wall, {cpu:9.2f} ms CPU (goal {goal_ms:.0f} ms CPU: {verdict}); "
              f"supports {len(a.supports)}, {a.statistics.iterations} iterations, "
              f"error {np.array2string(err, precision=4)}")
        for method in (1, 2):
            ms_m, cpu_m, g = _median_ms(lambda a=a, method=method: merge(map1, map2, a, method),
                                        max(1, repeats // 2))
            print(f"    merge method {method}: {ms_m:9.2f} ms wall, {cpu_m:9.2f} ms CPU -> {len(g)} landmarks")


def _demo_maps(folder: Path | None) -> dict:
    """The rendered demo's maps (``p3at demo --out DIR``: robot*.npz), or a random pair of its size."""
    from estimation.errors import MapFileError
    from estimation.landmark_map import LandmarkMap

    files = sorted(folder.glob("robot*.npz")) if folder is not None else []
    if len(files) >= 2:
        return {f.stem: LandmarkMap.load(f) for f in files}
    if folder is not None:   # a folder given is what to measure: not silently a random pair instead
        raise MapFileError(f"{folder}: holds {len(files)} robot*.npz map file(s), not the two or more of a demo's "
                           "--out folder")
    map1, map2, _ = random_pair(250, 800, 800, np.array([12.0, -3.0, 2.2]), seed=1)
    return {"robot1": map1, "robot2": map2}


def demo_align(folder: Path, repeats: int) -> None:
    """align on the rendered demo's first two maps (real maps: walls, a building's half turn, repeated corners)."""
    maps = _demo_maps(folder)
    (name1, map1), (name2, map2) = sorted(maps.items())[:2]
    print(f"demo maps {name1} + {name2} ({len(map1)} + {len(map2)} landmarks, {folder}):")
    for preset in ("paper", "robust"):
        ms, cpu, a = _median_ms(lambda preset=preset: align(map1, map2, preset, np.random.default_rng(0)), repeats)
        print(f"  align [{preset:6s}] {ms:9.2f} ms wall, {cpu:9.2f} ms CPU; found {a.found}, "
              f"supports {len(a.supports)}, {a.statistics.iterations} iterations")


def repeated_fusion(folder: Path | None, repeats: int) -> None:
    """A mission fuses its maps every few seconds, mostly unchanged: ``fuse_maps`` without and with the cache."""
    from fusion import AlignmentCache
    from runtime.fusion_report import fuse_maps

    maps = _demo_maps(folder)
    sizes = " and ".join(str(len(m)) for m in maps.values())
    print(f"repeated fusion of unchanged maps ({sizes} landmarks{', ' + str(folder) if folder else ', random'}):")
    seed = iter(range(10_000))
    fresh = _median_ms(lambda: fuse_maps(maps, rng=np.random.default_rng(next(seed))), repeats)
    cache = AlignmentCache()
    cached = _median_ms(lambda: fuse_maps(maps, rng=np.random.default_rng(next(seed)), cache=cache), repeats)
    print(f"  fuse_maps without cache {fresh[0]:9.2f} ms wall, {fresh[1]:9.2f} ms CPU")
    print(f"  fuse_maps with cache    {cached[0]:9.2f} ms wall, {cached[1]:9.2f} ms CPU "
          f"(ratio {fresh[0] / max(cached[0], 1e-9):.0f}x wall; pair hits {cache.hits}, misses {cache.misses})")
    # one map changes between fusions (a landmark fewer each time): its pairs are aligned again, the other
    # maps' self-structure comes from the cache
    last = sorted(maps)[-1]
    drop = iter(range(len(maps[last])))

    def one_changed():
        rows = np.arange(len(maps[last])) != next(drop)
        smaller = maps[last].subset(rows)
        if "external_ids" in smaller.metadata:           # subset() keeps the metadata as it is
            smaller.metadata["external_ids"] = list(np.asarray(smaller.metadata["external_ids"])[rows])
        return fuse_maps({**maps, last: smaller}, rng=np.random.default_rng(next(seed)), cache=cache)

    changed = _median_ms(one_changed, repeats)
    print(f"  one map changed, cache  {changed[0]:9.2f} ms wall, {changed[1]:9.2f} ms CPU "
          f"(self-structure hits {cache.self_hits}, misses {cache.self_misses})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skip-large", action="store_true", help="only the paper-size maps")
    parser.add_argument("--only-repeated", action="store_true", help="only the repeated-fusion (cache) figures")
    parser.add_argument("--demo-maps", type=Path, help="folder of a rendered demo's robot*.npz: align on its first "
                        "two maps, and the repeated fusion (default: a random pair of the demo's size)")
    args = parser.parse_args()
    if not args.only_repeated:
        run("paper size", 150, 263, 364, repeats=30, goal_ms=5.0)
        if not args.skip_large:
            run("large", 20_000, 50_000, 50_000, repeats=3, goal_ms=2000.0)
        if args.demo_maps is not None:
            demo_align(args.demo_maps, repeats=5)
    repeated_fusion(args.demo_maps, repeats=5)


if __name__ == "__main__":
    from estimation.errors import MapFileError

    try:
        main()
    except MapFileError as e:   # a map file of a given folder missing or unreadable: one line naming it
        print(f"{Path(__file__).name}: {e}", file=sys.stderr)
        sys.exit(2)
