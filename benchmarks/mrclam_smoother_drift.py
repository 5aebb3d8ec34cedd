"""The known-ID MRCLAM default with the smoother's heading-bias states: does the drifting heading bias of session 22
(O) change the smoothed maps, and are they still honest?

Run from the repository root:

    .venv/bin/python -m benchmarks.mrclam_smoother_drift [--robots 1,2,3,4,5] [--seeds 0,1,2] [--json]
        [--drift 0.16 10] [--drift 0.12 30]

For every robot and seed: ``eval_mrclam --association id --defaults``'s run (the robot's own calibrated noise model,
the known-ID filter, then the smoother), and on the same filter run the smoother again with each ``--drift`` (σ rad/m,
τ s: :class:`estimation.landmark_smoother.HeadingDrift`; default the two fits of session 22 on the first halves,
0.16 rad/m with 10 s and 0.12 rad/m with 30 s). Printed per variant: ATE, the rigid landmark error, the smoothed
pose NEES's share within χ²₃ 95 %, the landmark NEES within the bound (start frame and rigid), χ²/dof; then the
medians over robots and seeds. The filter's figures are the same in every variant (one filter run).
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

import estimation.dataset_smoothing as dataset_smoothing  # noqa: E402
from benchmarks.eval_mrclam import DATA  # noqa: E402
from estimation.dataset_slam import run_landmark_log  # noqa: E402
from estimation.datasets import read_mrclam  # noqa: E402
from estimation.fastslam import range_bearing_config  # noqa: E402
from estimation.landmark_smoother import HeadingDrift  # noqa: E402
from estimation.noise_estimation import DATASET_CALIBRATIONS, estimate_noise  # noqa: E402
from runtime.commands.options import non_negative_float  # noqa: E402

KEYS = ("ate_m", "landmark_error_rigid_median_m", "pose_nees_within_chi2_95", "landmark_nees_within_bound",
        "landmark_nees_rigid_within_bound", "smoother_chi2_per_dof")
DEFAULT_DRIFTS = ((0.16, 10.0), (0.12, 30.0))
OFF = "off"


def variants_of_run(log, noise, seed: int, drifts: list[HeadingDrift]) -> dict[str, dict]:
    """{variant: the run's metrics}: the default (the white model, "off") and each drift, one filter run."""
    original = dataset_smoothing.smooth_run
    out: dict[str, dict] = {}

    def each(*args, **kwargs):
        for drift in [HeadingDrift(0.0, 1.0), *drifts]:
            start = time.process_time()
            run = original(*args, heading_drift=drift)
            out[label(drift)] = dict(run.metrics, smoother_cpu_s=time.process_time() - start)
        return run

    dataset_smoothing.smooth_run = each
    try:
        run_landmark_log(log, range_bearing_config(n_particles=100), np.random.default_rng(seed), noise=noise,
                         association="id", robot=log.name, smooth=True)
    finally:
        dataset_smoothing.smooth_run = original
    return out


def label(drift: HeadingDrift) -> str:
    return f"σ {drift.sigma_per_m:g} rad/m, τ {drift.tau_s:g} s" if drift.on else OFF


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", default=str(DATA))
    parser.add_argument("--robots", default="1,2,3,4,5")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--drift", type=non_negative_float, nargs=2, action="append", metavar=("RAD_PER_M", "S"),
                        help="a heading drift (σ rad/m, τ s) to smooth with beside the default; repeatable "
                             "(default: 0.16 10 and 0.12 30)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    if any(not tau > 0 for _, tau in args.drift or []):
        parser.error("--drift: the correlation time must be > 0 s")
    if not os.path.isdir(args.data):
        print(f"mrclam_smoother_drift: no data set at {args.data}", file=sys.stderr)
        return 2
    drifts = [HeadingDrift(s, t) for s, t in (args.drift or DEFAULT_DRIFTS)]
    seeds = [int(s) for s in args.seeds.split(",")]
    rows = []
    for robot in (int(r) for r in args.robots.split(",")):
        log = read_mrclam(args.data, robot)
        noise = estimate_noise([log], **DATASET_CALIBRATIONS).model
        for seed in seeds:
            variants = variants_of_run(log, noise, seed, drifts)
            rows.append({"robot": robot, "seed": seed,
                         "variants": {k: {key: m.get(key) for key in (*KEYS, "smoother_cpu_s")}
                                      for k, m in variants.items()}})
            if not args.json:
                _print_row(rows[-1])
    labels = list(rows[0]["variants"]) if rows else []
    summary = {k: {key: statistics.median(r["variants"][k][key] for r in rows) for key in KEYS} for k in labels}
    if args.json:
        print(json.dumps({"rows": rows, "median": summary}))
    else:
        print("\nmedians over robots and seeds")
        for k in labels:
            print(f"  {k:28s} " + _figures(summary[k]))
    return 0


def _figures(m: dict) -> str:
    return (f"ATE {m['ate_m']:.3f} m, rigid {m['landmark_error_rigid_median_m']:.3f} m, pose NEES within "
            f"{100 * m['pose_nees_within_chi2_95']:.0f} %, landmark NEES within "
            f"{100 * m['landmark_nees_within_bound']:.0f} % "
            f"(rigid {100 * m['landmark_nees_rigid_within_bound']:.0f} %), χ²/dof {m['smoother_chi2_per_dof']:.3f}")


def _print_row(row: dict) -> None:
    for k, m in row["variants"].items():
        print(f"robot {row['robot']} seed {row['seed']} {k:28s} " + _figures(m)
              + f", {m['smoother_cpu_s']:.1f} s CPU", flush=True)


if __name__ == "__main__":
    sys.exit(main())
