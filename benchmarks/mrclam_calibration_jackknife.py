"""MRCLAM: how uncertain is a self-calibrated camera, really? The delete-a-block jackknife beside the Laplace errors.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.mrclam_calibration_jackknife --robot R --noise OTHERS.toml \
        [--blocks 10] [--data DIR] [--known-distance ID1 ID2 METRES]

``p3at slam noise --self-calibrate`` reports the calibration's standard errors from the smoothing's information
(Laplace): they assume the model's noise is all there is. On MRCLAM its b₀ came out 1.0-2.3 % low, 2-9 of those
errors (session 37 (A)). Here the log's sightings are cut into BLOCKS contiguous runs of equal count; the camera is
self-calibrated again with each run left out (the odometry kept whole), and the jackknife's standard error,
√((K−1)/K Σ (c_k − c̄)²), is printed beside the Laplace one. A block whose calibration has a problem (its solve did
not converge, or the calibration is not determined) is printed with it and left out of the jackknife (K the blocks
kept; the table's heading says how many were left out). Errors correlated over less than a block (the odometry's
slow heading and scale errors, a camera that drifts) widen the jackknife's; a bias shared by the whole log widens
neither. No ground truth is read. K + 1 self-calibrations: minutes of CPU.

Session 48 (A), with the tape and the odometry's scale free, 10 blocks, robots 1-5: a's jackknife error is 0.9-2.7
times the Laplace one, ψ's 3-8 times (the odometry stays whole as a block of bearings goes), and robot 1's a is still
4.0 of its jackknife errors off its truth fit: its blocks agree on an error the whole log shares
(benchmarks.mrclam_calibration_uncertainty compares this with the time-clustered sandwich).

Session 38 (lead; docs/fastslam-history.md).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from estimation.camera_calibration import ESTIMATED, FREE, KnownDistance, self_calibrate
from estimation.datasets import RangeBearingLog, read_mrclam
from estimation.noise_model import NoiseModel
from runtime.commands.options import finite_float, positive_int

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "mrclam" / "MRCLAM_Dataset2"


def jackknife(log: RangeBearingLog, noise: NoiseModel, blocks: int, known=()) -> tuple[np.ndarray, np.ndarray, list]:
    """(the whole log's calibration, its Laplace standard errors, the K leave-a-block-out calibrations)."""
    whole = self_calibrate(log, noise, known_distances=known)
    if whole.problem is not None:
        print(f"  whole log: {whole.problem} (its values and Laplace errors below are not an estimate)", flush=True)
    # blocks of whole frames: a frame's sightings stay together
    frame = np.searchsorted(np.unique(log.sighting_times), log.sighting_times)
    edges = np.quantile(frame, np.linspace(0, 1, blocks + 1))
    label = np.clip(np.searchsorted(edges, frame, side="right") - 1, 0, blocks - 1)
    left_out = []
    for k in range(blocks):
        calibration = self_calibrate(log.with_sightings(label != k), noise, known_distances=known)
        left_out.append(calibration)
        print(f"  block {k}: {int((label == k).sum())} sightings left out: " + ", ".join(
            f"{ESTIMATED[i]} {calibration.values[i]:+.4f}" for i in FREE)
            + ("" if calibration.problem is None else f" ({calibration.problem}: left out of the jackknife)"),
            flush=True)
    return whole.values, whole.standard_errors, left_out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--robot", type=positive_int, required=True)
    parser.add_argument("--noise", type=Path, required=True, help="the odometry's and sensor's model (TOML)")
    parser.add_argument("--blocks", type=positive_int, default=10, help="runs of sightings left out in turn (10)")
    parser.add_argument("--known-distance", type=finite_float, nargs=3, metavar=("ID1", "ID2", "METRES"),
                        help="a taped length between two landmarks (m; σ 0.005 m)")
    parser.add_argument("--data", type=Path, default=DATA, help="MRCLAM data set folder")
    args = parser.parse_args(argv)
    if not args.data.is_dir():
        print(f"mrclam_calibration_jackknife: {args.data}: no such folder (../shared/data/mrclam)", file=sys.stderr)
        return 2
    if args.blocks < 3:
        print("mrclam_calibration_jackknife: --blocks must be at least 3", file=sys.stderr)
        return 2
    known = () if args.known_distance is None else (
        KnownDistance(int(args.known_distance[0]), int(args.known_distance[1]), float(args.known_distance[2]), 0.005),)
    log = read_mrclam(args.data, args.robot, barcodes="table")
    values, laplace, left_out = jackknife(log, NoiseModel.load(args.noise), args.blocks, known)
    kept = [c for c in left_out if c.problem is None]   # a calibration with a problem is not an estimate
    k = len(kept)
    if k < 2:
        print(f"mrclam_calibration_jackknife: only {k} of {len(left_out)} blocks gave a calibration", file=sys.stderr)
        return 1
    stacked = np.array([c.values for c in kept])
    spread = np.sqrt((k - 1) / k * np.sum((stacked - stacked.mean(axis=0)) ** 2, axis=0))
    print(f"robot {args.robot}, {k} blocks" + ("" if k == len(left_out) else f" ({len(left_out) - k} of "
                                               f"{len(left_out)} left out: no calibration)")
          + ("" if not known else f", taped {known[0].first}-{known[0].second}"))
    print("| term | whole log | Laplace se | jackknife se | ratio |")
    print("|---|---|---|---|---|")
    for i in FREE:
        print(f"| {ESTIMATED[i]} | {values[i]:+.4f} | {laplace[i]:.4f} | {spread[i]:.4f} | "
              f"{spread[i] / laplace[i]:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
