"""Why MRCLAM FastSLAM maps align or not, and what limits their merge (docs/fusion.md, issue 13).

    .venv/bin/python -m benchmarks.fusion_mrclam_diagnosis DIR [DIR ...] [--truth-heading mocap|travel]

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

Session 7 (``merge_rules``, ``merge_breakdown``): every merge rule × calibration (``fuse_all(merge_rule=...,
calibration=...)``) with its error and NEES against Vicon, and where the default merge's error comes from: the same
merge with each map placed by its own best rigid fit to Vicon (no frame error), with the best linear weights the true
errors allow (in-sample: no weighting can do better), and the best single map on the same posts.

Session 10 (``drift_split``, maps whose files keep the frame's drift): each map's frame error and local error against
what its file says of both, and the merge with ``calibration="drift"`` among the rules.

Session 11 (``sighting_split``, maps whose files keep the sightings' spread): each map's real local σ against the σ
its own sightings' spread gives (per sighting and per mean), rank correlations over maps and over each map's
landmarks, and the merge with ``calibration="sightings"`` and its measured variants (pooled per map, with a floor,
per mean).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from eval_fusion import MRCLAM_DATASET2, frame_fit  # noqa: E402
from fusion_sim import mrclam_sighting_map, start_heading_refusal  # noqa: E402

import fusion.multi as multi  # noqa: E402
from estimation.datasets import TRUTH_HEADINGS  # noqa: E402
from estimation.geometry import compose, inverse, rot_z, transform_points  # noqa: E402
from estimation.landmark_map import LandmarkMap  # noqa: E402
from estimation.landmark_scores import rigid_fit_2d  # noqa: E402
from fusion import align, fuse_all  # noqa: E402
from fusion.merging import MERGE_RULES, transform_landmarks  # noqa: E402
from fusion.shape_covariance import (  # noqa: E402
    rigid_covariance,
    shape_covariances,
    shape_levels,
    sighting_variances,
)


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


def _nees_text(nees: np.ndarray) -> str:
    above = int(np.sum(nees > CHI2_2_99))
    return f"NEES vs Vicon median {np.median(nees):.1f}, {above} of {len(nees)} above {CHI2_2_99}"


def merge_rules(maps: list[LandmarkMap], truth: dict, alignments, title: str = "") -> None:
    """The merged map's error and NEES against Vicon for every merge rule and calibration of ``fuse_all``."""
    singles = [float(np.nanmedian(frame_fit(m, truth)[1])) for m in maps]
    print(f"\n{title}merge rule × calibration (best single map {min(singles):.3f} m; defaults: kalman, isotropic):")
    for calibration in multi.CALIBRATIONS:
        for rule in MERGE_RULES:
            merged = fuse_all(maps, "robust", 1, alignments=alignments, merge_rule=rule, calibration=calibration).map
            e = frame_fit(merged, truth)[1]
            print(f"  {rule:12s} {calibration:9s}: {len(merged)} landmarks, median {np.nanmedian(e):.3f} m, "
                  f"mean {np.nanmean(e):.3f} m; {_nees_text(landmark_nees(merged, truth))}")


def _by_identity(maps, poses, pose_covs, excluded) -> dict[int, list[tuple[int, np.ndarray, np.ndarray]]]:
    """Every map's landmarks placed by ``poses`` (``pose_covs`` added when given): identity -> [(map, xy, P_xy)]."""
    out: dict[int, list] = {}
    for k, m in enumerate(maps):
        x, P = transform_landmarks(m.positions, m.covariances, poses[k], None if pose_covs is None else pose_covs[k])
        for r, i in enumerate(m.metadata["external_ids"]):
            if (m.robot, int(i)) not in excluded:
                out.setdefault(int(i), []).append((k, x[r, :2], P[r, :2, :2]))
    return out


def _information_merge(items) -> tuple[np.ndarray, np.ndarray]:
    info = sum(np.linalg.inv(P) for _, _, P in items)
    P = np.linalg.inv(info)
    return P @ sum(np.linalg.solve(Pk, x) for _, x, Pk in items), P


def _placed_error(estimates: dict[int, np.ndarray], truth: dict, covs: dict | None = None):
    """Median error after the best rigid fit of id -> xy to the truth (and the NEES when ``covs`` are given)."""
    ids = sorted(i for i in estimates if i in truth)
    est, world = np.array([estimates[i] for i in ids]), np.array([truth[i] for i in ids])
    fit = rigid_fit_2d(est, world)
    e = transform_points(fit, _planar(est))[:, :2] - world
    if covs is None:
        return float(np.median(np.linalg.norm(e, axis=1))), None
    R = rot_z(fit[2])[:2, :2]
    nees = np.array([v @ np.linalg.solve(R @ covs[i] @ R.T, v) for v, i in zip(e, ids, strict=True)])
    return float(np.median(np.linalg.norm(e, axis=1))), nees


