"""``p3at robot``: talk to a P3-AT (or an ARCOS simulator) and run the virtual one.

- ``p3at robot info URL [--json]``: connect, print identity, CONFIG and the current state.
- ``p3at robot drive URL --vel M_S --rvel RAD_S --seconds T``: drive and print odometry as it goes; on a lost
  link it stops printing at once, says "link lost" and exits 1 (the robot's own 2 s watchdog stops it).
- ``p3at robot serve [--tcp PORT | --pty] [--world FILE] [--pose X,Y,TH] [--name NAME]``: run a virtual P3-AT.

URL is anything pyserial opens: ``/dev/ttyUSB0``, a pty path, ``socket://127.0.0.1:8101``.
Exit status: 0 done; 1 the robot could not be reached or failed; 2 bad arguments or files.
"""
from __future__ import annotations

import argparse
import math
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

from drivers.errors import BadFileError, DriverError, DriverTimeoutError, NotConnectedError
from runtime.commands.options import (
    MAX_TIME_SCALE,
    add_deprecated_alias,
    finite_float,
    non_negative_float,
    non_negative_int,
    positive_float,
    positive_int,
    time_scale_problem,
    whole_number_where,
)
from runtime.json_output import json_text
from runtime.terminal import printable

EXIT_DEVICE = 1
EXIT_BAD_INPUT = 2
# Command-line sessions are short and watched: notice a silent link fast (the library's default, 4 s, suits
# long runs that reconnect). 0.6 s = 6 SIP cycles of 100 ms, twice the longest gap (0.31 s) measured from the
# virtual robot on a loaded machine, so a slow robot is not taken for a lost one.
LINK_TIMEOUT = 0.6
STOP_MARGIN_CYCLES = 10   # state packets beyond twice a stop's time at the robot's deceleration (1 s of a P3-AT's)
# ARCOS's factory TransDecel (mm/s²), RotDecel (°/s²), SipCycle and SonarCycle (ms), for a CONFIG that lacks them
DEFAULT_TRANS_DECEL, DEFAULT_ROT_DECEL, DEFAULT_SIP_CYCLE, DEFAULT_SONAR_CYCLE = 300, 100, 100, 40
PACKET_WAIT_BACKSTOP = 600.0  # s; never reached: the packets, or the link's silence, end the wait first


def tcp_port(text: str) -> int:
    """A TCP port, 0-65535 (0: any free one)."""
    return whole_number_where(text, "a port from 0 to 65535", lambda port: 0 <= port <= 65535)


def register(subparsers: Any) -> None:
    robot = subparsers.add_parser("robot", help="P3-AT over ARCOS: info, drive, and a virtual robot to serve",
                                  description="Talk to a Pioneer P3-AT (or an ARCOS simulator such as MobileSim "
                                              "or AMRISim) through any pyserial URL, or serve a virtual one.")
    sub = robot.add_subparsers(dest="robot_command", metavar="ACTION", required=True)

    info = sub.add_parser("info", help="connect and print identity, CONFIG and current state",
                          description="Connect (SYNC0/1/2, OPEN, CONFIG), print the robot's identity, its CONFIG "
                                      "packet and its current state, then disconnect. Motors are not enabled.")
    _url_arguments(info)
    info.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    info.set_defaults(handler=_info)

    drive = sub.add_parser("drive", help="drive at a velocity for some seconds, printing odometry",
                           description="Enable the motors, drive at --vel m/s and --rvel rad/s for --seconds, "
                                       "printing odometry (x, y in metres, heading θ in radians) as it goes, "
                                       "then stop, disable the motors and disconnect. If the link is lost "
                                       "(no packet for --link-timeout s, or the port fails) it stops printing, "
                                       "says 'link lost' and exits with status 1.")
    _url_arguments(drive)
    drive.add_argument("--vel", type=finite_float, default=0.0, metavar="M_S", help="forward velocity, m/s (default 0)")
    drive.add_argument("--rvel", type=finite_float, default=0.0, metavar="RAD_S",
                       help="rotational velocity, rad/s, counter-clockwise (default 0)")
    drive.add_argument("--seconds", type=positive_float, required=True, metavar="S", help="how long to drive (s)")
    drive.add_argument("--every", type=positive_float, default=0.2, metavar="S", help="print interval (default 0.2 s)")
    drive.add_argument("--json", action="store_true", help="print one JSON object per line")
    drive.set_defaults(handler=_drive)

    serve = sub.add_parser("serve", help="run a virtual P3-AT in the simulated building",
                           description="Run a virtual P3-AT (the robot side of ARCOS) in the simulated building "
                                       "and print where it listens; runs until Ctrl-C. Any ARCOS client (this "
                                       "driver, ARIA) can connect to it.")
    where = serve.add_mutually_exclusive_group()
    where.add_argument("--tcp", type=tcp_port, metavar="PORT",
                       help="listen on 127.0.0.1:PORT, 0-65535 (default 8101; 0 = any free port)")
    where.add_argument("--pty", action="store_true", help="serve on a pseudo-terminal (prints its path)")
    serve.add_argument("--world", metavar="FILE", help="world file (default: the packaged building)")
    serve.add_argument("--start-pose", metavar="X,Y,THETA", help="start pose in metres and radians "
                                                       "(default: the world's start pose for NAME)")
    serve.add_argument("--name", default="robot1", help="robot name, also the SYNC2 name (default robot1)")
    add_deprecated_alias(serve, "--pose", "--start-pose")
    serve.add_argument("--subtype", default="p3at-sh", help="p3at-sh (ARCOS, default) or p3at (old P2OS units)")
    serve.add_argument("--time-scale", type=positive_float, default=1.0,
                       help=f"simulated seconds per wall second, at most {MAX_TIME_SCALE:g} (default 1)")
    serve.add_argument("--seed", type=non_negative_int, default=0, help="noise seed, a whole number >= 0 (default 0)")
    serve.add_argument("--duration", type=non_negative_float, metavar="S",
                       help="exit after S >= 0 seconds instead of at Ctrl-C")
    serve.set_defaults(handler=_serve)


