"""``p3at slam``: FastSLAM. ``simulate`` builds a map on a simulated run, ``dataset`` on a recorded landmark data set
(MRCLAM), ``noise`` fits a noise model from a log with ground truth; each scores against the truth where there is
some (``dataset`` maps a log without it unscored)."""
from __future__ import annotations

import argparse
import math
import sys

import numpy as np

from estimation.errors import EstimationError
from estimation.fastslam import FastSLAMConfig
from runtime.commands.options import (
    add_deprecated_alias,
    check_output_apart,
    check_output_file,
    finite_float,
    non_negative_int,
    particle_count,
    positive_float,
    positive_int,
    rerun_sink_problem,
)
from runtime.json_output import json_text


def register(subparsers) -> None:
    parser = subparsers.add_parser("slam", help="FastSLAM: a simulated run, a recorded landmark data set, noise models",
                                   description="FastSLAM over landmarks: a simulated run (simulate), a recorded "
                                               "range-bearing data set (dataset), a noise model fitted from a log "
                                               "with ground truth (noise).")
    sub = parser.add_subparsers(dest="slam_command", metavar="SUBCOMMAND", required=True)
    sim = sub.add_parser(
        "simulate", help="drive a virtual robot through the simulated building and build its map",
        description="One virtual robot follows a route of the simulated building (pure pursuit, simulated "
                    "time), observes with the synthetic stereo sensor, runs FastSLAM on its odometry and "
                    "observations, saves the most probable particle's map (in the robot's start frame, with "
                    "metadata.true_start_pose) and prints trajectory and landmark errors against the truth "
                    "beside dead reckoning.")
    sim.add_argument("--seconds", type=positive_float, default=300.0, help="simulated time limit (default 300 s; the "
                     "run also ends when the route is done)")
    sim.add_argument("--seed", type=non_negative_int, default=0,
                     help="random seed (sensor, odometry and filter), a whole number >= 0 (default 0)")
    sim.add_argument("--name", default="robot1", help="the world's robot whose start pose and route to use "
                     "(default robot1)")
    sim.add_argument("--start-pose", metavar="X,Y,THETA", help="start pose in the world (m, m, rad); default: the "
                     "world's start pose of --name, or the route's first waypoint facing the second")
    sim.add_argument("--world-route", metavar="FILE", help="route file of WORLD-frame waypoints (x y per line, m); "
                     "default: the world's route of --name")
    sim.add_argument("--world", metavar="FILE", help="building file (default: the packaged building)")
    sim.add_argument("--particles", type=particle_count, default=100, help="number of particles (100)")
    sim.add_argument("--fastslam", type=int, choices=(1, 2), default=2, help="FastSLAM version (2)")
    sim.add_argument("--camera-rate", type=positive_float, default=5.0, metavar="HZ",
                     help="stereo frames per second (default 5 Hz)")
    sim.add_argument("--out", required=True, metavar="MAP", help="map file to write (.npz landmark map)")
    sim.add_argument("--ply", metavar="FILE", help="also export the map as a PLY point cloud")
    sim.add_argument("--json", action="store_true", help="print the scores as one JSON object")
    for old, new in (("--robot", "--name"), ("--start", "--start-pose"), ("--route", "--world-route"),
                     ("--frame-rate", "--camera-rate")):
        add_deprecated_alias(sim, old, new)
    sim.set_defaults(handler=_simulate)
    _register_dataset(sub)
    _register_noise(sub)


def _parse_pose(text: str) -> np.ndarray:
    parts = text.replace(" ", "").split(",")
    try:
        pose = np.array([float(p) for p in parts])
    except ValueError:
        raise ValueError(f"--start-pose {text!r}: expected three numbers X,Y,THETA") from None
    if pose.shape != (3,) or not np.all(np.isfinite(pose)):
        raise ValueError(f"--start-pose {text!r}: expected three finite numbers X,Y,THETA")
    return pose


