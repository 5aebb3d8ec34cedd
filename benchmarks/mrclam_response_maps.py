"""MRCLAM: why a drive model that predicts short odometry increments better does not give better known-ID maps.

Run from the repository root:

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.mrclam_response_maps [--robots 1 2 3 4 5]
        [--drive response:0.2 | shape:DEAD,FAST,SLOW,WEIGHT[/DEAD,FAST,SLOW,WEIGHT]] [--section start|segments|all]
        [--first-seconds 1] [--segment-length 200] [--segment-step 50] [--seed 0] [--json]

Each robot's log is read twice: as written (the odometry: the command integrated, a pure delay fitted) and through
the drive model (``--drive``: ``response:T`` a first-order lag, ``estimation.odometry_response.with_drive_response``;
``shape:...`` a dead time and two first-order parts per channel, ``with_drive_shape``, as eval_mrclam's
``--drive-shape``), each with the noise model `p3at slam dataset` fits by default (DATASET_CALIBRATIONS) refitted on
its own odometry, and run known-ID and smoothed as ``benchmarks.eval_mrclam --association id --defaults`` runs it.

- **start** (the whole log): the smoothed ATE (the map's frame mapped to the world through the true start pose) and
  the ATE after an SE(3) alignment (the trajectory's shape alone), the map's frame error as one rigid motion (dx, dy,
  dθ; benchmarks.smoother_frame_diagnosis), and the change of dθ attributed to the factors whose actual errors moved it
  (by kind and window after the first sighting, linearised at the truth: smoother_frame_diagnosis.attribution). Then
  the swap: each problem solved again with the first ``--first-seconds`` s of odometry factors (increments,
  variances or both) taken from the other reading: do those few factors carry the whole difference?
- **segments**: the same two readings on segments of the log (sightings from s to s + ``--segment-length``, s every
  ``--segment-step`` s; the map's frame the pose at each segment's first sighting, the noise model the whole log's):
  each segment a start frame of its own, so the whole log's one draw of "the first second" becomes many. Per robot
  and pooled, the smoothed and aligned ATE's medians, how many segments each reading wins, and a Wilcoxon signed-rank
  test of the paired differences.

Session 45 (B; docs/fastslam-history.md "Session 45: why the drive's response does not help the maps (B)").
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

from benchmarks import evo_metrics  # noqa: E402
from benchmarks import smoother_frame_diagnosis as sfd  # noqa: E402
from benchmarks.eval_mrclam import drive_shape_option  # noqa: E402
from estimation.dataset_slam import run_landmark_log  # noqa: E402
from estimation.datasets import read_mrclam  # noqa: E402
from estimation.fastslam import range_bearing_config  # noqa: E402
from estimation.geometry import compose  # noqa: E402
from estimation.landmark_smoother import smooth  # noqa: E402
from estimation.noise_estimation import DATASET_CALIBRATIONS, estimate_noise  # noqa: E402
from estimation.odometry_response import first_order_response, with_drive_response, with_drive_shape  # noqa: E402
from runtime.commands.options import non_negative_int, positive_float, positive_int  # noqa: E402

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "mrclam" / "MRCLAM_Dataset2"


def drive_option(text: str):
    """``--drive``: ``response:T`` or ``shape:TURN[/TRAVEL]`` -> (label, a function log -> log)."""
    kind, _, value = text.partition(":")
    if kind == "response":
        try:
            T = float(value)
            first_order_response(np.zeros(1), np.zeros(1), T)   # refuses a T the response refuses, in its words
        except ValueError as error:
            raise argparse.ArgumentTypeError(f"response:T needs a time constant in s: {error}") from None
        return text, lambda log: with_drive_response(log, T)
    if kind == "shape":
        shapes = drive_shape_option(value)
        return text, lambda log: with_drive_shape(log, *shapes)
    raise argparse.ArgumentTypeError(f"expected response:T or shape:DEAD,FAST,SLOW,WEIGHT[/...], not {text!r}")


def start_section(log, drive, seed: int, first_seconds: float) -> dict:
    """The whole log, as read and through ``drive``: scores, frame, attribution, and the first seconds' swap."""
    caps, out = {}, {}
    for label, reading in (("as read", log), ("drive", drive(log))):
        noise = estimate_noise([reading], **DATASET_CALIBRATIONS).model
        cap = sfd.capture(reading, noise, seed)
        solution = smooth(cap.problem, cap.initial_poses, cap.initial_landmarks)
        scores = sfd.scores(cap, solution)
        truth = np.column_stack([cap.times[1:], compose(cap.true_start, cap.true_poses[1:])])
        estimate = np.column_stack([cap.times[1:], compose(cap.true_start, solution.poses[1:])])
        caps[label] = cap
        out[label] = {"ate_m": scores["ate_m"], "aligned_ate_m": evo_metrics.ate(truth, estimate,
                                                                                  align=True)["ate_rmse_m"],
                      "frame": scores["frame"], "lag_s": noise.odometry.lag_s,
                      "attribution": sfd.attribution(cap, solution.inliers)["rows"]}
    a, b = caps["as read"], caps["drive"]
    early = b.times[1:] <= first_seconds
    swaps = {}
    for label, base, other, what in (("drive, first seconds' increments as read", b, a, "increments"),
                                     ("drive, first seconds' variances as read", b, a, "variances"),
                                     ("drive, first seconds' factors as read", b, a, "both"),
                                     ("as read, first seconds' factors of the drive", a, b, "both")):
        inc, var = base.problem.increments.copy(), base.problem.increment_variances.copy()
        if what in ("increments", "both"):
            inc[early] = other.problem.increments[early]
        if what in ("variances", "both"):
            var[early] = other.problem.increment_variances[early]
        problem = dataclasses.replace(base.problem, increments=inc, increment_variances=var)
        scores = sfd.scores(base, smooth(problem, base.initial_poses, base.initial_landmarks))
        swaps[label] = {"ate_m": scores["ate_m"], "dtheta_rad": scores["frame"]["dtheta_rad"]}
    out.update(swap=swaps, first_increments=int(early.sum()))
    return out


