"""``p3at demo``: the two-robot mission on the virtual hardware (what ``make demo`` runs)."""
from __future__ import annotations

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


def _demo(args) -> int:
    if args.processes:
        from runtime.fleet.processes import run_processes_demo

        args.camera = args.camera or "synthetic"  # rendering every head in its own process costs far more CPU
        return run_processes_demo(args)
    args.camera = args.camera or "mock"
    return run_mission_command(args)
