"""Why MRCLAM FastSLAM maps align or not, and what limits their merge (docs/fusion.md, issue 13).

    .venv/bin/python -m benchmarks.fusion_mrclam_diagnosis DIR [DIR ...]

DIR holds robot1.npz ... robot5.npz of known-ID maps (``p3at slam dataset mrclam``, ``benchmarks.eval_mrclam
--maps``).  For every pair: the identities both maps hold, the supports found and needed, the chance supports a
wrong transform gathers, the gate radius, and how far the shared identities lie from each other after their own
best rigid fit (so a refusal can be told apart: too few shared landmarks for the gate's size, correct pairs
thrown out by the gate, or ambiguity).  Then the merge: each map's real σ about its best rigid fit to the Vicon
landmarks against the σ from the pairwise residuals (``fusion.multi.covariance_scales``) and the σ it claims;
the merged map by the claimed covariances, by the calibrated ones, by the real σ (oracle weights), and the
plain average of the two best maps each placed by its own best rigid fit (what no weighting can beat), with the
correlation of those two maps' errors; for the merged maps, the landmarks' NEES against Vicon (2-D, after the
best rigid fit: is the merged map confidently wrong?) and the identities the maps disagreed about
(``metadata["identity_conflicts"]``).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from eval_fusion import MRCLAM_DATASET2, frame_fit, rigid_fit_2d  # noqa: E402
from fusion_sim import mrclam_sighting_map  # noqa: E402

import fusion.multi as multi  # noqa: E402
from estimation.geometry import rot_z, transform_points  # noqa: E402
from estimation.landmark_map import LandmarkMap  # noqa: E402
from fusion import align, fuse_all  # noqa: E402


def _planar(points: np.ndarray) -> np.ndarray:
    return np.column_stack([points, np.zeros(len(points))])


def _median_error(est: np.ndarray, world: np.ndarray) -> float:
    fit = rigid_fit_2d(est, world)
    return float(np.median(np.linalg.norm(transform_points(fit, _planar(est))[:, :2] - world, axis=1)))


CHI2_2_99 = 9.210   # 99 % quantile of χ²(2)


def landmark_nees(m: LandmarkMap, truth: dict) -> np.ndarray:
    """Per landmark with a true position, e_xyᵀ Σ_xy⁻¹ e_xy after the map's best rigid fit to the truth (≈ χ²(2) when
    the map's covariances describe its shape errors)."""
    fit, _, ids = frame_fit(m, truth)
    R = rot_z(fit[2])[:2, :2]
    rows = [k for k in range(len(m)) if int(ids[k]) in truth]
    e = transform_points(fit, m.positions[rows])[:, :2] - np.array([truth[int(ids[k])] for k in rows])
    P = R @ m.covariances[rows][:, :2, :2] @ R.T
    return np.einsum("ki,ki->k", e, np.linalg.solve(P, e[..., None])[..., 0])


def refusals(maps: list[LandmarkMap]) -> None:
    print("| pair | shared identities | supports (needed) | chance supports per wrong transform | gate radius (m) | "
          "shared identities after their own best rigid fit: median / max residual (m) | outside the gate | found |")
    print("|---|---|---|---|---|---|---|---|")
    for i in range(len(maps)):
        for j in range(i + 1, len(maps)):
            a = align(maps[i], maps[j], "robust", np.random.default_rng(0))
            st = a.statistics
            d1 = dict(zip(maps[i].metadata["external_ids"], maps[i].positions[:, :2], strict=True))
            d2 = dict(zip(maps[j].metadata["external_ids"], maps[j].positions[:, :2], strict=True))
            shared = sorted(set(d1) & set(d2))
            p1, p2 = np.array([d1[k] for k in shared]), np.array([d2[k] for k in shared])
            fit = rigid_fit_2d(p2, p1)
            res = np.linalg.norm(p1 - transform_points(fit, _planar(p2))[:, :2], axis=1)
            print(f"| {maps[i].robot}–{maps[j].robot} | {len(shared)} | {st.supports} ({st.required_supports}) | "
                  f"{st.expected_chance_supports - 2:.2f} | {st.gate_radius:.2f} | {np.median(res):.2f} / "
                  f"{res.max():.2f} | {int(np.sum(res > st.gate_radius))} | {'yes' if a.found else 'no'} |")