def _simulate(args: argparse.Namespace) -> int:
    # imported here so that `p3at --help` does not pay for the simulator
    from mocks.world import World
    from runtime.motion import load_route
    from runtime.slam_sim import simulate

    try:
        check_output_file(args.out)
        check_output_file(args.ply, "--ply")
        inputs = {"--world": args.world, "--world-route": args.world_route}
        check_output_apart(args.out, files=inputs)
        check_output_apart(args.ply, "--ply", files={"--out": args.out, **inputs})
        world = World.load(args.world)
        if args.world_route:
            route = load_route(args.world_route)
        elif args.name in world.routes:
            route = np.asarray(world.routes[args.name], float)
        else:
            raise ValueError(f"the world has no route named {args.name!r} (it has {sorted(world.routes)}); "
                             f"give --world-route")
        if args.start_pose:
            start = _parse_pose(args.start_pose)
        elif not args.world_route and args.name in world.start_poses:
            start = np.asarray(world.start_poses[args.name], float)
        else:
            nxt = route[1] if len(route) > 1 else route[0] + [1.0, 0.0]
            start = np.array([route[0][0], route[0][1], math.atan2(nxt[1] - route[0][1], nxt[0] - route[0][0])])
        config = FastSLAMConfig(n_particles=args.particles, version=args.fastslam)
        result = simulate(world, start_pose=start, route=route, seconds=args.seconds, seed=args.seed,
                          config=config, robot=args.name, frame_rate=args.camera_rate)
        result.map.save(args.out)
        if args.ply:
            result.map.export_ply(args.ply)
    except (ValueError, OSError, EstimationError) as e:  # WorldFileError, RouteFileError, MapFileError included
        print(f"p3at slam simulate: {e}", file=sys.stderr)
        return 2
    metrics = dict(result.metrics, out=str(args.out), robot=args.name, seed=args.seed,
                   start=[float(v) for v in start], ply=None if args.ply is None else str(args.ply))
    if args.json:
        print(json_text(metrics))
    else:
        m = metrics
        print(f"slam simulate: {m['robot']}, {m['frames']} frames in {m['seconds']:.1f} s, "
              f"{m['particles']} particles, FastSLAM {m['version']}.0, seed {m['seed']}")
        print(f"  trajectory ATE        FastSLAM {m['ate_m']:.3f} m   dead reckoning {m['dead_reckoning_ate_m']:.3f} m")
        print(f"  final position error  FastSLAM {m['final_position_error_m']:.3f} m   dead reckoning "
              f"{m['dead_reckoning_final_position_error_m']:.3f} m")
        print(f"  landmarks {m['landmarks']} (of {m['distinct_features']} distinct features, "
              f"{m['duplicate_landmarks']} duplicates): RMS error {m['landmark_rms_error_m']:.3f} m, "
              f"median {m['landmark_median_error_m']:.3f} m")
        print(f"  pose NEES over {m['pose_nees_frames']} frames (3 is consistent): mean {m['pose_nees_mean']:.1f}, "
              f"median {m['pose_nees_median']:.1f}, {100 * m['pose_nees_within_chi2_95']:.0f} % below χ²₃(95 %) "
              f"against the particle cloud; median {m['pose_nees_drift_median']:.1f}, "
              f"{100 * m['pose_nees_drift_within_chi2_95']:.0f} % below against the map frame's drift")
        print(f"  map written to {m['out']}" + (f" and {m['ply']}" if m["ply"] else ""))
    return 0


# -- p3at slam dataset / p3at slam noise: recorded landmark data sets ---------------------------------------------
DATASET_FORMATS = ("mrclam",)


TRUTH_HEADING_HELP = ("the ground truth's heading: as the motion capture wrote it (mocap, default), or turned onto the "
                      "robot's direction of travel, measured from the truth's own positions (travel: on MRCLAM the "
                      "markers' frame is 0.003-0.017 rad off the wheels' axis, robot 1's wandering; "
                      "docs/fastslam.md, *The truth's heading*)")


