"""Speed of map alignment and merging (run by hand: ``.venv/bin/python benchmarks/bench_fusion.py``).

Goals (issue 6): two maps of the paper's size (263 and 364 landmarks) aligned in ≤ 5 ms; two maps of
50,000 landmarks each in ≤ 2 s.  Prints the median of several runs of align (both presets) and merge, wall and CPU time;
the goal's verdict is on the CPU time, which the machine's other load does not count.
Set OPENBLAS_NUM_THREADS=1 on a loaded machine: OpenBLAS's thread pool makes small matrix products
erratic (tens of ms) when other processes hold the cores.

``--against DIR`` (session 24): another checkout's ``fusion`` package (a git worktree of an older commit), imported
under its own name beside this one, aligns the same maps alternately with this checkout's in the same process: both
CPU medians, their ratio, and whether every result is the same to the bit -- a speed-up measured under one load, not
two runs under two loads.  (The other tree's fusion runs on this checkout's ``estimation``.)
"""
from __future__ import annotations

import argparse
import importlib.util
import os
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


def _fusion_from(root: Path):
    """The ``fusion`` package of the checkout ``root``, imported as ``fusion_against`` (beside this one's)."""
    init = root / "fusion" / "__init__.py"
    if not init.is_file():
        raise SystemExit(f"{Path(__file__).name}: --against {root}: no fusion/__init__.py there")
    spec = importlib.util.spec_from_file_location("fusion_against", init, submodule_search_locations=[str(init.parent)])
    module = importlib.util.module_from_spec(spec)
    sys.modules["fusion_against"] = module
    spec.loader.exec_module(module)
    return module


def _same_result(a, b) -> bool:
    """Two alignments equal to the bit: decision, reason, pose, covariances, supports, every statistic."""
    def bits(x):
        return None if x is None else np.asarray(x).tobytes()
    return (a.found == b.found and a.reason == b.reason and bits(a.pose) == bits(b.pose)
            and bits(a.covariance) == bits(b.covariance) and bits(a.start_covariance) == bits(b.start_covariance)
            and bits(a.supports) == bits(b.supports) and repr(a.statistics) == repr(b.statistics))


def alternated(map1, map2, other, repeats: int, rounds: int = 6) -> None:
    """This checkout's align and ``other``'s on the same maps, alternated round by round in this process (each round
    ``repeats // rounds`` alignments of each, the order swapped every round): CPU medians and their ratio."""
    per_round = max(1, repeats // rounds)
    for preset in ("paper", "robust"):
        sides = {"this": align, "against": other.align}
        results = {name: fn(map1, map2, preset, np.random.default_rng(0)) for name, fn in sides.items()}   # warm-up
        cpu = {name: [] for name in sides}
        for r in range(rounds):
            for name in (("this", "against") if r % 2 == 0 else ("against", "this")):
                for _ in range(per_round):
                    c0 = time.process_time()
                    sides[name](map1, map2, preset, np.random.default_rng(0))
                    cpu[name].append(time.process_time() - c0)
        this, against = (1000.0 * float(np.median(cpu[name])) for name in ("this", "against"))
        same = "every result the same to the bit" if _same_result(results["this"], results["against"]) else \
            "RESULTS DIFFER"
        print(f"  align [{preset:6s}] this checkout {this:8.2f} ms CPU, --against {against:8.2f} ms CPU "
              f"(ratio {against / max(this, 1e-9):.2f}, {rounds} rounds of {per_round} alternated; {same})")


def run(label: str, n_common: int, n1: int, n2: int, repeats: int, goal_ms: float, other=None) -> None:
    pose = np.array([12.0, -3.0, 2.2])
    extent = (35.0, 10.0) if n1 < 5000 else (350.0, 100.0)
    map1, map2, _ = random_pair(n_common, n1 - n_common, n2 - n_common, pose, seed=1, extent=extent)
    print(f"{label}: maps of {len(map1)} and {len(map2)} landmarks, {n_common} common")
    if other is not None:
        alternated(map1, map2, other, repeats)
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


def demo_align(folder: Path, repeats: int, other=None) -> None:
    """align on the rendered demo's first two maps (real maps: walls, a building's half turn, repeated corners)."""
    maps = _demo_maps(folder)
    (name1, map1), (name2, map2) = sorted(maps.items())[:2]
    print(f"demo maps {name1} + {name2} ({len(map1)} + {len(map2)} landmarks, {folder}):")
    if other is not None:
        alternated(map1, map2, other, repeats)
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
    parser.add_argument("--against", type=Path, metavar="DIR", help="another checkout (e.g. a git worktree of an "
                        "older commit): its fusion package aligns the same maps alternately with this one's, in this "
                        "process (paper-size pair, demo maps; not the large pair nor the repeated fusion)")
    args = parser.parse_args()
    other = None if args.against is None else _fusion_from(args.against.resolve())
    print(f"load average {os.getloadavg()[0]:.1f} at the start")
    if not args.only_repeated:
        run("paper size", 150, 263, 364, repeats=30, goal_ms=5.0, other=other)
        if not args.skip_large:
            run("large", 20_000, 50_000, 50_000, repeats=3, goal_ms=2000.0)
        if args.demo_maps is not None:
            demo_align(args.demo_maps, repeats=5, other=other)
        elif other is not None:                   # the demo's size without its maps: the random pair of that size
            map1, map2 = _demo_maps(None).values()
            print(f"random pair of the demo's size ({len(map1)} + {len(map2)} landmarks, 250 common):")
            alternated(map1, map2, other, repeats=12)
    repeated_fusion(args.demo_maps, repeats=5)
    print(f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    from estimation.errors import MapFileError

    try:
        main()
    except MapFileError as e:   # a map file of a given folder missing or unreadable: one line naming it
        print(f"{Path(__file__).name}: {e}", file=sys.stderr)
        sys.exit(2)
