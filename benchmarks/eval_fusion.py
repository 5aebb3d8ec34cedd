"""Reproduce the map-fusion paper's experiments on simulated two-robot maps of the building, then beat them.

    .venv/bin/python benchmarks/eval_fusion.py [--seeds 20] [--false-seeds 200] [--figures docs/figures]

Prints the tables of docs/fusion.md: Fig. 2 (alignment error against ground truth as the maps grow),
the robust preset's accuracy goal, false alignments on maps that share nothing, Fig. 4 (common landmarks
by Method 1 and Method 2, and how many are right), and the merged map's accuracy; with --figures it also
writes the PNG figures (Figs. 2, 3, 4, 5 and 6).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import fusion_plots  # noqa: E402
from fusion_sim import MapNoise, building_pair, load_world, non_overlapping_pair, random_pair, true_common  # noqa: E402

from estimation.geometry import inverse, transform_points  # noqa: E402
from estimation.landmark_map import LandmarkMap  # noqa: E402
from fusion import align, alignment_error, common_landmarks, merge, true_relative_pose  # noqa: E402
from fusion.alignment import refine_pose  # noqa: E402

FRACTIONS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
PRESETS = ("paper", "robust")
WRONG_M, WRONG_RAD = 0.3, 0.1          # a found alignment this far off counts as a false alignment


def _fmt(v, digits=3):
    return "—" if v is None or not np.isfinite(v) else f"{v:.{digits}f}"


def growth(seeds: int, noise: MapNoise):
    """Fig. 2 + Fig. 4 data: per fraction, per seed, per preset."""
    rows = []
    for f in FRACTIONS:
        for seed in range(seeds):
            s1, s2 = building_pair(f, seed, noise)
            truth = true_relative_pose(s1.map, s2.map)
            true_pairs = {tuple(p) for p in true_common(s1, s2).tolist()}
            rec = {"fraction": f, "seed": seed, "n1": len(s1.map), "n2": len(s2.map), "common": len(true_pairs)}
            for preset in PRESETS:
                a = align(s1.map, s2.map, preset, np.random.default_rng(seed))
                rec[preset] = {"found": a.found, "error": alignment_error(a.pose, truth) if a.found else None}
                for method in (1, 2):
                    if a.found:
                        pairs = common_landmarks(s1.map, s2.map, a, method)
                        right = sum(tuple(p) in true_pairs for p in pairs.tolist())
                        rec[preset][f"m{method}"] = (len(pairs), right)
                    else:
                        rec[preset][f"m{method}"] = (0, 0)
            rows.append(rec)
    return rows


def print_growth(rows, seeds):
    print(f"\n### Fig. 2 — alignment error vs ground truth as the maps grow (mean over {seeds} seeds; "
          "max in brackets)\n")
    print("| route | landmarks 1 / 2 | true common | preset | found | abs dtx (m) | abs dty (m) | abs dθ (rad) |")
    print("|---|---|---|---|---|---|---|---|")
    for f in FRACTIONS:
        rs = [r for r in rows if r["fraction"] == f]
        n1, n2, c = (np.mean([r[k] for r in rs]) for k in ("n1", "n2", "common"))
        for preset in PRESETS:
            errs = np.array([r[preset]["error"] for r in rs if r[preset]["found"]]).reshape(-1, 3)
            found = len(errs)
            cells = [f"{_fmt(errs[:, k].mean())} [{_fmt(errs[:, k].max())}]" if found else "—" for k in range(3)]
            print(f"| {f:.1f} | {n1:.0f} / {n2:.0f} | {c:.0f} | {preset} | {found}/{len(rs)} | " + " | ".join(cells)
                  + " |")


def print_goal(rows):
    print("\n### Accuracy once the maps share ≥ 30 landmarks (all fractions and seeds)\n")
    print("| preset | cases | found | max abs dtx (m) | max abs dty (m) | max abs dθ (rad) "
          "| within 0.05 m / 0.01 rad |")
    print("|---|---|---|---|---|---|---|")
    for preset in PRESETS:
        rs = [r for r in rows if r["common"] >= 30]
        errs = np.array([r[preset]["error"] for r in rs if r[preset]["found"]]).reshape(-1, 3)
        within = np.sum((errs[:, 0] < 0.05) & (errs[:, 1] < 0.05) & (errs[:, 2] < 0.01)) if len(errs) else 0
        mx = errs.max(axis=0) if len(errs) else [np.nan] * 3
        print(f"| {preset} | {len(rs)} | {len(errs)} | {_fmt(mx[0])} | {_fmt(mx[1])} | {_fmt(mx[2], 4)} | "
              f"{within}/{len(rs)} |")
    wrong = {p: sum(1 for r in rows if r[p]["found"] and (max(r[p]["error"][:2]) > WRONG_M
                                                           or r[p]["error"][2] > WRONG_RAD)) for p in PRESETS}
    print(f"\nWrong alignments reported on overlapping maps (error > {WRONG_M} m or {WRONG_RAD} rad), all "
          f"{len(rows)} cases: " + ", ".join(f"{p} {wrong[p]}" for p in PRESETS))


def false_alignments(seeds: int, noise: MapNoise):
    print(f"\n### False alignments on maps that share nothing ({seeds} seeds each)\n")
    print("| maps | preset | alignments reported (should be 0) |")
    print("|---|---|---|")
    cases = {
        "building, disjoint features, full routes": lambda s: non_overlapping_pair(1.0, s, noise),
        "building, disjoint features, 60 % of routes": lambda s: non_overlapping_pair(0.6, s, noise),
        "random 250 + 300 landmarks, 35 × 10 m": lambda s: random_pair(0, 250, 300, (3, 1, 0.4), seed=s)[:2],
    }
    for name, make in cases.items():
        found = dict.fromkeys(PRESETS, 0)
        for seed in range(seeds):
            m1, m2 = make(seed)
            m1, m2 = getattr(m1, "map", m1), getattr(m2, "map", m2)
            for preset in PRESETS:
                found[preset] += align(m1, m2, preset, np.random.default_rng(seed)).found
        for preset in PRESETS:
            print(f"| {name} | {preset} | {found[preset]}/{seeds} |")


def small_overlap(seeds: int):
    print(f"\n### Detecting a small overlap (random maps of 150 + 200 landmarks plus the common ones, 35 × 10 m, "
          f"σ 0.05 m, descriptor noise 0.4; {seeds} seeds)\n")
    print("| common landmarks | preset | found | mean abs dtx, dty (m), dθ (rad) |")
    print("|---|---|---|---|")
    pose = np.array([6.0, 2.0, 2.5])
    for n in (4, 6, 8, 10, 12, 15, 20, 25, 30):
        res = {p: [] for p in PRESETS}
        for seed in range(seeds):
            m1, m2, _ = random_pair(n, 150, 200, pose, seed=seed, sigma=0.05, descriptor_noise=0.4)
            for preset in PRESETS:
                a = align(m1, m2, preset, np.random.default_rng(seed))
                if a.found:
                    res[preset].append(alignment_error(a.pose, pose))
        for preset in PRESETS:
            e = np.array(res[preset]).reshape(-1, 3)
            cell = ", ".join(f"{e[:, k].mean():.3f}" for k in range(3)) if len(e) else "—"
            print(f"| {n} | {preset} | {len(e)}/{seeds} | {cell} |")


def print_common(rows, seeds):
    print(f"\n### Fig. 4 — common landmarks found by Method 1 and Method 2 (mean over {seeds} seeds; "
          "correct ones in brackets)\n")
    print("| route | true common | paper M1 | paper M2 | robust M1 | robust M2 |")
    print("|---|---|---|---|---|---|")
    for f in FRACTIONS:
        rs = [r for r in rows if r["fraction"] == f]
        cells = []
        for preset in PRESETS:
            for m in ("m1", "m2"):
                n = np.mean([r[preset][m][0] for r in rs])
                right = np.mean([r[preset][m][1] for r in rs])
                cells.append(f"{n:.1f} ({right:.1f})")
        print(f"| {f:.1f} | {np.mean([r['common'] for r in rs]):.1f} | " + " | ".join(cells) + " |")


def merged_accuracy(seeds: int, noise: MapNoise):
    print(f"\n### Merged map at the end of the routes (mean over {seeds} seeds)\n")
    print("| preset | method | landmarks 1 + 2 -> merged | common | position error of common landmarks: map 1 -> "
          "merged (m) | mean trace of their covariance: map 1 -> merged (m²) |")
    print("|---|---|---|---|---|---|")
    world = load_world()
    for preset in PRESETS:
        for method in (1, 2):
            acc = []
            for seed in range(seeds):
                s1, s2 = building_pair(1.0, seed, noise)
                a = align(s1.map, s2.map, preset, np.random.default_rng(seed))
                if not a.found:
                    continue
                g = merge(s1.map, s2.map, a, method)
                pairs = common_landmarks(s1.map, s2.map, a, method)
                truth = {tuple(p) for p in true_common(s1, s2).tolist()}
                right = np.array([tuple(p) in truth for p in pairs.tolist()], bool)
                rows = pairs[right, 0]
                start = np.asarray(s1.map.metadata["true_start_pose"])
                true_local = transform_points(inverse(start), world.features[s1.feature_index[rows]])
                acc.append((len(s1.map), len(s2.map), len(g), len(pairs),
                            np.linalg.norm(s1.map.positions[rows] - true_local, axis=1).mean(),
                            np.linalg.norm(g.positions[rows] - true_local, axis=1).mean(),
                            np.trace(s1.map.covariances[rows], axis1=1, axis2=2).mean(),
                            np.trace(g.covariances[rows], axis1=1, axis2=2).mean()))
            m = np.mean(acc, axis=0)
            print(f"| {preset} | {method} | {m[0]:.0f} + {m[1]:.0f} -> {m[2]:.0f} | {m[3]:.0f} | "
                  f"{m[4]:.3f} -> {m[5]:.3f} | {m[6]:.4f} -> {m[7]:.4f} |")


def oracle_pose(map1, map2, pairs: np.ndarray) -> np.ndarray:
    """The best rigid fit of map 2 onto map 1 given the true common landmarks (weighted least squares):
    what a perfect alignment algorithm would return on these (imperfect) maps."""
    truth = true_relative_pose(map1, map2)
    if len(pairs) < 2:
        return np.full(3, np.nan)
    p1, p2 = map1.positions[pairs[:, 0]], map2.positions[pairs[:, 1]]
    pose, _, _ = refine_pose(p1, map1.covariances[pairs[:, 0]], p2, map2.covariances[pairs[:, 1]], truth)
    return pose


def drift_table(seeds: int, noise: MapNoise, drifts=(0.002, 0.005, 0.01)):
    print(f"\n### Maps warped by correlated heading drift (full routes, mean over {seeds} seeds; max in brackets)\n")
    print("Error against the true start poses, and against the best rigid fit on the true common landmarks "
          "(the part the alignment itself is responsible for).\n")
    print("| heading drift (rad/√m) | preset | found | vs truth: abs dtx, dty (m), dθ (rad) | "
          "vs best rigid fit: abs dtx, dty (m), dθ (rad) |")
    print("|---|---|---|---|---|")
    for drift in drifts:
        nz = MapNoise(**{**noise.__dict__, "heading_drift": drift})
        res = {p: ([], []) for p in PRESETS}
        for seed in range(seeds):
            s1, s2 = building_pair(1.0, seed, nz)
            truth = true_relative_pose(s1.map, s2.map)
            best = oracle_pose(s1.map, s2.map, true_common(s1, s2))
            for preset in PRESETS:
                a = align(s1.map, s2.map, preset, np.random.default_rng(seed))
                if a.found:
                    res[preset][0].append(alignment_error(a.pose, truth))
                    res[preset][1].append(alignment_error(a.pose, best))
        for preset in PRESETS:
            t, b = np.array(res[preset][0]).reshape(-1, 3), np.array(res[preset][1]).reshape(-1, 3)
            cell = lambda e: ", ".join(f"{e[:, k].mean():.3f} [{e[:, k].max():.3f}]" for k in range(3))  # noqa: E731
            print(f"| {drift} | {preset} | {len(t)}/{seeds} | {cell(t)} | {cell(b)} |")


def slam_table(folder: Path, title: str = "FastSLAM maps from `p3at slam simulate`"):
    """Pairs of FastSLAM maps ``*_r1.npz`` / ``*_r2.npz`` written by ``p3at slam simulate``."""
    world = load_world()
    pairs = sorted(folder.glob("*_r1.npz"))
    print(f"\n### {title} ({len(pairs)} pairs)\n")
    print("| pair | landmarks 1 / 2 | true common | preset | supports | vs truth: abs dtx, dty (m), dθ (rad) | "
          "vs best rigid fit: abs dtx, dty (m), dθ (rad) | Method 1 / 2 common (correct) |")
    print("|---|---|---|---|---|---|---|---|")
    for f1 in pairs:
        f2 = f1.with_name(f1.name.replace("_r1", "_r2"))
        if not f2.exists():
            continue
        m1, m2 = LandmarkMap.load(f1), LandmarkMap.load(f2)
        feats = []
        for m in (m1, m2):           # each landmark's world feature: nearest in descriptor among those within 0.6 m
            local = transform_points(inverse(np.asarray(m.metadata["true_start_pose"])), world.features)
            d = np.linalg.norm(m.positions[:, None, :] - local[None, :, :], axis=2)
            dd = np.linalg.norm(m.descriptors[:, None, :] - world.feature_descriptors[None, :, :], axis=2)
            dd[d > 0.6] = np.inf
            feats.append(np.where(np.isfinite(dd.min(axis=1)), dd.argmin(axis=1), -1))
        rows2 = {int(f): r for r, f in enumerate(feats[1]) if f >= 0}
        common = np.array([(r, rows2[int(f)]) for r, f in enumerate(feats[0]) if f >= 0 and int(f) in rows2],
                          np.int64).reshape(-1, 2)
        truth, best = true_relative_pose(m1, m2), oracle_pose(m1, m2, common)
        cset = {tuple(p) for p in common.tolist()}
        for preset in PRESETS:
            a = align(m1, m2, preset, np.random.default_rng(0))
            if not a.found:
                print(f"| {f1.stem[:-3]} | {len(m1)} / {len(m2)} | {len(common)} | {preset} | not found | | | |")
                continue
            et, eb = alignment_error(a.pose, truth), alignment_error(a.pose, best)
            cm = []
            for method in (1, 2):
                pr = common_landmarks(m1, m2, a, method)
                cm.append(f"{len(pr)} ({sum(tuple(p) in cset for p in pr.tolist())})")
            print(f"| {f1.stem[:-3]} | {len(m1)} / {len(m2)} | {len(common)} | {preset} | {len(a.supports)} | "
                  f"{et[0]:.3f}, {et[1]:.3f}, {et[2]:.4f} | {eb[0]:.3f}, {eb[1]:.3f}, {eb[2]:.4f} | "
                  f"{' / '.join(cm)} |")


def figures(rows, out: Path, noise: MapNoise):
    x = np.array(FRACTIONS)
    series = {}
    for preset in PRESETS:
        for k, name in enumerate(("tx", "ty", "theta")):
            vals = []
            for f in FRACTIONS:
                e = [r[preset]["error"][k] for r in rows if r["fraction"] == f and r[preset]["found"]]
                vals.append(np.mean(e) if e else np.nan)
            series[f"{preset} {name}"] = np.array(vals)
    fusion_plots.line_plot(out / "fusion_fig2_alignment_error.png", x, series,
                           "Fig. 2: alignment error vs ground truth (mean over seeds)", "fraction of the routes driven",
                           "error (m, rad)", y_max=0.1, hlines={"0.05": 0.05, "0.01": 0.01})
    common = {"true common": np.array([np.mean([r["common"] for r in rows if r["fraction"] == f]) for f in FRACTIONS])}
    for preset in PRESETS:
        for m in ("m1", "m2"):
            common[f"{preset} Method {m[1]}"] = np.array(
                [np.mean([r[preset][m][0] for r in rows if r["fraction"] == f]) for f in FRACTIONS])
    fusion_plots.line_plot(out / "fusion_fig4_common_landmarks.png", x, common,
                           "Fig. 4: common landmarks between map 1 and map 2", "fraction of the routes driven",
                           "landmarks")

    s1, s2 = building_pair(1.0, 0, noise)
    a = align(s1.map, s2.map, "robust", np.random.default_rng(0))
    g = merge(s1.map, s2.map, a, 1)
    world = load_world()
    to_local = inverse(np.asarray(s1.map.metadata["true_start_pose"]))
    zeros = np.zeros((len(world.walls), 1))
    walls = np.column_stack([transform_points(to_local, np.hstack([world.walls[:, :2], zeros]))[:, :2],
                             transform_points(to_local, np.hstack([world.walls[:, 2:], zeros]))[:, :2]])
    blue, orange, green = (200, 90, 30), (30, 120, 230), (60, 170, 60)
    fusion_plots.map_2d(out / "fusion_fig3a_local_maps.png",
                        [("map 1", s1.map.positions, blue), ("map 2 (own frame)", s2.map.positions, orange)],
                        "Fig. 3(a): the local maps, each in its robot's start frame",
                        poses=[("robot 1", np.zeros(3)), ("robot 2", np.zeros(3))])
    x2 = transform_points(a.pose, s2.map.positions)
    fusion_plots.map_2d(out / "fusion_fig3b_aligned_maps.png",
                        [("map 1", s1.map.positions, blue), ("map 2 aligned", x2, orange)],
                        "Fig. 3(b): map 2 aligned to map 1 (robust RANSAC)", segments=walls,
                        poses=[("robot 1", np.zeros(3)), ("robot 2", a.pose)])
    both = g.seen_by.all(axis=1)
    only1 = g.seen_by[:, 0] & ~both
    only2 = g.seen_by[:, 1] & ~both
    groups = [("robot 1 only", g.positions[only1], blue), ("robot 2 only", g.positions[only2], orange),
              ("merged (both)", g.positions[both], green)]
    fusion_plots.map_2d(out / "fusion_fig5_merged_2d.png", groups, "Fig. 5: merged map (2-D view)", segments=walls,
                        poses=[("robot 1", np.zeros(3)), ("robot 2", a.pose)])
    fusion_plots.map_3d(out / "fusion_fig6_merged_3d.png", groups, "Fig. 6: merged map (3-D view)")
    print(f"\nfigures written to {out}/fusion_fig*.png")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20, help="random seeds per snapshot (20)")
    parser.add_argument("--false-seeds", type=int, default=200, help="seeds per non-overlap case (200)")
    parser.add_argument("--descriptor-noise", type=float, default=MapNoise().descriptor_noise,
                        help=f"descriptor noise of the simulated maps ({MapNoise().descriptor_noise})")
    parser.add_argument("--figures", type=Path, help="write the PNG figures into this folder")
    parser.add_argument("--slam-maps", type=Path, help="folder of FastSLAM map pairs NAME_r1.npz / NAME_r2.npz")
    parser.add_argument("--slam-growth", type=Path, help="folder of FastSLAM map pairs of one run cut at several "
                        "times (tNNNs_r1.npz / tNNNs_r2.npz)")
    args = parser.parse_args()
    noise = MapNoise(descriptor_noise=args.descriptor_noise)
    t0 = time.perf_counter()
    print(f"simulated maps: {noise}")
    rows = growth(args.seeds, noise)
    print_growth(rows, args.seeds)
    print_goal(rows)
    false_alignments(args.false_seeds, noise)
    small_overlap(args.seeds)
    print_common(rows, args.seeds)
    merged_accuracy(min(args.seeds, 10), noise)
    drift_table(min(args.seeds, 10), noise)
    if args.slam_growth:
        slam_table(args.slam_growth, "Fig. 2 on FastSLAM maps: one run of each robot cut after t seconds")
    if args.slam_maps:
        slam_table(args.slam_maps)
    if args.figures:
        figures(rows, args.figures, noise)
    print(f"\n({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