def _register_dataset(sub) -> None:
    parser = sub.add_parser(
        "dataset", help="run FastSLAM on a recorded landmark data set and score it against its ground truth",
        description="Play one robot of a range-bearing landmark data set (MRCLAM: a folder of .dat or .dat.gz "
                    "files) through FastSLAM: its odometry and its landmark sightings (other robots' barcodes are "
                    "not landmarks), then (known-ID association) smooths the whole log from the best particle. "
                    "Writes the map in the robot's frame at its first sighting, with metadata.true_start_pose "
                    "from the ground truth (so that `p3at fuse` scores alignments), and prints "
                    "trajectory, map and consistency scores against the ground truth. A log without ground truth "
                    "(no RobotN_Groundtruth.dat) is mapped the same way and not scored: it needs --noise FILE and "
                    "--barcodes table.")
    parser.add_argument("format", choices=DATASET_FORMATS, help="data set format")
    parser.add_argument("folder", metavar="DIR", help="the data set's folder")
    parser.add_argument("--robot", type=positive_int, required=True, metavar="N", help="robot number (1-5 in MRCLAM)")
    parser.add_argument("--out", required=True, metavar="MAP", help="map file to write (.npz landmark map)")
    parser.add_argument("--rerun", default=None, metavar="SINK",
                        help="also write the run to Rerun: FILE.rrd, spawn (a live viewer) or a rerun+http:// URL; "
                             "the paths (estimated, dead reckoning, true), the map over the true landmarks, the pose "
                             "NEES over time")
    parser.add_argument("--association", choices=("id", "unknown"), default="id",
                        help="id: the barcode decides the landmark; unknown: position only, barcodes used for "
                             "scoring only (default id)")
    parser.add_argument("--noise", metavar="FILE", help="noise model (TOML, see `p3at slam noise`); default: "
                        "estimated from this robot's own log and ground truth with the range calibration, heading "
                        "bias, odometry lag and turns' variance (as `p3at slam noise --range-calibration "
                        "--heading-bias --odometry-lag --turn-variance`), and said so; a log without ground truth "
                        "needs it")
    parser.add_argument("--barcodes", choices=("verified", "inferred", "table"), default="verified",
                        help="Barcodes.dat: refuse it if the ground truth contradicts it (verified, default), "
                             "correct it from the ground truth (inferred), or trust it unchecked (table; the only "
                             "choice for a log without ground truth)")
    parser.add_argument("--truth-heading", choices=("mocap", "travel"), default="mocap", help=TRUTH_HEADING_HELP)
    parser.add_argument("--no-inflation", action="store_true",
                        help="take consecutive sightings as independent (default: the sensor variances are "
                             "multiplied by the noise model's variance inflation for correlated sightings)")
    parser.add_argument("--smooth", action=argparse.BooleanOptionalAction, default=None,
                        help="after the filter, solve for the whole log's most probable trajectory and map together "
                             "(full SLAM from the best particle): the map, trajectory and scores are then the "
                             "smoother's, the filter's beside them (docs/fastslam.md). Default: on with --association "
                             "id, off with unknown (where it is refused: the filter's own associations make it "
                             "confidently wrong); --no-smooth gives the filter alone")
    parser.add_argument("--chain", action="store_true",
                        help="with --association unknown: instead of the filter's own associations, the chain of "
                             "benchmarks/mrclam_constellation with session 30's recipe (estimation.name_chain): "
                             "names chained over 40 s windows, merged round by round where whole passes match, "
                             "screened, left out when ambiguous, and smoothed; the map holds its names (no barcodes, "
                             "no identities). Takes minutes per run (MRCLAM robot 1's whole log: 5.8 min of CPU); "
                             "--until S reads the log up to S only (and fits the noise model there)")
    parser.add_argument("--seeds", type=_seed_list, metavar="S,S,...",
                        help="with --chain: one run per seed (instead of --seed), the names most runs agree on voted "
                             "and smoothed into one map (benchmarks/mrclam_seed_vote); the map records the seeds and "
                             "each landmark's support (metadata.vote, read by `p3at fuse`). As many runs' time")
    parser.add_argument("--particles", type=particle_count, default=100, help="number of particles (100)")
    parser.add_argument("--fastslam", type=int, choices=(1, 2), default=2, help="FastSLAM version (2)")
    parser.add_argument("--seed", type=non_negative_int, default=0, help="random seed of the filter, >= 0 (0)")
    parser.add_argument("--until", type=positive_float, metavar="S", help="stop at this log time (s)")
    parser.add_argument("--json", action="store_true", help="print the scores as one JSON object")
    parser.set_defaults(handler=_dataset)


def _seed_list(text: str) -> list[int]:
    """``--seeds``: two or more distinct seeds >= 0, comma-separated."""
    seeds = [non_negative_int(part.strip()) for part in text.split(",")]
    if len(seeds) < 2 or len(set(seeds)) != len(seeds):
        raise argparse.ArgumentTypeError(f"two or more distinct seeds, comma-separated (e.g. 0,1,2), not {text!r}")
    return seeds


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


# a tape's σ: the default of --known-distance's SIGMA (m)
KNOWN_DISTANCE_SIGMA_M = 0.005


class _KnownDistance(argparse.Action):
    """``--known-distance ID1 ID2 METRES [SIGMA]`` (repeatable): appends (id1, id2, metres, sigma) after checking
    the words (each already a finite number): two different whole landmark ids, a distance > 0, a σ > 0."""

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        text = " ".join(f"{v:g}" for v in values)
        problem = None
        if len(values) not in (3, 4):
            problem = "four or three numbers"
        elif not all(v == int(v) and v >= 0 for v in values[:2]):
            problem = "whole landmark ids"
        elif values[0] == values[1]:
            problem = "two different landmarks"
        elif not values[2] > 0:
            problem = "a distance > 0"
        elif len(values) == 4 and not values[3] > 0:
            problem = "a sigma > 0"
        if problem is not None:
            raise argparse.ArgumentError(self, f"expected ID1 ID2 METRES [SIGMA] ({problem}: two different landmark "
                                               f"ids, a distance > 0 m, a sigma > 0 m), not {text!r}")
        sigma = float(values[3]) if len(values) == 4 else KNOWN_DISTANCE_SIGMA_M
        known = [*(getattr(namespace, self.dest, None) or []), (int(values[0]), int(values[1]), float(values[2]),
                                                                  sigma)]
        setattr(namespace, self.dest, known)