def segments_section(log, drive, seed: int, length: float, step: float) -> dict:
    """Per reading, per segment start s: smoothed ATE, aligned ATE and frame dθ of the segment's known-ID run."""
    out = {}
    for label, reading in (("as read", log), ("drive", drive(log))):
        noise = estimate_noise([reading], **DATASET_CALIBRATIONS).model
        rows = []
        end = reading.sighting_times[-1] if len(reading) else 0.0
        for s in np.arange(step, end - length, step):
            part = reading.with_sightings(reading.sighting_times >= s)
            run = run_landmark_log(part, range_bearing_config(n_particles=100), np.random.default_rng(seed),
                                   noise=noise, association="id", robot=log.name, until=float(s + length), smooth=True)
            aligned = evo_metrics.ate(run.true_trajectory, run.estimated_trajectory, align=True)["ate_rmse_m"]
            frame = run.metrics.get("landmark_frame_error", [np.nan] * 3)
            rows.append({"start_s": float(s), "ate_m": run.metrics["ate_m"], "aligned_ate_m": aligned,
                         "dtheta_rad": float(frame[2])})
        out[label] = rows
    return out


def compare_segments(per_robot: dict) -> list[dict]:
    """Per robot and pooled: medians, wins, and the signed-rank test of drive − as read."""
    from scipy.stats import wilcoxon  # here: scipy.stats takes 0.5-1 s to import, which --help need not wait for

    rows = []
    for name, robots in [(str(r), [r]) for r in per_robot] + [("all", list(per_robot))]:
        a = [x for r in robots for x in per_robot[r]["as read"]]
        b = [x for r in robots for x in per_robot[r]["drive"]]
        row = {"robot": name, "segments": len(a)}
        for key in ("ate_m", "aligned_ate_m"):
            x, y = np.array([s[key] for s in a]), np.array([s[key] for s in b])
            d = y - x
            row[key] = {"median_as_read": float(np.median(x)), "median_drive": float(np.median(y)),
                        "drive_better": int(np.sum(d < -1e-3)), "drive_worse": int(np.sum(d > 1e-3)),
                        "median_difference": float(np.median(d)),
                        "p": float(wilcoxon(d).pvalue) if len(d) > 5 and np.any(d != 0) else float("nan")}
        rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--robots", type=positive_int, nargs="+", default=[1, 2, 3, 4, 5])
    parser.add_argument("--drive", type=drive_option, default=drive_option("response:0.2"),
                        help="response:T (a first-order lag) or shape:DEAD,FAST,SLOW,WEIGHT[/...] (default "
                        "response:0.2)")
    parser.add_argument("--section", choices=("start", "segments", "all"), default="all")
    parser.add_argument("--first-seconds", type=positive_float, default=1.0)
    parser.add_argument("--segment-length", type=positive_float, default=200.0)
    parser.add_argument("--segment-step", type=positive_float, default=50.0)
    parser.add_argument("--seed", type=non_negative_int, default=0)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    if not args.data.is_dir():
        print(f"mrclam_response_maps: no data set at {args.data}", file=sys.stderr)
        return 2
    label, drive = args.drive
    result = {"drive": label, "start": {}, "segments": {}}
    for r in args.robots:
        log = read_mrclam(args.data, r)
        if args.section in ("start", "all"):
            result["start"][r] = start = start_section(log, drive, args.seed, args.first_seconds)
            if not args.json:
                _print_start(r, label, start, args.first_seconds)
        if args.section in ("segments", "all"):
            result["segments"][r] = segments_section(log, drive, args.seed, args.segment_length, args.segment_step)
    if result["segments"]:
        result["segment_comparison"] = compare_segments(result["segments"])
    if args.json:
        print(json.dumps(result))
        return 0
    if result["segments"]:
        print(f"\n== segments of {args.segment_length:g} s every {args.segment_step:g} s: as read vs {label}")
        for row in result["segment_comparison"]:
            print(f"robot {row['robot']:>3} ({row['segments']} segments): " + "; ".join(
                f"{key} median {v['median_as_read']:.3f} -> {v['median_drive']:.3f} m, drive better/worse "
                f"{v['drive_better']}/{v['drive_worse']}, median Δ {v['median_difference']:+.4f} (p {v['p']:.3f})"
                for key, v in ((k, row[k]) for k in ("ate_m", "aligned_ate_m"))))
    return 0


