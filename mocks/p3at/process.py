"""Virtual P3-ATs served from their own process, on the wall clock (issue 15's SIP timing).

In one Python process beside rendering and FastSLAM, a server thread runs when the GIL and the CPU let it: a
render preempted while it holds the GIL keeps the SIP from leaving (in a ``--realtime`` demo, 70 % of the SIP
gaps fell outside 100 ± 20 ms). A robot is a separate machine; so, as AMRISim does, the robots of one world are
served by one child process (:func:`child_main`) of their own: the usual :class:`TcpServer`
threads, one world (the robots still collide with each other and hear each other's sonar).

The parent keeps its own :class:`~mocks.world.World` for the things that look at the robots (the virtual heads
render from ``world.pose(name)``, the mission scores against it): each robot is attached to it
(``World.attach_robot``) with a source that reads the child's latest true pose from a :class:`PoseTable`, a
memory-mapped file. The child publishes every robot's pose after each physics step (10 ms) and wakes at least
that often, so a pose read in the parent is at most one step plus a scheduling delay old.

Control goes through the child's stdin and stdout, one JSON object a line (no pickle): the parent writes the
configuration; the child answers ``{"ready": {name: port}}`` (or ``{"failed": why}``), reports a server thread
that died (``{"error": ...}``), and stops when its stdin closes (the parent closed it, or died), answering with
each robot's SIP send times (``{"stopped": ...}``). The child ignores SIGINT: the mission must still stop its
robots through their drivers before the robots go away.

Scheduling. The child starts a session of its own (``setsid``). Linux shares the CPU between sessions first
(autogroups, on by default in desktop and most server kernels), so in the mission's session the robots would
queue behind its own rendering and FastSLAM threads, whatever their nice values. In its own session, and asking
for nice -10 (granted only with CAP_SYS_NICE or an RLIMIT_NICE that allows it; ``RobotProcess.priority`` says
what it got), the process wakes on time: it needs ~1 % of a core per robot. Measured on a 2-core VM at load
average 14, one robot alone: 25 % of the SIP gaps outside 100 ± 20 ms at normal priority, 0-1.4 % at -10
(docs/virtual-robot.md has the table).
"""
from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import mmap
import os
import select
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivers.arcos.params import builtin_params
from mocks.p3at.options import FirmwareDefaults, OdometryErrors
from mocks.world import World

_SLOT_WORDS = 8  # per robot: sequence counter, x, y, θ, simulated time, contact, 2 spare (64 bytes, a cache line)
_NO_CONTACT, _WALL = -1.0, -2.0  # the contact word: what the robot is pressed against (k >= 0: robot k of the table)
_ROOT = Path(__file__).resolve().parents[2]  # the project, for the child's import path
_CHILD = "import sys; from mocks.p3at.process import child_main; sys.exit(child_main())"
DEFAULT_NICE = -10  # asked for, granted only with CAP_SYS_NICE or RLIMIT_NICE (see the module docstring)


class RobotProcessError(RuntimeError):
    """The virtual robots' process failed to start, or one of its servers (or the process itself) stopped."""


