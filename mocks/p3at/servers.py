"""Thin servers around :class:`VirtualP3AT`: a TCP listener (``socket://``) and a pseudo-terminal (a tty path).

Each server owns one named daemon thread that moves bytes between the link and the pure model and wakes for
the model's next SIP. ``close()`` is idempotent, joins the thread and takes the robot out of the world.

Two kinds of clock:

- a plain callable (wall clock, ``time.monotonic``): simulated time = (clock() − start) × time_scale, so
  ``time_scale=5`` runs the robot five times faster than the wall clock (SIPs every 20 ms of wall time) for
  quick demos; the watchdog still waits 2 s of wall time, since a client's PULSEs keep wall time.
- a lockstep :class:`mocks.simclock.SimClock`: the server thread is a participant; the physics of every
  virtual robot on that clock is stepped together, 10 ms at a time, by the clock's advance hook (so a sensor
  sampling at ``t`` sees the world at ``t``), and the thread only moves bytes. It is runnable while bytes
  wait to be read, while the client has written bytes not yet read (``client_sent``: the client's byte
  count, e.g. the driver's ``bytes_written``; loopback TCP can hold bytes in the kernel for a moment), or
  while packets wait to be sent. ``last_sip_sent`` is the clock time of the last SIP it put on the wire,
  for a quiescence predicate "every SIP reached the runtime". Simulated time = the clock's time.
"""

from __future__ import annotations

import collections
import contextlib
import errno
import math
import os
import select
import selectors
import socket
import termios
import threading
import time
import tty
from collections.abc import Callable
from typing import Any

import numpy as np

from mocks.p3at.model import STEP_S, VirtualP3AT
from mocks.simclock import is_lockstep
from mocks.world import World

_READ_SIZE = 4096
_MAX_WAIT_S = 0.05  # poll at least this often so close() is prompt


