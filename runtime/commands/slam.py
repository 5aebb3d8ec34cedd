"""``p3at slam``: FastSLAM. ``simulate`` builds a map on a simulated run, ``dataset`` on a recorded landmark data set
(MRCLAM), ``noise`` fits a noise model from a log with ground truth; each scores against the truth where there is
some (``dataset`` maps a log without it unscored). This module holds the parsers; each subcommand's work is in its
own module (``slam_simulate``, ``slam_dataset``, ``slam_noise``), imported only when it runs."""
from __future__ import annotations

import argparse

from runtime.commands.options import (
    add_deprecated_alias,
    finite_float,
    non_negative_int,
    particle_count,
    positive_float,
    positive_int,
)


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


def _simulate(args: argparse.Namespace) -> int:
    from runtime.commands.slam_simulate import run_simulate
    return run_simulate(args)


def _dataset(args: argparse.Namespace) -> int:
    from runtime.commands.slam_dataset import run_dataset
    return run_dataset(args)


def _noise(args: argparse.Namespace) -> int:
    from runtime.commands.slam_noise import run_noise
    return run_noise(args)


# -- p3at slam dataset / p3at slam noise: recorded landmark data sets ---------------------------------------------
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
                        "bias, odometry lag, turns' variance and the stall after the command's dips (as `p3at slam "
                        "noise --range-calibration --heading-bias --odometry-lag --turn-variance --command-stall`), "
                        "and said so; a log without ground truth needs it")
    parser.add_argument("--barcodes", choices=("verified", "inferred", "table"), default="verified",
                        help="Barcodes.dat: refuse it if the ground truth contradicts it (verified, default), "
                             "correct it from the ground truth (inferred), or trust it unchecked (table; the only "
                             "choice for a log without ground truth)")
    parser.add_argument("--truth-heading", choices=("mocap", "travel"), default="mocap",
                        help=TRUTH_HEADING_HELP + "; score against the truth the noise model's camera was referenced "
                        "to: travel for a model from --self-calibrate or fitted with --truth-heading travel, mocap "
                        "for one fitted against the motion capture as written")
    parser.add_argument("--no-inflation", action="store_true",
                        help="take consecutive sightings as independent (default: the sensor variances are "
                             "multiplied by the noise model's variance inflation for correlated sightings)")
    parser.add_argument("--smooth", action=argparse.BooleanOptionalAction, default=None,
                        help="after the filter, solve for the whole log's most probable trajectory and map together "
                             "(full SLAM from the best particle): the map, trajectory and scores are then the "
                             "smoother's, the filter's beside them (docs/fastslam.md). Default: on with --association "
                             "id, off with unknown (where it is refused: the filter's own associations make it "
                             "confidently wrong); --no-smooth gives the filter alone")
    parser.add_argument("--frame", choices=("first-sighting", "checked"), default="first-sighting",
                        help="the smoothed map's frame: the robot's pose at its first sighting (first-sighting, "
                             "default), or the first pose whose frame no single sighting can move unseen (checked: "
                             "no sighting's least detectable error moves a frame coordinate by more than δ₀ = 4.13 "
                             "of its σ, the test behind the frame-reliability warning); the map, its true_start_pose "
                             "and every score are then in that pose's frame, map_frame_* in --json say which "
                             "(estimation.map_frame). Needs the smoother (--association id)")
    parser.add_argument("--image-timing", action="store_true",
                        help="the smoother holds one bearing error shared by all the sightings of one image, of σ "
                             "|ω|·σ_t: ω the odometry's turn rate at the image's stamp, σ_t = P/√12 the timing "
                             "uncertainty of a stamp one period P apart from the next (the log's median, 0.24 s on "
                             "MRCLAM: 0.069 s), as the image's bearings' joint covariance (estimation.image_timing). "
                             "Off by default; needs the smoother (--association id)")
    parser.add_argument("--drop-repeats", choices=("readings", "images"),
                        help="readings: drop the readings that repeat their landmark's previous reading word for "
                             "word (range and bearing equal: the camera's held reading, one measurement reported again "
                             "under a later stamp), keeping its first report at its own stamp; images: also the other "
                             "readings of each image holding one (stamped as late as the held reading). Before the "
                             "noise fit and the filter (estimation.datasets.repeats); --json says how many "
                             "(repeated_readings_dropped, repeated_image_mates_dropped). Off by default")
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
                             "positions, so the camera's scale is not the odometry's alone; the odometry's "
                             "translation scale is then estimated too, recorded in [fit] (docs/fastslam-history.md, "
                             "Session 37 (D), Session 39 (B)). Repeatable")
    parser.add_argument("--estimate-sigmas", action="store_true",
                        help="with --self-calibrate: estimate the sensor's noise too, the range sigma (one factor on "
                             "its a + b r) and the bearing sigma, from the log's own residuals (variance components, "
                             "the correlations kept from --noise); written to [range_bearing], their figures to "
                             "[fit]. Without it the sigmas are --noise's")
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
    parser.add_argument("--command-stall", action="store_true",
                        help="also fit the random stall after a one-sample dip of the commanded velocity (the robot "
                             "stops a while, its odometry goes on), written as [odometry] stall_sigma_s: the "
                             "increment holding a dip gets (w sigma)^2 on its heading, (v sigma)^2 on x and y; `p3at "
                             "slam dataset` fits it when no --noise is given (docs/fastslam-history.md, Session 41 "
                             "(A))")
    parser.add_argument("--json", action="store_true", help="print the model and the fit as one JSON object")
    parser.set_defaults(handler=_noise)
