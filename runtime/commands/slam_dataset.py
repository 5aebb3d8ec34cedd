"""``p3at slam dataset``: FastSLAM on a recorded landmark data set, scored against its ground truth (the parser is in
:mod:`.slam`)."""
from __future__ import annotations

import argparse
import sys

import numpy as np

from estimation.errors import EstimationError
from runtime.commands.options import check_output_apart, check_output_file, rerun_sink_problem
from runtime.commands.slam_noise import no_sensor_fit
from runtime.json_output import json_text


def _chain_problem(args: argparse.Namespace) -> str | None:
    """What makes ``--chain`` meaningless with the other options given, in one line (None: nothing)."""
    if not args.chain:
        return "--seeds votes runs of the chain: it needs --chain" if args.seeds else None
    if args.association != "unknown":
        return "--chain names the landmarks itself: it needs --association unknown"
    if args.smooth is not None:
        return "--chain smooths the whole log by its own names: --smooth/--no-smooth do not apply"
    if args.no_inflation:
        return "--chain uses the noise model's variance inflation as measured: --no-inflation does not apply"
    if args.fastslam != 2:
        return "--chain's filter is FastSLAM 2.0 as measured: --fastslam 1 does not apply"
    if args.seeds and args.seed != 0:
        return "--seeds gives each run its seed: --seed does not apply"
    return None


def _frame_problem(args: argparse.Namespace) -> str | None:
    """What makes ``--frame checked`` meaningless with the other options given, in one line (None: nothing): the
    frame is chosen on the known-ID smoother's solution."""
    if args.frame == "first-sighting":
        return None
    if args.chain:
        return "--frame checked is chosen on the known-ID smoother's solution: the chain's map keeps its own frame"
    if args.association != "id" or args.smooth is False:
        return "--frame checked is chosen on the smoother's solution: it needs --association id and the smoother"
    return None


def _image_timing_problem(args: argparse.Namespace) -> str | None:
    """What makes ``--image-timing`` meaningless with the other options given, in one line (None: nothing): the
    shared error per image is the known-ID smoother's."""
    if not args.image_timing:
        return None
    if args.chain or args.association != "id" or args.smooth is False:
        return ("--image-timing is the known-ID smoother's bearing model: it needs --association id and the smoother "
                "(not --chain, not --no-smooth)")
    return None


def _check_rerun_sink(sink: str | None) -> None:
    """Refuse a ``--rerun`` sink before the run, not after it: FILE.rrd (its folder writable), spawn or a URL."""
    if (problem := rerun_sink_problem(sink, ("spawn",))) is not None:
        raise ValueError(problem)


def run_dataset(args: argparse.Namespace) -> int:
    from dataclasses import asdict

    from estimation.datasets import drop_repeated_readings, read_mrclam

    try:
        _check_arguments(args)
        # the chain has no frame cut: it reads the log up to --until (its in-sample noise fit too)
        log = read_mrclam(args.folder, args.robot, barcodes=args.barcodes, until=args.until if args.chain else None,
                          truth_heading=args.truth_heading)
        repeats = None
        if args.drop_repeats:   # before the noise fit too: a repeat is not a second sample of the sensor's error
            log, repeats = drop_repeated_readings(log, whole_images=args.drop_repeats == "images")
        noise, noise_source = _noise_model(args, log)
        run = _run(args, log, noise)
        run.map.metadata["noise_model"] = asdict(noise.odometry) | (asdict(noise.range_bearing)
                                                                     if noise.range_bearing else {})
        run.map.save(args.out)
    except (ValueError, OSError, EstimationError) as e:   # DatasetError, NoiseModelError, MapFileError included
        print(f"p3at slam dataset: {e}", file=sys.stderr)
        return 2
    warnings = _warnings(args, run.metrics, noise)
    if args.rerun:
        from runtime.dataset_recording import record_dataset_run
        from runtime.rerun_sink import ViewerError
        try:
            record_dataset_run(args.rerun, run, log, f"robot{args.robot}", warnings)
        except (OSError, ViewerError) as e:
            print(f"p3at slam dataset: the map is written to {args.out}, but the recording failed: {e}",
                  file=sys.stderr)
            return 2
    metrics = dict(run.metrics, out=str(args.out), robot=args.robot, dataset=log.name, seed=args.seed,
                   noise=noise_source, notes=list(log.notes), recording=args.rerun, warnings=warnings,
                   stamp_resolution=[q.as_dict() for q in log.stamp_resolution])
    if repeats is not None:
        metrics["repeated_readings_dropped"] = repeats.count
        if args.drop_repeats == "images":
            metrics["repeated_image_mates_dropped"] = repeats.mates_count
    if args.json:
        # every warning on stderr too, one line each: a user piping the JSON still sees them
        for warning in metrics["warnings"]:
            print(f"p3at slam dataset: warning: {warning}", file=sys.stderr)
        print(json_text(metrics))
        return 0
    _print_summary(metrics)
    return 0