class _Server:
    """Shared lifecycle: the model, the simulated clock, the thread."""

    url: str
    port: int | None

    def __init__(self, model: VirtualP3AT, clock: Callable[[], float], time_scale: float, thread_name: str) -> None:
        if not time_scale > 0:
            raise ValueError(f"time_scale must be > 0, got {time_scale!r}")
        self.lockstep = is_lockstep(clock)
        if self.lockstep and time_scale != 1.0:
            raise ValueError("a lockstep clock runs as fast as the machine allows: time_scale must be 1")
        self.model = model
        model.watchdog_s *= time_scale  # the client's silence counts in wall time
        self.world = model.world
        self.name = model.name
        self.time_scale = float(time_scale)
        self._clock = clock
        self._t0 = clock()
        self._sim0 = model.time
        self._lock = threading.Lock()  # guards the model against callers peeking from other threads
        self._stop = threading.Event()
        self._closed = False
        self._closing = False
        self._thread_done = False
        self._io_left_to_thread = False
        self.join_timeout = 5.0  # wall s close() waits for the thread (see close)
        self._thread = threading.Thread(target=self._run_guarded, name=thread_name, daemon=True)
        self.error: BaseException | None = None  # what stopped the thread, if anything did
        # lockstep bookkeeping (see the module docstring)
        self.rx_bytes = 0
        self.client_sent: Callable[[], int] | None = None
        self.last_sip_sent = -math.inf
        self.sip_wall_times: collections.deque[float] = collections.deque(maxlen=100_000)  # monotonic, per SIP sent
        self._outbox = bytearray()
        self._outbox_has_sip = False
        # wall clock: the longest the thread sleeps (the model's physics and pose are at most this old), and a
        # hook called with the model after each of its steps, under the server's lock (e.g. to share the pose)
        self.wake_s = _MAX_WAIT_S
        self.on_moved: Callable[[VirtualP3AT], None] | None = None
        if self.lockstep:
            if abs(model.time - clock()) > 1e-9:
                raise ValueError("on a lockstep clock the model must start at the clock's time (start_time)")
            self._token = clock.add_participant(f"p3at:{model.name}", world=True)
            _physics(clock).add(self)

    @property
    def touching(self) -> str | None:
        """What the robot is pressed against now: another robot's name, "wall", or None (``VirtualP3AT.touching``)."""
        return self.model.touching

    def sim_now(self) -> float:
        if self.lockstep:
            return self._clock()
        return self._sim0 + (self._clock() - self._t0) * self.time_scale

    # -- lockstep ------------------------------------------------------------------------------------------
    def _advance_model(self, t: float) -> bool:
        """Physics to ``t`` (the clock's advance hook, every participant blocked); due packets go to the outbox.
        False once the server is closed."""
        with self._lock:
            if self._closed:
                return False
            sips = self.model.stats.sips
            out = self.model.advance(t)
            if out:
                self._outbox += out
                self._outbox_has_sip |= self.model.stats.sips > sips
        return True

    def _bytes_in_flight(self) -> bool:
        return self.client_sent is not None and self._connected() and self.client_sent() > self.rx_bytes

    def _ready(self) -> bool:
        return (self._stop.is_set() or bool(self._outbox) or self._bytes_in_flight()
                or bool(select.select(self._fds(), [], [], 0)[0]))

    def _run_lockstep(self) -> None:
        with self._clock.participant(self._token):
            while not self._stop.is_set():
                self._clock.wait_for(self._ready, until=self.model.next_deadline())
                give_up = time.monotonic() + 2.0  # a client that counted bytes it never sent must not hang us
                while not self._stop.is_set():
                    self._service_io()
                    if not self._bytes_in_flight() or time.monotonic() > give_up:
                        break
                    select.select(self._fds(), [], [], 0.001)
                with self._lock:
                    out, self._outbox = bytes(self._outbox), bytearray()
                    sip, self._outbox_has_sip = self._outbox_has_sip, False
                if out and self._emit(out) and sip:
                    self.last_sip_sent = self._clock()
                    self.sip_wall_times.append(time.monotonic())

    def _received(self, data: bytes) -> bytes:
        """Lockstep: bytes from the client, applied now; returns the immediate replies."""
        with self._lock:
            out = self.model.receive(data, self.sim_now())
            self.rx_bytes += len(data)
        return out

    # -- wall clock ----------------------------------------------------------------------------------------
    def _wall_step(self, data: bytes = b"") -> None:
        """Wall clock: apply the client's bytes (if any) and run the model to now; send what fell due.

        Deadlines are absolute: the model's SIPs fall at open + k·SipCycle of simulated time, itself a fixed
        function of the clock, so a late wake-up sends the SIP late but never shifts the ones after it.

        The watchdog counts only the silence this thread saw. Bytes it reads came at some instant since it last
        looked, which it cannot know if it ran late (a loaded machine), so the physics up to now runs without the
        watchdog before they are applied; and a step without bytes first makes sure none wait on the link (if some
        do, the data step that follows at once takes them). Without both, a thread starved for the watchdog's 2 s
        of wall time stopped a robot whose client had pulsed all along."""
        with self._lock:
            sips = self.model.stats.sips
            now = self.sim_now()
            if data:
                out = self.model.advance(now, watchdog=False) + self.model.receive(data, now)
            elif self._bytes_waiting():
                return
            else:
                out = self.model.advance(now)
            self.rx_bytes += len(data)
            sips = self.model.stats.sips - sips
            moved = self.on_moved
            if moved is not None:
                moved(self.model)
        if self._emit(out) and sips:
            self.sip_wall_times.extend([time.monotonic()] * sips)

    # subclasses: the descriptors to watch, one pass over them, sending, whether a client is there
    def _fds(self) -> list:
        raise NotImplementedError

    def _bytes_waiting(self) -> bool:
        """Whether the client's bytes (or its hang-up) wait on the link now."""
        raise NotImplementedError

    def _service_io(self) -> None:
        raise NotImplementedError

    def _emit(self, data: bytes) -> bool:
        raise NotImplementedError

    def _connected(self) -> bool:
        raise NotImplementedError

    def _wait_s(self) -> float:
        """Wall seconds until the model next has something to send (capped)."""
        ahead = (self.model.next_deadline() - self.sim_now()) / self.time_scale
        return max(0.0, min(self.wake_s, ahead))

    def _run_guarded(self) -> None:
        try:
            if self.lockstep:
                self._run_lockstep()
            else:
                self._run()
        except BaseException as exc:  # noqa: BLE001 - recorded for the owner; the thread must end quietly
            self.error = exc
        finally:
            with self._lock:
                self._thread_done = True
                close_io = self._io_left_to_thread
            if close_io:
                self._close_io()

    def _run(self) -> None:
        raise NotImplementedError

    def _close_io(self) -> None:
        raise NotImplementedError

    def close(self) -> None:
        """Stop the thread, release the port or pty, take the robot out of the world. Safe to call twice."""
        if self._closing:
            return
        self._closing = True
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=self.join_timeout)
        with self._lock:
            self._closed = True
            # A thread still running (starved, or waiting for a lockstep baton) closes the port or pty itself as
            # it ends: closed under it, the descriptors' numbers would go to the next server or client, and the
            # thread would read and write there.
            self._io_left_to_thread = not self._thread_done and self._thread.ident is not None
        if self.lockstep:
            _physics(self._clock).remove(self)
            self._clock.discard(self._token)
        if not self._io_left_to_thread:
            self._close_io()
        self.model.close()

    def __enter__(self) -> Any:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name!r} at {self.url}>"


