"""``p3at run``: the onboard runtime of one robot, on real hardware or on the virtual robot."""
from __future__ import annotations

import re
import sys
from pathlib import Path

from runtime.mission_cli import add_mission_arguments, mission_inputs_problem, run_mission_command


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "run", help="run the onboard pipeline on a robot (real: --robot /dev/ttyUSB0 --camera usb; default mocks)",
        description="The onboard runtime: the P3-AT driver and the stereo head on their own threads, odometry "
                    "interpolated to each frame, the front end, FastSLAM, map snapshots, motion from a route "
                    "file, the sonar wall follower or none. Ctrl-C or SIGTERM stops the motors, flushes every "
                    "file and exits cleanly.")
    parser.add_argument("--robot", default="mock", metavar="URL",
                        help="mock (a virtual P3-AT in the simulated building, default), a serial device such as "
                             "/dev/ttyUSB0, or socket://host:port")
    # camera None: chosen by --robot in _run; a --camera given is kept as given
    add_mission_arguments(parser, robots=1, seconds=600.0, out="out/run", camera=None, camera_rate=15.0,
                          camera_default="mock; usb with --robot URL")
    parser.add_argument("--name", default=None, metavar="ROBOT",
                        help="this robot's name in a fleet (its Zenoh keys p3at/FLEET/ROBOT/...); with --robot mock, "
                             "which of the world's robots to run (default robot1)")
    parser.set_defaults(handler=_run)


def _run(args) -> int:
    problem = robot_word_problem(args.robot) or mission_inputs_problem(args)
    if problem is not None:
        print(f"p3at run: {problem}", file=sys.stderr)
        return 2
    if args.camera is None:
        args.camera = "mock" if args.robot == "mock" else "usb"  # a real robot carries a real head
    if args.camera == "usb" and args.robot != "mock":  # (a virtual robot with --camera usb is refused as a config)
        problem = usb_head_problem()
        if problem is not None:
            print(f"p3at run: {problem}", file=sys.stderr)
            return 1
    return run_mission_command(args, robot_url=args.robot)


def usb_head_problem() -> str | None:
    """Why the stereo head on USB cannot be found (None when it is there), said before the robot is connected:
    the driver's message (it names no option) and this command's way to the virtual head. The head is looked for,
    not opened: the mission opens it."""
    from drivers.errors import DeviceNotFoundError
    from drivers.videre.transport import UsbTransport

    try:
        UsbTransport.find()
    except DeviceNotFoundError as e:
        return (f"{e}; without the head, the virtual robot with its virtual head runs as "
                "p3at run --robot mock --camera mock")
    return None


def robot_word_problem(robot: str) -> str | None:
    """A --robot that is neither mock, nor a URL, nor a path (a mistyped ``mock``): said as a bad argument before
    anything is looked for. It used to be taken for a serial device, and the first thing said was the USB head's
    absence (exit 1), which named neither the option nor the typo. A path (``/dev/ttyUSB0``) or a URL is left to
    the drivers, which say whether the device answers."""
    if "://" in robot:
        return _robot_url_problem(robot)
    if robot == "mock" or (robot.strip() and ("/" in robot or Path(robot).exists())):   # Path('') is the folder
        return None
    hint = "; did you mean mock?" if robot.strip().lower() == "mock" else ""
    if re.fullmatch(r"[A-Za-z0-9_.-]+:[0-9]+", robot):   # a bare HOST:PORT
        hint = f"; did you mean socket://{robot}?"
    return (f"--robot {robot}: no such robot: give mock (the virtual P3-AT), a serial device such as /dev/ttyUSB0, "
            f"or socket://host:port{hint}")


def _robot_url_problem(url: str) -> str | None:
    """A --robot URL pyserial has no handler for (http://, ftp://), or a socket:// one without a usable port: said
    before anything is looked for (the USB head is looked for before the robot is opened, so the driver's own words
    came after the head's absence, exit 1)."""
    import importlib.util

    from drivers.arcos.robot import url_problem

    scheme = url.split("://", 1)[0]
    known = scheme.isidentifier() and importlib.util.find_spec(f"serial.urlhandler.protocol_{scheme}") is not None
    if not known:
        return (f"--robot {url}: no such robot URL: pyserial knows socket://host:port (a simulator or a serial "
                "bridge), rfc2217://host:port and a serial device such as /dev/ttyUSB0")
    problem = url_problem(url)
    return None if problem is None else f"--robot {url}: {problem}"