def _check_arguments(args: argparse.Namespace) -> None:
    """Refuse, before anything is read, options that do not go together and outputs that cannot be written or would
    replace what the run reads; raises ValueError (OutputPathError is one) with a one-line reason."""
    from runtime.commands.file_kinds import out_problem

    if (problem := _chain_problem(args) or _frame_problem(args) or _image_timing_problem(args)) is not None:
        raise ValueError(problem)
    check_output_file(args.out)
    _check_rerun_sink(args.rerun)
    # neither output may replace what the run reads (the noise model, a table of the data set) or the other
    recording = args.rerun if args.rerun is not None and args.rerun.endswith(".rrd") else None
    check_output_apart(args.out, files={"--noise": args.noise, "--rerun": recording},
                       folders={"data set": args.folder})
    check_output_apart(recording, "--rerun", files={"--noise": args.noise}, folders={"data set": args.folder})
    if (problem := out_problem(args.out, "map")) is not None:   # after: '--out X is the --noise file' says more
        raise ValueError(problem)


def _noise_model(args: argparse.Namespace, log):
    """(the noise model, where it comes from in words): --noise's, else fitted to this log's own ground truth;
    raises ValueError if the log's own fit fails."""
    from estimation.noise_estimation import DATASET_CALIBRATIONS, estimate_noise
    from estimation.noise_model import NoiseModel

    if args.noise:
        return NoiseModel.load(args.noise), str(args.noise)
    try:
        noise = estimate_noise([log], **DATASET_CALIBRATIONS).model
        if (problem := no_sensor_fit(noise, [log])) is not None:
            raise ValueError(problem)
    except ValueError as e:
        raise ValueError(f"fitting this log's own noise model: {e} (give one with --noise FILE)") from None
    return noise, ("estimated from this log's own ground truth with its range calibration, heading bias, "
                   "odometry lag, turns' variance and the stall after the command's dips (no --noise given)")


def _run(args: argparse.Namespace, log, noise):
    """The filter over the log: the chain (--chain), else FastSLAM with --association (smoothed where it applies)."""
    from estimation.dataset_slam import run_landmark_log
    from estimation.fastslam import range_bearing_config

    smooth = args.association == "id" if args.smooth is None else args.smooth
    config = range_bearing_config(n_particles=args.particles, version=args.fastslam)
    if args.chain:
        try:
            return _chain_run(log, noise, config, args)
        except np.linalg.LinAlgError as e:
            raise ValueError(_singular_chain(noise, e)) from None
    return run_landmark_log(log, config, np.random.default_rng(args.seed), noise=noise,
                            association=args.association, robot=f"robot{args.robot}", until=args.until,
                            inflate_correlated=not args.no_inflation, smooth=smooth, frame=args.frame,
                            image_timing=args.image_timing)


def _warnings(args: argparse.Namespace, metrics: dict, noise) -> list[str]:
    """What the user must not miss about the written map, one sentence each."""
    from estimation.frame_reliability import reliability_warning
    from estimation.naming_reliability import naming_warning

    # the frame resting on single sightings: from the design, with or without a truth (the chain's map's too); the
    # chain's frame or path resting on a naming nothing checks, likewise
    reliability = reliability_warning(metrics)
    naming = naming_warning(metrics)
    return (_map_warnings(metrics) + ([] if reliability is None else [reliability])
            + ([] if naming is None else [naming])
            + (_frame_warnings(noise, args.truth_heading, metrics) if args.noise else []))


