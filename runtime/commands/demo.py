"""``p3at demo``: the two-robot mission on the virtual hardware (what ``make demo`` runs)."""
from __future__ import annotations

import sys

from runtime.commands.options import check_output_folder
from runtime.mission_cli import add_mission_arguments, run_mission_command


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "demo", help="two virtual P3-ATs map the simulated building; their maps are fused and scored",
        description="Start virtual P3-ATs (wire-level ARCOS mocks driven by the real driver) with virtual stereo "
                    "heads at the building's start poses, unknown to each other; each runs the onboard pipeline "
                    "(front end, FastSLAM) while following its route; maps are exchanged, fused at intervals and "
                    "at the end, and the alignment is scored against the truth. Prints a summary table and "
                    "writes a Rerun recording. Runs in simulated time (lockstep): the same seed gives the same "
                    "maps and figures on any machine, however busy; --realtime runs on the wall clock.")
    add_mission_arguments(parser, robots=2, seconds=200.0, out="out/demo", camera="mock", camera_rate=3.75)
    parser.add_argument("--processes", action="store_true",
                        help="each robot (virtual P3-AT, head and runtime) its own process, maps over Zenoh on "
                             "loopback, the fusion node in this one; each robot keeps its own simulated time; "
                             "--camera synthetic unless given (docs/fleet.md)")
    parser.set_defaults(handler=_demo, camera=None)


def mission_inputs_problem(args) -> str | None:
    """Why the mission's own files cannot serve (None when they can), said before any robot starts: the output
    folder (with --log-sensors: no earlier run's log in it: the second run failed after it had replaced the first
    one's mission.rrd with an empty recording), the building (--world; on virtual robots also the number of robots
    it has start poses for) and the route (--route, when the robots follow one)."""
    from mocks.world import World
    from runtime.motion import load_route

    virtual = getattr(args, "robot", "mock") == "mock"   # `p3at run` has --robot; `p3at demo` drives mocks only
    try:
        check_output_folder(args.out)
        world = World.load(args.world) if args.world is not None or virtual else None
        if args.route is not None and args.motion == "route":
            load_route(args.route)
    except (ValueError, OSError) as e:   # OutputPathError, WorldFileError, RouteFileError
        return str(e)
    if args.log_sensors:   # the log writer refuses a folder that holds a log, once the mission is under way
        from pathlib import Path

        held = sorted(str(p) for p in Path(args.out).glob("*-log") if p.is_dir() and any(p.glob("*.mcap*")))
        if held:
            return (f"--out {args.out}: {held[0]} already holds a sensor log of an earlier run; give another --out "
                    "(or move it)")
    if world is not None and virtual and len(world.start_poses) < args.robots:
        return (f"--robots {args.robots}: the world '{world.name}' has {len(world.start_poses)} start poses "
                f"({', '.join(sorted(world.start_poses))})")
    return None


def _demo(args) -> int:
    problem = mission_inputs_problem(args)
    if problem is not None:
        print(f"p3at demo: {problem}", file=sys.stderr)
        return 2
    if args.processes:
        from runtime.fleet.processes import run_processes_demo

        args.camera = args.camera or "synthetic"  # rendering every head in its own process costs far more CPU
        return run_processes_demo(args)
    args.camera = args.camera or "mock"
    return run_mission_command(args)