def _url_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("url", metavar="URL", help="serial device, pty path or socket://HOST:PORT")
    parser.add_argument("--params", metavar="FILE", help="robot parameter file (default: chosen by the subtype)")
    parser.add_argument("--baud", type=positive_int, default=9600, help="serial baud rate (default 9600)")
    parser.add_argument("--link-timeout", type=positive_float, default=LINK_TIMEOUT, metavar="S",
                        help=f"seconds without any packet before the link counts as lost (default {LINK_TIMEOUT}: "
                             "six SIP cycles, twice the longest gap seen from a loaded virtual robot)")


def _fail(action: str, message: object, status: int) -> int:
    print(f"p3at robot {action}: {message}", file=sys.stderr)
    return status


def _open(args: argparse.Namespace):
    import logging

    from drivers.arcos.robot import P3AT

    if not logging.getLogger().handlers:
        # Nobody configured logging: keep Python's last-resort handler from printing the driver's warnings
        # beside this command's own one-line message (a lost link would be said twice).
        logging.getLogger("drivers").addHandler(logging.NullHandler())
    return P3AT(args.url, params=args.params, baudrate=args.baud, reconnect=False,
                link_timeout=args.link_timeout).connect()


# ---------------------------------------------------------------------------------------------------- info
def _state_dict(state: Any) -> dict[str, Any]:
    return {
        "stamp": state.stamp, "x": state.x, "y": state.y, "theta": state.theta, "v": state.v, "w": state.w,
        "battery_volts": state.battery_volts, "motors_enabled": state.motors_enabled,
        "stop_pressed": state.stop_pressed, "left_stall": state.left_stall, "right_stall": state.right_stall,
        "front_bumpers": state.front_bumpers, "rear_bumpers": state.rear_bumpers,
        "sonars": [{"index": s.index, "range_m": s.range_m, "pose": list(s.pose)} for s in state.sonars],
    }


