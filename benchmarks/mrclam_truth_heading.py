"""MRCLAM: is Vicon's heading the robot's? Its offset from the direction of travel, and what the camera says.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.mrclam_truth_heading [--data DIR] [--robots 1 2 3 4 5]

Per robot (estimation/datasets/truth_heading.py): Vicon's heading minus the direction of its own displacement on
forward, nearly straight 1 s steps (mean, spread over time, the smoothing width chosen, steps used). Then the camera,
an instrument the offset was not measured with: the RMS (and 1.4826 × MAD) of its bearings about the truth with each
log's median removed, against Vicon's heading and against the travel-aligned one; and, over 20 s windows, the
correlation between the mean bearing residual against Vicon and the mean offset (the camera following the travel,
not the markers, gives a correlation near 1 where the offset wanders). Seconds of CPU.

Session 38 (lead; docs/fastslam-history.md, *Session 38: the truth's heading*).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from estimation.datasets import RangeBearingLog, read_mrclam, travel_heading_offset
from estimation.geometry import wrap_angle
from runtime.commands.options import positive_int

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "mrclam" / "MRCLAM_Dataset2"
GROSS_RAD = 0.2          # a bearing this far off the truth is a misread, not noise
WINDOW_S = 20.0


def bearing_residuals(log: RangeBearingLog) -> tuple[np.ndarray, np.ndarray]:
    """(times, residuals): the camera's bearings minus the truth's, of the sightings of posts with a known position,
    gross misreads left out and the log's median removed (the camera's own mounting offset)."""
    index = {int(i): k for k, i in enumerate(log.truth_ids)}
    known = np.array([int(i) in index for i in log.landmark_ids], bool)
    poses = log.true_pose(log.sighting_times[known])
    posts = log.truth_positions[[index[int(i)] for i in log.landmark_ids[known]]].reshape(-1, 2)
    predicted = np.arctan2(posts[:, 1] - poses[:, 1], posts[:, 0] - poses[:, 0]) - poses[:, 2]
    residual = wrap_angle(log.bearings[known] - predicted)
    kept = np.abs(residual) < GROSS_RAD
    return log.sighting_times[known][kept], residual[kept] - np.median(residual[kept])


def spread(residuals: np.ndarray) -> tuple[float, float]:
    """(RMS, 1.4826 × median absolute deviation)."""
    return float(np.sqrt(np.mean(residuals ** 2))), float(1.4826 * np.median(np.abs(residuals)))


def window_correlation(times: np.ndarray, residuals: np.ndarray, offset) -> float:
    """Over WINDOW_S windows: the correlation of the mean bearing residual with the mean offset."""
    edges = np.arange(times[0], times[-1], WINDOW_S)
    pairs = [(residuals[k].mean(), offset.at(times[k]).mean())
             for a, b in zip(edges[:-1], edges[1:], strict=True) if (k := (times >= a) & (times < b)).sum() >= 10]
    pairs = np.array(pairs)
    return float(np.corrcoef(pairs.T)[0, 1]) if len(pairs) > 2 and np.std(pairs[:, 1]) > 1e-9 else float("nan")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=DATA, help="MRCLAM data set folder")
    parser.add_argument("--robots", type=positive_int, nargs="+", default=[1, 2, 3, 4, 5])
    args = parser.parse_args(argv)
    if not args.data.is_dir():
        print(f"mrclam_truth_heading: {args.data}: no such folder (../shared/data/mrclam)", file=sys.stderr)
        return 2
    print("| robot | offset mean rad | spread rad | smoothing | steps | camera vs Vicon RMS / MAD rad | vs travel | "
          "20 s correlation |")
    print("|---|---|---|---|---|---|---|---|")
    for robot in args.robots:
        mocap = read_mrclam(args.data, robot)
        travel = read_mrclam(args.data, robot, truth_heading="travel")
        offset = travel_heading_offset(mocap.ground_truth, mocap.name)
        times, against_vicon = bearing_residuals(mocap)
        width = "constant" if np.isinf(offset.width_s) else f"{offset.width_s:g} s"
        vicon, aligned = spread(against_vicon), spread(bearing_residuals(travel)[1])
        print(f"| {robot} | {np.mean(offset.offsets):+.4f} | {np.std(offset.offsets):.4f} | {width} | {offset.steps} | "
              f"{vicon[0]:.4f} / {vicon[1]:.4f} | {aligned[0]:.4f} / {aligned[1]:.4f} | "
              f"{window_correlation(times, against_vicon, offset):+.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
