"""Quality of the visual front end on real stereo pairs (and rendered frames when the virtual head exists).

Run from the repository root:  .venv/bin/python -m benchmarks.eval_frontend  [--data ../shared/data] [--json]
Prints the tables of docs/frontend.md.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

from estimation.frontend import (
    FrontEndConfig,
    StereoMatchConfig,
    TriangulationNoise,
    run_frontend,
)
from estimation.frontend.evaluation import (
    chi2_interval,
    middlebury_truth,
    nees,
    score_disparities,
    sgbm_disparity,
    truth_at,
)
from runtime.commands.features import front_end_from_calibration

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_DATA = ROOT / ".." / "shared" / "data"
# the real pairs have no metric calibration: score disparities only, keep every positive one
PIXELS_ONLY = TriangulationNoise(min_disparity=0.5, max_depth=1e9)


def read_grey(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise FileNotFoundError(f"cannot read image {path}")
    return image


def evaluate_pair(left: np.ndarray, right: np.ndarray, truth: np.ndarray, max_disparity: int,
                  truth_is_sgbm: bool = False) -> list[dict]:
    """Rows (one per descriptor) scoring our sparse matches against ``truth``, and SGBM at the same pixels."""
    sgbm = sgbm_disparity(left, right, max_disparity)
    rows = []
    for kind in ("usurf", "sift", "orb"):
        config = FrontEndConfig(descriptor=kind, matching=StereoMatchConfig(max_disparity=max_disparity),
                                noise=PIXELS_ONLY)
        matches = run_frontend(left, right, config)
        ours = score_disparities(matches.left_pixels, matches.disparities, truth)
        row = {"descriptor": kind, "matches": len(matches), **{f"ours_{k}": v for k, v in ours.as_dict().items()}}
        if not truth_is_sgbm:
            at_pixels = truth_at(matches.left_pixels, sgbm)
            theirs = score_disparities(matches.left_pixels, at_pixels, truth)
            row.update({f"sgbm_{k}": v for k, v in theirs.as_dict().items()})
        rows.append(row)
    return rows


def evaluate_real(data: Path) -> dict[str, list[dict]]:
    results: dict[str, list[dict]] = {}
    cones = data / "stereo" / "middlebury-cones"
    if cones.is_dir():
        truth = middlebury_truth(cv2.imread(str(cones / "disp2.pgm"), cv2.IMREAD_UNCHANGED))
        results["cones (truth: disp2.pgm)"] = evaluate_pair(read_grey(cones / "im2.png"), read_grey(cones / "im6.png"),
                                                            truth, max_disparity=64)
    tsukuba = data / "stereo" / "tsukuba"
    if tsukuba.is_dir():
        left, right = read_grey(tsukuba / "tsukuba_l.png"), read_grey(tsukuba / "tsukuba_r.png")
        proxy = np.nan_to_num(sgbm_disparity(left, right, 32), nan=0.0)  # no truth here: agreement with SGBM
        results["tsukuba (reference: SGBM, no truth)"] = evaluate_pair(left, right, proxy, 32, truth_is_sgbm=True)
    return results


# robot poses (x, y, θ) in the packaged office building: along the corridor, both ways, and turned to the walls
RENDER_POSES = ((3.0, 5.0, 0.0), (8.0, 5.0, np.pi), (5.0, 5.0, 0.5), (10.0, 4.5, -0.3), (20.0, 5.5, 2.6),
                (15.0, 7.5, -1.2))


def rendered_frames(poses=RENDER_POSES, seed: int = 0, noise_dn: float = 1.0):
    """Yield (pose, left uint8, right uint8, renderer, calibration) of raw frames of the virtual head.

    The renderer gives radiance 0..1; it becomes digital numbers ×255 plus Gaussian noise of ``noise_dn``.
    """
    from drivers.videre import calibration
    from mocks.stereo_head.renderer import StereoRenderer
    from mocks.world import World

    calib = calibration.load(ROOT / "mocks" / "stereo_head" / "data" / "sth_mdcs2_default.ini")
    renderer = StereoRenderer(World.load(), calib)
    rng = np.random.default_rng(seed)
    for pose in poses:
        pose = np.asarray(pose, dtype=float)
        images = [np.clip(np.rint(im * 255.0 + rng.normal(0.0, noise_dn, im.shape)), 0, 255).astype(np.uint8)
                  for im in renderer.render(pose)]
        yield pose, images[0], images[1], renderer, calib


def world_to_base(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """World points (N, 3) in the frame of a robot at planar pose (x, y, θ)."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    dx, dy = points[:, 0] - pose[0], points[:, 1] - pose[1]
    return np.column_stack([c * dx + s * dy, -s * dx + c * dy, points[:, 2]])