def _register_noise(sub) -> None:
    parser = sub.add_parser(
        "noise", help="estimate a robot's noise model (odometry and sensor) from a log with ground truth",
        description="Fit odometry noise (random walk per metre and per radian, with scale calibration) from the "
                    "residuals of odometry increments against the ground truth, and range-bearing sensor noise "
                    "from the residuals of the sightings against the true landmark positions; write it as a TOML "
                    "noise model for `p3at slam dataset --noise`. Several --robot options pool their logs. With "
                    "--self-calibrate: the robot's camera calibration from its own log WITHOUT ground truth "
                    "(odometry, and sightings associated by barcode), into the model given with --noise.")
    parser.add_argument("format", choices=DATASET_FORMATS, help="data set format")
    parser.add_argument("folder", metavar="DIR", help="the data set's folder")
    parser.add_argument("--robot", type=positive_int, action="append", required=True, metavar="N",
                        help="robot number; repeat to pool several robots")
    parser.add_argument("--out", required=True, metavar="FILE", help="noise model to write (.toml)")
    parser.add_argument("--window", type=positive_float, default=None, metavar="S",
                        help="odometry residual window (default 5 s; see docs/fastslam.md, Noise models)")
    parser.add_argument("--barcodes", choices=("verified", "inferred", "table"), default=None,
                        help="Barcodes.dat handling, as for `slam dataset` (default verified; with --self-calibrate "
                             "table, the only one that reads no ground truth)")
    parser.add_argument("--truth-heading", choices=("mocap", "travel"), default=None,
                        help=TRUTH_HEADING_HELP + "; the fit is made against it (a travel fit is recorded in the "
                        "file's [fit])")
    parser.add_argument("--calibration-per-log", action="store_true",
                        help="with several --robot: fit the range calibration (--range-calibration) and the bearing "
                             "offset to each robot's log on its own and measure the sensor's sigmas and correlations "
                             "about each one's own calibration; the model carries the logs' mean calibration. The "
                             "sigmas then transfer to a robot whose own camera is calibrated apart (--self-calibrate; "
                             "docs/fastslam-history.md, Session 37 (A))")
    parser.add_argument("--self-calibrate", action="store_true",
                        help="estimate the camera calibration of one --robot (range offset a, range scale b0, "
                             "range scale per radian b1, bearing offset) from its own odometry and sightings, "
                             "associated by barcode (fiducials), by smoothing the whole log with the calibration as "
                             "four more unknowns: its ground "
                             "truth is not read. Writes --noise's model with this calibration; refuses (exit 1) when "
                             "the log does not determine it")
    parser.add_argument("--noise", metavar="FILE",
                        help="with --self-calibrate: the noise model to start from (odometry, sensor sigmas, b2; e.g. "
                             "fitted on other robots with --calibration-per-log)")
    parser.add_argument("--known-distance", action=_KnownDistance, type=finite_float, nargs="+", default=[],
                        metavar="ID1 ID2 METRES [SIGMA]",
                        help="with --self-calibrate: a length measured outside the log (a tape between two posts), "
                             "landmarks ID1 and ID2 (barcode subjects) METRES apart with standard deviation SIGMA "
                             f"(default {KNOWN_DISTANCE_SIGMA_M} m, a tape's); a factor on the two landmarks' "
                             "positions, so the camera's scale is not the odometry's alone (docs/fastslam-history.md, "
                             "Session 37 (D)). Repeatable")
    parser.add_argument("--heading-bias", action="store_true",
                        help="also fit a heading bias per metre driven (a robot that curves on a straight run), "
                             "written as [odometry] heading_bias_per_m and applied where the scales are. Off by "
                             "default: on MRCLAM it did not lower the trajectory error "
                             "(docs/fastslam-history.md, Session 5)")
    parser.add_argument("--range-calibration", action="store_true",
                        help="also fit the range's calibration r <- a + r (b0 + b1 phi + b2 phi^2) (a camera that "
                             "reports depth along its axis, not range), written to [range_bearing]. Off by default "
                             "(docs/fastslam-history.md, Sessions 8-9)")
    parser.add_argument("--odometry-lag", action="store_true",
                        help="also fit the time by which the odometry leads the motion (commanded velocities), "
                             "written as [odometry] lag_s; `slam dataset` reads the odometry that much earlier. Off "
                             "by default (docs/fastslam-history.md, Session 9)")
    parser.add_argument("--turn-translation", action="store_true",
                        help="also fit the travel the robot does not make per radian turned (each increment's "
                             "distance d -> max(d - c |dtheta|, 0)) beside the translation scale, written as "
                             "[odometry] forward_deficit_per_rad and applied where the scales are. Off by default "
                             "(docs/fastslam-history.md, Session 16 (Q))")
    parser.add_argument("--turn-variance", action="store_true",
                        help="also fit how much a turn's forward error outlasts one increment (the turns' "
                             "overdispersion), written as [odometry] turn_xy_inflation: the x/y variance of a turn's "
                             "increments is multiplied by it. Off by default "
                             "(docs/fastslam-history.md, Session 16 (lead))")
    parser.add_argument("--heading-drift", action="store_true",
                        help="also fit a drifting heading bias per metre (a Gauss-Markov process: stationary "
                             "sigma_b rad/m, correlation time tau s) to the dead reckoning's NEES over 5-600 s, "
                             "written as [odometry] heading_drift_sigma_per_m and heading_drift_tau_s; the filter "
                             "carries one such bias per particle. Off by default (docs/fastslam.md, Noise models)")
    parser.add_argument("--time-variance", action="store_true",
                        help="also fit a heading variance per second of each increment, moving or not (a heading "
                             "that wanders with time: bumps, pushes), written as [odometry] theta_var_per_s. Off by "
                             "default: on MRCLAM the data show rare large faults, not such a variance "
                             "(docs/fastslam-history.md, Session 35 (A))")
    parser.add_argument("--json", action="store_true", help="print the model and the fit as one JSON object")
    parser.set_defaults(handler=_noise)