class PoseTable:
    """True poses shared between processes through a memory-mapped file, one slot per robot.

    Each slot is a seqlock: the single writer makes the slot's counter odd, writes x, y, θ and the simulated
    time, and makes it even again; a reader copies the slot between two reads of the counter and retries unless
    both were the same even number, so it never sees half an update. (CPython writes each number with one
    store, and x86-64 and the loads/stores of one core keep their order; the reader's retry covers the rest.)
    """

    def __init__(self, path: str | os.PathLike, robots: int, *, create: bool = False) -> None:
        self.path = Path(path)
        self.robots = robots
        size = robots * _SLOT_WORDS * 8
        flags = os.O_RDWR | (os.O_CREAT | os.O_EXCL if create else 0)
        fd = os.open(self.path, flags, 0o600)
        try:
            if create:
                os.ftruncate(fd, size)
            elif os.fstat(fd).st_size != size:
                raise ValueError(f"{self.path}: {os.fstat(fd).st_size} bytes, {size} expected for {robots} robots")
            self._map = mmap.mmap(fd, size)
        finally:
            os.close(fd)
        self._seq = np.frombuffer(self._map, dtype=np.uint64).reshape(robots, _SLOT_WORDS)[:, 0]
        self._data = np.frombuffer(self._map, dtype=np.float64).reshape(robots, _SLOT_WORDS)[:, 1:6]

    @classmethod
    def create(cls, robots: int) -> PoseTable:
        """A new table in a fresh file (in /dev/shm where there is one: memory, not disk)."""
        folder = "/dev/shm" if os.path.isdir("/dev/shm") else None
        handle, path = tempfile.mkstemp(prefix="p3at-poses-", dir=folder)
        os.close(handle)
        os.unlink(path)  # O_EXCL below: the file is ours
        return cls(path, robots, create=True)

    def write(self, index: int, pose: np.ndarray, t: float, contact: int | None = None) -> None:
        """Publish robot ``index``'s pose and simulated time, and what it is pressed against (``contact``: the table
        index of another robot, -2 a wall, None nothing)."""
        seq = int(self._seq[index])
        self._seq[index] = seq + 1  # odd: an update is under way
        self._data[index, :3] = pose
        self._data[index, 3] = t
        self._data[index, 4] = _NO_CONTACT if contact is None else float(contact)
        self._seq[index] = seq + 2

    def read(self, index: int) -> tuple[np.ndarray, float]:
        """The slot's pose (3,) and the simulated time it is of (nan, nan, nan and -inf before the first write)."""
        values = self._slot(index)
        if values is None:
            return np.full(3, np.nan), -math.inf
        return values[:3], float(values[3])

    def contact(self, index: int) -> int | None:
        """What robot ``index`` is pressed against: another robot's index, -2 a wall, None nothing."""
        values = self._slot(index)
        return None if values is None or values[4] == _NO_CONTACT else int(values[4])

    def _slot(self, index: int) -> np.ndarray | None:
        while True:
            before = int(self._seq[index])
            values = self._data[index].copy()
            if before % 2 == 0 and int(self._seq[index]) == before:
                return None if before == 0 else values
            time.sleep(0)  # the writer is mid-update: let it finish

    def close(self, unlink: bool = False) -> None:
        self._seq = self._data = None  # the views must go before the map can close
        with contextlib.suppress(BufferError, ValueError):
            self._map.close()
        if unlink:
            with contextlib.suppress(FileNotFoundError):
                self.path.unlink()


@dataclass(frozen=True)
class RobotSpec:
    """One virtual P3-AT to serve: its name in the world, its start pose (default: the world's), its model's
    seed, wheel-odometry errors, subtype and firmware defaults (e.g. ``FirmwareDefaults(robot_contact=
    "footprint")``; see :class:`~mocks.p3at.model.VirtualP3AT`)."""

    name: str
    pose: tuple[float, float, float] | None = None
    seed: int = 0
    odometry: OdometryErrors = OdometryErrors()
    subtype: str = "p3at-sh"
    firmware: FirmwareDefaults = FirmwareDefaults()


class RemoteServer:
    """The parent's handle on one robot served by a :class:`RobotProcess`: what a mission uses of a server."""

    def __init__(self, process: RobotProcess, name: str, host: str, port: int) -> None:
        self._process = process
        self.name = name
        self.host = host
        self.port = port
        self.url = f"socket://{host}:{port}"
        self.time_scale = process.time_scale
        self.sip_wall_times: list[float] = []  # CLOCK_MONOTONIC of every SIP sent; filled when the process stops

    @property
    def error(self) -> BaseException | None:
        """What stopped this robot's server (or the whole process), normally None."""
        return self._process.error_of(self.name)

    def true_pose(self) -> np.ndarray:
        return self._process.pose(self.name)

    @property
    def touching(self) -> str | None:
        """What the robot is pressed against now: another robot's name, "wall", or None (as the child published)."""
        return self._process.touching(self.name)

    def __repr__(self) -> str:
        return f"<RemoteServer {self.name!r} at {self.url} (pid {self._process.pid})>"