def _print_summary(m: dict) -> None:
    """The run's figures for a reader (``--json`` prints ``m`` whole instead)."""
    print(f"slam dataset: {m['dataset']}, {m['frames']} frames over {m['seconds']:.0f} s, {m['particles']} "
          f"particles, FastSLAM {m['version']}.0, association {m['association']}, "
          + (f"seeds {','.join(map(str, m['seeds']))}" if "seeds" in m else f"seed {m['seed']}"))
    for note in m["notes"]:
        print(f"  note: {note}")
    print(f"  noise model: {m['noise']}")
    if "chain_runs" in m:
        print("  the chain's runs voted: " + ", ".join(
            f"seed {r['seed']} {r['names']} names ({r['pairs_apart_from_vote']} sighting pairs named otherwise)"
            for r in m["chain_runs"]) + f"; smoothed from seed {m['vote_started_from_seed']}'s, "
            f"{m['vote_contested_names']} names held by fewer than all runs")
    if "chain_names" in m:
        rounds = f", rounds {m['chain_rounds']}" if "chain_rounds" in m else ""
        print(f"  the chain: {m['chain_names']} names{rounds}, {m['chain_sightings_named']} "
              f"of {m['chain_sightings']} sightings named, smoothed with χ² per degree of freedom "
              f"{m['smoother_chi2_per_dof']:.2f} ({m['smoother_outliers']} sightings dropped as outliers)")
    if m.get("smoothed"):
        print(f"  smoothed over the whole log: {m['smoother_sightings'] - m['smoother_outliers']} of "
              f"{m['smoother_sightings']} sightings kept, χ² per degree of freedom {m['smoother_chi2_per_dof']:.2f}"
              + ("" if m["smoother_converged"] else ", NOT converged")
              + ("" if "filter_ate_m" not in m else f"; the filter alone: ATE {m['filter_ate_m']:.3f} m")
              + ("" if "filter_landmark_error_median_m" not in m else f", landmark error "
                 f"{m['filter_landmark_error_median_m']:.3f} m ({m['filter_landmark_error_rigid_median_m']:.3f} m "
                 "rigid)"))
    estimator = "chain" if "chain_names" in m else "smoothed" if m.get("smoothed") else "FastSLAM"
    if "ate_m" in m:
        print(f"  trajectory ATE        {estimator} {m['ate_m']:.3f} m   dead reckoning "
              f"{m['dead_reckoning_ate_m']:.3f} m")
    if "true_landmarks" in m:
        print(f"  landmarks {m['landmarks']} for {m['true_landmarks']} true ({m['duplicate_landmarks']} duplicates, "
              f"{100 * m['duplicate_fraction']:.0f} %): median error {m['landmark_error_median_m']:.3f} m in the start "
              f"frame, {m['landmark_error_rigid_median_m']:.3f} m after the best rigid fit")
        print(f"  landmark NEES: {100 * m['landmark_nees_within_bound']:.0f} % below χ²₂(95 %) "
              f"({100 * m['landmark_nees_rigid_within_bound']:.0f} % after the rigid fit)")
    else:   # no truth for the landmarks, or none at all (then no ATE nor NEES either)
        print(f"  landmarks {m['landmarks']}; not scored: {m['unscored']}")
    if "pose_nees_mean" in m:
        print(f"  pose NEES over {m['pose_nees_frames']} frames (3 is consistent): mean {m['pose_nees_mean']:.1f}, "
              f"median {m['pose_nees_median']:.1f}, {100 * m['pose_nees_within_chi2_95']:.0f} % below χ²₃(95 %)")
    for warning in m["warnings"]:
        print(f"  WARNING: {warning}")
    print(f"  map written to {m['out']}" + (f", the run to Rerun: {m['recording']}" if m["recording"] else ""))


def _singular_chain(noise, error: Exception) -> str:
    """Why the chain's smoothing could not be solved, in one line: a noise model whose σ are far below any sensor's
    (a fit to exact, simulated sightings) makes its normal equations numerically singular."""
    sensor = noise.range_bearing
    return (f"the chain's smoothing is numerically singular ({error}): the noise model's sensor σ are "
            f"{sensor.range_sigma_m:.2g} m in range and {sensor.bearing_sigma_rad:.2g} rad in bearing, "
            f"too small for any real sensor (a fit to exact, simulated sightings?); give a model with --noise FILE")