def _check_rerun_sink(sink: str | None) -> None:
    """Refuse a ``--rerun`` sink before the run, not after it: FILE.rrd (its folder writable), spawn or a URL."""
    if (problem := rerun_sink_problem(sink, ("spawn",))) is not None:
        raise ValueError(problem)


def _dataset(args: argparse.Namespace) -> int:
    from dataclasses import asdict

    from estimation.dataset_slam import run_landmark_log
    from estimation.datasets import read_mrclam
    from estimation.fastslam import range_bearing_config
    from estimation.noise_model import DATASET_CALIBRATIONS, NoiseModel, estimate_noise

    try:
        if (problem := _chain_problem(args)) is not None:
            raise ValueError(problem)
        check_output_file(args.out)
        _check_rerun_sink(args.rerun)
        # neither output may replace what the run reads (the noise model, a table of the data set) or the other
        recording = args.rerun if args.rerun is not None and args.rerun.endswith(".rrd") else None
        check_output_apart(args.out, files={"--noise": args.noise, "--rerun": recording},
                           folders={"data set": args.folder})
        check_output_apart(recording, "--rerun", files={"--noise": args.noise}, folders={"data set": args.folder})
        # the chain has no frame cut: it reads the log up to --until (its in-sample noise fit too)
        log = read_mrclam(args.folder, args.robot, barcodes=args.barcodes, until=args.until if args.chain else None,
                          truth_heading=args.truth_heading)
        if args.noise:
            noise, noise_source = NoiseModel.load(args.noise), str(args.noise)
        else:
            try:
                noise = estimate_noise([log], **DATASET_CALIBRATIONS).model
                if (problem := _no_sensor_fit(noise, [log])) is not None:
                    raise ValueError(problem)
            except ValueError as e:
                raise ValueError(f"fitting this log's own noise model: {e} (give one with --noise FILE)") from None
            noise_source = ("estimated from this log's own ground truth with its range calibration, heading bias, "
                            "odometry lag and turns' variance (no --noise given)")
        smooth = args.association == "id" if args.smooth is None else args.smooth
        config = range_bearing_config(n_particles=args.particles, version=args.fastslam)
        if args.chain:
            try:
                run = _chain_run(log, noise, config, args)
            except np.linalg.LinAlgError as e:
                raise ValueError(_singular_chain(noise, e)) from None
        else:
            run = run_landmark_log(log, config, np.random.default_rng(args.seed), noise=noise,
                                   association=args.association, robot=f"robot{args.robot}", until=args.until,
                                   inflate_correlated=not args.no_inflation, smooth=smooth)
        run.map.metadata["noise_model"] = asdict(noise.odometry) | (asdict(noise.range_bearing)
                                                                     if noise.range_bearing else {})
        run.map.save(args.out)
    except (ValueError, OSError, EstimationError) as e:   # DatasetError, NoiseModelError, MapFileError included
        print(f"p3at slam dataset: {e}", file=sys.stderr)
        return 2
    if args.rerun:
        from runtime.dataset_recording import record_dataset_run
        from runtime.rerun_log import ViewerError
        try:
            record_dataset_run(args.rerun, run, log, f"robot{args.robot}")
        except (OSError, ViewerError) as e:
            print(f"p3at slam dataset: the map is written to {args.out}, but the recording failed: {e}",
                  file=sys.stderr)
            return 2
    metrics = dict(run.metrics, out=str(args.out), robot=args.robot, dataset=log.name, seed=args.seed,
                   noise=noise_source, notes=list(log.notes), recording=args.rerun, warnings=_map_warnings(run.metrics),
                   stamp_resolution=[q.as_dict() for q in log.stamp_resolution])
    if args.json:
        print(json_text(metrics))
        return 0
    m = metrics
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
    return 0


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


