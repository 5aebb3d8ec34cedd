"""MRCLAM data set 2 through `p3at slam dataset`'s code path: five robots, both association modes, every figure of
issue 13, and the maps for `p3at fuse`.

Run from the repository root:

    .venv/bin/python -m benchmarks.eval_mrclam [--data ../shared/data/mrclam/MRCLAM_Dataset2] [--robots 1,2,3,4,5]
        [--association id,unknown] [--noise own|others|FILE] [--particles 100] [--seed 0] [--until S]
        [--maps /tmp/mrclam-maps] [--no-inflation] [--heading-bias] [--sensor-correlation lag1|passes]
        [--range-calibration] [--odometry-lag] [--turn-translation] [--turn-variance] [--time-variance] [--smooth]
        [--defaults]
        [--heading-drift whole|first-half|SIGMA,TAU] [--truth-heading mocap|travel] [--set FIELD=VALUE ...] [--json]

Per robot and mode: ATE (hand-written, map frame mapped to the world through the true start pose) and the same
with evo (`benchmarks/evo_metrics.py`: APE rmse without alignment, and with SE(3) Umeyama alignment, which removes
the map frame's own error), dead-reckoning ATE, RPE over 1 m, landmarks against the true ones the robot saw,
duplicate fraction, landmark error in the start frame and after the best rigid fit, the fraction of landmarks
under the χ²₂ 95 % NEES bound (start frame and after the rigid fit), pose NEES (mean, median, fraction under
χ²₃ 95 %). Then the issue's targets, met or not. Maps go to MAPS/{id,unknown}/robotN.npz.

Noise: ``own`` fits each robot's model from its own log against the truth (what `p3at slam dataset` does without
--noise); ``others`` from the other robots' logs only (no robot is scored with noise fitted on itself);
``first-half`` from the first half of the robot's own log (its sightings before the median sighting time: the
second half is scored on a model that never saw it); a FILE is used for every robot. ``--range-calibration``: fit
the range's calibration too (estimate_noise(range_calibration=True): the camera reports depth, not range;
docs/fastslam-history.md "Session 8"; a FILE is used as it is). ``--no-inflation``: take consecutive sightings as
independent (the sensor variances are not multiplied by the noise model's variance_inflation). ``--heading-bias``:
fit the odometry's heading bias per metre beside the rotation scale (estimate_noise(heading_bias=True); off by
default, docs/fastslam-history.md "Session 5"; a FILE is used as it is). ``--sensor-correlation passes``: the sensor's
correlation (its variance inflation) measured over whole passes of sightings instead of from the lag-1 correlation
of consecutive ones (estimate_noise's sensor_correlation; docs/fastslam-history.md "Session 5").
``--turn-translation``: fit the odometry's forward deficit per radian turned beside the translation scale
(estimate_noise(turn_translation=True): MRCLAM's robots cover 0.65 of the commanded distance in arcs;
docs/fastslam-history.md "Session 16 (Q)"; a FILE is used as it is).
``--turn-variance``: fit the inflation of the x/y variance of a turn's increments, the turns' overdispersion
(estimate_noise(turn_variance=True): a turn's forward error persists through it; docs/fastslam-history.md "Session 16:
the odometry's variance in turns (lead)"; a FILE is used as it is).
``--time-variance``: fit the odometry's heading variance per second too (estimate_noise(time_variance=True), the
noise model's ``theta_var_per_s``: the heading wanders with time, moving or not; not among the defaults:
docs/fastslam-history.md "Session 35: a heading variance per second (A)"; a FILE is used as it is).
``--command-stall``: fit the random stall after a one-sample dip of the commanded velocity too
(estimate_noise(command_stall=True), the noise model's ``stall_sigma_s``; docs/fastslam-history.md "Session 41: the
stall after a dip of the command ... (A)"; a FILE is used as it is).
``--smooth``: the known-ID runs smoothed over the whole log after the filter (``run_landmark_log(smooth=True)``,
docs/fastslam-history.md "Session 15"); the filter's own figures stay under ``filter_``.
``--defaults``: what `p3at slam dataset` does without options: the range calibration, heading bias, odometry lag and
turns' variance fitted (session 17), the stall after the command's dips too (session 42; ``DATASET_CALIBRATIONS``),
and the known-ID runs smoothed.
``--heading-drift``: each particle carries a drifting heading bias per metre (estimation/fastslam/motion.py; the
noise model's ``heading_drift_sigma_per_m``, ``heading_drift_tau_s``), its (σ_b, τ) fitted on the robot's whole log
(``whole``: estimate_noise(heading_drift=True)), on the first half of its log in time (``first-half``: the half's own
calibrated model, the benchmark ``mrclam_odometry_horizons``'s halves), or given (``0.16,10``); the rest of the model
as without it (docs/fastslam-history.md "Session 23 ... (D)").
``--truth-heading travel``: every log read with its ground truth's heading turned onto the robot's direction of travel
(``read_mrclam(truth_heading="travel")``, estimation/datasets/truth_heading.py), so the noise models fitted in sample
and every score are against that truth; ``mocap`` (default) keeps Vicon's heading as written.
``--response-time T``: the commanded velocities through a first-order lag of T s before the noise fit and the runs
(estimation.odometry_response; docs/fastslam-history.md "Session 44: the drive's response (D)"). ``--drive-shape
TURN[/TRAVEL]``: the same with a dead time and two first-order parts per channel, each "DEAD,FAST,SLOW,WEIGHT" (MRCLAM's
fitted shapes: turn 0.15,0,0.3,0.45, travel 0,0.5,0,0; benchmarks.mrclam_drive_response --section shape); both off.
``--set`` overrides a FastSLAMConfig field (a diagnosis,
e.g. ``--set existence_miss=0``); the overrides are printed with the figures.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

from benchmarks import evo_metrics  # noqa: E402
from benchmarks.config_overrides import config_overrides  # noqa: E402
from benchmarks.output_paths import output_refusal  # noqa: E402
from estimation.dataset_slam import run_landmark_log  # noqa: E402
from estimation.datasets import TRUTH_HEADINGS, read_mrclam  # noqa: E402
from estimation.fastslam import range_bearing_config  # noqa: E402
from estimation.landmark_scores import DUPLICATE_GOAL, NEES_WITHIN_GOAL  # noqa: E402
from estimation.noise_estimation import DATASET_CALIBRATIONS, estimate_noise  # noqa: E402
from estimation.noise_model import NoiseModel  # noqa: E402
from estimation.odometry_response import ResponseShape, with_drive_response, with_drive_shape  # noqa: E402
from runtime.commands.options import non_negative_float, non_negative_int, particle_count, positive_float  # noqa: E402

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "mrclam" / "MRCLAM_Dataset2"
COLUMNS = (("ate_m", "ATE", 3), ("evo_ate_m", "evo", 3), ("evo_ate_aligned_m", "evo-al", 3),
           ("dead_reckoning_ate_m", "DR", 2), ("rpe_1m_m", "RPE1m", 3), ("landmarks", "lm", 0),
           ("true_landmarks", "true", 0), ("duplicate_fraction", "dup", 2), ("landmark_error_median_m", "lm-err", 3),
           ("landmark_error_rigid_median_m", "lm-rig", 3), ("landmark_nees_within_bound", "NEES<b", 2),
           ("landmark_nees_rigid_within_bound", "rig<b", 2), ("pose_nees_median", "poseNEES", 1),
           ("pose_nees_within_chi2_95", "pose<b", 2), ("seconds_cpu", "cpu s", 0))


def heading_drift_option(text: str):
    """``--heading-drift``: "whole", "first-half" or "SIGMA,TAU" (σ_b ≥ 0 rad/m, τ > 0 s)."""
    if text in ("whole", "first-half"):
        return text
    try:
        sigma, tau = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected whole, first-half or SIGMA,TAU, not {text!r}") from None
    if not (0.0 <= sigma <= 1.0 and 0.0 < tau < float("inf")):
        raise argparse.ArgumentTypeError(f"SIGMA must lie in [0, 1] rad/m and TAU be > 0 s, not {text!r}")
    return (sigma, tau)


def drive_shape_option(text: str) -> tuple[ResponseShape, ResponseShape]:
    """``--drive-shape``: "TURN" or "TURN/TRAVEL", each "DEAD,FAST,SLOW,WEIGHT" (s, s, s, and the slow part's
    weight: estimation.odometry_response.ResponseShape); the travel's shape is the turn's when not given."""
    try:
        parts = [tuple(float(v) for v in part.split(",")) for part in text.split("/")]
        if not 1 <= len(parts) <= 2 or any(len(p) != 4 for p in parts):
            raise ValueError("expected four numbers per shape")
        shapes = [ResponseShape(*p) for p in parts]
    except (ValueError, TypeError) as error:
        raise argparse.ArgumentTypeError(f"expected DEAD,FAST,SLOW,WEIGHT[/DEAD,FAST,SLOW,WEIGHT] (s, s, s, weight): "
                                         f"{error}") from None
    return shapes[0], shapes[-1]


def with_drift(model: NoiseModel, log, how, fit: dict) -> NoiseModel:
    """``model`` with the heading drift of ``--heading-drift`` (see the module docstring): ``fit`` is estimate_noise's
    options (the calibrations), with which the drift's own model is fitted."""
    if how == "whole":
        drift = estimate_noise([log], **fit, heading_drift=True).model.odometry
        how = (drift.heading_drift_sigma_per_m, drift.heading_drift_tau_s)
    elif how == "first-half":
        from benchmarks.mrclam_odometry_horizons import half

        drift = estimate_noise([half(log, True)], **fit, heading_drift=True).model.odometry
        how = (drift.heading_drift_sigma_per_m, drift.heading_drift_tau_s)
    return replace(model, odometry=replace(model.odometry, heading_drift_sigma_per_m=how[0],
                                           heading_drift_tau_s=how[1]))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--robots", default="1,2,3,4,5")
    parser.add_argument("--association", default="id,unknown")
    parser.add_argument("--noise", default="own", help="own | others | first-half | FILE (see the module docstring)")
    parser.add_argument("--particles", type=particle_count, default=100)
    parser.add_argument("--seed", type=non_negative_int, default=0)
    parser.add_argument("--until", type=positive_float)
    parser.add_argument("--maps", type=Path, default=Path("/tmp/mrclam-maps"))
    parser.add_argument("--no-inflation", action="store_true", help="do not inflate the sensor variances for "
                        "correlated sightings")
    parser.add_argument("--sensor-correlation", choices=("lag1", "passes"), default="lag1")
    parser.add_argument("--heading-bias", action="store_true", help="fit the odometry's heading bias per metre "
                        "beside the rotation scale")
    parser.add_argument("--range-calibration", action="store_true", help="fit the range's calibration (the camera "
                        "reports depth along its axis, not range)")
    parser.add_argument("--odometry-lag", action="store_true", help="fit the time by which the odometry (commanded "
                        "velocity) leads the motion, and read it that much earlier")
    parser.add_argument("--turn-translation", action="store_true", help="fit the forward travel the robot loses per "
                        "radian turned beside the translation scale")
    parser.add_argument("--turn-variance", action="store_true", help="fit the inflation of the x/y variance of a "
                        "turn's increments (a turn's forward error persists through it)")
    parser.add_argument("--time-variance", action="store_true", help="fit the odometry's heading variance per second "
                        "(the heading wanders with time, moving or not)")
    parser.add_argument("--command-stall", action="store_true", help="fit the random stall after a one-sample dip of "
                        "the commanded velocity (the robot stops a while, its odometry goes on)")
    parser.add_argument("--smooth", action="store_true", help="smooth the known-ID runs over the whole log")
    parser.add_argument("--defaults", action="store_true", help="what `p3at slam dataset` does without options: "
                        "the calibrations of DATASET_CALIBRATIONS, and the known-ID runs smoothed")
    parser.add_argument("--heading-drift", type=heading_drift_option, default=None,
                        metavar="whole|first-half|SIGMA,TAU", help="a drifting heading bias per particle: (σ_b "
                        "rad/m, τ s) fitted on the whole log, its first half, or given")
    parser.add_argument("--truth-heading", choices=TRUTH_HEADINGS, default="mocap",
                        help="the ground truth's heading: Vicon's as written (mocap, default) or turned onto the "
                        "robot's direction of travel (travel); the in-sample noise fits and the scores use it")
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                        help="override a FastSLAMConfig field (JSON value), e.g. existence_miss=0")
    parser.add_argument("--response-time", type=non_negative_float, default=0.0, metavar="T",
                        help="integrate the commanded velocities through a first-order response of time constant T "
                        "s (v and ω; estimation.odometry_response) before everything (the noise fit and the runs); "
                        "0, the default: the odometry as read")
    parser.add_argument("--drive-shape", type=drive_shape_option, default=None,
                        metavar="DEAD,FAST,SLOW,WEIGHT[/DEAD,FAST,SLOW,WEIGHT]",
                        help="integrate the commanded turn rate (and speed, after the slash; else the same) through a "
                        "dead time and two first-order parts (estimation.odometry_response.ResponseShape) before "
                        "everything, as --response-time (which it replaces); off by default")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    if args.drive_shape is not None and args.response_time:
        parser.error("--drive-shape and --response-time are two descriptions of the drive: give one")

    def read(*a, **k):
        log = read_mrclam(*a, truth_heading=args.truth_heading, **k)
        if args.drive_shape is not None:
            return with_drive_shape(log, *args.drive_shape)
        return with_drive_response(log, args.response_time)
    if args.defaults:
        vars(args).update(DATASET_CALIBRATIONS, smooth=True)
    overrides = config_overrides(args.set)
    robots = [int(r) for r in args.robots.split(",")]
    modes = args.association.split(",")
    if not args.data.is_dir():
        print(f"eval_mrclam: no data set at {args.data}", file=sys.stderr)
        return 2
    refusal = output_refusal("eval_mrclam", "--maps", args.maps, args.data)
    if refusal:
        print(refusal, file=sys.stderr)
        return 2

    logs = {r: read(args.data, r) for r in robots}
    others = {r: read(args.data, r) for r in range(1, 6) if r not in logs} if args.noise == "others" else {}
    noise = {}
    fit = {"heading_bias": args.heading_bias, "sensor_correlation": args.sensor_correlation,
           "range_calibration": args.range_calibration, "odometry_lag": args.odometry_lag,
           "turn_translation": args.turn_translation, "turn_variance": args.turn_variance,
           "time_variance": args.time_variance, "command_stall": args.command_stall}
    for r in robots:
        if args.noise == "own":
            noise[r] = estimate_noise([logs[r]], **fit).model
        elif args.noise == "others":
            pool = [log for k, log in {**logs, **others}.items() if k != r]
            noise[r] = estimate_noise(pool, **fit).model
        elif args.noise == "first-half":
            noise[r] = estimate_noise([read(args.data, r, until=float(np.median(logs[r].sighting_times)))],
                                      **fit).model
        else:
            noise[r] = NoiseModel.load(args.noise)
        if args.heading_drift is not None:
            noise[r] = with_drift(noise[r], logs[r], args.heading_drift, fit)

    results = {}
    for mode in modes:
        for r in robots:
            start = time.process_time()
            run = run_landmark_log(logs[r], range_bearing_config(**({"n_particles": args.particles} | overrides)),
                                   np.random.default_rng(args.seed), noise=noise[r], association=mode,
                                   robot=f"robot{r}", until=args.until, inflate_correlated=not args.no_inflation,
                                   smooth=args.smooth and mode == "id")
            cpu = time.process_time() - start
            out = args.maps / mode / f"robot{r}.npz"
            run.map.save(out)
            m = dict(run.metrics, seconds_cpu=cpu, map=str(out))
            evo = evo_metrics.ate(run.true_trajectory, run.estimated_trajectory)
            aligned = evo_metrics.ate(run.true_trajectory, run.estimated_trajectory, align=True)
            rpe = evo_metrics.rpe(run.true_trajectory, run.estimated_trajectory, delta=1.0)
            m.update(evo_ate_m=evo["ate_rmse_m"], evo_ate_aligned_m=aligned["ate_rmse_m"],
                     rpe_1m_m=rpe["rpe_translation_rmse_m"], rpe_1m_rad=rpe["rpe_rotation_rmse_rad"])
            results[(mode, r)] = m
            if not args.json:
                print(f"  {mode:7s} robot{r}: ATE {m['ate_m']:.3f} m (DR {m['dead_reckoning_ate_m']:.2f}), "
                      f"{m['landmarks']} landmarks, {cpu:.0f} s CPU", flush=True)

    summary = _summary(results, robots, modes)
    if args.json:
        print(json.dumps({"runs": {f"{mode}/robot{r}": m for (mode, r), m in results.items()}, "summary": summary,
                          "noise": args.noise, "heading_bias": args.heading_bias,
                          "sensor_correlation": args.sensor_correlation,
                          "range_calibration": args.range_calibration, "odometry_lag": args.odometry_lag,
                          "odometry_lag_s": {r: noise[r].odometry.lag_s for r in robots},
                          "heading_bias_per_m": {r: noise[r].odometry.heading_bias_per_m for r in robots},
                          "turn_translation": args.turn_translation,
                          "forward_deficit_per_rad": {r: noise[r].odometry.forward_deficit_per_rad for r in robots},
                          "turn_variance": args.turn_variance,
                          "turn_xy_inflation": {r: noise[r].odometry.turn_xy_inflation for r in robots},
                          "time_variance": args.time_variance,
                          "command_stall": args.command_stall,
                          "stall_sigma_s": {r: noise[r].odometry.stall_sigma_s for r in robots},
                          "theta_var_per_s": {r: noise[r].odometry.theta_var_per_s for r in robots},
                          "heading_drift": {r: [noise[r].odometry.heading_drift_sigma_per_m,
                                                noise[r].odometry.heading_drift_tau_s] for r in robots},
                          "truth_heading": args.truth_heading, "response_time_s": args.response_time,
                          "drive_shape": None if args.drive_shape is None else
                          [[s.dead_time_s, s.fast_s, s.slow_s, s.slow_weight] for s in args.drive_shape],
                          "overrides": overrides, "inflation": not args.no_inflation, "smooth": args.smooth,
                          "particles": args.particles, "seed": args.seed,
                          "maps": str(args.maps)}))
        return 0
    print(f"\nMRCLAM {args.data.name}, {args.particles} particles, seed {args.seed}, noise: {args.noise}, "
          f"truth heading: {args.truth_heading}"
          + (f", until {args.until:g} s" if args.until else "") + (f", overrides {overrides}" if overrides else "")
          + (", odometry heading bias per metre " + " ".join(f"{noise[r].odometry.heading_bias_per_m:+.4f}"
                                                            for r in robots) + " rad/m" if args.heading_bias else "")
          + (", forward deficit per radian turned " + " ".join(f"{noise[r].odometry.forward_deficit_per_rad:.4f}"
                                                              for r in robots) + " m/rad" if args.turn_translation
             else "")
          + (", x/y variance in turns × " + " ".join(f"{noise[r].odometry.turn_xy_inflation:.2f}" for r in robots)
             if args.turn_variance else "")
          + (", heading variance per second " + " ".join(f"{noise[r].odometry.theta_var_per_s:.2e}" for r in robots)
             + " rad²/s" if args.time_variance else "")
          + (", sensor variances not inflated" if args.no_inflation else ", sensor variances inflated for correlation"))
    header = "mode    robot " + " ".join(f"{label:>8s}" for _, label, _ in COLUMNS)
    print(header)
    for (mode, r), m in results.items():
        print(f"{mode:7s} {r:5d} " + " ".join(f"{m[k]:8.{d}f}" if isinstance(m[k], float) else f"{m[k]:8d}"
                                              for k, _, d in COLUMNS))
    print()
    for line in summary["lines"]:
        print(line)
    print(f"\nmaps for `p3at fuse`: {args.maps}/{{{','.join(modes)}}}/robotN.npz")
    return 0