class RobotProcess:
    """A child process serving virtual P3-ATs over TCP on the wall clock; see the module docstring.

    ``servers[name]`` are :class:`RemoteServer` handles (``.url``, ``.port``, ``.error``, ``.sip_wall_times``);
    the robots are attached to the given world (``world.pose(name)`` is the child's live true pose) until
    ``close()``, which is idempotent and stops the child (every robot at once). Use :func:`serve_tcp_process`.
    """

    def __init__(self, world: World, robots: Sequence[RobotSpec], *, host: str = "127.0.0.1",
                 time_scale: float = 1.0, nice: int | None = DEFAULT_NICE, startup_timeout: float = 60.0) -> None:
        if world.source is None:
            raise ValueError("a world served from another process must come from a file (World.load)")
        names = [r.name for r in robots]
        if not names or len(set(names)) != len(names):
            raise ValueError(f"robots must be named, each once: {names}")
        for spec in robots:
            if spec.pose is None and spec.name not in world.start_poses:
                raise ValueError(f"no pose given and world {world.name!r} has no start pose {spec.name!r}")
        if not time_scale > 0:
            raise ValueError(f"time_scale must be > 0, got {time_scale!r}")
        self.world = world
        self.names = names
        self.time_scale = float(time_scale)
        self.servers: dict[str, RemoteServer] = {}
        self.priority = "normal"  # what the child obtained, in words (see the module docstring)
        self._errors: dict[str, BaseException] = {}
        self._buffer = b""
        self._closed = False
        self._attached: list[str] = []
        self._table = PoseTable.create(len(names))
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(_ROOT), os.environ.get("PYTHONPATH")])))
        try:
            self._child = subprocess.Popen([sys.executable, "-c", _CHILD], stdin=subprocess.PIPE,
                                           stdout=subprocess.PIPE, env=env, cwd=_ROOT,
                                           start_new_session=True)  # its own scheduling group: see the docstring
        except BaseException:
            self._table.close(unlink=True)
            raise
        self.pid = self._child.pid
        try:
            config = {"world": str(world.source), "poses": str(self._table.path), "host": host,
                      "time_scale": self.time_scale, "nice": nice,
                      "robots": [{"name": r.name, "pose": None if r.pose is None else [float(v) for v in r.pose],
                                  "seed": int(r.seed), "odometry": dataclasses.asdict(r.odometry),
                                  "subtype": r.subtype, "firmware": dataclasses.asdict(r.firmware)}
                                 for r in robots]}
            self._child.stdin.write((json.dumps(config) + "\n").encode())
            self._child.stdin.flush()
            reply = self._read_message(time.monotonic() + startup_timeout)
            if reply is None or "ready" not in reply:
                why = reply.get("failed") if reply else f"no answer (exit status {self._child.poll()})"
                raise RobotProcessError(f"the virtual robots' process did not start: {why}")
            self.priority = str(reply.get("priority", "normal"))
            self._table.path.unlink()  # both sides have it mapped: a hard kill leaves no file behind
            for index, (name, spec) in enumerate(zip(names, robots, strict=True)):
                self.servers[name] = RemoteServer(self, name, host, int(reply["ready"][name]))
                params = builtin_params(spec.subtype)
                world.attach_robot(name, lambda index=index: self._table.read(index)[0],
                                   footprint=(params.length_m, params.width_m))
                self._attached.append(name)
        except BaseException:
            self.close()
            raise
        os.set_blocking(self._child.stdout.fileno(), False)

    # -- the child's messages -----------------------------------------------------------------------------------
    def _read_message(self, deadline: float) -> dict | None:
        """The child's next message line, waiting until ``deadline`` (None at its end or at end of file)."""
        fd = self._child.stdout.fileno()
        while b"\n" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([fd], [], [], left)[0]:
                return None
            chunk = os.read(fd, 1 << 16)
            if not chunk:
                return None
            self._buffer += chunk
        line, self._buffer = self._buffer.split(b"\n", 1)
        try:
            message = json.loads(line)
        except ValueError:
            return {"failed": f"unreadable message {line[:80]!r}"}
        return message if isinstance(message, dict) else {"failed": f"unexpected message {line[:80]!r}"}

    def _note(self, message: dict) -> None:
        error = message.get("error")
        if isinstance(error, dict) and error.get("robot") in self.names:
            self._errors.setdefault(error["robot"], RobotProcessError(str(error.get("message"))))

    def _poll(self) -> None:
        while not self._closed:
            message = self._read_message(time.monotonic())
            if message is None:
                break
            self._note(message)
        if not self._closed and self._child.poll() is not None:
            for name in self.names:
                self._errors.setdefault(name, RobotProcessError(
                    f"the virtual robots' process exited with status {self._child.returncode}"))

    def error_of(self, name: str) -> BaseException | None:
        self._poll()
        return self._errors.get(name)

    def pose(self, name: str) -> np.ndarray:
        """The robot's latest true pose (3,) as the child published it."""
        return self._table.read(self.names.index(name))[0]

    def touching(self, name: str) -> str | None:
        """What the robot is pressed against as the child published it: another robot's name, "wall", or None."""
        code = self._table.contact(self.names.index(name))
        if code is None:
            return None
        return self.names[code] if 0 <= code < len(self.names) else "wall"

    # -- lifecycle ------------------------------------------------------------------------------------------
    def close(self, timeout: float = 10.0) -> None:
        """Take the robots out of the world, stop the child (its servers close their ports), collect each
        robot's SIP send times. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        for name in self._attached:
            self.world.remove_robot(name)
        with contextlib.suppress(OSError):
            self._child.stdin.close()  # end of file: the child stops
        deadline = time.monotonic() + timeout
        with contextlib.suppress(OSError, ValueError):
            os.set_blocking(self._child.stdout.fileno(), True)
            while (message := self._read_message(deadline)) is not None:
                stopped = message.get("stopped")
                if isinstance(stopped, dict):
                    for name, figures in stopped.items():
                        if name in self.servers and isinstance(figures, dict):
                            self.servers[name].sip_wall_times = [float(t) for t in figures.get("sip_wall_times", [])]
                else:
                    self._note(message)
        try:
            self._child.wait(max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            self._child.kill()
            self._child.wait()
        self._child.stdout.close()
        self._table.close(unlink=True)

    def __enter__(self) -> RobotProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def serve_tcp_process(world: World, robots: Sequence[RobotSpec], *, host: str = "127.0.0.1",
                      time_scale: float = 1.0, nice: int | None = DEFAULT_NICE) -> RobotProcess:
    """Serve ``robots`` (virtual P3-ATs in ``world``, which must come from a file) from a child process, each on
    an ephemeral TCP port on ``host``, on the wall clock (k× faster with ``time_scale=k``). The robots appear in
    ``world`` with their live true poses. ``nice``: the scheduling priority the child asks for where the OS
    allows it (None: leave it; ``.priority`` says what it got). Returns the started :class:`RobotProcess`."""
    return RobotProcess(world, robots, host=host, time_scale=time_scale, nice=nice)


# -- the child ------------------------------------------------------------------------------------------------
def _say(message: dict) -> None:
    """One line to the parent; nothing once the parent is gone (a killed ``p3at run --realtime``: its end of the
    pipe closed, nobody is left to tell, and a traceback would only reach the user's terminal)."""
    try:
        sys.stdout.write(json.dumps(message) + "\n")
        sys.stdout.flush()
    except BrokenPipeError:
        # Python flushes stdout once more at exit: let that go to /dev/null instead of failing there too
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())


