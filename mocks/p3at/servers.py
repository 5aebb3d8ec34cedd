"""Thin servers around :class:`VirtualP3AT`: a TCP listener (``socket://``) and a pseudo-terminal (a tty path).

Each server owns one named daemon thread that moves bytes between the link and the pure model and wakes for
the model's next SIP. ``close()`` is idempotent, joins the thread and takes the robot out of the world.
Simulated time = (clock() − start) × time_scale, so ``time_scale=5`` runs the robot five times faster than
the wall clock (SIPs every 20 ms of wall time) for quick demos; the watchdog still waits 2 s of wall time,
since a client's PULSEs keep wall time.
"""

from __future__ import annotations

import contextlib
import errno
import os
import selectors
import socket
import termios
import threading
import time
import tty
from collections.abc import Callable
from typing import Any

import numpy as np

from mocks.p3at.model import VirtualP3AT
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
        self._thread = threading.Thread(target=self._run_guarded, name=thread_name, daemon=True)
        self.error: BaseException | None = None  # what stopped the thread, if anything did

    def sim_now(self) -> float:
        return self._sim0 + (self._clock() - self._t0) * self.time_scale

    def _wait_s(self) -> float:
        """Wall seconds until the model next has something to send (capped)."""
        ahead = (self.model.next_deadline() - self.sim_now()) / self.time_scale
        return max(0.0, min(_MAX_WAIT_S, ahead))

    def _run_guarded(self) -> None:
        try:
            self._run()
        except BaseException as exc:  # noqa: BLE001 - recorded for the owner; the thread must end quietly
            self.error = exc

    def _run(self) -> None:
        raise NotImplementedError

    def _close_io(self) -> None:
        raise NotImplementedError

    def close(self) -> None:
        """Stop the thread, release the port or pty, take the robot out of the world. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
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
        self.connections = 0
        super().__init__(model, clock, time_scale, f"p3at-tcp-{model.name}-{self.port}")
        self._thread.start()

    def _drop_client(self, selector: selectors.BaseSelector) -> None:
        if self._client is not None:
            with contextlib.suppress(KeyError, ValueError):
                selector.unregister(self._client)
            self._client.close()
            self._client = None

    def _send(self, data: bytes, selector: selectors.BaseSelector) -> None:
        if not data or self._client is None:
            return
        try:
            self._client.sendall(data)
        except OSError:
            self._drop_client(selector)

    def _run(self) -> None:
        with selectors.DefaultSelector() as selector:
            selector.register(self._listener, selectors.EVENT_READ, "listen")
            try:
                while not self._stop.is_set():
                    for key, _ in selector.select(timeout=self._wait_s()):
                        if key.data == "listen":
                            try:
                                conn, _addr = self._listener.accept()
                            except OSError:
                                continue
                            self._drop_client(selector)
                            conn.setblocking(True)
                            conn.settimeout(1.0)
                            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                            self._client = conn
                            self.connections += 1
                            selector.register(conn, selectors.EVENT_READ, "client")
                            with self._lock:
                                self.model.reset_session()
                        elif key.data == "client" and self._client is not None:
                            try:
                                data = self._client.recv(_READ_SIZE)
                            except OSError:
                                data = b""
                            if not data:  # the client went away: the robot's session ends with it
                                self._drop_client(selector)
                                with self._lock:
                                    self.model.reset_session()
                                continue
                            with self._lock:
                                out = self.model.receive(data, self.sim_now())
                            self._send(out, selector)
                    with self._lock:
                        out = self.model.advance(self.sim_now())
                    self._send(out, selector)
            finally:
                self._drop_client(selector)

    def _close_io(self) -> None:
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
                        with self._lock:
                            out = self.model.receive(data, self.sim_now())
                        self._write(out)
                with self._lock:
                    out = self.model.advance(self.sim_now())
                self._write(out)

    def _close_io(self) -> None:
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)


def _model(world: World, name: str, pose: np.ndarray | None, model_options: dict[str, Any]) -> VirtualP3AT:
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
    model = _model(world, name, pose, dict(model_options))
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
    model = _model(world, name, pose, dict(model_options))
    try:
        return PtyServer(model, clock, time_scale)
    except BaseException:
        model.close()
        raise
