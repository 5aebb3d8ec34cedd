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

from estimation.frontend import FrontEndConfig, StereoMatchConfig, TriangulationNoise, run_frontend
from estimation.frontend.evaluation import middlebury_truth, score_disparities, sgbm_disparity, truth_at

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
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    results = {"real": evaluate_real(args.data)}
    if not results["real"]:
        print(f"no stereo data under {args.data}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(results, indent=2))
        return 0
    for name, rows in results["real"].items():
        print_table(name, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