def _no_sensor_fit(model, logs) -> str | None:
    """Why a fitted noise model has no sensor part (None when it has one): too few sightings of landmarks whose
    positions the data set knows. `slam noise` wrote such a model without a word (exit 0) and `slam dataset --noise`
    then refused it; `slam dataset` said its own fitted model 'has no [range_bearing] section'."""
    if model.range_bearing is not None:
        return None
    known = sum(int(np.isin(log.landmark_ids, log.truth_ids).sum()) for log in logs)
    return (f"too few sightings of landmarks with known positions to fit the sensor noise ({known} in the log): the "
            "model would lack its [range_bearing] part, which slam dataset needs")


MIN_WINDOW_INTERVALS = 3   # odometry intervals a residual window must span at the least


def _window_problem(window: float, logs) -> str | None:
    """Why ``--window`` is too short for these logs (None when it is not): a window must span MIN_WINDOW_INTERVALS
    of a log's odometry intervals (their median), else its windows hold one row or none and the fit is of nothing
    (session 23: ``--window 1e-300`` wrote a model, exit 0)."""
    for log in logs:
        stamps = log.odometry[:, 0]
        interval = float(np.median(np.diff(stamps))) if len(stamps) > 1 else 0.0
        if window < MIN_WINDOW_INTERVALS * interval:
            return (f"--window {window:g}: shorter than {MIN_WINDOW_INTERVALS} odometry intervals of {log.name} "
                    f"({interval:.3g} s, the median); give at least {MIN_WINDOW_INTERVALS * interval:.3g} s (default "
                    "5 s)")
        span = float(stamps[-1] - stamps[0]) if len(stamps) > 1 else 0.0
        if window > span:   # no window fits; 1e308 overflowed the window's count of intervals (exit 70)
            return f"--window {window:g}: longer than the odometry of {log.name} ({span:.3g} s); give a shorter one"
    return None


_FIT_FLAGS = ("heading_bias", "range_calibration", "odometry_lag", "turn_translation", "turn_variance",
              "heading_drift", "time_variance", "calibration_per_log")


def _self_calibration_problem(args: argparse.Namespace) -> str | None:
    """What makes ``slam noise``'s options meaningless together, in one line (None: nothing)."""
    if not args.self_calibrate:
        if args.known_distance:
            return "--known-distance is a length for --self-calibrate: it needs --self-calibrate"
        return "--noise is the model --self-calibrate starts from: it needs --self-calibrate" if args.noise else None
    if args.noise is None:
        return "--self-calibrate needs --noise FILE: the odometry and sensor sigmas it keeps"
    if len(set(args.robot)) != 1:
        return "--self-calibrate calibrates one robot's camera: give one --robot"
    given = [f"--{name.replace('_', '-')}" for name in _FIT_FLAGS if getattr(args, name)]
    if args.window is not None:
        given.append("--window")
    if given:
        return f"--self-calibrate estimates the camera alone (the rest is --noise's): {', '.join(given)} do not apply"
    if args.truth_heading is not None:
        return "--self-calibrate reads no ground truth: --truth-heading does not apply"
    if args.barcodes not in (None, "table"):
        return (f"--self-calibrate reads no ground truth, and --barcodes {args.barcodes} checks the table against it: "
                "give --barcodes table (its default)")
    return None


