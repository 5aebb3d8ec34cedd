"""``p3at demo``: the two-robot mission on the virtual hardware (what ``make demo`` runs)."""
from __future__ import annotations

import sys

from runtime.commands.options import RERUN_KEYWORDS, check_output_folder, rerun_sink_problem, time_scale_problem
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
                             "--camera synthetic unless given; its own loopback port and fleet name, so not with "
                             "--exchange or --fleet (docs/fleet.md)")
    # None: not given (--processes refuses them given, _processes_problem); the in-process demo's defaults in _demo
    parser.set_defaults(handler=_demo, camera=None, exchange=None, fleet=None)


def _processes_problem(args) -> str | None:
    """Why --processes cannot run as asked (None when it can): --exchange or --fleet given. Its robots and fusion
    node meet on a loopback port and a fleet name made for the run (runtime/fleet/processes.py), so that two demos
    never hear each other or the lab's fleet; honouring a user's exchange would need two Zenoh configurations (the
    node's listen side, the robots' connect side, with their own certificates), which one --exchange cannot give."""
    given = [option for option, value in (("--exchange", args.exchange), ("--fleet", args.fleet)) if value is not None]
    if not given:
        return None
    return (f"{' and '.join(given)} {'does' if len(given) == 1 else 'do'} not apply to --processes: its robots and "
            "fusion node meet on a loopback port and a fleet name of their own; for a fleet on your exchange, run "
            "p3at run --exchange SPEC --fleet NAME for each robot and p3at fuse --live (docs/fleet.md)")


def mission_inputs_problem(args) -> str | None:
    """Why the mission's own files cannot serve (None when they can), said before any robot starts: the output
    folder (with --log-sensors: no earlier run's log in it: the second run failed after it had replaced the first
    one's mission.rrd with an empty recording), the building (--world; on virtual robots also the number of robots
    it has start poses for), the route (--route, when the robots follow one) and the --rerun sink (a URL Rerun
    refuses, a word that is neither a keyword nor FILE.rrd, a .rrd no file can be written at)."""
    from mocks.world import World, robot_name_problem
    from runtime.motion import load_route

    virtual = getattr(args, "robot", "mock") == "mock"   # `p3at run` has --robot; `p3at demo` drives mocks only
    # the mission (or the fusion node of --processes) opens it only once started
    sink = rerun_sink_problem(args.rerun, RERUN_KEYWORDS)
    if sink is not None:
        return sink
    if args.realtime and (problem := time_scale_problem(args.time_scale)) is not None:
        return problem
    if virtual and args.motion == "route":
        # the virtual P3-AT's top speed: faster, every command was clamped with a warning on stderr (--speed 100:
        # a hundred lines in 3 s)
        from drivers.arcos.params import builtin_params

        top = builtin_params("p3at-sh").max_velocity_m_s
        if args.speed > top:
            return f"--speed {args.speed:g}: faster than the virtual P3-AT's top speed, {top:g} m/s"
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
    name = getattr(args, "name", None)   # `p3at run --name`: on the virtual robot, which of the world's robots
    if name is not None and (problem := robot_name_problem(name)) is not None:   # run --name ../x: OUT/../x.npz
        return f"--name {name!r}: {problem}"
    if world is not None and virtual and name is not None and name not in world.start_poses:
        return (f"--name {name}: the world '{world.name}' has no robot {name!r} (it has "
                f"{', '.join(sorted(world.start_poses))})")
    if world is not None and virtual and len(world.start_poses) < args.robots:
        return (f"--robots {args.robots}: the world '{world.name}' has {len(world.start_poses)} start poses "
                f"({', '.join(sorted(world.start_poses))})")
    if str(getattr(args, "exchange", "")).partition(":")[0] == "zenoh":
        # a robot's name is its Zenoh key chunk: one the map encoder refuses ended the mission after its start
        # ("mission failed: robot name 'robot 1' must be ...", exit 1)
        from runtime.fleet.mapwire import ROBOT_NAME

        if virtual and world is not None:
            names = [name] if name is not None else sorted(world.start_poses)[: args.robots]
        else:
            names = [name or "robot1"]
        bad = next((n for n in names if not ROBOT_NAME.fullmatch(n)), None)
        if bad is not None:
            where = f"--name {bad!r}" if bad == name else f"robot {bad!r} of the world '{world.name}'"
            return f"{where}: on a Zenoh exchange a robot's name is its key chunk, 1-64 of A-Z a-z 0-9 _ -"
    return None


def _demo(args) -> int:
    problem = (_processes_problem(args) if args.processes else None) or mission_inputs_problem(args)
    if problem is not None:
        print(f"p3at demo: {problem}", file=sys.stderr)
        return 2
    if args.processes:
        from runtime.fleet.processes import run_processes_demo

        args.camera = args.camera or "synthetic"  # rendering every head in its own process costs far more CPU
        return run_processes_demo(args)
    from runtime.fleet.options import DEFAULT_FLEET

    args.camera = args.camera or "mock"
    args.exchange, args.fleet = args.exchange or "inprocess", args.fleet or DEFAULT_FLEET
    return run_mission_command(args)
