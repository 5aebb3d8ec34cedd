"""What ``p3at demo`` and ``p3at run`` share: the mission's arguments, their checks, the progress display, the summary.

Importing this module imports neither the mission nor the estimation stack (``p3at demo --help`` and ``p3at run
--help`` load this and their own command's module; tests/test_cli_consistency.py): the mission is imported when one
runs."""
from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

from runtime.commands.options import (
    RERUN_KEYWORDS,
    check_output_folder,
    float_where,
    non_negative_float,
    non_negative_int,
    particle_count,
    positive_float,
    positive_int,
    recording_id,
    rerun_sink_problem,
    start_sigmas,
    time_scale_problem,
)
from runtime.fleet.options import add_exchange_arguments, open_exchange
from runtime.json_output import json_text
from runtime.limits import CAMERAS, MOTIONS


def camera_latency(text: str) -> float:
    """Seconds in [0, 1): the bound MissionConfig also checks, here so that ``demo --processes`` refuses it
    before starting any process."""
    return float_where(text, "a number in [0, 1) s", lambda value: 0.0 <= value < 1.0)


def add_mission_arguments(parser: argparse.ArgumentParser, *, robots: int, seconds: float, out: str,
                          camera: str | None, camera_rate: float, camera_default: str | None = None) -> None:
    parser.add_argument("--robots", type=positive_int, default=robots, help=f"number of robots (default {robots})")
    parser.add_argument("--seconds", type=positive_float, default=seconds,
                        help=f"mission length at most, s (default {seconds:g}; ends earlier when the routes are done)")
    parser.add_argument("--seed", type=non_negative_int, default=0,
                        help="seed of every random generator, a whole number >= 0 (default 0)")
    parser.add_argument("--out", type=Path, default=Path(out), help=f"output folder (default {out})")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    parser.add_argument("--camera", choices=CAMERAS, default=camera,
                        help=f"mock: rendered frames through the Videre driver; synthetic: simulated observations "
                             f"(fast); usb: a real head (default {camera_default or camera})")
    parser.add_argument("--camera-rate", type=positive_float, default=camera_rate, metavar="HZ",
                        help=f"stereo frames per second, Hz (default {camera_rate:g})")
    parser.add_argument("--camera-latency", type=camera_latency, default=None, metavar="S",
                        help="s from a stereo pair's exposure to its arrival, in [0, 1), subtracted from frame "
                             "timestamps (default: the virtual head's 0.06; 0 for a real head -- measure yours)")
    parser.add_argument("--particles", type=particle_count, default=100, help="FastSLAM particles (default 100)")
    parser.add_argument("--max-corners", type=positive_int, default=150,
                        help="Harris corners per image (default 150; fewer observations, faster FastSLAM)")
    parser.add_argument("--max-observations", type=non_negative_int, default=0,
                        help="FastSLAM's cap on observations per frame, most precise first (default 0: all)")
    parser.add_argument("--motion", choices=MOTIONS, default="route",
                        help="route: follow a route (default); explore: sonar wall following; none: another drives")
    parser.add_argument("--route", type=Path, default=None,
                        help="route file (x y per line, in the robot's odometry frame) instead of the world's routes")
    parser.add_argument("--speed", type=positive_float, default=0.35, help="m/s along routes (default 0.35)")
    parser.add_argument("--fusion-interval", type=non_negative_float, default=20.0,
                        help="s between map fusions during the mission (0: at the end only; default 20)")
    parser.add_argument("--preset", choices=("robust", "paper"), default="robust",
                        help="alignment preset (default robust; paper: the paper's parameters)")
    parser.add_argument("--method", type=int, choices=(1, 2), default=1,
                        help="common landmarks for merging: 1 RANSAC supports (default), 2 nearest in position")
    parser.add_argument("--rerun", default="file", metavar="SINK",
                        help="file (OUT/mission.rrd, default), spawn (a live viewer), none, FILE.rrd or a "
                             "rerun+http:// URL")
    parser.add_argument("--log-sensors", action="store_true", help="log raw SIPs and frames to OUT/<robot>-log/")
    parser.add_argument("--world", type=Path, default=None, help="building file for the virtual robots")
    parser.add_argument("--realtime", action="store_true",
                        help="virtual robots on the wall clock (hardware-in-the-loop timing: does this machine keep "
                             "up?) instead of simulated time; frames the virtual heads cannot deliver on time are "
                             "dropped and counted")
    parser.add_argument("--time-scale", type=positive_float, default=1.0,
                        help="with --realtime: simulated seconds per wall-clock second (default 1)")
    parser.add_argument("--map-save-interval", type=non_negative_float, default=10.0, metavar="S",
                        help="write every robot's map to OUT/<robot>.npz every S s of mission time, atomically, so "
                             "a killed mission leaves its maps (0: at the end only; default 10)")
    # realistic by default: a robot's wheel odometry drifts, and showing FastSLAM correcting it is the point
    parser.add_argument("--odometry", choices=("exact", "realistic"), default="realistic",
                        help="virtual robots' wheel odometry errors (default realistic: 1 %% scale, 3 %% track, "
                             "noise; exact: no error)")
    parser.add_argument("--recording-id", type=recording_id, default=None, metavar="ID",
                        help="Rerun recording id shared with other processes of a fleet, so that their recordings "
                             "open as one (default: a new id)")
    parser.add_argument("--start-prior", type=start_sigmas, default=None, metavar="SIGMA_XY,SIGMA_YAW",
                        help="give the fusion the virtual robots' configured start poses as a rough prior on their "
                             "relative start, each known to within these standard deviations (m, rad; e.g. 1,0.3); "
                             "a best alignment that contradicts it is reported not found (default: off, the robots "
                             "are unknown to each other)")
    parser.add_argument("--smooth", action=argparse.BooleanOptionalAction, default=True,
                        help="at the mission's end, smooth each robot's map over the readings of its keyframes (full "
                             "SLAM after the filter) and fuse the smoothed maps: OUT/<robot>.npz holds the smoothed "
                             "map, OUT/<robot>-filter.npz the filter's; a robot past 1000 keyframes or 100000 "
                             "readings keeps the filter's map (default: on since session 51; --no-smooth: the "
                             "filter's maps, nothing kept)")
    parser.add_argument("--quiet", action="store_true", help="no progress display")
    add_exchange_arguments(parser)