def _chain_run(log, noise, config, args: argparse.Namespace):
    """``--chain``: estimation.name_chain.run_chain with session 30's recipe (ChainSettings()) and the filter's seed,
    its final state as the data set run the command writes and prints (estimation.chain_map.chain_run)."""
    import dataclasses

    from estimation.chain_map import chain_run
    from estimation.name_chain import ChainSettings, run_chain
    from estimation.seed_vote import chain_vote, voted_landmark_map

    if noise.range_bearing is None:
        raise ValueError("the chain needs the noise model's sensor part (its [range_bearing] section)")
    if not len(log):
        before = "" if args.until is None else f" before {args.until:g} s"
        raise ValueError(f"{log.name}: nothing to name: no sightings{before}")
    robot = f"robot{args.robot}"
    if args.seeds:
        results, vote = chain_vote(log, noise, config, args.seeds)
        state = vote.state
        run = dataclasses.replace(chain_run(log, state, robot), map=voted_landmark_map(log, vote, args.seeds, robot))
        run.metrics.update(chain_runs=[{"seed": seed, "names": int(len(r.state.named.names)),
                                        "rounds": int(r.rounds_done), "pairs_apart_from_vote": int(apart)}
                                       for seed, r, apart in zip(args.seeds, results, vote.apart, strict=True)],
                           seeds=list(args.seeds), vote_started_from_seed=args.seeds[vote.nearest],
                           vote_contested_names=int(np.sum(vote.support < len(args.seeds))))
    else:
        result = run_chain(log, noise, config, ChainSettings(seed=args.seed))
        state = result.state
        run = chain_run(log, state, robot)
        run.metrics.update(chain_rounds=int(result.rounds_done))
    run.metrics.update(frames=len(state.named.frame_times), particles=config.n_particles, version=config.version,
                       association="unknown-chain", chain_names=int(len(state.named.names)),
                       chain_sightings_named=int((state.names >= 0).sum()), chain_sightings=int(len(state.names)),
                       smoother_chi2_per_dof=float(state.solution.chi2_per_dof),
                       smoother_outliers=int((~state.solution.inliers).sum()))
    return run


def _frame_warnings(noise, truth_heading: str, metrics: dict) -> list[str]:
    """A map scored against another truth's heading than the one its camera's bearing offset is referenced to: a
    self-calibrated camera (``self_calibration_*`` in the model's [fit]) or a travel fit is the wheels' frame, a fit
    against the motion capture its markers' (docs/fastslam.md, *The truth's heading*). For a model given with --noise;
    one fitted here is fitted against the truth it is scored with."""
    if "true_start_pose" not in metrics:
        return []
    travel = noise.fit.get("truth_heading") == "travel" or any(k.startswith("self_calibration_") for k in noise.fit)
    referenced = "travel" if travel else "mocap"
    if referenced == truth_heading:
        return []
    return [f"the noise model's camera is referenced to the {_FRAMES[referenced]} and the map is scored against the "
            f"{_FRAMES[truth_heading]}: the start-frame figures carry their difference (up to 0.017 rad on MRCLAM); "
            f"--truth-heading {referenced} scores the map in its own frame"]


_FRAMES = {"mocap": "motion capture's heading", "travel": "direction of travel"}


def _map_warnings(metrics: dict) -> list[str]:
    """What the ground truth says about the written map that its user must not miss: covariances that do not hold
    its errors (a map confidently wrong) and duplicates (one post mapped more than once)."""
    from estimation.landmark_scores import DUPLICATE_GOAL, NEES_WITHIN_GOAL

    warnings = []
    within = metrics.get("landmark_nees_within_bound", float("nan"))
    if within < NEES_WITHIN_GOAL:
        warnings.append(f"only {100 * within:.0f} % of the landmarks are within their covariance's χ²₂ 95 % bound "
                        f"(the goal is {100 * NEES_WITHIN_GOAL:.0f} %): the map claims more certainty than "
                        "it has; do not fuse or navigate on its covariances")
    duplicates = metrics.get("duplicate_fraction", 0.0)
    if duplicates > DUPLICATE_GOAL:
        warnings.append(f"{100 * duplicates:.0f} % of the landmarks are duplicates of another (true landmarks mapped "
                        "more than once)")
    return warnings