def merge_limits(maps: list[LandmarkMap], truth: dict) -> None:
    fits = [frame_fit(m, truth) for m in maps]
    real_var = np.array([np.nanmean(f[1] ** 2) / 2 for f in fits])
    claimed_var = np.array([multi.claimed_variance(m) for m in maps])
    alignments = multi.pairwise_alignments(maps, "robust", np.random.default_rng(0))
    scales = multi.covariance_scales(maps, alignments)
    hat = "—" if scales is None else ", ".join(f"{np.sqrt(v):.3f}" for v in scales * claimed_var)
    real = ", ".join(f"{np.sqrt(v):.3f}" for v in real_var)
    claimed = ", ".join(f"{np.sqrt(v):.3f}" for v in claimed_var)
    print(f"\nσ per axis about the best rigid fit to Vicon (real): {real} m; from the pairwise residuals: {hat} m; "
          f"claimed: {claimed} m")
    rows = [("by the claimed covariances", dict(calibrate=False)), ("calibrated (covariance_scales)", {})]
    original = multi.covariance_scales
    for label, kw in rows:
        merged = fuse_all(maps, "robust", 1, alignments=alignments, **kw).map
        e = frame_fit(merged, truth)[1]
        nees = landmark_nees(merged, truth)
        conflicts = "; ".join(f"id {c['identity']} of {c['robot']} {c['distance_m']:.2f} m off "
                              f"(d² {c['mahalanobis_d2']:.1f} > {c['gate_d2']:.2f})"
                              for c in merged.metadata.get("identity_conflicts", []))
        print(f"merged {label}: {len(merged)} landmarks, median {np.nanmedian(e):.3f} m, mean {np.nanmean(e):.3f} m; "
              f"NEES vs Vicon median {np.median(nees):.1f} (χ²(2): 1.4), {int(np.sum(nees > CHI2_2_99))} of "
              f"{len(nees)} above {CHI2_2_99}; identity conflicts: {conflicts or 'none'}")
    try:
        multi.covariance_scales = lambda *_a, **_k: real_var / claimed_var
        e = frame_fit(fuse_all(maps, "robust", 1, alignments=alignments).map, truth)[1]
        print(f"merged by the real σ (oracle weights): median {np.nanmedian(e):.3f} m, mean {np.nanmean(e):.3f} m")
    finally:
        multi.covariance_scales = original
    singles = [float(np.nanmedian(f[1])) for f in fits]
    print("single maps: " + ", ".join(f"{m.robot} {v:.3f}" for m, v in zip(maps, singles, strict=True)) + " m median")
    best = np.argsort(real_var)[:2]
    placed = []
    for k in best:
        x = transform_points(fits[k][0], maps[k].positions)[:, :2]
        placed.append(dict(zip(map(int, maps[k].metadata["external_ids"]), x, strict=True)))
    ids = [i for i in truth if all(i in p for p in placed)]
    world = np.array([truth[i] for i in ids])
    avg = np.mean([[p[i] for i in ids] for p in placed], axis=0)
    errs = [np.concatenate([p[i] - truth[i] for i in ids]) for p in placed]
    alone = [_median_error(np.array([p[i] for i in ids]), world) for p in placed]
    print(f"the two best maps ({', '.join(maps[k].robot for k in best)}), each placed by its own best rigid fit, "
          f"averaged: median {_median_error(avg, world):.3f} m against {alone[0]:.3f} / {alone[1]:.3f} m alone on the "
          f"same {len(ids)} landmarks; correlation of their errors {np.corrcoef(*errs)[0, 1]:+.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", type=Path, nargs="+", help="folders of robot1.npz ... robot5.npz")
    parser.add_argument("--mrclam", type=Path, default=MRCLAM_DATASET2, help="MRCLAM dataset 2 folder (the truth)")
    args = parser.parse_args()
    if not args.mrclam.is_dir():
        print(f"fusion_mrclam_diagnosis: {args.mrclam} not found (the Vicon landmarks are needed)", file=sys.stderr)
        raise SystemExit(2)
    truth = mrclam_sighting_map(args.mrclam, 1).truth
    for folder in args.folders:
        maps = [LandmarkMap.load(folder / f"robot{r}.npz") for r in range(1, 6)]
        print(f"\n### {folder}\n")
        refusals(maps)
        merge_limits(maps, truth)


if __name__ == "__main__":
    main()