def config_from_args(args: argparse.Namespace, robot_url: str = "mock"):
    """The :class:`runtime.mission.MissionConfig` of the parsed arguments."""
    from runtime.mission import MissionConfig

    return MissionConfig(
        robots=args.robots, seconds=args.seconds, seed=args.seed, camera=args.camera, camera_rate=args.camera_rate,
        camera_latency=args.camera_latency,
        particles=args.particles, max_corners=args.max_corners, max_observations=args.max_observations,
        motion=args.motion, speed=args.speed,
        fusion_interval=args.fusion_interval,
        preset=args.preset, method=args.method, out=args.out, rerun=args.rerun, log_sensors=args.log_sensors,
        world=args.world, robot_url=robot_url, route_file=args.route, time_scale=args.time_scale,
        odometry=args.odometry, robot_name=getattr(args, "name", None), realtime=args.realtime,
        map_save_interval=args.map_save_interval, recording_id=args.recording_id,
        start_prior=getattr(args, "start_prior", None), smooth=getattr(args, "smooth", True))


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
    if args.route is not None and args.motion != "route":   # it was run, the route ignored without a word
        return f"--route {args.route}: only --motion route follows a route (this run has --motion {args.motion})"
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


class Progress:
    """One status line, rewritten in place on a terminal, printed every few seconds otherwise (stderr)."""

    def __init__(self, enabled: bool, stream=None) -> None:
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.tty = self.stream.isatty()
        self._last = 0.0
        self._lock = threading.Lock()
        self._open_line = False

    def line(self, text: str) -> None:
        if not self.enabled:
            return
        with self._lock:
            if self.tty:
                self.stream.write("\r\x1b[2K" + text)
                self._open_line = True
            elif time.monotonic() - self._last >= 5.0:
                self.stream.write(text + "\n")
                self._last = time.monotonic()
            self.stream.flush()

    def event(self, text: str) -> None:
        if not self.enabled:
            return
        with self._lock:
            if self._open_line:
                self.stream.write("\r\x1b[2K")
                self._open_line = False
            self.stream.write(f"  {text}\n")
            self.stream.flush()

    def warning(self, text: str) -> None:
        """A line said at once even under --quiet (a recording's writer died), below an open status line."""
        with self._lock:
            if self._open_line:
                self.stream.write("\r\x1b[2K")
                self._open_line = False
            self.stream.write(text + "\n")
            self.stream.flush()

    def done(self) -> None:
        with self._lock:
            if self._open_line:
                self.stream.write("\n")
                self._open_line = False


STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)


def hold_stop_signals() -> tuple[list[int], Callable[[], None]]:
    """Until the mission can take them, Ctrl-C and SIGTERM are noted instead of acted on: (the signals noted, a
    function restoring the handlers there were). The mission's imports take a second or more, and a Ctrl-C
    then raised KeyboardInterrupt wherever the import was; inside importlib's module-lock callback Python prints
    it as 'Exception ignored' and goes on, and the mission ran to its end with the Ctrl-C lost (session 47)."""
    if threading.current_thread() is not threading.main_thread():
        return [], lambda: None
    noted: list[int] = []
    previous = {s: signal.getsignal(s) for s in STOP_SIGNALS}
    for s in STOP_SIGNALS:
        signal.signal(s, lambda signum, frame: noted.append(signum))

    def restore() -> None:
        for s, handler in previous.items():
            signal.signal(s, handler)
    return noted, restore


def run_mission_command(args: argparse.Namespace, robot_url: str = "mock") -> int:
    noted, restore_signals = hold_stop_signals()  # first: the imports below are where a Ctrl-C got lost
    try:
        return _run_mission(args, robot_url, noted)
    finally:
        restore_signals()


def _run_mission(args: argparse.Namespace, robot_url: str, noted: list[int]) -> int:
    from runtime.mission import Mission, install_stop_signals, sensor_log_dropped_line
    from runtime.report import format_summary

    prog = f"p3at {args.command}" if getattr(args, "command", None) else "p3at"   # its errors name the command
    try:
        config = config_from_args(args, robot_url)
    except ValueError as e:
        print(f"{prog}: {e}", file=sys.stderr)
        return 2
    progress = Progress(not args.quiet)
    try:  # a Zenoh exchange (runtime/fleet) when --exchange zenoh[:CONFIG]; None: the mission's in-process one
        exchange = open_exchange(args.exchange, args.fleet, "robot", on_event=progress.event)
    except (ValueError, RuntimeError) as e:
        print(f"{prog}: {e}", file=sys.stderr)
        return 2
    mission = Mission(config, progress=progress.line, events=progress.event, exchange=exchange,
                      warnings=lambda text: progress.warning(f"{prog}: warning: {text}"))
    restore = install_stop_signals(mission.stop)
    if noted:  # stopped before the mission began: no robot is connected, nothing is written
        restore()
        if exchange is not None:
            exchange.close()
        return 128 + noted[0]
    try:
        result = mission.run()
    except (OSError, ValueError, LookupError, RuntimeError) as e:  # drivers' and files' typed errors
        progress.done()
        print(f"{prog}: mission failed: {e}", file=sys.stderr)
        return 1
    finally:
        restore()
        progress.done()
        if exchange is not None:
            exchange.close()
    if args.json:
        print(json_text(result.summary, indent=2))
    else:
        print(format_summary(result.summary))
        print()
        print("Files written:")
        print("\n".join(f"  {f}" for f in result.summary["files"]))
    if result.recording is not None:
        whole = "" if "recording" not in {f.stage for f in result.failures} else " (incomplete: its writer failed)"
        print(f"Rerun recording{whole}: {result.recording}\n  open it with:   rerun {result.recording}\n"
              f"  summarise it:   p3at review {result.recording}", file=sys.stderr if args.json else sys.stdout)
    for name, figures in result.summary["robots"].items():  # a sensor log with holes is said even with --quiet
        if figures.get("sensor_log_dropped"):
            print(f"{prog}: warning: {sensor_log_dropped_line(name, figures['sensor_log_dropped'])}", file=sys.stderr)
    if result.failures:  # a stage died: the figures above are what was there when it stopped
        print(mission_failure_line(prog, result.failures), file=sys.stderr)
    return 1 if result.failures else 0


def mission_failure_line(prog: str, failures: list) -> str:
    """The one line that says a mission failed: its first failure, the cause (a full disk fails every file after
    it: each is in the summary's failures table), and how many more there were."""
    first, more = str(failures[0]), len({str(f) for f in failures} - {str(failures[0])})
    also = f" (and {more} more failure{'s' if more > 1 else ''}: the summary lists them)" if more else ""
    return f"{prog}: mission failed: {first}{also}"