def _noise(args: argparse.Namespace) -> int:
    from dataclasses import asdict, replace

    from estimation.datasets import read_mrclam
    from estimation.noise_model import estimate_noise
    from estimation.odometry_consistency import CHI2_3_95, CHI2_3_MEDIAN, fit_keys, odometry_consistency

    if (problem := _self_calibration_problem(args)) is not None:
        print(f"p3at slam noise: {problem}", file=sys.stderr)
        return 2
    if args.self_calibrate:
        return _self_calibrate(args)
    args.window = 5.0 if args.window is None else args.window
    try:
        check_output_file(args.out)
        check_output_apart(args.out, folders={"data set": args.folder})   # its tables stay as they are
        logs = [read_mrclam(args.folder, robot, barcodes=args.barcodes or "verified",
                            truth_heading=args.truth_heading or "mocap") for robot in dict.fromkeys(args.robot)]
        short = _window_problem(args.window, logs)
        if short is not None:
            raise ValueError(short)
        estimate = estimate_noise(logs, window_s=args.window, heading_bias=args.heading_bias,
                                  range_calibration=args.range_calibration, odometry_lag=args.odometry_lag,
                                  turn_translation=args.turn_translation, turn_variance=args.turn_variance,
                                  heading_drift=args.heading_drift, time_variance=args.time_variance,
                                  calibration_per_log=args.calibration_per_log,
                                  platform="iRobot Create (MRCLAM; odometry = commanded velocities)")
        if (problem := _no_sensor_fit(estimate.model, logs)) is not None:
            raise ValueError(problem)
        # does the fitted random walk hold beyond its window? dead reckoning's NEES per horizon, into [fit] too
        consistency = odometry_consistency([(log.odometry, log.ground_truth) for log in logs], estimate.model)
        aligned = {"truth_heading": "travel"} if args.truth_heading == "travel" else {}
        model = replace(estimate.model, fit={**estimate.model.fit, **fit_keys(consistency), **aligned})
        model.save(args.out)
    except (ValueError, OSError, EstimationError) as e:
        print(f"p3at slam noise: {e}", file=sys.stderr)
        return 2
    windows = [dict(window_s=w, xy_sigma_per_sqrt_m=a, theta_sigma_per_sqrt_rad=b, theta_sigma_per_sqrt_m=c)
               for w, a, b, c in estimate.odometry_by_window.tolist()]
    if args.json:
        print(json_text({"out": str(args.out), "robot": model.robot, "odometry": asdict(model.odometry),
                         "range_bearing": asdict(model.range_bearing) if model.range_bearing else None,
                         "fit": model.fit, "odometry_by_window": windows,
                         "odometry_consistency": [row.as_dict() for row in consistency]}))
        return 0
    o, rb = model.odometry, model.range_bearing
    print(f"slam noise: {model.robot}")
    print(f"  odometry: σ_xy {math.sqrt(o.xy_var_per_m):.4f} m/√m, σ_θ {math.sqrt(o.theta_var_per_rad):.4f} rad/√rad "
          f"+ {math.sqrt(o.theta_var_per_m):.4f} rad/√m (windows of {args.window:g} s); scales: translation "
          f"{o.translation_scale:.4f}, rotation {o.rotation_scale:.4f}")
    if args.heading_bias:
        se = model.fit.get("heading_bias_per_m_standard_error")
        print(f"  heading bias: {o.heading_bias_per_m:+.4f} rad/m ± {se:.4f} (standard error)" if se is not None
              else f"  heading bias: none ({model.fit.get('heading_bias_note', 'not fitted')})")
    if args.odometry_lag:
        print(f"  odometry lag: {o.lag_s:.2f} s (heading error per 0.25 s: "
              f"{model.fit.get('odometry_no_lag_heading_rms_rad', float('nan')):.4f} rad read as stamped, "
              f"{model.fit.get('odometry_lag_heading_rms_rad', float('nan')):.4f} rad read {o.lag_s:.2f} s earlier)"
              if "odometry_lag_note" not in model.fit else f"  odometry lag: none ({model.fit['odometry_lag_note']})")
    if args.turn_translation:
        se = model.fit.get("forward_deficit_per_rad_standard_error", float("nan"))
        print(f"  forward deficit: {o.forward_deficit_per_rad:.4f} m/rad ± {se:.4f} (standard error; {args.window:g} s "
              "windows' "
              f"displacement error {model.fit.get('forward_deficit_none_displacement_rms_m', float('nan')):.4f} m "
              f"RMS with one translation scale, {model.fit.get('forward_deficit_displacement_rms_m', float('nan')):.4f}"
              f" m with the deficit)" if "forward_deficit_note" not in model.fit
              else f"  forward deficit: none ({model.fit['forward_deficit_note']})")
    if args.turn_variance:
        print(f"  x/y variance in turns: × {o.turn_xy_inflation:.2f} (over "
              f"{model.fit.get('turn_xy_inflation_turns', 0)} turns)" if "turn_xy_inflation_note" not in model.fit
              else f"  x/y variance in turns: × 1 ({model.fit['turn_xy_inflation_note']})")
    if args.heading_drift:
        print(f"  drifting heading bias: σ_b {o.heading_drift_sigma_per_m:.2f} rad/m, τ {o.heading_drift_tau_s:g} s "
              f"(cost {model.fit['heading_drift_cost']:.1f} against {model.fit['heading_drift_cost_without']:.1f} "
              f"without)" if o.heading_drift_sigma_per_m > 0 else "  drifting heading bias: none (no drift made the "
              "dead reckoning more consistent)")
    if args.time_variance:
        print(f"  heading variance per second: {o.theta_var_per_s:.3g} rad²/s (σ_θ {math.sqrt(o.theta_var_per_s):.4f} "
              "rad/√s, moving or not)")
    for row in windows:
        print(f"    at {row['window_s']:>4g} s windows: σ_xy {row['xy_sigma_per_sqrt_m']:.4f} m/√m, σ_θ "
              f"{row['theta_sigma_per_sqrt_rad']:.4f} rad/√rad + {row['theta_sigma_per_sqrt_m']:.4f} rad/√m")
    if consistency:
        print(f"  dead reckoning under this model over longer paths (NEES of the end pose; consistent: median "
              f"{CHI2_3_MEDIAN:.2f}, 95 % below {CHI2_3_95:.2f}):")
    for row in consistency:
        print(f"    {row.horizon_s:>4g} s: median {row.nees_median:5.2f}, {100 * row.within_chi2_95:5.1f} % within "
              f"({row.windows} windows, {row.independent} without overlap): {row.verdict}")
    if rb:
        print(f"  sensor: σ_r = {rb.range_sigma_m:.4f} m + {rb.range_sigma_per_m:.4f}·r, "
              f"σ_φ {rb.bearing_sigma_rad:.4f} rad, bearing offset {rb.bearing_offset_rad:+.4f} rad; "
              f"{100 * model.fit.get('sensor_outlier_fraction', 0.0):.1f} % outliers set aside")
    print(f"  written to {args.out}")
    return 0


