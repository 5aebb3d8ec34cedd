"""``p3at slam simulate``: one virtual robot maps the simulated building (the parser is in :mod:`.slam`)."""
from __future__ import annotations

import argparse
import math
import sys

import numpy as np

from estimation.errors import EstimationError
from estimation.fastslam import FastSLAMConfig
from runtime.commands.options import check_output_apart, check_output_file
from runtime.json_output import json_text


def _parse_pose(text: str) -> np.ndarray:
    parts = text.replace(" ", "").split(",")
    try:
        pose = np.array([float(p) for p in parts])
    except ValueError:
        raise ValueError(f"--start-pose {text!r}: expected three numbers X,Y,THETA") from None
    if pose.shape != (3,) or not np.all(np.isfinite(pose)):
        raise ValueError(f"--start-pose {text!r}: expected three finite numbers X,Y,THETA")
    return pose


def _check_inside(world, start: np.ndarray, route: np.ndarray, start_option: str | None,
                  route_option: str | None) -> None:
    """ValueError (one line) when the start pose or a route waypoint lies outside the building's bounds: the
    simulated robot does not collide, so it would drive where no wall or feature is and map nothing (session 48:
    --start-pose 100,100,0 ran and printed nan figures)."""
    x0, y0, x1, y1 = world.bounds
    where = f"outside the world {world.name!r} (x {x0:g} to {x1:g} m, y {y0:g} to {y1:g} m)"
    if not (x0 <= start[0] <= x1 and y0 <= start[1] <= y1):
        origin = start_option or "the start pose"
        raise ValueError(f"{origin}: ({start[0]:g}, {start[1]:g}) is {where}")
    outside = [k for k, (x, y) in enumerate(route[:, :2]) if not (x0 <= x <= x1 and y0 <= y <= y1)]
    if outside:
        k = outside[0]
        raise ValueError(f"{route_option or 'the route'}: waypoint {k + 1} ({route[k, 0]:g}, {route[k, 1]:g}) is "
                         f"{where}" + (f", and {len(outside) - 1} more" if len(outside) > 1 else ""))


def run_simulate(args: argparse.Namespace) -> int:
    # imported here so that `p3at --help` does not pay for the simulator
    from mocks.world import World
    from runtime.commands.file_kinds import out_problem
    from runtime.motion import load_route
    from runtime.slam_sim import simulate

    try:
        check_output_file(args.out)
        check_output_file(args.ply, "--ply")
        inputs = {"--world": args.world, "--world-route": args.world_route}
        check_output_apart(args.out, files=inputs)
        check_output_apart(args.ply, "--ply", files={"--out": args.out, **inputs})
        if (problem := out_problem(args.out, "map")) is not None:   # after: '--out X is the --world file' says more
            raise ValueError(problem)
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
        _check_inside(world, start, route, "--start-pose" if args.start_pose else None,
                      "--world-route" if args.world_route else None)
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