def _info(args: argparse.Namespace) -> int:
    from drivers.arcos.codec import config_to_dict

    try:
        with _open(args) as robot:
            # Give the sonars one firing round so every range is filled in (each SIP carries only new ones), in
            # the robot's own time: a starved simulator's round takes longer on the wall clock
            first = robot.state
            cycles = _sonar_round_cycles(robot.config, len(first.sonar_ranges()))
            state = _wait_in_packets(robot, first, cycles, lambda s: all(r is not None for r in s.sonar_ranges()))
            identity, config, params = robot.identity, robot.config, robot.params
            stats = robot.stats
    except BadFileError as e:
        return _fail("info", e, EXIT_BAD_INPUT)
    except DriverError as e:
        return _fail("info", e, EXIT_DEVICE)
    config_fields = config_to_dict(config) if config is not None else None
    if args.json:
        print(json_text({
            "url": args.url,
            "identity": {"name": identity.name, "type": identity.type, "subtype": identity.subtype},
            "params": params.source, "config": config_fields, "state": _state_dict(state),
            "parser": {"packets": stats.packets, "dropped_bytes": stats.dropped_bytes,
                       "bad_checksums": stats.bad_checksums},
        }, indent=2))
        return 0
    kind = f"{printable(identity.type)} {printable(identity.subtype)}"
    print(f"robot     {printable(identity.name)}  ({kind}) at {args.url}")
    print(f"params    {params.source}")
    if config_fields is None:
        print("config    (the robot sent no CONFIG packet)")
    else:
        print("config    " + "  ".join(f"{k}={printable(v) if isinstance(v, str) else v}"
                                       for k, v in config_fields.items()))
    print(f"pose      x={state.x:.3f} m  y={state.y:.3f} m  θ={state.theta:+.4f} rad  "
          f"v={state.v:.3f} m/s  ω={state.w:+.4f} rad/s")
    print(f"battery   {state.battery_volts:.1f} V   motors {'on' if state.motors_enabled else 'off'}"
          f"   stall L/R {int(state.left_stall)}/{int(state.right_stall)}"
          f"   bumpers front {state.front_bumpers:#04x} rear {state.rear_bumpers:#04x}"
          f"   stop button {'pressed' if state.stop_pressed else 'released'}")
    ranges = " ".join("-" if r is None else f"{r:.2f}" for r in state.sonar_ranges())
    print(f"sonar m   {ranges}")
    return 0


# ---------------------------------------------------------------------------------------------------- drive
def _drive(args: argparse.Namespace) -> int:
    columns = ("t [s]", "x [m]", "y [m]", "θ [rad]", "v [m/s]", "ω [rad/s]")

    def show(t: float, state: Any) -> None:
        if args.json:
            print(json_text({"t": round(t, 3), "x": state.x, "y": state.y, "theta": state.theta, "v": state.v,
                             "w": state.w, "stalled": state.stalled, "bumped": state.bumped}), flush=True)
        else:
            flags = (" STALL" if state.stalled else "") + (" BUMP" if state.bumped else "")
            values = (t, state.x, state.y, state.theta, state.v, state.w)
            print("".join(f"{v:>10.3f}" if k < 3 else f"{v:>+10.4f}" for k, v in enumerate(values)) + flags,
                  flush=True)

    lost = threading.Event()  # set on the reader thread the moment the driver declares the link lost
    try:
        with _open(args) as robot:
            robot.subscribe_link(lambda event: event.kind == "lost" and lost.set())
            if not args.json:
                print("".join(f"{c:>10}" for c in columns), flush=True)
            try:
                robot.motors_on()
                robot.set_velocity_limits(max_v=max(abs(args.vel), 0.1), max_w=max(abs(args.rvel), 0.1))
                robot.set_velocity(args.vel, args.rvel)
                start = time.monotonic()
                while (elapsed := time.monotonic() - start) < args.seconds:
                    if lost.wait(min(args.every, args.seconds - elapsed)):
                        break  # robot.state below would raise; say it once, now
                    show(time.monotonic() - start, robot.state)
            finally:
                if robot.connected:
                    try:
                        robot.stop()
                    except NotConnectedError:
                        pass  # lost in between: the robot's watchdog stops it
            stopped = _stopped_state(robot, args.vel, args.rvel)  # waits for the robot to stand: the line's time
            # is after the wait
            show(time.monotonic() - start, stopped)
    except BadFileError as e:
        return _fail("drive", e, EXIT_BAD_INPUT)
    except DriverError as e:
        return _fail("drive", e, EXIT_DEVICE)
    return 0


def _stopped_state(robot: Any, v: float, w: float) -> Any:
    """The robot's first state that reports it stopped, waited for in the robot's own time: its state packets, as
    many as twice the stop takes at its own deceleration, plus STOP_MARGIN_CYCLES (:func:`_stop_cycles`). A starved
    simulator's packets, like its motion, come slower, so it gets the same travel to stop in as a real robot; a link
    that goes silent ends the wait as lost (``--link-timeout``). A robot still moving after them is an error
    (exit 1), as a silent one is. The stop is sized from the larger of the last reported speed and the commanded
    ``v`` (m/s), ``w`` (rad/s): the last state may predate the acceleration (a packet or more old, or a starved
    simulator's), and the robot never exceeds what it was told."""
    first = robot.state
    cycles = _stop_cycles(robot.config, max(abs(first.v), abs(v)), max(abs(first.w), abs(w)))
    state = _wait_in_packets(robot, first, cycles, lambda s: s.v == 0.0 and s.w == 0.0)
    if state.v != 0.0 or state.w != 0.0:
        raise DriverTimeoutError(f"{robot.url}: the robot still reports v {state.v:+.3f} m/s, w {state.w:+.3f} rad/s "
                                 f"{cycles} state packets after the stop command")
    return state


