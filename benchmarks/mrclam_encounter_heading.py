"""MRCLAM: are the odometry's large heading faults where robots meet?

Run from the repository root:

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.mrclam_encounter_heading [--data DIR] [--near 1.0 1.5]

Why (session 34, helper A): the two errors that two runs of the unknown-association chain share (robot 2 at
1,305-1,317 s, robot 3 at 484-488.5 s) both follow a heading fault of the commanded-velocity odometry larger than
two neighbouring posts' angular separation, and both happen while another robot is 1-2 m away. This asks whether
that is general. Per robot and 1-s step: the heading error of the calibrated odometry (the fitted model's scales and
lag, ``DATASET_CALIBRATIONS``) against Vicon, and the distance to the nearest other robot (the others' Vicon, so
this is a measurement of the data, not something a method may use). Printed for each ``--near`` distance D: steps
near (< D at either end of the step) and far, and the share of steps whose |error| exceeds 0.06 and 0.10 rad, in all
steps, in turning ones (the odometry turns > 0.1 rad in the step) and in straight ones; pooled over the robots, then
per robot.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

from benchmarks.eval_mrclam import DATA  # noqa: E402
from estimation.datasets import RangeBearingLog, read_mrclam  # noqa: E402
from estimation.geometry import between  # noqa: E402
from estimation.noise_estimation import DATASET_CALIBRATIONS, estimate_noise  # noqa: E402
from runtime.commands.options import positive_float  # noqa: E402

ROBOTS = (1, 2, 3, 4, 5)
TURNING_RAD = 0.1           # the odometry's turn in a step above which the step is "turning"
FAULTS_RAD = (0.06, 0.10)   # |heading error| per step counted as a fault


def heading_steps(log: RangeBearingLog, others: list[RangeBearingLog], step_s: float = 1.0) -> dict:
    """Per ``step_s`` step of ``log`` (within its ground truth): ``start_s`` (its start, s from the log's start),
    ``error`` (rad, |true − calibrated odometry| heading change), ``turn`` (rad, the calibrated odometry's heading
    change) and ``nearest_m`` (the nearest of ``others`` at either end of the step, by their ground truth)."""
    noise = estimate_noise([log], **DATASET_CALIBRATIONS).model
    times = np.arange(log.ground_truth[0, 0] + step_s, log.ground_truth[-1, 0], step_s)
    true = log.true_pose(times)
    odometry = noise.calibrate_increments(log.odometry_increments(noise.odometry_times(times)))
    truth = between(true[:-1], true[1:])
    error = np.abs((truth[:, 2] - odometry[:, 2] + np.pi) % (2 * np.pi) - np.pi)
    nearest = np.full(len(times), np.inf)
    for other in others:
        where = other.true_pose(times)
        nearest = np.minimum(nearest, np.hypot(where[:, 0] - true[:, 0], where[:, 1] - true[:, 1]))
    return {"start_s": times[:-1] - log.start_time, "error": error, "turn": odometry[:, 2],
            "nearest_m": np.minimum(nearest[:-1], nearest[1:])}


def fault_shares(steps: list[dict], near_m: float) -> dict:
    """Over ``steps`` (from :func:`heading_steps`, pooled): for near (< ``near_m``) and far steps, in all, turning and
    straight steps, the count and the share of |error| above each of ``FAULTS_RAD``."""
    error = np.concatenate([s["error"] for s in steps])
    near = np.concatenate([s["nearest_m"] for s in steps]) < near_m
    turning = np.abs(np.concatenate([s["turn"] for s in steps])) > TURNING_RAD
    out = {}
    for motion, mask in (("all", np.ones_like(near)), ("turning", turning), ("straight", ~turning)):
        for side, where in (("near", near), ("far", ~near)):
            chosen = error[mask & where]
            out[f"{motion} {side}"] = {"steps": int(len(chosen)),
                                       **{f"> {f:.2f} rad": float(np.mean(chosen > f)) if len(chosen) else None
                                          for f in FAULTS_RAD}}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.mrclam_encounter_heading",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--data", default=str(DATA))
    parser.add_argument("--near", type=positive_float, nargs="+", default=[1.0, 1.5], metavar="M",
                        help="distances to the nearest other robot that count as an encounter")
    args = parser.parse_args(argv)
    if not Path(args.data).is_dir():
        print(f"mrclam_encounter_heading: no data set at {args.data}", file=sys.stderr)
        return 2
    logs = {r: read_mrclam(args.data, r) for r in ROBOTS}
    steps = {r: heading_steps(log, [o for k, o in logs.items() if k != r]) for r, log in logs.items()}
    for near_m in args.near:
        print(f"encounters: another robot within {near_m:g} m (1-s steps; share of |heading error| above "
              f"{' / '.join(f'{f:g}' for f in FAULTS_RAD)} rad, near against far)")
        for label, chosen in [("all robots", list(steps.values()))] + [(f"robot {r}", [s]) for r, s in steps.items()]:
            shares = fault_shares(chosen, near_m)
            print(f"  {label:10s} " + "; ".join(_pair(shares, motion) for motion in ("all", "turning", "straight")))
    return 0


def _pair(shares: dict, motion: str) -> str:
    near, far = shares[f"{motion} near"], shares[f"{motion} far"]

    def pct(row):
        return " / ".join("-" if row[k] is None else f"{100 * row[k]:.1f} %" for k in row if k != "steps")
    return f"{motion} {near['steps']} near {pct(near)} against {far['steps']} far {pct(far)}"


if __name__ == "__main__":
    sys.exit(main())
