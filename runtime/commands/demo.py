"""``p3at demo``: the two-robot mission on the virtual hardware (what ``make demo`` runs)."""
from __future__ import annotations

import sys

from runtime.mission_cli import add_mission_arguments, mission_inputs_problem, run_mission_command


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