def merge_breakdown(maps: list[LandmarkMap], truth: dict, alignments) -> None:
    """Where the default merge's error comes from: each map's frame (its placement in the reference frame), the
    merge weights, or the maps' shapes (what is left with perfect frames and the best weights the truth allows)."""
    fused = fuse_all(maps, "robust", 1, alignments=alignments)
    excluded = {(c["robot"], int(c["identity"])) for c in fused.map.metadata.get("identity_conflicts", [])}
    scales = fused.covariance_scales or [1.0] * len(maps)
    calibrated = [multi.calibrated_map(m, c) for m, c in zip(maps, scales, strict=True)]
    fits = []
    for m in maps:      # each map's best rigid fit to Vicon, without the landmarks the merge withheld
        ids = [int(i) for i in m.metadata["external_ids"]]
        keep = [r for r, i in enumerate(ids) if i in truth and (m.robot, i) not in excluded]
        fits.append(rigid_fit_2d(m.positions[keep, :2], np.array([truth[ids[r]] for r in keep])))
    oracle = [compose(inverse(fits[fused.reference]), f) for f in fits]   # in the reference map's frame
    frame_err = [between_text(p, o) for p, o in zip(fused.placements, oracle, strict=True)]
    print("\nwhere the default merge's error comes from (identities the merge withheld left out):")
    print("  each map's placement in the reference frame against its own best rigid fit to Vicon: "
          + ", ".join(f"{m.robot} {t}" for m, t in zip(maps, frame_err, strict=True)))
    rows = [("as merged (placements, their covariance added)", fused.placements, fused.placement_covariances),
            ("placed by the alignments' start-frame poses (before session 9)", fused.poses, fused.covariances),
            ("each map on its own best rigid fit (no frame error)", oracle, None)]
    for label, poses, covs in rows:
        g = _by_identity(calibrated, poses, covs, excluded)
        merged = {i: _information_merge(items) for i, items in g.items()}
        err, nees = _placed_error({i: v[0] for i, v in merged.items()}, truth, {i: v[1] for i, v in merged.items()})
        print(f"  {label}: median {err:.3f} m; {_nees_text(nees)}")
    # a common frame re-estimated from all maps (generalised Procrustes): each map's pose refitted to the merged
    # landmarks (its alignment covariance kept), the landmarks merged again, five rounds
    poses = [np.asarray(p, float) for p in fused.placements]
    for _ in range(5):
        merged = {i: _information_merge(items)
                  for i, items in _by_identity(calibrated, poses, fused.placement_covariances, excluded).items()}
        for k, m in enumerate(maps):
            if k != fused.reference:
                ids = [int(i) for i in m.metadata["external_ids"]]
                keep = [r for r, i in enumerate(ids) if i in merged and (m.robot, i) not in excluded]
                poses[k] = rigid_fit_2d(m.positions[keep, :2], np.array([merged[ids[r]][0] for r in keep]))
    merged = {i: _information_merge(items)
              for i, items in _by_identity(calibrated, poses, fused.placement_covariances, excluded).items()}
    err, nees = _placed_error({i: v[0] for i, v in merged.items()}, truth, {i: v[1] for i, v in merged.items()})
    print(f"  in a common frame re-estimated from all maps (each map refitted to the merged landmarks, 5 rounds): "
          f"median {err:.3f} m; {_nees_text(nees)}")
    placed = _by_identity(maps, fits, None, excluded)          # in the Vicon frame
    common = sorted(i for i, items in placed.items() if len(items) == len(maps) and i in truth)
    errors = np.array([[np.r_[placed[i][k][1] - truth[i]] for i in common] for k in range(len(maps))])  # (K, L, 2)
    flat = errors.reshape(len(maps), -1)
    C = flat @ flat.T / flat.shape[1]
    w = np.linalg.solve(C, np.ones(len(maps)))
    w /= w.sum()
    best_linear = {i: sum(w[k] * placed[i][k][1] for k in range(len(maps))) for i in common}
    alone = [_placed_error({i: placed[i][k][1] for i in common}, truth)[0] for k in range(len(maps))]
    print(f"  on the {len(common)} posts every map holds, each map on its own best rigid fit: weights from the true "
          f"errors' covariance (best linear, in-sample) {', '.join(f'{v:+.2f}' for v in w)} -> median "
          f"{_placed_error(best_linear, truth)[0]:.3f} m; each map alone {', '.join(f'{v:.3f}' for v in alone)} m; "
          f"correlation of the maps' errors (pairs 12 13 14 15 23 ...) "
          f"{np.array2string(np.corrcoef(flat)[np.triu_indices(len(maps), 1)], precision=2)}")


