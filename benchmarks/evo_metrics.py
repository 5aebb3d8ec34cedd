"""ATE and RPE with evo (the field's standard trajectory evaluation package) for benchmarks and evaluations.

    python benchmarks/evo_metrics.py OUT/robot1-truth.tum OUT/robot1.tum [--align] [--delta 1.0]
    python benchmarks/evo_metrics.py OUT/robot1-truth.tum OUT/robot1-odometry.tum

prints the absolute trajectory error (APE of the translation, RMSE/mean/max, m) and the relative pose error over
``delta`` metres travelled (translation, m; rotation, rad) of the estimate against the reference. The mission's TUM
files (runtime.trajectories) are all in the robot's map frame, so no alignment is needed (``--align``: Umeyama SE(3)
first, for trajectories in other frames). Functions for scripts: :func:`load`, :func:`ate`, :func:`rpe`,
:func:`evaluate` (planar (T, 4) arrays or TUM paths).
"""
from __future__ import annotations

import argparse
import copy
import json
import sys
from pathlib import Path

import numpy as np
from evo.core import filters, metrics, sync
from evo.core.trajectory import PoseTrajectory3D
from evo.core.units import Unit
from evo.tools import file_interface

from runtime.commands.options import positive_float


def from_planar(rows: np.ndarray) -> PoseTrajectory3D:
    """An evo trajectory from planar rows (T, 4) (t, x, y, θ)."""
    rows = np.asarray(rows, float).reshape(-1, 4)
    xyz = np.column_stack([rows[:, 1], rows[:, 2], np.zeros(len(rows))])
    wxyz = np.column_stack([np.cos(rows[:, 3] / 2), np.zeros(len(rows)), np.zeros(len(rows)), np.sin(rows[:, 3] / 2)])
    return PoseTrajectory3D(positions_xyz=xyz, orientations_quat_wxyz=wxyz, timestamps=rows[:, 0])


def load(trajectory) -> PoseTrajectory3D:
    """A TUM path (read by evo's own reader), planar rows (T, 4), or an evo trajectory."""
    if isinstance(trajectory, PoseTrajectory3D):
        return trajectory
    if isinstance(trajectory, str | Path):
        return file_interface.read_tum_trajectory_file(str(trajectory))
    return from_planar(trajectory)


def _associated(reference, estimate, align: bool, max_diff: float):
    ref, est = sync.associate_trajectories(load(reference), load(estimate), max_diff=max_diff)
    est = copy.deepcopy(est)
    if align:
        est.align(ref, correct_scale=False)
    return ref, est


def ate(reference, estimate, *, align: bool = False, max_diff: float = 0.01) -> dict[str, float]:
    """APE of the translation (m): rmse, mean, median, max, and the number of associated poses."""
    ref, est = _associated(reference, estimate, align, max_diff)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    stats = ape.get_all_statistics()
    return {"ate_rmse_m": float(stats["rmse"]), "ate_mean_m": float(stats["mean"]),
            "ate_median_m": float(stats["median"]), "ate_max_m": float(stats["max"]), "poses": ref.num_poses}


def rpe(reference, estimate, *, delta: float = 1.0, align: bool = False, max_diff: float = 0.01) -> dict[str, float]:
    """RPE over ``delta`` metres travelled: translation RMSE (m) and rotation RMSE (rad)."""
    ref, est = _associated(reference, estimate, align, max_diff)
    out = {}
    for relation, key in ((metrics.PoseRelation.translation_part, "rpe_translation_rmse_m"),
                          (metrics.PoseRelation.rotation_angle_rad, "rpe_rotation_rmse_rad")):
        metric = metrics.RPE(relation, delta=delta, delta_unit=Unit.meters, all_pairs=False)
        try:
            metric.process_data((ref, est))
            out[key] = float(metric.get_statistic(metrics.StatisticsType.rmse))
        except (metrics.MetricsException, filters.FilterException):  # a path shorter than delta: no pair to compare
            out[key] = float("nan")
    return out


def evaluate(reference, estimate, *, delta: float = 1.0, align: bool = False) -> dict[str, float]:
    return {**ate(reference, estimate, align=align), **rpe(reference, estimate, delta=delta, align=align)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("reference", type=Path, help="TUM file of the reference (e.g. OUT/robot1-truth.tum)")
    parser.add_argument("estimate", type=Path, help="TUM file of the estimate (e.g. OUT/robot1.tum)")
    parser.add_argument("--align", action="store_true", help="Umeyama SE(3) alignment before the metrics")
    parser.add_argument("--delta", type=positive_float, default=1.0, help="RPE distance, m travelled (default 1)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    try:
        result = evaluate(args.reference, args.estimate, delta=args.delta, align=args.align)
    except (OSError, file_interface.FileInterfaceException, sync.SyncException) as e:
        print(f"evo_metrics: {e}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(f"{args.estimate} against {args.reference}: {result['poses']} poses")
        print(f"  ATE  rmse {result['ate_rmse_m']:.4f} m  mean {result['ate_mean_m']:.4f} m  "
              f"max {result['ate_max_m']:.4f} m")
        print(f"  RPE over {args.delta:g} m  translation {result['rpe_translation_rmse_m']:.4f} m  "
              f"rotation {result['rpe_rotation_rmse_rad']:.4f} rad")
    return 0


if __name__ == "__main__":
    sys.exit(main())