class TcpServer(_Server):
    """Serves one virtual P3-AT on a TCP port; one client at a time. A new connection replaces the old one and
    gets a fresh session (handshake again), as a robot behind a serial-to-TCP bridge would."""

    def __init__(self, model: VirtualP3AT, host: str, port: int, clock: Callable[[], float], time_scale: float):
        self._listener = socket.create_server((host, port), reuse_port=False)
        self._listener.setblocking(False)
        self.host = host
        self.port = self._listener.getsockname()[1]
        self.url = f"socket://{host}:{self.port}"
        self._client: socket.socket | None = None
        self._selector: selectors.BaseSelector | None = None  # the wall-clock loop's; None in lockstep
        self.connections = 0
        super().__init__(model, clock, time_scale, f"p3at-tcp-{model.name}-{self.port}")
        self._thread.start()

    def _accept(self) -> bool:
        """A new client replaces the old one and gets a fresh session (a robot behind a serial-to-TCP bridge).
        False if the connection vanished before it was accepted."""
        try:
            conn, _addr = self._listener.accept()
        except OSError:
            return False
        self._drop_client()
        conn.setblocking(True)
        conn.settimeout(1.0)
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        _quick_ack(conn)
        self._client = conn
        self.connections += 1
        if self._selector is not None:
            self._selector.register(conn, selectors.EVENT_READ, "client")
        with self._lock:
            self.model.reset_session()
        return True

    def _read_client(self) -> bytes | None:
        """One read from the client, acknowledged at once; None when the client went away (its session ends)."""
        try:
            data = self._client.recv(_READ_SIZE)
            _quick_ack(self._client)
        except OSError:
            data = b""
        if data:
            return data
        self._drop_client()
        with self._lock:
            self.model.reset_session()
        return None

    def _drop_client(self) -> None:
        if self._client is not None:
            if self._selector is not None:
                with contextlib.suppress(KeyError, ValueError):
                    self._selector.unregister(self._client)
            self._client.close()
            self._client = None

    def _run(self) -> None:
        with selectors.DefaultSelector() as selector:
            self._selector = selector
            selector.register(self._listener, selectors.EVENT_READ, "listen")
            try:
                while not self._stop.is_set():
                    for key, _ in selector.select(timeout=self._wait_s()):
                        if key.data == "listen":
                            self._accept()
                        elif key.data == "client" and key.fileobj is self._client:
                            # Not a replaced client's stale event: read from the one it belongs to.
                            data = self._read_client()
                            if data is not None:
                                self._wall_step(data)
                    self._wall_step()
            finally:
                self._drop_client()
                self._selector = None

    # lockstep I/O (the thread's participant loop in _Server)
    def _fds(self) -> list:
        return [self._listener] + ([self._client] if self._client is not None else [])

    def _connected(self) -> bool:
        return self._client is not None

    def _bytes_waiting(self) -> bool:
        return self._client is not None and bool(select.select([self._client], [], [], 0)[0])

    def _service_io(self) -> None:
        readable, _, _ = select.select(self._fds(), [], [], 0)
        if self._listener in readable:
            self._accept()
        if self._client is not None and self._client in readable:
            data = self._read_client()
            if data is not None:
                self._emit(self._received(data))

    def _emit(self, data: bytes) -> bool:
        if not data or self._client is None:
            return False
        try:
            self._client.sendall(data)
        except OSError:
            self._drop_client()
            return False
        return True

    def _close_io(self) -> None:
        self._drop_client()
        self._listener.close()


