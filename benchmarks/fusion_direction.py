"""Does a fusion decision depend on which map is aligned onto which?  ``align(A, B)`` against ``align(B, A)``
(docs/fusion-history.md, "Session 44").

``fusion.align`` is not symmetric: its ratio test runs from map 1's landmarks, so the putative correspondences,
RANSAC's draws and the gates differ with the direction (session 43: on rendered demo seed 4, robot 2 against robot
1's part before its gap found the building's half turn on 28 of 40 RANSAC seeds, the other direction never). For
every pair and every RANSAC seed s (``default_rng(s)`` both ways) it counts:

- both found and consistent: B->A within the reported uncertainty of the inverse of A->B (χ²₃ of the difference
  under the sum of the two alignments' own covariances, p >= 0.01);
- both found and inconsistent (p < 0.01);
- one found, the other not (which one, and the other's reason);
- neither found;

and how many founds of each direction are wrong against the true start poses (more than 0.3 m or 0.1 rad off,
eval_fusion's line) where the maps carry them. Pairs:

    .venv/bin/python benchmarks/fusion_direction.py --demo DIR [DIR ...]   # p3at demo --out DIR: robot1/2.npz
    .venv/bin/python benchmarks/fusion_direction.py --mrclam-maps DIR      # robot1..5.npz, e.g. FastSLAM maps
    .venv/bin/python benchmarks/fusion_direction.py --mrclam-sightings     # MRCLAM dataset 2's sighting maps
    .venv/bin/python benchmarks/fusion_direction.py --false-pairs N        # N of each kind of eval_fusion's
                                                                           # non-overlapping pairs

``--ratio-sides both`` (or ``either``) aligns with the robust preset's ratio test on both sides of a match
(``AlignmentConfig.ratio_sides``, session 45): the two directions then start from the same correspondences.

A demo folder gives its two whole maps and, for a map that flagged itself, each part (``fusion.split``) against
the other map, aligned as ``check_split`` does (the other map first, the part as map 2). A part made after its
map's gap does not share its map's start, so it is not scored against the truth. On MRCLAM's FastSLAM maps a found
can be more than 0.3 m off the true starts by robot 1's frame error alone (eval_fusion's MRCLAM table: 4 of 10,
all covered by their start-frame covariance); the column counts them all the same.
"""
from __future__ import annotations

import argparse
import sys
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

from benchmarks.fusion_sim import MRCLAM_DATASET2, false_pair_kinds, mrclam_sighting_map  # noqa: E402
from estimation import chi2  # noqa: E402
from estimation.geometry import inverse, wrap_angle  # noqa: E402
from estimation.landmark_map import LandmarkMap  # noqa: E402
from fusion.alignment import align, alignment_error_xy_theta, true_relative_pose  # noqa: E402
from fusion.alignment_config import ROBUST, AlignmentConfig  # noqa: E402
from fusion.matching import RATIO_SIDES  # noqa: E402
from fusion.split import split_id, split_map  # noqa: E402
from runtime.commands.options import positive_int  # noqa: E402

WRONG_M, WRONG_RAD = 0.3, 0.1      # eval_fusion's false alignment
CONSISTENT_P = 0.01


def _own_covariance(a) -> np.ndarray:
    return np.zeros((3, 3)) if a.covariance is None else np.asarray(a.covariance, float)


def _wrong(pose, truth) -> bool:
    xy, theta = alignment_error_xy_theta(pose, truth)
    return bool(xy > WRONG_M or theta > WRONG_RAD)


def both_ways(map_a: LandmarkMap, map_b: LandmarkMap, draws: int, scored: bool = True,
              config: AlignmentConfig = ROBUST) -> list[dict]:
    """Per RANSAC seed: align(A, B) and align(B, A), whether each is found and wrong (None without the truth), and
    for two founds the p-value and size of their difference."""
    truth = true_relative_pose(map_a, map_b) if scored else None
    rows = []
    for s in range(draws):
        ab = align(map_a, map_b, config, np.random.default_rng(s))
        ba = align(map_b, map_a, config, np.random.default_rng(s))
        row = {"ab": ab, "ba": ba, "p": None, "dxy": None, "dtheta": None,
               "wrong_ab": None if truth is None or not ab.found else _wrong(ab.pose, truth),
               "wrong_ba": None if truth is None or not ba.found else _wrong(inverse(np.asarray(ba.pose)), truth)}
        if ab.found and ba.found:
            back = ab.inverse()
            d = np.asarray(ba.pose, float) - np.asarray(back.pose, float)
            d[2] = wrap_angle(d[2])
            cov = _own_covariance(back) + _own_covariance(ba) + 1e-12 * np.eye(3)
            row.update(p=float(chi2.sf(float(d @ np.linalg.solve(cov, d)), 3)), dxy=float(np.hypot(d[0], d[1])),
                       dtheta=float(abs(d[2])))
        rows.append(row)
    return rows


def print_header() -> None:
    print("| pair A <- B | draws | both found, consistent | both found, inconsistent | one found | neither | "
          "A <- B found (wrong) | B <- A found (wrong) | notes |")
    print("|---|---|---|---|---|---|---|---|---|")


