"""Accuracy of eICP, ICP and PL-ICP on the CARMEN logs in ../shared/data/laser (prints Markdown tables).

    .venv/bin/python benchmarks/eval_scanmatch.py                 # the tables in docs/scanmatch.md
    .venv/bin/python benchmarks/eval_scanmatch.py --methods eicp-mesh --stride 5

Table 1: scans k apart (k = 1, 5, 10), initial guess = the reference relative pose perturbed by a fixed-size
error (0.2 m in a random direction and ±5°, seeded, the same for every method).  Table 2: k = 1 from the
identity (the logs carry no odometry, so this is the honest "no prior" case).  Table 3: the convergence basin,
success rate as the initial error grows (k = 1).  A match succeeds within 0.10 m and 2° of the reference.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from estimation.scanmatch import MatchConfig, read_laser_log  # noqa: E402
from estimation.scanmatch.evaluate import is_success, match_pairs, perturbed_guesses  # noqa: E402
from runtime.commands.options import non_negative_float, non_negative_int, positive_int  # noqa: E402

DATA = ROOT / ".." / "shared" / "data" / "laser"
LOGS = ("aces", "csail")
BASIN_LEVELS = ((0.05, 1.0), (0.1, 2.0), (0.2, 5.0), (0.4, 10.0), (0.6, 15.0), (0.8, 20.0), (1.0, 30.0))


def load(name: str):
    readings = read_laser_log(DATA / f"{name}-corrected.log.gz")
    return [r.scan() for r in readings], np.array([r.pose for r in readings])


def row_stats(outcomes) -> dict:
    t = np.array([o.translation_error for o in outcomes])
    r = np.array([o.rotation_error for o in outcomes])
    return {"n": len(outcomes), "t_med": np.median(t), "t_p90": np.percentile(t, 90),
            "r_med": np.degrees(np.median(r)), "success": np.mean(is_success(t, r)),
            "converged": np.mean([o.result.converged for o in outcomes]),
            "iterations": np.mean([o.result.iterations for o in outcomes]),
            "ms": 1e3 * np.mean([o.seconds for o in outcomes])}


def print_accuracy(title, rows):
    print(f"\n### {title}\n")
    print("| log | k | method | pairs | trans. err. median (cm) | p90 (cm) | rot. err. median (°) | success | "
          "converged | iterations | time (ms) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for (log, k, method), s in rows:
        print(f"| {log} | {k} | {method} | {s['n']} | {100 * s['t_med']:.1f} | {100 * s['t_p90']:.1f} | "
              f"{s['r_med']:.2f} | {100 * s['success']:.1f} % | {100 * s['converged']:.1f} % | "
              f"{s['iterations']:.1f} | {s['ms']:.2f} |")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--methods", default="eicp,icp,plicp")
    parser.add_argument("--ks", default="1,5,10")
    parser.add_argument("--stride", type=positive_int, default=1, help="use every STRIDE-th pair")
    parser.add_argument("--basin-stride", type=positive_int, default=4)
    parser.add_argument("--perturb", type=non_negative_float, nargs=2, default=(0.2, 5.0), metavar=("M", "DEG"))
    parser.add_argument("--seed", type=non_negative_int, default=0)
    parser.add_argument("--skip-basin", action="store_true")
    args = parser.parse_args(argv)
    if not (DATA / "aces-corrected.log.gz").is_file():
        print(f"laser logs not found in {DATA.resolve()}", file=sys.stderr)
        return 1
    methods = args.methods.split(",")
    ks = [int(k) for k in args.ks.split(",")]
    config = MatchConfig()
    data = {name: load(name) for name in LOGS}

    perturbed, identity = [], []
    for name in LOGS:
        scans, poses = data[name]
        for k in ks:
            pairs = [(i, i + k) for i in range(0, len(scans) - k, args.stride)]
            rng = np.random.default_rng([args.seed, k, LOGS.index(name)])
            guesses = perturbed_guesses(poses, pairs, args.perturb[0], np.radians(args.perturb[1]), rng)
            for method in methods:
                perturbed.append(((name, k, method), row_stats(match_pairs(scans, poses, pairs, method, guesses,
                                                                            config))))
        pairs = [(i, i + 1) for i in range(0, len(scans) - 1, args.stride)]
        for method in methods:
            identity.append(((name, 1, method), row_stats(match_pairs(scans, poses, pairs, method,
                                                                       np.zeros((len(pairs), 3)), config))))
    print_accuracy(f"Scans k apart, initial guess = reference ⊕ ({args.perturb[0]} m, ±{args.perturb[1]}°)",
                   perturbed)
    print_accuracy("Consecutive scans from the identity (no odometry in the logs)", identity)
    if args.skip_basin:
        return 0

    print(f"\n### Convergence basin: success rate vs initial error (k = 1, every {args.basin_stride}th pair of "
          f"both logs)\n")
    print("| initial error | " + " | ".join(methods) + " |")
    print("|---|" + "---|" * len(methods))
    for level, (meters, degrees) in enumerate(BASIN_LEVELS):
        rates = {m: [] for m in methods}
        for name in LOGS:
            scans, poses = data[name]
            pairs = [(i, i + 1) for i in range(0, len(scans) - 1, args.basin_stride)]
            rng = np.random.default_rng([args.seed, 100 + level, LOGS.index(name)])
            guesses = perturbed_guesses(poses, pairs, meters, np.radians(degrees), rng)
            for method in methods:
                rates[method] += [o.success for o in match_pairs(scans, poses, pairs, method, guesses, config)]
        print(f"| {meters:.2f} m, {degrees:.0f}° | " + " | ".join(f"{100 * np.mean(rates[m]):.1f} %"
                                                               for m in methods) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
