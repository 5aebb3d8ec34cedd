"""MRCLAM: is the self-calibration's uncertainty honest once its residuals' time structure is counted?

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.mrclam_calibration_uncertainty [--robot R ...] \
        [--draws 20] [--data DIR]

Per robot R, as session 39 (B)'s chain makes its truth-free file: the other four robots' model (range calibration,
heading bias, odometry lag, turns' variance, the stall after the command's dips, each camera's calibration apart,
fitted against the travel truth), then R's camera self-calibrated from its own log with one taped length (its two
most-sighted posts, their distance from Landmark_Groundtruth.dat, σ 5 mm) and the odometry's scale free. Against it,
the same terms fitted on R's own truth (travel), the reference. For a, b₀, b₁, ψ and the range bias at R's own
sightings (the mean of r'_self − r'_truth over the kept sightings; b₂ is the other robots' in the one, R's in the
other) it prints the error against the reference over σ, for σ from

- the Laplace covariance (what ``p3at slam noise --self-calibrate`` prints);
- the time-clustered sandwich (``estimation.calibration_uncertainty``) over blocks of 10, 30, 60 and 240 s, and the
  Newey–West estimate at Andrews' bandwidth (the largest over a, b₀, b₁, ψ; a rule that reads no truth), each with
  its leverage factor κ divided out (measured on draws of the model's own errors).

An honest σ gives ratios of order 1 on every robot: neither ≪ 1 (σ too large) nor ≫ 1. The calibration reads no
truth; the reference does. Per robot: four noise fits and one self-calibration, about a minute of CPU.

Session 48 (A; docs/fastslam-history.md).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from estimation.calibration_uncertainty import (
    andrews_bandwidth,
    clustered_covariance,
    corrected,
    influences,
    newey_west_covariance,
    null_draws,
    per_second,
)
from estimation.camera_calibration import ESTIMATED, KnownDistance, self_calibrate
from estimation.datasets import read_mrclam
from estimation.noise_estimation import estimate_noise
from runtime.commands.options import positive_int

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "mrclam" / "MRCLAM_Dataset2"
# each robot's two most-sighted posts and their distance (session 37 (D)'s rule, fixed before any run)
TAPES = {1: (11, 12, 1.7407), 2: (11, 20, 7.6596), 3: (11, 18, 6.4372), 4: (11, 13, 2.7814), 5: (11, 17, 5.9930)}
FITS = dict(heading_bias=True, range_calibration=True, odometry_lag=True, turn_variance=True, command_stall=True)
TERMS = ("a", "b0", "b1", "psi")
TERM_INDEX = (0, 1, 2, 4)   # into ESTIMATED
BLOCKS = (10.0, 30.0, 60.0, 240.0)


def robot_rows(data: Path, robot: int, draws: int) -> tuple[list[tuple[str, np.ndarray, np.ndarray]], dict]:
    """[(method, σ's (5,), ratios (5,))] for a, b₀, b₁, ψ and the range bias, and the robot's figures."""
    others = [read_mrclam(data, r, barcodes="verified", truth_heading="travel") for r in TAPES if r != robot]
    own = read_mrclam(data, robot, barcodes="verified", truth_heading="travel")
    model = estimate_noise(others, calibration_per_log=True, **FITS).model
    truth = estimate_noise([own], **FITS).model.range_bearing
    log = read_mrclam(data, robot, barcodes="table")
    first, second, metres = TAPES[robot]
    calibration = self_calibrate(log, model, known_distances=(KnownDistance(first, second, metres, 0.005),),
                                 keep_solution=True)
    if calibration.problem is not None:
        raise RuntimeError(f"robot {robot}: {calibration.problem}")
    found = influences(log, calibration, draws=draws)
    difference = calibration.values - np.array([getattr(truth, k) for k in ESTIMATED])
    kept = calibration.solution.inliers
    r, phi = log.ranges[kept], log.bearings[kept]
    bias = difference[0] + float(np.mean(r * (difference[1] + difference[2] * phi + difference[3] * phi ** 2)))
    k = len(found.free)
    gradient = np.zeros(k)
    gradient[:3] = [1.0, float(np.mean(r)), float(np.mean(r * phi))]   # the free terms a, b₀, b₁ come first
    errors = np.append(difference[list(TERM_INDEX)], bias)

    def row(name: str, covariance: np.ndarray) -> tuple[str, np.ndarray, np.ndarray]:
        sigma = np.sqrt(np.append(np.diag(covariance)[:4], gradient @ covariance @ gradient))
        return name, sigma, errors / sigma

    rows = [row("Laplace (printed)", found.laplace)]
    for length in BLOCKS:
        kappa = null_draws(found, lambda draw, length=length: clustered_covariance(found, length, draw))
        rows.append(row(f"blocks of {length:g} s / κ", corrected(clustered_covariance(found, length), kappa)))
    series = per_second(found)
    bandwidth = max(andrews_bandwidth(series[:, j]) for j in range(4))
    kappa = null_draws(found, lambda draw: newey_west_covariance(found, bandwidth, draw))
    rows.append(row(f"Newey–West, Andrews {bandwidth:.0f} s / κ",
                    corrected(newey_west_covariance(found, bandwidth), kappa)))
    return rows, dict(bandwidth=bandwidth, errors=errors, translation_scale=calibration.translation_scale)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--robot", type=positive_int, action="append", help="robots (1-5; repeat; default all)")
    parser.add_argument("--draws", type=positive_int, default=20, help="draws of the model's errors for κ (20)")
    parser.add_argument("--data", type=Path, default=DATA, help="MRCLAM data set folder")
    args = parser.parse_args(argv)
    robots = args.robot or sorted(TAPES)
    if any(r not in TAPES for r in robots):
        print("mrclam_calibration_uncertainty: --robot must be 1-5 (MRCLAM dataset 2)", file=sys.stderr)
        return 2
    if not args.data.is_dir():
        print(f"mrclam_calibration_uncertainty: {args.data}: no such folder (../shared/data/mrclam)", file=sys.stderr)
        return 2
    summary = {}
    for robot in robots:
        rows, figures = robot_rows(args.data, robot, args.draws)
        summary[robot] = rows
        print(f"\nrobot {robot}: self-calibrated − truth fit: " + ", ".join(
            f"{n} {e:+.4f}" for n, e in zip((*TERMS, "range bias m"), figures["errors"], strict=True))
            + f"; Andrews' bandwidth {figures['bandwidth']:.1f} s", flush=True)
        print("| σ from | " + " | ".join(f"{n}: σ (error/σ)" for n in (*TERMS, "range bias")) + " |")
        print("|---|" + "---|" * 5)
        for name, sigma, ratio in rows:
            print(f"| {name} | " + " | ".join(f"{s:.4f} ({q:+.1f})" for s, q in zip(sigma, ratio, strict=True)) + " |")
    print("\nerror/σ of the range offset a and of the range bias, per robot:")
    print("| σ from | " + " | ".join(f"robot {r}" for r in robots) + " |")
    print("|---|" + "---|" * len(robots))
    for i, (name, _, _) in enumerate(summary[robots[0]]):
        print(f"| {name} | " + " | ".join(f"{summary[r][i][2][0]:+.1f} / {summary[r][i][2][4]:+.1f}"
                                          for r in robots) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