def _known_text(known, calibration=None) -> str:
    """The known distances in words ('' if none): ', with ... taped' for the source, the map's fit with one."""
    if not known:
        return ""
    if calibration is None:
        return ", with " + ", ".join(f"{k.first}-{k.second} {k.metres:g} ± {k.sigma_m:g} m" for k in known) + " taped"
    return "".join(f" {k.first}-{k.second} {k.metres:g} ± {k.sigma_m:g} m (the map's {d:.4f} m)"
                   for k, d in zip(known, calibration.fitted_distances_m, strict=True))


def _self_calibrate(args: argparse.Namespace) -> int:
    """``slam noise --self-calibrate``: the camera's calibration without ground truth
    (estimation.camera_calibration)."""
    from estimation.camera_calibration import ESTIMATED, KnownDistance, self_calibrate
    from estimation.datasets import read_mrclam
    from estimation.noise_model import NoiseModel

    try:
        check_output_file(args.out)
        check_output_apart(args.out, files={"--noise": args.noise}, folders={"data set": args.folder})
        noise = NoiseModel.load(args.noise)
        if noise.range_bearing is None:
            raise ValueError(f"{args.noise}: the noise model has no [range_bearing] section to calibrate")
        log = read_mrclam(args.folder, args.robot[0], barcodes="table")
        known = tuple(KnownDistance(*k) for k in args.known_distance)
        calibration = self_calibrate(log, noise, known_distances=known)
        model = None
        if calibration.problem is None:
            model = calibration.applied(
                noise, robot=log.name,
                source=f"camera calibration (range offset, scale, scale per radian, bearing offset) self-calibrated by "
                       f"p3at slam "
                       f"noise --self-calibrate from {log.name}'s odometry and sightings associated by barcode, "
                       f"without its ground truth{_known_text(known)}; the rest from the model given "
                       f"({noise.robot}: {noise.source})")
            model.save(args.out)
    except (ValueError, OSError, EstimationError) as e:
        print(f"p3at slam noise: {e}", file=sys.stderr)
        return 2
    given = {k: float(getattr(noise.range_bearing, k)) for k in ESTIMATED}
    if args.json:
        print(json_text({"out": str(args.out) if model is not None else None, "robot": log.name,
                         "association": "barcode", "ground_truth_read": False, "noise": str(args.noise),
                         "calibration": calibration.as_dict(), "given": given,
                         "odometry_translation_scale": noise.odometry.translation_scale}))
    else:
        c, se = calibration, calibration.standard_errors
        print(f"slam noise --self-calibrate: {log.name} (sightings associated by barcode; the ground truth is not "
              f"read)")
        print(f"  camera: range r' = a + r (b0 + b1 phi + b2 phi^2): a {c.range_offset_m:+.4f} ± {se[0]:.4f} m, b0 "
              f"{c.range_scale:.4f} ± {se[1]:.4f}, b1 {c.range_scale_per_rad:+.4f} ± {se[2]:.4f} /rad; bearing offset "
              f"{c.bearing_offset_rad:+.4f} ± {se[4]:.4f} rad (standard errors; given: a "
              f"{given['range_offset_m']:+.4f}, b0 {given['range_scale']:.4f}, b1 "
              f"{given['range_scale_per_rad']:+.4f}, offset "
              f"{given['bearing_offset_rad']:+.4f}; b2 {c.range_scale_per_rad2:.4f} and the sigmas kept from "
              f"{args.noise})")
        print(f"  fit: {c.sightings} sightings ({c.outliers} set aside as outliers), {c.landmarks} landmarks, "
              f"{c.frames} frames, chi2/dof {c.chi2_per_dof:.2f}, {c.iterations} iterations; the calibrated range's "
              f"own sigma {c.range_sd_rms_m:.4f} m RMS against one sighting's {c.range_sigma_rms_m:.4f} m")
        if known:
            print(f"  known distances (taped, a factor on the two landmarks):{_known_text(known, calibration)}")
        else:
            print(f"  b0 is relative to the odometry's scale (translation scale "
                  f"{noise.odometry.translation_scale:.4f} from {args.noise}): an odometry scale wrong by 1 % moves b0 "
                  "by 1 %, and the standard errors leave it out")
        print(f"  written to {args.out}" if model is not None
              else f"  not determined: {calibration.problem}; nothing written")
    if model is None:
        if not args.json:
            print(f"p3at slam noise: the camera's calibration is not determined on {log.name}: {calibration.problem}",
                  file=sys.stderr)
        return 1
    return 0