def drift_split(maps: list[LandmarkMap], truth: dict, alignments) -> None:
    """Per map: which part of its error is frame (rigid: its best rigid fit to Vicon against its true start, at its
    landmarks' centroid) and which local (about that fit), and what its own file says of both (the drift it keeps,
    ``fusion.shape_covariance``: the rigid part's covariance and each landmark's about the rigid placement), beside
    the three-cornered hat's σ.  Maps without the drift fields are skipped (made before session 10)."""
    if any(m.drift_covariances is None for m in maps):
        print("\nframe and local error against what each file says: skipped (a map without the drift fields)")
        return
    scales = multi.covariance_scales(maps, alignments)
    hat = [np.nan] * len(maps) if scales is None else np.sqrt(scales * [multi.claimed_variance(m) for m in maps])
    shapes = [shape_covariances(m) for m in maps]
    levels = shape_levels(maps, shapes, alignments)
    print("\n| map | frame error at the centroid, xy (m) / θ (rad) | the file's rigid σ, xy (m) / θ (rad) | frame NEES "
          "(χ²₃) | local σ per axis, real (m) | the file's shape σ (m) | hat σ (m) | shape NEES under the file, median "
          "(χ²₂: 1.39) / under a I + b S |")
    print("|---|---|---|---|---|---|---|---|")
    for m, shape, h in zip(maps, shapes, hat, strict=True):
        fit, err, ids = frame_fit(m, truth)
        ok = np.isfinite(err)
        start = np.asarray(m.metadata["true_start_pose"], float)
        centroid = np.r_[m.positions[:, :2].mean(axis=0), 0.0][None]
        d_xy = (transform_points(fit, centroid) - transform_points(start, centroid))[0, :2]
        d_xy = rot_z(-start[2])[:2, :2] @ d_xy                      # in the map's frame, as the file's covariance
        d_th = float(np.arctan2(np.sin(fit[2] - start[2]), np.cos(fit[2] - start[2])))
        F = rigid_covariance(m)      # the chain model's cross terms need not make it PSD: clipped, so NEES by pinv
        d = np.r_[d_xy, d_th]
        world = np.array([truth[int(i)] for i in ids[ok]])
        r = (transform_points(fit, m.positions[ok])[:, :2] - world) @ rot_z(fit[2])[:2, :2]   # into the map's frame
        nees = np.einsum("ki,ki->k", r, np.linalg.solve(shape[ok], r[..., None])[..., 0])
        text = "—"
        if levels is not None:
            P = levels[0] * np.eye(2) + levels[1] * shape[ok]
            text = f"{np.median(np.einsum('ki,ki->k', r, np.linalg.solve(P, r[..., None])[..., 0])):.1f}"
        file_shape = np.sqrt(np.mean(np.trace(shape, axis1=1, axis2=2)) / 2)
        print(f"| {m.robot} | {np.hypot(*d_xy):.3f} / {abs(d_th):.4f} | {np.sqrt(F[0, 0] + F[1, 1]):.3f} / "
              f"{np.sqrt(F[2, 2]):.4f} | {d @ np.linalg.pinv(F) @ d:.1f} | {np.sqrt(np.nanmean(err ** 2) / 2):.3f} | "
              f"{file_shape:.3f} | {h:.3f} | {np.median(nees):.1f} / {text} |")
    if levels is not None:
        print(f"a I + b S fitted on the pairs (fusion.shape_covariance.shape_levels): "
              f"a = ({np.sqrt(levels[0]):.3f} m)², b = {levels[1]:.3f}")


def _spearman(a, b) -> float:
    ra, rb = np.argsort(np.argsort(a)), np.argsort(np.argsort(b))
    return float(np.corrcoef(ra, rb)[0, 1])


