"""The alignment's support gate with honest landmark covariances: "inflate" (the default) against "residual".

Prints, for the final maps of demo folders (``p3at demo --out DIR``), each rule's decision, supports, supports
needed, rival, self-repeat, gate radius and scale κ, and the error against the true start poses; the maps' claimed
σ (median per-axis xy) and the residuals the winner leaves (median |r| and normalised r²/var over χ²₂'s median).
``--mrclam DIR`` aligns the ten pairs of robot1..5.npz with both rules; ``--false-pairs N`` runs the seven kinds of
non-overlapping pairs of ``eval_fusion --trust-only`` (same generators and seeds) with the "residual" rule.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.fusion_gate_scale --demo /tmp/r8/demo-before \
        /tmp/r8/demo-lever /tmp/r8/demo-after --mrclam /tmp/f6/maps/id --false-pairs 1000
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from itertools import combinations
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from fusion_sim import false_pair_kinds  # noqa: E402

from estimation.geometry import transform_points  # noqa: E402
from estimation.landmark_map import LandmarkMap  # noqa: E402
from fusion.alignment import align, alignment_error, true_relative_pose  # noqa: E402
from fusion.alignment_config import ROBUST  # noqa: E402
from fusion.gate_scale import CHI2_2_MEDIAN, GATE_SCALES  # noqa: E402
from runtime.commands.options import non_negative_int  # noqa: E402

RULES = {rule: replace(ROBUST, gate_scale=rule) for rule in GATE_SCALES}
WRONG_M, WRONG_RAD = 0.3, 0.1          # as eval_fusion: this far off counts as a false alignment


def _sigma(m: LandmarkMap) -> float:
    return float(np.sqrt(np.median(np.trace(m.covariances[:, :2, :2], axis1=1, axis2=2) / 2)))


def _row(m1: LandmarkMap, m2: LandmarkMap, rule: str) -> str:
    a = align(m1, m2, RULES[rule])
    s = a.statistics
    truth = true_relative_pose(m1, m2)
    err = "—"
    if a.pose is not None and truth is not None:
        e = alignment_error(a.pose, truth)
        err = f"{np.hypot(e[0], e[1]):.3f} / {e[2]:.4f}"
    resid = "—"
    if a.pose is not None and len(a.supports):
        i, j = a.supports[:, 0], a.supports[:, 1]
        r = m1.positions[i, :2] - transform_points(a.pose, m2.positions[j])[:, :2]
        var = 0.5 * (np.trace(m1.covariances[i, :2, :2], axis1=1, axis2=2)
                     + np.trace(m2.covariances[j, :2, :2], axis1=1, axis2=2)) + 2 * ROBUST.position_floor ** 2
        n2 = np.einsum("ki,ki->k", r, r) / var
        resid = f"{np.median(np.linalg.norm(r, axis=1)):.3f} / {np.median(n2) / CHI2_2_MEDIAN:.3f}"
    verdict = "found" if a.found else "not found: " + a.reason.split(";")[0].split(" (")[0]
    return (f"| {rule} | {verdict} | {s.supports} | {s.required_supports} | {s.second_best_supports} | "
            f"{s.self_repeat_supports} | {s.gate_radius:.3f} | {s.gate_inflation:.3f} | {resid} | {err} |")


def demo_table(folders: list[Path]) -> None:
    print("\n### Final maps of demo runs: the gate rules\n")
    print("| run | landmarks 1 / 2 | claimed σ xy median 1 / 2 (m) | rule | decision | supports | needed | rival | "
          "self-repeat | gate radius (m) | κ | winner's residual median |r| (m) / r²/var over χ²₂ median | "
          "error vs truth xy (m) / θ (rad) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for folder in folders:
        m1, m2 = LandmarkMap.load(folder / "robot1.npz"), LandmarkMap.load(folder / "robot2.npz")
        head = f"| {folder.name} | {len(m1)} / {len(m2)} | {_sigma(m1):.3f} / {_sigma(m2):.3f} "
        for rule in GATE_SCALES:
            print(head + _row(m1, m2, rule))


def mrclam_table(folder: Path) -> None:
    maps = {r: LandmarkMap.load(folder / f"robot{r}.npz") for r in range(1, 6)}
    print(f"\n### MRCLAM maps {folder}: ten pairs\n")
    print("| pair | rule | decision | supports | needed | rival | self-repeat | gate radius (m) | κ | residual | "
          "error vs Vicon starts xy (m) / θ (rad) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    found = dict.fromkeys(GATE_SCALES, 0)
    for a, b in combinations(maps, 2):
        for rule in GATE_SCALES:
            row = _row(maps[a], maps[b], rule)
            found[rule] += "| found |" in row
            print(f"| {a}-{b} " + row)
    print("\nfound: " + ", ".join(f"{rule} {n}/10" for rule, n in found.items()))


def false_pairs(total: int, rule: str = "residual") -> None:
    """eval_fusion.false_alarms' seven kinds (same generators and seeds), one rule."""
    kinds = false_pair_kinds()
    per = max(1, -(-total // len(kinds)))
    print(f"\n### No false alignment, gate rule {rule!r} ({per * len(kinds)} pairs: {per} of each kind)\n")
    print("| maps | alignments reported (should be 0) | smallest gate scale κ |")
    print("|---|---|---|")
    total_found = 0
    for name, make in kinds.items():
        found, kappas = 0, []
        for seed in range(per):
            m1, m2 = make(seed)
            m1, m2 = getattr(m1, "map", m1), getattr(m2, "map", m2)
            a = align(m1, m2, RULES[rule], np.random.default_rng(seed))
            found += a.found
            kappas.append(a.statistics.gate_inflation)
        total_found += found
        print(f"| {name} | {found}/{per} | {min(kappas):.3f} |")
    print(f"\nTotal alignments reported on {per * len(kinds)} non-overlapping pairs ({rule}): {total_found}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--demo", type=Path, nargs="*", default=[], help="demo output folders (robot1/2.npz)")
    parser.add_argument("--mrclam", type=Path, help="folder of MRCLAM maps robot1..5.npz")
    parser.add_argument("--false-pairs", type=non_negative_int, default=0,
                        help="non-overlapping pairs, over seven kinds")
    args = parser.parse_args()
    t0 = time.perf_counter()
    if args.demo:
        demo_table(args.demo)
    if args.mrclam:
        mrclam_table(args.mrclam)
    if args.false_pairs:
        false_pairs(args.false_pairs)
    print(f"\n({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    from estimation.errors import MapFileError

    try:
        main()
    except MapFileError as e:   # a map file of a given folder missing or unreadable: one line naming it
        print(f"{Path(__file__).name}: {e}", file=sys.stderr)
        sys.exit(2)