class PtyServer(_Server):
    """Serves one virtual P3-AT on a pseudo-terminal; ``url`` is the slave path a client opens like a serial port.

    The server keeps its own handle on the slave so the pty survives clients closing and reopening it (a serial
    line does not notice either): a reopened client sees whatever the robot kept sending, like a real robot.
    """

    def __init__(self, model: VirtualP3AT, clock: Callable[[], float], time_scale: float):
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave, termios.TCSANOW)
        os.set_blocking(self._master, False)
        self.url = os.ttyname(self._slave)
        self.port = None
        super().__init__(model, clock, time_scale, f"p3at-pty-{model.name}")
        self._thread.start()

    def _write(self, data: bytes) -> None:
        # Nobody reading: the pty buffer fills and the rest is lost, as on a serial line with no listener.
        view = memoryview(data)
        while view:
            try:
                n = os.write(self._master, view)
            except BlockingIOError:
                return
            except OSError as exc:
                if exc.errno in (errno.EIO, errno.EAGAIN):
                    return
                raise
            view = view[n:]

    def _run(self) -> None:
        with selectors.DefaultSelector() as selector:
            selector.register(self._master, selectors.EVENT_READ)
            while not self._stop.is_set():
                if selector.select(timeout=self._wait_s()):
                    try:
                        data = os.read(self._master, _READ_SIZE)
                    except (BlockingIOError, InterruptedError):
                        data = b""
                    except OSError as exc:
                        if exc.errno != errno.EIO:
                            raise
                        data = b""
                        time.sleep(0.01)
                    if data:
                        self._wall_step(data)
                self._wall_step()

    # lockstep I/O (the thread's participant loop in _Server)
    def _fds(self) -> list:
        return [self._master]

    def _connected(self) -> bool:
        return True

    def _bytes_waiting(self) -> bool:
        return bool(select.select([self._master], [], [], 0)[0])

    def _service_io(self) -> None:
        if not select.select([self._master], [], [], 0)[0]:
            return
        try:
            data = os.read(self._master, _READ_SIZE)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            if exc.errno != errno.EIO:
                raise
            return
        if data:
            self._emit(self._received(data))

    def _emit(self, data: bytes) -> bool:
        if data:
            self._write(data)
        return bool(data)

    def _close_io(self) -> None:
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)


def _quick_ack(conn: socket.socket) -> None:
    """ACK at once (Linux TCP_QUICKACK, which the kernel clears again: set after every read). The driver's
    pyserial socket does not set TCP_NODELAY, so a command written as two packets (VEL, RVEL) would otherwise
    hold its second half back until the delayed ACK of the first, ~40 ms later."""
    quickack = getattr(socket, "TCP_QUICKACK", None)
    if quickack is not None:
        with contextlib.suppress(OSError):
            conn.setsockopt(socket.IPPROTO_TCP, quickack, 1)


class _Physics:
    """Steps the physics of every virtual robot on one lockstep clock together, 10 ms at a time, so each robot
    meets the others (collisions, sonar echoes) where they are at that instant; the clock's advance hook."""

    def __init__(self) -> None:
        self._servers: list[_Server] = []
        self._lock = threading.Lock()

    def add(self, server: _Server) -> None:
        with self._lock:
            self._servers.append(server)

    def remove(self, server: _Server) -> None:
        with self._lock:
            if server in self._servers:
                self._servers.remove(server)

    def advance(self, t: float) -> None:
        with self._lock:
            servers = list(self._servers)
        while servers:
            behind = [s for s in servers if s.model.time + STEP_S <= t + 1e-9]
            if not behind:
                break
            for server in behind:
                if not server._advance_model(min(t, server.model.time + STEP_S)):
                    servers.remove(server)
        for server in servers:  # packets due exactly at t
            server._advance_model(t)


def _physics(clock) -> _Physics:
    def make() -> _Physics:
        physics = _Physics()
        clock.add_on_advance(physics.advance)
        return physics
    return clock.extension("p3at-physics", make)


def _model(world: World, name: str, pose: np.ndarray | None, model_options: dict[str, Any],
           clock: Callable[[], float]) -> VirtualP3AT:
    if is_lockstep(clock):
        model_options.setdefault("start_time", clock())  # simulated time is the clock's time
    if "rng" not in model_options and "seed" in model_options:
        model_options["rng"] = np.random.default_rng(model_options.pop("seed"))
    model_options.pop("seed", None)
    return VirtualP3AT(world, name, pose, **model_options)


def serve_tcp(
    world: World,
    name: str,
    pose: np.ndarray | None = None,
    *,
    host: str = "127.0.0.1",
    port: int = 8101,
    time_scale: float = 1.0,
    clock: Callable[[], float] = time.monotonic,
    **model_options: Any,
) -> TcpServer:
    """Run a virtual P3-AT named ``name`` in ``world`` (at ``pose``, default ``world.start_poses[name]``) on TCP.

    port 0 picks a free port (see ``.port`` / ``.url``). model_options go to :class:`VirtualP3AT`
    (subtype, params, rng or seed, odometry, sensors, firmware). Returns a started :class:`TcpServer`.
    """
    model = _model(world, name, pose, dict(model_options), clock)
    try:
        return TcpServer(model, host, port, clock, time_scale)
    except BaseException:
        model.close()
        raise


def serve_pty(
    world: World,
    name: str,
    pose: np.ndarray | None = None,
    *,
    time_scale: float = 1.0,
    clock: Callable[[], float] = time.monotonic,
    **model_options: Any,
) -> PtyServer:
    """Run a virtual P3-AT on a new pseudo-terminal; ``.url`` is the tty path for ``serial.serial_for_url``."""
    model = _model(world, name, pose, dict(model_options), clock)
    try:
        return PtyServer(model, clock, time_scale)
    except BaseException:
        model.close()
        raise
