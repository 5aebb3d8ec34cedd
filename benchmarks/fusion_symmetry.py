"""Is the rendered building's half-turn symmetry real in appearance?  The true and the half-turned hypothesis of
rendered demo maps, side by side, on every piece of evidence the maps hold (docs/fusion-history.md, "Rendered demo:
is the half-turn symmetry real in appearance?").

    .venv/bin/python -m benchmarks.fusion_symmetry DIR [DIR ...]     # DIR: p3at demo --out DIR (robot1/2.npz)

Only rendered demo maps (descriptors, the simulator's start poses) have the truth this needs; any other folder
(MRCLAM maps from ``fusion_sim.py mrclam``, a missing map) is refused in one line, exit 2, before any work.

For each run, the robust preset's RANSAC hypotheses (two correspondences each) are split into those within 1 m
and 0.14 rad of the true relative pose of the maps (the composition of each map's best rigid fit to the
simulator's features, as in eval_fusion's demo table) and those turned by π ± 0.14 rad from it; the best of each
group is polished like a winner and scored with its own gate.  Per hypothesis it prints: supports (one-to-one),
the median descriptor distance of its supports, how many lie on the floor / walls / ceiling (z < 0.05 m, up to
2.6 m, above), the median xy and z residuals, the supports' principal spread, the overlap cells (2 m squares
holding ≥ 5 landmarks of each map under the hypothesis) that hold a support, the supports counted by guided
matching over all landmarks (position gate, then nearest descriptor < 0.8), and map-2 landmarks that land within
0.1 m (3-D) of a map-1 landmark.  Truth is used only to say which hypothesis is which.
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from eval_fusion import _feature_fit  # noqa: E402
from fusion_sim import load_world  # noqa: E402

import fusion.alignment as al  # noqa: E402
import fusion.ransac as rs  # noqa: E402
from estimation.geometry import between, transform_points  # noqa: E402
from estimation.landmark_map import LandmarkMap  # noqa: E402
from fusion.alignment_config import ROBUST  # noqa: E402

CELL = 2.0               # metres: overlap cells
CELL_LANDMARKS = 5       # landmarks of each map for a cell to count as mapped by both
FLOOR_Z, CEILING_Z = 0.05, 2.6


def _best_in(problem, poses: np.ndarray, select: np.ndarray):
    """The best-supported hypothesis among poses[select], polished like a winner: (pose, mask, problem) or None."""
    cand = poses[select]
    if len(cand) == 0:
        return None
    counts = problem.distinct_counts(problem.masks(cand))
    pose = cand[int(np.argmax(counts))]
    pose, _, mask, polished = rs.polish(replace(problem), pose, problem.masks(pose[None])[0], ROBUST)
    return pose, polished.one_to_one(polished.masks(pose[None])[0], pose), polished


def _overlap_cells(m1: LandmarkMap, m2: LandmarkMap, pose: np.ndarray, support_xy: np.ndarray) -> tuple[int, int]:
    def mapped(xy):
        cells, n = np.unique(np.floor(xy / CELL).astype(int), axis=0, return_counts=True)
        return {tuple(c) for c, k in zip(cells, n, strict=True) if k >= CELL_LANDMARKS}
    both = mapped(m1.positions[:, :2]) & mapped(transform_points(pose, m2.positions)[:, :2])
    with_support = {tuple(c) for c in np.floor(support_xy / CELL).astype(int)} & both
    return len(both), len(with_support)


def describe(m1: LandmarkMap, m2: LandmarkMap, pose: np.ndarray, mask: np.ndarray, problem) -> dict:
    i, j = problem.i[mask], problem.j[mask]
    desc = np.linalg.norm(m1.descriptors[i] - m2.descriptors[j], axis=1)
    r = problem.p1[mask] - transform_points(pose, problem.p2[mask])
    z = problem.p1[mask, 2]
    cells, covered = _overlap_cells(m1, m2, pose, problem.p1[mask, :2])
    guided = al.guided_supports(m1, m2, pose, ROBUST)
    near, _ = cKDTree(m1.positions).query(transform_points(pose, m2.positions))
    return {
        "supports": int(mask.sum()), "descriptor": float(np.median(desc)),
        "floor": int((z < FLOOR_Z).sum()), "wall": int(((z >= FLOOR_Z) & (z <= CEILING_Z)).sum()),
        "ceiling": int((z > CEILING_Z).sum()),
        "r_xy": float(np.median(np.hypot(r[:, 0], r[:, 1]))), "r_z": float(np.median(np.abs(r[:, 2]))),
        "spread": al.support_spread(problem.p1[mask, :2]), "cells": (covered, cells), "guided": len(guided),
        "coincide": int((near < 0.1).sum()),
    }


def refusal(folder: Path) -> str | None:
    """Why ``folder`` cannot be studied here (one line), or None when it holds two rendered demo maps."""
    for k in (1, 2):
        path = folder / f"robot{k}.npz"
        if not path.is_file():
            return f"{path}: no such map (this needs p3at demo --out folders)"
        try:
            m = LandmarkMap.load(path)
        except Exception as exc:  # noqa: BLE001 - any unreadable file gets the same one line
            return f"{path}: not a landmark map ({type(exc).__name__}: {exc})"
        if "dataset" in m.metadata or m.metadata.get("external_ids") is not None:
            return (f"{path}: a map of the data set {m.metadata.get('dataset', '?')}, not a rendered demo map "
                    "(this compares appearance in the simulated building; use p3at demo --out folders)")
        if m.descriptor_size == 0 or "true_start_pose" not in m.metadata:
            return f"{path}: not a rendered demo map (no descriptors or no true_start_pose)"
    return None


def run(folder: Path, world) -> list[str]:
    m1, m2 = (LandmarkMap.load(folder / f"robot{k}.npz") for k in (1, 2))
    fits = [_feature_fit(m, world.features)[0] for m in (m1, m2)]
    truth = between(fits[0], fits[1])
    a = al.align(m1, m2, "robust", np.random.default_rng(0))
    pairs, _ = rs.putative_correspondences(m1, m2, ROBUST, np.random.default_rng(0))
    problem = rs.correspondence_problem(m1, m2, pairs, ROBUST, False)
    rng = np.random.default_rng(1)
    first, second = rng.integers(len(pairs), size=(2, 30_000))
    poses, valid = rs.pair_hypotheses(problem.p1, problem.p2, first, second, ROBUST)
    poses = poses[valid & rs.distance_preserved(problem, first, second, ROBUST)]
    near = np.hypot(*(poses[:, :2] - truth[:2]).T) < 1.0
    groups = {"true": near & (np.cos(poses[:, 2] - truth[2]) > np.cos(0.14)),
              "half turn": np.cos(poses[:, 2] - truth[2] - np.pi) > np.cos(0.14)}
    if a.found:
        verdict = f"found ({a.statistics.supports} supports)"
    else:
        verdict = "not found: " + a.reason.split(";")[0].split("(")[0].strip()
    rows = []
    for name, select in groups.items():
        best = _best_in(problem, poses, select)
        if best is None:
            rows.append(f"| {folder.name} | {name} | – | | | | | | | | |")
            continue
        pose, mask, polished = best
        e = al.alignment_error_xy_theta(pose, truth)
        d = describe(m1, m2, pose, mask, polished)
        rows.append(
            f"| {folder.name} | {name} ({e[0]:.2f} m / {e[1]:.2f} rad) | {d['supports']} | {d['descriptor']:.3f} | "
            f"{d['floor']} / {d['wall']} / {d['ceiling']} | {d['r_xy']:.3f} / {d['r_z']:.3f} | "
            f"{d['spread'][0]:.2f} / {d['spread'][1]:.2f} | {d['cells'][0]} of {d['cells'][1]} | {d['guided']} | "
            f"{d['coincide']} | {verdict if name == 'true' else ''} |")
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", type=Path, nargs="+", help="p3at demo --out folders (robot1.npz, robot2.npz)")
    args = parser.parse_args(argv)
    for folder in args.folders:
        reason = refusal(folder)
        if reason is not None:
            print(f"fusion_symmetry: {reason}", file=sys.stderr)
            return 2
    world = load_world()
    print("| run | hypothesis (off the maps' composed fits) | supports | descriptor distance (median) | "
          "floor / wall / ceiling | residual xy / z (m, median) | spread (m) | overlap cells with a support | "
          "guided supports (all landmarks) | landmarks within 0.1 m | robust preset |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for folder in args.folders:
        for row in run(folder, world):
            print(row, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