def sighting_split(maps: list[LandmarkMap], truth: dict, alignments) -> None:
    """Per map: the real local σ (about its best rigid fit to Vicon) against the σ its own sightings' spread gives
    (``fusion.shape_covariance.sighting_variances``, per sighting and per mean), the drift's shape σ and the hat's;
    Spearman over each map's landmarks (squared error about the fit against v_l); then the merge by
    ``calibration="sightings"`` and its variants (``fusion.multi.sighting_calibrated``).  Maps without the field are
    skipped (made before session 11)."""
    if any(m.sighting_covariances is None for m in maps):
        print("\nthe sightings' spread against the real local error: skipped (a map without sighting_covariances)")
        return
    scales = multi.covariance_scales(maps, alignments)
    hat = [np.nan] * len(maps) if scales is None else np.sqrt(scales * [multi.claimed_variance(m) for m in maps])
    print("\n| map | local σ per axis, real (m) | sightings' σ, per sighting (m) | per mean (m) | drift shape σ (m) | "
          "hat σ (m) | Spearman over its landmarks, e² vs v (per sighting / per mean) |")
    print("|---|---|---|---|---|---|---|")
    real, spread, spread_mean = [], [], []
    for m, h in zip(maps, hat, strict=True):
        _, err, _ = frame_fit(m, truth)
        ok = np.isfinite(err)
        v, vm = sighting_variances(m), sighting_variances(m, "mean")
        shape = shape_covariances(m)
        drift = "—" if shape is None else f"{np.sqrt(np.mean(np.trace(shape, axis1=1, axis2=2)) / 2):.3f}"
        real.append(np.sqrt(np.nanmean(err ** 2) / 2))
        spread.append(np.sqrt(np.mean(v)))
        spread_mean.append(np.sqrt(np.mean(vm)))
        print(f"| {m.robot} | {real[-1]:.3f} | {spread[-1]:.3f} | {spread_mean[-1]:.3f} | {drift} | {h:.3f} | "
              f"{_spearman(err[ok] ** 2, v[ok]):+.2f} / {_spearman(err[ok] ** 2, vm[ok]):+.2f} |")
    print(f"Spearman over the maps, real σ vs the sightings' σ: per sighting {_spearman(real, spread):+.2f}, per mean "
          f"{_spearman(real, spread_mean):+.2f}, the hat {_spearman(real, hat):+.2f}")
    singles = [float(np.nanmedian(frame_fit(m, truth)[1])) for m in maps]
    print(f"merged by the sightings' spread (best single map {min(singles):.3f} m):")
    variants = [("calibration='sightings' (b v_l, per sighting)", {}), ("per mean (b v_l / n_l)", {"per": "mean"}),
                ("pooled per map (b mean v)", {"pooled": True}), ("with a floor ((a + b v_l), shape_levels)",
                                                                   {"floor": True})]
    original = multi.sighting_calibrated
    for label, kw in variants:
        try:
            multi.sighting_calibrated = lambda ms, al, _kw=kw: original(ms, al, **_kw)
            merged = fuse_all(maps, "robust", 1, alignments=alignments, calibration="sightings").map
        finally:
            multi.sighting_calibrated = original
        e = frame_fit(merged, truth)[1]
        print(f"  {label}: {len(merged)} landmarks, median {np.nanmedian(e):.3f} m, mean {np.nanmean(e):.3f} m; "
              f"{_nees_text(landmark_nees(merged, truth))}")


def between_text(pose, reference) -> str:
    d = compose(inverse(np.asarray(reference, float)), np.asarray(pose, float))
    return f"{np.hypot(d[0], d[1]):.3f} m / {abs(np.arctan2(np.sin(d[2]), np.cos(d[2]))):.4f} rad"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", type=Path, nargs="+", help="folders of robot1.npz ... robot5.npz")
    parser.add_argument("--mrclam", type=Path, default=MRCLAM_DATASET2, help="MRCLAM dataset 2 folder (the truth)")
    parser.add_argument("--truth-heading", choices=TRUTH_HEADINGS, default="mocap",
                        help="MRCLAM's ground-truth heading: Vicon's as written (mocap, default) or turned onto each "
                             "robot's direction of travel (travel), for the sighting maps; the maps in DIR must have "
                             "been made with the same (p3at slam dataset --truth-heading), else refused")
    args = parser.parse_args(argv)
    if not args.mrclam.is_dir():
        print(f"fusion_mrclam_diagnosis: {args.mrclam} not found (the Vicon landmarks are needed)", file=sys.stderr)
        raise SystemExit(2)
    placed = [mrclam_sighting_map(args.mrclam, r, truth_heading=args.truth_heading) for r in range(1, 6)]
    sightings, truth = [s.map for s in placed], placed[0].truth
    folders = {folder: [LandmarkMap.load(folder / f"robot{r}.npz") for r in range(1, 6)] for folder in args.folders}
    for folder, maps in folders.items():
        if (problem := start_heading_refusal(maps, placed, args.truth_heading)) is not None:
            parser.exit(2, f"fusion_mrclam_diagnosis: {folder}: {problem}\n")
    heading = "" if args.truth_heading == "mocap" else ", the truth's heading on the direction of travel"
    merge_rules(sightings, truth, multi.pairwise_alignments(sightings, "robust", np.random.default_rng(0)),
                f"MRCLAM sighting maps (real sightings placed from Vicon poses{heading}, not SLAM): ")
    for folder, maps in folders.items():
        print(f"\n### {folder}{heading}\n")
        refusals(maps)
        merge_limits(maps, truth)
        alignments = multi.pairwise_alignments(maps, "robust", np.random.default_rng(0))
        drift_split(maps, truth, alignments)
        sighting_split(maps, truth, alignments)
        merge_rules(maps, truth, alignments)
        merge_breakdown(maps, truth, alignments)


if __name__ == "__main__":
    main()
