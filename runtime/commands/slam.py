"""``p3at slam``: onboard FastSLAM. ``slam simulate`` builds a map on a simulated run and scores it."""
from __future__ import annotations

import argparse
import json
import math
import sys

import numpy as np

from estimation.errors import EstimationError
from estimation.fastslam import FastSLAMConfig
from runtime.commands.options import add_deprecated_alias, positive_float


def register(subparsers) -> None:
    parser = subparsers.add_parser("slam", help="onboard FastSLAM over 3-D visual landmarks",
                                   description="Onboard FastSLAM over 3-D visual landmarks.")
    sub = parser.add_subparsers(dest="slam_command", metavar="SUBCOMMAND", required=True)
    sim = sub.add_parser(
        "simulate", help="drive a virtual robot through the simulated building and build its map",
        description="One virtual robot follows a route of the simulated building (pure pursuit, simulated "
                    "time), observes with the synthetic stereo sensor, runs FastSLAM on its odometry and "
                    "observations, saves the most probable particle's map (in the robot's start frame, with "
                    "metadata.true_start_pose) and prints trajectory and landmark errors against the truth "
                    "beside dead reckoning.")
    sim.add_argument("--seconds", type=float, default=300.0, help="simulated time limit (default 300 s; the "
                     "run also ends when the route is done)")
    sim.add_argument("--seed", type=int, default=0, help="random seed (sensor, odometry and filter)")
    sim.add_argument("--name", default="robot1", help="the world's robot whose start pose and route to use "
                     "(default robot1)")
    sim.add_argument("--start-pose", metavar="X,Y,THETA", help="start pose in the world (m, m, rad); default: the "
                     "world's start pose of --name, or the route's first waypoint facing the second")
    sim.add_argument("--world-route", metavar="FILE", help="route file of WORLD-frame waypoints (x y per line, m); "
                     "default: the world's route of --name")
    sim.add_argument("--world", metavar="FILE", help="building file (default: the packaged building)")
    sim.add_argument("--particles", type=int, default=100, help="number of particles (100)")
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
        if args.particles < 1:
            raise ValueError(f"--particles must be at least 1, not {args.particles}")
        if not (args.seconds > 0 and args.camera_rate > 0):
            raise ValueError("--seconds must be positive")
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
                   start=[float(v) for v in start])
    if args.json:
        print(json.dumps(metrics))
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
              f"median {m['pose_nees_median']:.1f}, {100 * m['pose_nees_within_chi2_95']:.0f} % below χ²₃(95 %)")
        print(f"  map written to {m['out']}")
    return 0