def print_row(label: str, rows: list[dict]) -> Counter:
    kinds = Counter()
    for r in rows:
        found = r["ab"].found + r["ba"].found
        kinds["consistent" if found == 2 and r["p"] >= CONSISTENT_P else "inconsistent" if found == 2 else
              "one" if found == 1 else "neither"] += 1
    notes = []
    both = [r for r in rows if r["p"] is not None]
    if both:
        notes.append(f"largest difference {max(r['dxy'] for r in both):.3f} m / "
                     f"{max(r['dtheta'] for r in both):.4f} rad, smallest p {min(r['p'] for r in both):.2g}")
    one = [r for r in rows if r["ab"].found != r["ba"].found]
    for way, key, other in (("A <- B", "ab", "ba"), ("B <- A", "ba", "ab")):
        only = [r for r in one if r[key].found]
        if only:
            notes.append(f"only {way} found {len(only)}× (the other: {only[0][other].reason[:70]}…)")

    def founds(key):
        n = sum(r[key].found for r in rows)
        if not n:
            return "0"
        wrong = [r[f"wrong_{key}"] for r in rows if r[key].found]
        return f"{n} ({sum(bool(w) for w in wrong)})" if all(w is not None for w in wrong) else f"{n} (no truth)"

    print(f"| {label} | {len(rows)} | {kinds['consistent']} | {kinds['inconsistent']} | {kinds['one']} | "
          f"{kinds['neither']} | {founds('ab')} | {founds('ba')} | {'; '.join(notes)} |", flush=True)
    return kinds


def demo_pairs(folder: Path):
    """(label, A, B, scored) of a demo folder: the whole maps, and each flagged map's parts against the other map."""
    r1, r2 = (LandmarkMap.load(folder / f"{name}.npz") for name in ("robot1", "robot2"))
    yield f"{folder.name} robot1 <- robot2", r1, r2, True
    for name, flagged, other, other_name in (("robot1", r1, r2, "robot2"), ("robot2", r2, r1, "robot1")):
        first = split_id(flagged)
        if first is None:
            continue
        before, after = split_map(flagged, first)
        yield f"{folder.name} {other_name} <- {name}'s part before its gap ({len(before)})", other, before, True
        yield (f"{folder.name} {other_name} <- {name}'s part after its gap ({len(after)}, not scored)", other, after,
               False)


def five_map_pairs(maps: list[LandmarkMap], title: str):
    for i in range(len(maps)):
        for j in range(i + 1, len(maps)):
            yield f"{title} {maps[i].robot} <- {maps[j].robot}", maps[i], maps[j], True


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--demo", type=Path, nargs="+", default=[], metavar="DIR",
                        help="p3at demo --out folders (robot1.npz, robot2.npz)")
    parser.add_argument("--mrclam-maps", type=Path, action="append", default=[], metavar="DIR",
                        help="a folder of five MRCLAM maps robot1..5.npz (e.g. eval_mrclam --maps)")
    parser.add_argument("--mrclam-sightings", action="store_true",
                        help=f"MRCLAM dataset 2's maps from real sightings placed from Vicon poses ({MRCLAM_DATASET2})")
    parser.add_argument("--false-pairs", type=positive_int, default=None, metavar="N",
                        help="N pairs of each kind of eval_fusion's non-overlapping pairs (seeds 0..N-1)")
    parser.add_argument("--draws", type=positive_int, default=8, help="RANSAC seeds per pair and direction (8)")
    parser.add_argument("--ratio-sides", choices=RATIO_SIDES, default=ROBUST.ratio_sides,
                        help="whose ratio test a match must pass: map 1's landmark (the robust preset), both "
                             "landmarks' or either's (AlignmentConfig.ratio_sides)")
    args = parser.parse_args(argv)
    config = replace(ROBUST, ratio_sides=args.ratio_sides)
    if not (args.demo or args.mrclam_maps or args.mrclam_sightings or args.false_pairs):
        parser.error("nothing to measure: give --demo, --mrclam-maps, --mrclam-sightings or --false-pairs")
    if args.mrclam_sightings and not MRCLAM_DATASET2.is_dir():
        parser.error(f"--mrclam-sightings: {MRCLAM_DATASET2} not found")
    print(f"ratio test: {args.ratio_sides}")
    print_header()
    total = Counter()
    for folder in args.demo:
        for label, a, b, scored in demo_pairs(folder):
            total += print_row(label, both_ways(a, b, args.draws, scored, config))
    for folder in args.mrclam_maps:
        maps = [LandmarkMap.load(folder / f"robot{r}.npz") for r in range(1, 6)]
        for label, a, b, scored in five_map_pairs(maps, folder.name):
            total += print_row(label, both_ways(a, b, args.draws, scored, config))
    if args.mrclam_sightings:
        maps = [mrclam_sighting_map(MRCLAM_DATASET2, r).map for r in range(1, 6)]
        for label, a, b, scored in five_map_pairs(maps, "sightings"):
            total += print_row(label, both_ways(a, b, args.draws, scored, config))
    if args.false_pairs:
        for kind, make in false_pair_kinds().items():
            rows = []
            for seed in range(args.false_pairs):
                m1, m2 = make(seed)
                rows += both_ways(getattr(m1, "map", m1), getattr(m2, "map", m2), args.draws, False, config)
            total += print_row(f"{kind} ({args.false_pairs} pairs)", rows)
    print(f"\nIn all: {total['consistent']} both found and consistent, {total['inconsistent']} both found and "
          f"inconsistent, {total['one']} found one way only, {total['neither']} neither.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
