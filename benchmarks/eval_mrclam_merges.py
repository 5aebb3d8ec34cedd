"""MRCLAM in unknown association: duplicates and the filter's merges scored against the barcodes.

Run from the repository root:

    .venv/bin/python -m benchmarks.eval_mrclam_merges [--robots 1,2,3,4,5] [--seed 0] [--particles 100]
        [--range-calibration] [--heading-bias] [--set FIELD=VALUE ...]

Per robot (each robot's noise fitted on its own log, as ``eval_mrclam`` does with ``--noise own``): ATE, duplicate
fraction, landmarks, and every id pair the filter merged (``FastSLAM.merged_pairs``) with the barcode each
landmark stands for (the majority of the sightings that made or matched it, as ``eval_mrclam`` attributes them).
A merge of two landmarks attributed to different barcodes joined distinct posts ("wrong"). ``--set`` overrides a
FastSLAMConfig field (JSON value), e.g. ``--set merge_covisibility=false`` for the merge without co-visibility.
``--particles``, ``--range-calibration`` and ``--heading-bias`` as in ``eval_mrclam`` (each robot's noise model also
fits the camera's depth-not-range calibration, docs/fastslam-history.md "Session 8: the floor", and the odometry's
heading bias per metre, "Session 5").
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

import estimation.dataset_slam as dataset_slam  # noqa: E402
from benchmarks.config_overrides import config_overrides  # noqa: E402
from benchmarks.eval_mrclam import DATA  # noqa: E402
from benchmarks.slam_consistency import RecordingFastSLAM  # noqa: E402
from estimation.datasets import read_mrclam  # noqa: E402
from estimation.fastslam import range_bearing_config  # noqa: E402
from estimation.landmark_scores import attribute_landmarks, count_sightings  # noqa: E402
from estimation.noise_estimation import estimate_noise  # noqa: E402
from runtime.commands.options import non_negative_int, positive_int  # noqa: E402


@dataclass(frozen=True)
class RunSetup:
    """What every unknown-association script runs a robot with, beside ``--set``: the particles and whether the
    robot's noise model fits the camera's range calibration and the odometry's heading bias (``eval_mrclam``'s
    options of the same names)."""

    particles: int = 100
    range_calibration: bool = False
    heading_bias: bool = False

    def config(self, overrides: dict):
        return range_bearing_config(**{"n_particles": self.particles, **overrides})

    def noise(self, log):
        return estimate_noise([log], range_calibration=self.range_calibration, heading_bias=self.heading_bias).model


PLAIN = RunSetup()   # 100 particles, each robot's own fitted noise: the figures of sessions 7-9


def run_robot(log, seed: int, overrides: dict, setup: RunSetup = PLAIN) -> dict:
    original = dataset_slam.FastSLAM
    dataset_slam.FastSLAM = RecordingFastSLAM
    try:
        run = dataset_slam.run_landmark_log(log, setup.config(overrides), np.random.default_rng(seed),
                                            noise=setup.noise(log), association="unknown", robot=log.name)
    finally:
        dataset_slam.FastSLAM = original
    slam = RecordingFastSLAM.last
    # the frames as run_landmark_log forms them: sightings sharing a time stamp, from the first sighting on
    times, first = np.unique(log.sighting_times, return_index=True)
    bounds = np.append(first, len(log))[1:]
    votes: dict[int, dict[int, int]] = {}
    for report, start, stop in zip(slam.reports, first, bounds, strict=False):
        count_sightings(votes, log.landmark_ids[start:stop], report)
    pairs = {(a, b): e for a, b, e in slam.merged_pairs}
    ids = np.array([i for pair in pairs for i in pair], np.int64)
    barcode = dict(zip(ids.tolist(), attribute_landmarks(votes, ids).tolist(), strict=True))
    wrong = [(a, b) for a, b in pairs if barcode[a] != barcode[b]]
    m = run.metrics
    return {"robot": log.name, "ate_m": m["ate_m"], "duplicate_fraction": m["duplicate_fraction"],
            "landmarks": m["landmarks"], "true_landmarks": m["true_landmarks"],
            "landmark_error_rigid_median_m": m["landmark_error_rigid_median_m"], "merges": len(pairs),
            "merges_by_covisibility": int(sum(pairs.values())), "merges_wrong": len(wrong),
            "merges_wrong_by_covisibility": int(sum(pairs[p] for p in wrong)),
            "wrong_merges": [{"older": a, "newer": b, "older_votes": votes.get(a), "newer_votes": votes.get(b)}
                             for a, b in wrong]}


def robots_main(argv: list[str] | None, name: str, description: str, run_robot, print_rows) -> int:
    """The command line the MRCLAM unknown-association scripts share: ``run_robot(log, seed, overrides, setup) ->
    row`` per robot of ``--robots``, then the rows as JSON (``--json``) or a title and ``print_rows(rows)``."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--robots", default="1,2,3,4,5")
    parser.add_argument("--seed", type=non_negative_int, default=0)
    parser.add_argument("--particles", type=positive_int, default=100)
    parser.add_argument("--range-calibration", action="store_true",
                        help="fit the camera's range calibration into each robot's noise model")
    parser.add_argument("--heading-bias", action="store_true",
                        help="fit the odometry's heading bias per metre into each robot's noise model")
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    if not args.data.is_dir():
        print(f"{name}: no data set at {args.data}", file=sys.stderr)
        return 2
    overrides = config_overrides(args.set)
    setup = RunSetup(args.particles, args.range_calibration, args.heading_bias)
    rows = [run_robot(read_mrclam(args.data, int(r)), args.seed, overrides, setup) for r in args.robots.split(",")]
    if args.json:
        print(json.dumps({"seed": args.seed, "overrides": overrides, "particles": setup.particles,
                          "range_calibration": setup.range_calibration, "heading_bias": setup.heading_bias,
                          "rows": rows}))
        return 0
    print(f"MRCLAM unknown association, seed {args.seed}, {setup.particles} particles"
          + (", range calibrated" if setup.range_calibration else "")
          + (", heading bias fitted" if setup.heading_bias else "")
          + (f", overrides {overrides}" if overrides else ""))
    print_rows(rows)
    return 0


def _print_rows(rows: list[dict]) -> None:
    print("| robot | ATE m | landmarks | duplicates | merged id pairs (by co-visibility) | wrong (by co-visibility) |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['robot']} | {r['ate_m']:.3f} | {r['landmarks']}/{r['true_landmarks']} | "
              f"{100 * r['duplicate_fraction']:.1f} % | {r['merges']} ({r['merges_by_covisibility']}) | "
              f"{r['merges_wrong']} ({r['merges_wrong_by_covisibility']}) |")


def main(argv: list[str] | None = None) -> int:
    return robots_main(argv, "eval_mrclam_merges", __doc__.split("\n\n")[0], run_robot, _print_rows)


if __name__ == "__main__":
    sys.exit(main())