def _raise_priority(nice: int) -> str:
    """Ask for a higher scheduling priority: the nice value of this process's autogroup (the kernel shares the CPU
    between sessions first, so within our own session a task's nice would change nothing) and of the process
    (inherited by the server threads created after; what counts where autogroups are off). Says what it got."""
    got = []
    try:
        with open("/proc/sys/kernel/sched_autogroup_enabled") as f:
            autogroups = f.read().strip() == "1"
        if autogroups:
            with open("/proc/self/autogroup", "w") as f:
                f.write(str(nice))
            got.append(f"autogroup nice {nice}")
    except OSError:
        pass
    try:
        os.setpriority(os.PRIO_PROCESS, 0, nice)
        got.append(f"nice {nice}")
    except OSError as exc:
        if not got:
            return f"normal (nice {nice} refused: {exc.strerror or exc})"
    return ", ".join(got)


def _contact_code(touching: str | None, indices: dict[str, int]) -> int | None:
    """A model's ``touching`` as the pose table's contact word."""
    if touching is None:
        return None
    return indices.get(touching, int(_WALL))


def child_main() -> int:
    """The child process: serve the robots its stdin describes until that closes (see the module docstring)."""
    from mocks.p3at.model import STEP_S
    from mocks.p3at.servers import serve_tcp

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent stops us (see the module docstring)
    servers = []
    table = None
    try:
        config = json.loads(sys.stdin.readline())
        priority = "normal" if config.get("nice") is None else _raise_priority(int(config["nice"]))
        world = World.load(config["world"])
        table = PoseTable(config["poses"], len(config["robots"]))
        indices = {robot["name"]: i for i, robot in enumerate(config["robots"])}
        for index, robot in enumerate(config["robots"]):
            pose = None if robot["pose"] is None else np.asarray(robot["pose"], float)
            server = serve_tcp(world, robot["name"], pose, host=config["host"], port=0,
                               time_scale=config["time_scale"], seed=robot["seed"],
                               odometry=OdometryErrors(**robot["odometry"]), subtype=robot["subtype"],
                               firmware=FirmwareDefaults(**robot["firmware"]))
            servers.append(server)
            table.write(index, server.model.true_pose(), server.model.time)
            server.wake_s = STEP_S  # the shared pose is at most one physics step old
            server.on_moved = lambda model, i=index: table.write(i, model.true_pose(), model.time,
                                                                 _contact_code(model.touching, indices))
    except Exception as exc:  # noqa: BLE001 - reported to the parent in one line
        _say({"failed": f"{type(exc).__name__}: {exc}"})
        for server in servers:
            server.close()
        return 1
    _say({"ready": {s.name: s.port for s in servers}, "priority": priority})
    reported: set[str] = set()
    while True:
        if select.select([sys.stdin], [], [], 0.1)[0] and not sys.stdin.readline():
            break  # end of file: the parent closed us (or died)
        for server in servers:
            if server.error is not None and server.name not in reported:
                reported.add(server.name)
                _say({"error": {"robot": server.name, "message": f"{type(server.error).__name__}: {server.error}"}})
    for server in servers:
        server.close()
    _say({"stopped": {s.name: {"sips": s.model.stats.sips, "sip_wall_times": list(s.sip_wall_times)}
                      for s in servers}})
    table.close()
    return 0

