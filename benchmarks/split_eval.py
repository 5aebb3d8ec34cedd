"""A flagged map split at its alarm and each part aligned (fusion/split.py): what it changes, against the truth.

Run from the repository root:

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.split_eval demo DEMO_DIR [DEMO_DIR ...] [--kick]
    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.split_eval same MAPS_DIR

``demo``: `p3at demo --out` folders (robot1.npz, robot2.npz carrying ``metadata["self_check"]``). Per folder, the
fusion of the two maps as given (``fusion.fuse_all``) and with the check (``fusion.split.fuse_checked``): each
flagged map's split (landmarks before / after the gap), each part's alignment to the other map (supports, error
against the true start poses), the χ² of the parts' difference and how far apart their alignments place the map's
landmarks (``fusion.split.parts_apart``), the decision; then, for both fusions, the
placement of robot 2's start frame against the truth (its whole map's, or the part made before the gap) and the
fused map's landmark error against the simulator's true features: the fused map put in the world by robot 1's
true start pose, each landmark's distance to the nearest feature, over the landmarks robot 2 contributed alone
(its common ones are fused with robot 1's): median, and the share within 0.15 m.

``--kick`` adds a lost-map variant of every folder whose maps align: robot 2's landmarks from its split point on
(its alarm's ``first_id_after_gap`` when it flagged itself, else its median id) turned by ``KICK_THETA`` about
their centroid and shifted by ``KICK_SHIFT``, as a map that lost its heading at the gap builds the rest, and the
map flagged at that point. The demo's own diverged maps do not align at all (whole or in parts), so they cannot
show what the split does to a misplaced part; these can.

``same``: maps of one run (MRCLAM known-ID: MAPS_DIR/robot1.npz ...): the fusion with the check against the one
without, landmark by landmark (a map set none of which flagged itself must not change).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

from benchmarks.fusion_sim import load_world
from estimation.geometry import transform_points
from estimation.landmark_map import LandmarkMap
from fusion import fuse_all, true_relative_pose
from fusion.alignment import alignment_error_xy_theta
from fusion.split import fuse_checked, split_id

KICK_THETA = 0.2    # rad: the demo's diverged maps are 0.13-0.25 rad off (docs/fastslam-history.md)
KICK_SHIFT = 0.5    # m
NEAR = 0.15         # m: a landmark "on a feature"


def _figures(fusion, sources, maps, true_map2, features_tree) -> tuple[str, str, str]:
    """(robot 2's start frame against the truth; the fused map's landmarks against the true features: count, median
    distance to the nearest, share within NEAR; robot 2's landmarks against where the true start poses put them in
    ``true_map2`` (the map before any kick): median, share farther than 0.5 m)."""
    if fusion is None:
        return "not fused", "-", "-"
    m = fusion.map
    d, _ = features_tree.query(transform_points(np.asarray(maps[0].metadata["true_start_pose"], float), m.positions))
    landmarks = f"{len(m)}: {np.median(d):.3f} m, {np.mean(d < NEAR):.1%}"
    pieces = [i for i, (k, _) in enumerate(sources) if k == 1 and fusion.poses[i] is not None]
    if not pieces:
        return "left out", landmarks, "-"
    truth = true_relative_pose(maps[0], maps[1])
    exy, eth = alignment_error_xy_theta(fusion.poses[pieces[0]], truth)
    what = "" if sources[pieces[0]][1] in (None, "before") else " (part after)"
    true_rows = {int(v): r for r, v in enumerate(true_map2.ids)}
    placed, meant = [], []
    for i in pieces:
        piece = maps[1] if sources[i][1] is None else None
        ids = (piece.ids if piece is not None else
               np.sort(maps[1].ids[(maps[1].ids < _first(maps[1])) == (sources[i][1] == "before")]))
        placed.append(m.positions[fusion.rows[i]])
        meant.append(transform_points(truth, true_map2.positions[[true_rows[int(v)] for v in ids]]))
    off = np.linalg.norm((np.concatenate(placed) - np.concatenate(meant))[:, :2], axis=1)
    return (f"{exy:.3f} m / {eth:.4f} rad{what}", landmarks,
            f"{len(off)}: {np.median(off):.3f} m, {np.mean(off > 0.5):.0%}")


def _first(m: LandmarkMap) -> int:
    return int(split_id(m))


def _kicked(m: LandmarkMap, first: int) -> LandmarkMap:
    out = m.subset(np.arange(len(m)))
    after = out.ids >= first
    centre = out.positions[after, :2].mean(axis=0)
    c, s = np.cos(KICK_THETA), np.sin(KICK_THETA)
    xy = (out.positions[after, :2] - centre) @ np.array([[c, s], [-s, c]]) + centre + KICK_SHIFT
    out.positions[after, :2] = xy
    verdict = dict(out.metadata.get("self_check") or {})
    if not verdict.get("lost"):
        verdict = {**verdict, "lost": True, "n_alarms": 1, "alarms": [{"first_id_after_gap": int(first)}]}
    out.metadata = {**out.metadata, "self_check": verdict}
    return out


def _row(name: str, maps: list[LandmarkMap], tree, true_map2: LandmarkMap) -> None:
    checked = fuse_checked(maps, rng=np.random.default_rng(0))
    unchecked = " | ".join(_figures(checked.whole, [(k, None) for k in range(len(maps))], maps, true_map2, tree))
    if not checked.checks:
        print(f"| {name} | not flagged | | | | | {unchecked} | = | = | = |")
        return
    with_check = " | ".join(_figures(checked.fusion, checked.sources, maps, true_map2, tree))
    truth = true_relative_pose(maps[0], maps[1])
    for c in checked.checks:
        parts = []
        for p in c.parts:
            j = 1 - c.index
            a = p.alignments[j] if j in p.aligned_to else p.at_other.get(j, p.alignments.get(j))
            if p.too_small:
                parts.append(f"{p.landmarks}: too small")
            elif a is None or not a.found:
                parts.append(f"{p.landmarks}: not found")
            else:
                pose = a.pose if c.index == 1 else np.asarray(a.inverse().pose)
                exy, eth = alignment_error_xy_theta(pose, truth)
                at = " at the other part's" if j not in p.aligned_to else ""
                parts.append(f"{p.landmarks}: {len(a.supports)}{at}, {exy:.2f} m / {eth:.3f}")
        chi = ", ".join(f"{x:.1f} (p {p:.2g}; {m:.2f} m apart)"
                        for (_, x, p), (_, m) in zip(c.comparisons, c.apart, strict=True)) or "-"
        print(f"| {name} | robot{c.index + 1} at id {c.first_id} | {parts[0]} | {parts[1]} | {chi} | {c.decision} | "
              f"{unchecked} | {with_check} |")


def demo(folders: list[Path], kick: bool) -> None:
    tree = cKDTree(load_world().features)
    print("| run | flagged map, split | part before: landmarks: supports, error xy / θ (rad) | part after | χ² (p; "
          "farthest a landmark is placed apart by the parts' alignments) | "
          "decision | unchecked: robot 2's frame | fused landmarks: median to a feature, within 0.15 m | robot 2's "
          "landmarks off their place: median, > 0.5 m | checked: robot 2's frame | fused landmarks | robot 2's "
          "landmarks |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for folder in folders:
        maps = [LandmarkMap.load(folder / f"robot{r}.npz") for r in (1, 2)]
        _row(folder.name, maps, tree, maps[1])
        if kick:
            first = split_id(maps[1])
            first = int(np.median(maps[1].ids)) if first is None else first
            kicked = [maps[0], _kicked(maps[1], first)]
            if fuse_checked(maps, rng=np.random.default_rng(0)).whole is not None:
                _row(f"{folder.name} lost", kicked, tree, maps[1])


def same(folder: Path) -> None:
    maps = [LandmarkMap.load(p) for p in sorted(folder.glob("robot*.npz"))]
    flagged = sum(split_id(m) is not None for m in maps)
    verdicts = sum("self_check" in m.metadata for m in maps)
    checked = fuse_checked(maps, rng=np.random.default_rng(0))
    plain = fuse_all(maps, rng=np.random.default_rng(0))
    diff = float(np.max(np.abs(checked.fusion.map.positions - plain.map.positions))) \
        if len(checked.fusion.map) == len(plain.map) else float("inf")
    print(f"{folder}: {len(maps)} maps, {verdicts} carrying a self-check verdict, {flagged} flagged; fused with the "
          f"check: {len(checked.fusion.map)} landmarks, "
          f"without: {len(plain.map)}; largest position difference {diff:.3g} m")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="what", required=True)
    d = sub.add_parser("demo")
    d.add_argument("folders", type=Path, nargs="+")
    d.add_argument("--kick", action="store_true", help="add a lost-map variant of every folder whose maps align")
    s = sub.add_parser("same")
    s.add_argument("folder", type=Path)
    args = parser.parse_args()
    if args.what == "demo":
        demo(args.folders, args.kick)
    else:
        same(args.folder)


if __name__ == "__main__":
    main()
