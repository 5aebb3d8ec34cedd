"""Signed bias of the front end's disparities (measured - true) on rendered frames and on the real cones pair.

A fractional depth error that grows with depth is what a constant disparity bias gives (Z' = fB/(d + δ)), and a
depth-dependent landmark bias makes a scale error in the filter (docs/fastslam-history.md, session 20 (S)). This prints
the signed disparity error by depth band and by the fractional part of the true disparity (pixel locking of a sub-pixel
estimator shows as a sawtooth), for each sub-pixel mode, and the signed error of the depth Z and of the range along
the ray.

Run from the repository root:
    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.disparity_bias [--poses 24] [--json]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import cv2
import numpy as np

from estimation.frontend import FrontEndConfig, StereoMatchConfig, TriangulationNoise, run_frontend
from estimation.frontend.evaluation import middlebury_truth, truth_at
from runtime.commands.options import non_negative_int, positive_int

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_DATA = ROOT / ".." / "shared" / "data"
BANDS = ((1.0, 2.0), (2.0, 4.0), (4.0, 6.0), (6.0, np.inf))
FRACTION_BINS = 8
MODES = ("ssd", "corner")


def corridor_poses(count: int, seed: int = 0) -> np.ndarray:
    """Robot poses (count, 3) along the office building's corridors, both ways, with small heading jitter."""
    rng = np.random.default_rng(seed)
    base = [(x, 5.0 + rng.uniform(-0.5, 0.5), h) for x in np.linspace(2.0, 24.0, 12) for h in (0.0, np.pi)]
    base += [(3.0, 5.0, 0.0), (8.0, 5.0, np.pi), (5.0, 5.0, 0.5), (10.0, 4.5, -0.3), (20.0, 5.5, 2.6),
             (15.0, 7.5, -1.2)]
    poses = np.array(base, float)[:count]
    poses[:, 2] += rng.uniform(-0.1, 0.1, len(poses))
    return poses


def stats(values: np.ndarray, rng: np.random.Generator, resamples: int = 400) -> dict:
    """n, mean, median, standard error of the mean and a bootstrap standard error of the median."""
    values = np.asarray(values, float)
    n = len(values)
    if n < 2:
        return {"n": n, "mean": float("nan"), "median": float("nan"), "se_mean": float("nan"),
                "se_median": float("nan")}
    medians = np.median(values[rng.integers(0, n, (resamples, n))], axis=1)
    return {"n": n, "mean": float(values.mean()), "median": float(np.median(values)),
            "se_mean": float(values.std(ddof=1) / np.sqrt(n)), "se_median": float(medians.std(ddof=1))}


def rendered_errors(poses: np.ndarray, subpixel: str, seed: int = 0, noise_dn: float = 1.0,
                    config: FrontEndConfig | None = None) -> dict[str, np.ndarray]:
    """Per reading on rendered frames: true disparity, signed disparity error, true depth Z, signed Z and range
    errors (m), for the front end with ``subpixel``."""
    from drivers.videre import calibration
    from mocks.stereo_head.renderer import StereoRenderer
    from mocks.world import World
    from runtime.commands.features import front_end_from_calibration

    calib = calibration.load(ROOT / "mocks" / "stereo_head" / "data" / "sth_mdcs2_default.ini")
    renderer = StereoRenderer(World.load(), calib)
    base = config or FrontEndConfig()
    config = dataclasses.replace(base, matching=dataclasses.replace(base.matching, subpixel=subpixel))
    front_end = front_end_from_calibration(calib, config)
    geometry = front_end.config.geometry
    fb = geometry.fx * geometry.baseline
    rng = np.random.default_rng(seed)
    out: dict[str, list] = {k: [] for k in ("true_d", "error_d", "z", "error_z", "error_range")}
    for pose in poses:
        images = [np.clip(np.rint(im * 255.0 + rng.normal(0.0, noise_dn, im.shape)), 0, 255).astype(np.uint8)
                  for im in renderer.render(pose)]
        front_end.process(images[0], images[1], 0.0)
        m = front_end.last_matches
        world = renderer.true_points(pose, m.left_pixels, "left", rectified=True)
        cam = np.linalg.inv(renderer.camera_pose_world(pose, "left", rectified=True))
        truth = world @ cam[:3, :3].T + cam[:3, 3]  # rectified left camera frame
        known = np.all(np.isfinite(truth), axis=1)
        truth, d = truth[known], np.asarray(m.disparities, float)[known]
        measured = np.asarray(m.points_camera, float)[known]
        z_true = truth[:, 2]
        true_d = fb / z_true
        out["true_d"].append(true_d)
        out["error_d"].append(d - true_d)
        out["z"].append(z_true)
        out["error_z"].append(measured[:, 2] - z_true)
        out["error_range"].append(np.linalg.norm(measured, axis=1) - np.linalg.norm(truth, axis=1))
    return {k: np.concatenate(v) if v else np.zeros(0) for k, v in out.items()}