def _print_start(robot: int, label: str, start: dict, first_seconds: float) -> None:
    a, b = start["as read"], start["drive"]
    print(f"robot {robot}: ATE {a['ate_m']:.3f} -> {b['ate_m']:.3f} m ({label}); aligned {a['aligned_ate_m']:.4f} -> "
          f"{b['aligned_ate_m']:.4f}; frame dθ {a['frame']['dtheta_rad']:+.4f} -> {b['frame']['dtheta_rad']:+.4f} rad; "
          f"lag_s {a['lag_s']:.3f} -> {b['lag_s']:.3f}")
    for ra, rb in zip(a["attribution"], b["attribution"], strict=True):
        change = rb["contribution"][2] - ra["contribution"][2]
        if abs(change) >= 5e-4:
            print(f"    Δdθ from {ra['factor']:11s} {ra['from_s']:>4g}-{ra['to_s']:<4g} s: {change:+.4f} rad "
                  f"(its share of dθ's variance {ra['variance_share'][2]:.2f})")
    for name, s in start["swap"].items():
        print(f"    {name} ({start['first_increments']} increments, {first_seconds:g} s): ATE {s['ate_m']:.3f} m, "
              f"dθ {s['dtheta_rad']:+.4f}")


if __name__ == "__main__":
    raise SystemExit(main())