def _wait_in_packets(robot: Any, first: Any, cycles: int, done: Callable[[Any], bool]) -> Any:
    """The first state after ``first`` for which ``done`` holds, or the one ``cycles`` state packets on, or the first
    of a new session (a reconnect): a wait in the robot's own time. A link that goes silent ends it as lost."""
    return robot.wait_for_state(PACKET_WAIT_BACKSTOP, lambda s: done(s) or s.session != first.session
                                or s.sequence - first.sequence >= cycles)


def _config_field(config: Any, name: str, default: int) -> int:
    """A positive CONFIG field, or ARCOS's factory value where the robot sent none (a CONFIG may end early)."""
    value = getattr(config, name, None)
    return value if isinstance(value, int) and value > 0 else default


def _stop_cycles(config: Any, v: float, w: float) -> int:
    """State packets a robot moving at ``v`` (m/s), ``w`` (rad/s) is given to stop: twice the time its CONFIG's
    TransDecel and RotDecel take, in its SipCycle, plus a margin."""
    trans_decel = _config_field(config, "trans_decel", DEFAULT_TRANS_DECEL) / 1000.0
    rot_decel = math.radians(_config_field(config, "rot_decel", DEFAULT_ROT_DECEL))
    cycle = _config_field(config, "sip_cycle", DEFAULT_SIP_CYCLE) / 1000.0
    seconds = max(abs(v) / trans_decel, abs(w) / rot_decel)
    return math.ceil(2.0 * seconds / cycle) + STOP_MARGIN_CYCLES


def _sonar_round_cycles(config: Any, sonars: int) -> int:
    """State packets in which ``sonars`` sonars, fired one every SonarCycle, all report: twice a round, plus a
    margin (16 sonars of a P3-AT: 0.64 s, 23 packets)."""
    sonar = _config_field(config, "sonar_cycle", DEFAULT_SONAR_CYCLE) / 1000.0
    cycle = _config_field(config, "sip_cycle", DEFAULT_SIP_CYCLE) / 1000.0
    return math.ceil(2.0 * sonars * sonar / cycle) + STOP_MARGIN_CYCLES


# ---------------------------------------------------------------------------------------------------- serve
def _parse_pose(text: str) -> tuple[float, float, float]:
    parts = text.split(",")
    if len(parts) != 3:
        raise ValueError(f"--start-pose wants X,Y,THETA (three numbers), got {text!r}")
    values = tuple(float(p) for p in parts)
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"--start-pose values must be finite, got {text!r}")
    return values  # type: ignore[return-value]


def _serve(args: argparse.Namespace) -> int:
    import numpy as np

    from mocks.p3at import serve_pty, serve_tcp
    from mocks.world import World, WorldFileError

    if (problem := time_scale_problem(args.time_scale)) is not None:
        return _fail("serve", problem, EXIT_BAD_INPUT)
    try:
        pose = np.array(_parse_pose(args.start_pose)) if args.start_pose else None
        world = World.load(args.world)
    except (ValueError, WorldFileError, OSError) as e:
        return _fail("serve", e, EXIT_BAD_INPUT)
    options = {"subtype": args.subtype, "seed": args.seed, "time_scale": args.time_scale}
    try:
        if args.pty:
            server = serve_pty(world, args.name, pose, **options)
        else:
            server = serve_tcp(world, args.name, pose, port=8101 if args.tcp is None else args.tcp, **options)
    except (ValueError, DriverError) as e:
        return _fail("serve", e, EXIT_BAD_INPUT)
    except OSError as e:
        return _fail("serve", f"cannot listen: {e}", EXIT_DEVICE)
    with server:
        x, y, th = world.pose(args.name)
        done = threading.Event()
        try:
            print(f"virtual P3-AT {args.name!r} ({args.subtype}) at x={x:.2f} y={y:.2f} theta={th:.2f} in "
                  f"{world.name!r}; listening on {server.url}", flush=True)
            print("connect with: p3at robot info " + server.url + "   (Ctrl-C to stop)", flush=True)
            # None: until Ctrl-C; so is a duration past what a wait can take (1e308 s: OverflowError, exit 70)
            done.wait(args.duration if args.duration is not None and args.duration < threading.TIMEOUT_MAX else None)
        except KeyboardInterrupt:
            pass
        if server.error is not None:
            return _fail("serve", f"server stopped: {server.error}", EXIT_DEVICE)
    return 0