def real_errors(data: Path, subpixel: str) -> dict[str, np.ndarray] | None:
    """Signed disparity errors on Middlebury cones (im2/im6, disp2.pgm = disparity × 4); None if absent."""
    cones = data / "stereo" / "middlebury-cones"
    if not (cones / "disp2.pgm").is_file():
        return None
    left = cv2.imread(str(cones / "im2.png"), cv2.IMREAD_GRAYSCALE)
    right = cv2.imread(str(cones / "im6.png"), cv2.IMREAD_GRAYSCALE)
    truth = middlebury_truth(cv2.imread(str(cones / "disp2.pgm"), cv2.IMREAD_UNCHANGED))
    config = FrontEndConfig(matching=StereoMatchConfig(max_disparity=64, subpixel=subpixel),
                            noise=TriangulationNoise(min_disparity=0.5, max_depth=1e9))
    matches = run_frontend(left, right, config)
    # truth at the sub-pixel left position: bilinear in u between the two neighbouring columns
    px = np.asarray(matches.left_pixels, float)
    u0 = np.floor(px[:, 0])
    a = px[:, 0] - u0
    t0 = truth_at(np.column_stack([u0, px[:, 1]]), truth)
    t1 = truth_at(np.column_stack([u0 + 1, px[:, 1]]), truth)
    known = np.isfinite(t0) & np.isfinite(t1) & (t0 > 0) & (t1 > 0) & (np.abs(t1 - t0) <= 0.5)
    true_d = (1 - a) * t0 + a * t1
    error = np.asarray(matches.disparities, float) - true_d
    known &= np.abs(error) <= 1.0  # inliers: the bias of good matches, not the outliers' mean
    return {"true_d": true_d[known], "error_d": error[known]}


def _weighted(values: np.ndarray, weights: np.ndarray) -> float:
    return float(np.sum(weights * values) / np.sum(weights)) if len(values) else float("nan")


def summarise(errors: dict[str, np.ndarray], rng: np.random.Generator) -> dict:
    e, true_d = errors["error_d"], errors["true_d"]
    inlier = np.abs(e) <= 1.0
    summary = {"all_inliers": stats(e[inlier], rng), "outlier_share": float(np.mean(~inlier)) if len(e) else 0.0}
    frac = true_d - np.floor(true_d)
    summary["by_fraction"] = [
        {"fraction": [k / FRACTION_BINS, (k + 1) / FRACTION_BINS],
         **stats(e[inlier & (frac >= k / FRACTION_BINS) & (frac < (k + 1) / FRACTION_BINS)], rng)}
        for k in range(FRACTION_BINS)]
    if "z" in errors:
        z = errors["z"]
        summary["by_depth"] = []
        for lo, hi in BANDS:
            band = inlier & (z >= lo) & (z < hi)
            summary["by_depth"].append({
                "band_m": [lo, hi if np.isfinite(hi) else None],
                "disparity_px": stats(e[band], rng),
                "z_m": stats(errors["error_z"][band], rng),
                "relative_z": stats(errors["error_z"][band] / z[band], rng),
                # the filter fuses a reading with the weight of its own covariance, σ_Z² ∝ 1/d⁴ at the MEASURED d:
                # a reading that errs short (d too large) weighs more. The fused mean of Z'/Z - 1 with those weights,
                # and with the same weights at the true d (what a covariance at the predicted point would give)
                "relative_z_own_weights": _weighted(errors["error_z"][band] / z[band],
                                                    (errors["true_d"][band] + e[band]) ** 4),
                "relative_z_true_weights": _weighted(errors["error_z"][band] / z[band], errors["true_d"][band] ** 4),
                "range_m": stats(errors["error_range"][band], rng)})
    return summary


def measure(poses: int = 24, data: Path = DEFAULT_DATA, modes=MODES, seed: int = 0) -> dict:
    rng = np.random.default_rng(12345)
    results = {"rendered": {}, "cones": {}}
    pose_list = corridor_poses(poses, seed)
    for mode in modes:
        results["rendered"][mode] = summarise(rendered_errors(pose_list, mode, seed), rng)
        real = real_errors(data, mode)
        if real is not None:
            results["cones"][mode] = summarise(real, rng)
    return results


def _fmt(s: dict, scale: float = 1.0, unit: str = "") -> str:
    return (f"{s['mean'] * scale:+.4f}{unit} ± {s['se_mean'] * scale:.4f} (median {s['median'] * scale:+.4f} ± "
            f"{s['se_median'] * scale:.4f}, n={s['n']})")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=positive_int, default=24)
    parser.add_argument("--seed", type=non_negative_int, default=0)
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    results = measure(args.poses, args.data, args.modes, args.seed)
    if args.json:
        json.dump(results, sys.stdout, indent=2)
        print()
        return 0
    for source, by_mode in results.items():
        for mode, s in by_mode.items():
            print(f"\n{source}, subpixel={mode}: signed disparity error (|e| ≤ 1 px; outliers "
                  f"{s['outlier_share']:.1%}): {_fmt(s['all_inliers'], unit=' px')}")
            for row in s.get("by_depth", []):
                hi = row["band_m"][1]
                band = f"{row['band_m'][0]:.0f}-{hi:.0f} m" if hi else f"{row['band_m'][0]:.0f}+ m"
                print(f"  Z {band:>7}: d {_fmt(row['disparity_px'], unit=' px')}")
                print(f"           Z {_fmt(row['z_m'], 1000, ' mm')}  Z/Z {_fmt(row['relative_z'], 100, ' %')}")
                print(f"           range {_fmt(row['range_m'], 1000, ' mm')}")
                print(f"           Z/Z fused with the readings' own weights {row['relative_z_own_weights']:+.3%}, "
                      f"with weights at the true d {row['relative_z_true_weights']:+.3%}")
            print("  by the fractional part of the true disparity:")
            for row in s["by_fraction"]:
                print(f"    [{row['fraction'][0]:.3f}, {row['fraction'][1]:.3f}): mean {row['mean']:+.4f} px "
                      f"± {row['se_mean']:.4f} (n={row['n']})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