def _summary(results: dict, robots: list[int], modes: list[str]) -> dict:
    lines, out = [], {}

    def figures(mode, key):
        return np.array([results[(mode, r)][key] for r in robots if (mode, r) in results], float)

    if "id" in modes:
        ate = figures("id", "ate_m")
        rigid = figures("id", "landmark_error_rigid_median_m")
        out.update(id_ate_median_m=float(np.median(ate)), id_ate_max_m=float(np.max(ate)),
                   id_landmark_error_rigid_median_m=float(np.median(rigid)))
        lines.append(f"known-ID: median ATE {np.median(ate):.3f} m (target <= 0.25): "
                     f"{_verdict(np.median(ate) <= 0.25)}; every robot <= 0.5 m (max {np.max(ate):.3f}): "
                     f"{_verdict(np.max(ate) <= 0.5)}; landmark error after rigid fit, median "
                     f"{np.median(rigid):.3f} m (target <= 0.15): {_verdict(np.median(rigid) <= 0.15)}")
    if "unknown" in modes:
        dup = figures("unknown", "duplicate_fraction")
        out.update(unknown_duplicate_fraction_max=float(np.max(dup)))
        line = (f"unknown: duplicates max {100 * np.max(dup):.1f} % (target < {100 * DUPLICATE_GOAL:g} %): "
                f"{_verdict(np.max(dup) < DUPLICATE_GOAL)}")
        if "id" in modes:
            ratio = figures("unknown", "ate_m") / figures("id", "ate_m")
            out.update(unknown_over_id_ate_max=float(np.max(ratio)))
            line += (f"; ATE unknown/id per robot {', '.join(f'{x:.2f}' for x in ratio)} (target <= 1.5): "
                     f"{_verdict(np.max(ratio) <= 1.5)}")
        lines.append(line)
    for mode in modes:
        nees = figures(mode, "landmark_nees_within_bound")
        rigid = figures(mode, "landmark_nees_rigid_within_bound")
        pose = figures(mode, "pose_nees_within_chi2_95")
        out[f"{mode}_landmark_nees_within_bound_min"] = float(np.min(nees))
        lines.append(f"{mode}: landmarks under the NEES bound (target >= {100 * NEES_WITHIN_GOAL:g} %): "
                     f"{100 * np.min(nees):.0f}-{100 * np.max(nees):.0f} % in the start frame, "
                     f"{100 * np.min(rigid):.0f}-{100 * np.max(rigid):.0f} % after the rigid fit: "
                     f"{_verdict(np.min(nees) >= NEES_WITHIN_GOAL)}; "
                     f"poses under χ²₃ 95 %: "
                     f"{100 * np.min(pose):.0f}-{100 * np.max(pose):.0f} %")
    out["lines"] = lines
    return out


def _verdict(ok) -> str:
    return "met" if ok else "NOT met"


if __name__ == "__main__":
    sys.exit(main())