def evaluate_rendered(poses=RENDER_POSES, seed: int = 0) -> dict:
    """3-D error and covariance consistency of the front end on rendered frames against the true points."""
    errors, nees_3d, disparity_errors, depths = [], [], [], []
    front_end = None
    for pose, left, right, renderer, calib in rendered_frames(poses, seed):
        front_end = front_end or front_end_from_calibration(calib)
        obs = front_end.process(left, right, 0.0)
        matches = front_end.last_matches
        truth = world_to_base(pose, renderer.true_points(pose, matches.left_pixels, "left", rectified=True))
        known = np.all(np.isfinite(truth), axis=1)
        error = obs.points[known] - truth[known]
        camera = front_end.config.geometry.left_camera_to_base()
        truth_camera = (truth[known] - camera[:3, 3]) @ camera[:3, :3]
        geometry = front_end.config.geometry
        errors.append(error)
        nees_3d.append(nees(error, obs.covariances[known]))
        disparity_errors.append(matches.disparities[known] - geometry.fx * geometry.baseline / truth_camera[:, 2])
        depths.append(truth_camera[:, 2])
    error, n3, dd, depth = (np.concatenate(a) for a in (errors, nees_3d, disparity_errors, depths))
    sigma_d = front_end.config.noise.sigma_d
    upper3 = chi2_interval(3, 0.90)[1]  # one-sided 95 % bound of χ²(3)
    upper1 = chi2_interval(1, 0.90)[1]  # one-sided 95 % bound of χ²(1)
    norm = np.linalg.norm(error, axis=1)
    return {
        "frames": len(poses), "points": int(len(error)),
        "median_depth_m": float(np.median(depth)),
        "median_3d_error_m": float(np.median(norm)), "p90_3d_error_m": float(np.percentile(norm, 90)),
        "median_relative_3d_error": float(np.median(norm / depth)),
        "disparity_within_1px": float(np.mean(np.abs(dd) <= 1.0)),
        "median_disparity_error_px": float(np.median(np.abs(dd))),
        "rms_disparity_error_px_inliers": float(np.sqrt(np.mean(dd[np.abs(dd) <= 1.0] ** 2))),
        "nees3_below_chi2_95": float(np.mean(n3 <= upper3)), "nees3_median": float(np.median(n3)),
        "disparity_nees_below_chi2_95": float(np.mean((dd / sigma_d) ** 2 <= upper1)),
        "chi2_3_95": upper3, "chi2_1_95": upper1,
    }


def print_rendered(r: dict) -> None:
    print(f"\nrendered frames of the virtual head ({r['frames']} poses, {r['points']} points, "
          f"median depth {r['median_depth_m']:.2f} m)")
    print("| measure | value |\n|---|---|")
    rows = [
        ("3-D error, median", f"{r['median_3d_error_m'] * 100:.1f} cm ({r['median_relative_3d_error']:.1%} of depth)"),
        ("3-D error, 90th percentile", f"{r['p90_3d_error_m'] * 100:.1f} cm"),
        ("disparity within 1 px of the truth", f"{r['disparity_within_1px']:.1%}"),
        ("disparity error, median / RMS of those within 1 px",
         f"{r['median_disparity_error_px']:.3f} / {r['rms_disparity_error_px_inliers']:.3f} px"),
        (f"3-D NEES ≤ χ²₃(95 %) = {r['chi2_3_95']:.2f}",
         f"{r['nees3_below_chi2_95']:.1%} (median {r['nees3_median']:.2f})"),
        (f"disparity NEES (e_d/σ_d)² ≤ χ²₁(95 %) = {r['chi2_1_95']:.2f}", f"{r['disparity_nees_below_chi2_95']:.1%}"),
    ]
    for name, value in rows:
        print(f"| {name} | {value} |")


def print_table(name: str, rows: list[dict]) -> None:
    print(f"\n{name}")
    has_sgbm = "sgbm_within_1px" in rows[0]
    header = "| descriptor | matches | scored | within 1 px | median error px |"
    header += " SGBM same pixels: within 1 px | SGBM median px |" if has_sgbm else ""
    print(header)
    print("|" + "---|" * (header.count("|") - 1))
    for r in rows:
        line = (f"| {r['descriptor']} | {r['matches']} | {r['ours_evaluated']} | {r['ours_within_1px']:.1%} |"
                f" {r['ours_median_error_px']:.3f} |")
        if has_sgbm:
            line += f" {r['sgbm_within_1px']:.1%} ({r['sgbm_evaluated']}) | {r['sgbm_median_error_px']:.3f} |"
        print(line)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA, help="the shared data folder")
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    parser.add_argument("--no-render", action="store_true", help="skip the rendered frames")
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    results: dict = {"real": evaluate_real(args.data)}
    if not results["real"]:
        print(f"no stereo data under {args.data}: real pairs skipped", file=sys.stderr)
    if not args.no_render:
        results["rendered"] = evaluate_rendered()
    if args.json:
        print(json.dumps(results, indent=2))
        return 0
    for name, rows in results["real"].items():
        print_table(name, rows)
    if "rendered" in results:
        print_rendered(results["rendered"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
