"""The P3-AT driver: ARCOS over any pyserial URL (a tty, a pty path, ``socket://127.0.0.1:8101``).

The wire format, the state tracking and the clamping are pure modules (``codec``, ``state``, ``motion``); this
module is the thin I/O around them: the port, the handshake, a named daemon reader thread that keeps the
latest :class:`~drivers.arcos.state.RobotState`, sends PULSE whenever nothing was sent for 500 ms, notices a
lost link and reconnects with backoff (motors disabled on return).

Threads: commands may be called from any thread (writes are serialised); subscriber callbacks run on the
reader thread and must return quickly. The clock is injected for time stamps and timeouts; it must advance
with real time (the reader waits on real time), e.g. ``time.monotonic`` (default) or ``time.time``, or be a
lockstep simulated clock with ``wait_for(predicate, timeout=...)`` (``mocks.simclock.SimClock``): then
:meth:`P3AT.wait_for_state` and :meth:`P3AT.request_config` wait on that clock, in its seconds. A participant of
lockstep that blocked on the wall clock instead would hold simulated time still, so the packet it waits for could
never come: it waited out its whole timeout and failed.
"""
from __future__ import annotations

import collections
import errno
import logging
import os
import re
import threading
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import serial

from drivers.arcos import motion
from drivers.arcos.codec import (
    SIP_IDS,
    EncoderCounts,
    Identity,
    IoPacket,
    PacketId,
    PacketParser,
    ParserStats,
    decode_config,
    decode_encoder,
    decode_identity,
    decode_io,
    decode_sip,
    encode_command,
)
from drivers.arcos.commands import BAUD_CODES, SYNC0, SYNC2, Command
from drivers.arcos.params import RobotParams, builtin_params, load_params
from drivers.arcos.state import RobotState, StateTracker
from drivers.errors import DeviceNotFoundError, DriverTimeoutError, NotConnectedError, ProtocolError

log = logging.getLogger(__name__)

READ_TIMEOUT = 0.05  # s; the reader wakes at least this often (keep-alive and link checks)


class ClampWarning(UserWarning):
    """A command value was outside the robot's limits and was clamped."""


@dataclass(frozen=True)
class LinkEvent:
    """Reported to link subscribers: ``kind`` is "lost" or "restored"."""

    kind: str
    stamp: float
    session: int  # the session that was lost / the new session
    reason: str


Unsubscribe = Callable[[], None]


class _Subscribers:
    def __init__(self, what: str) -> None:
        self._what = what
        self._callbacks: list[Callable[[Any], None]] = []
        self._lock = threading.Lock()

    def add(self, callback: Callable[[Any], None]) -> Unsubscribe:
        with self._lock:
            self._callbacks.append(callback)

        def remove() -> None:
            with self._lock:
                if callback in self._callbacks:
                    self._callbacks.remove(callback)
        return remove

    def call(self, item: Any) -> None:
        with self._lock:
            callbacks = list(self._callbacks)
        for callback in callbacks:
            try:
                callback(item)
            except Exception:  # a subscriber's bug must not stop the reader (and so the keep-alive)
                log.exception("%s subscriber %r raised", self._what, callback)


class _ReadFailedError(NotConnectedError):
    """A read the port refused (the peer closed or reset the link). Its message names the port, for the caller of
    a session step; ``reason`` is what the link's "lost" event says: pyserial's own words, as for any I/O error."""

    def __init__(self, url: str, cause: BaseException) -> None:
        super().__init__(f"{url}: link dropped ({cause})")
        self.reason = f"I/O error: {cause}"


def _close_quietly(port: Any) -> None:
    try:
        port.close()
    except (serial.SerialException, OSError):
        pass


def is_local_serial_device(url: str) -> bool:
    """A real serial port, where HOSTBAUD makes sense (not a URL scheme, not a pseudo-terminal)."""
    if "://" in url:
        return False
    return not os.path.realpath(url).startswith("/dev/pts/")


def hostbaud_code(url: str, config: Any, baudrate: int, fast_baudrate: int | None) -> int | None:
    """The HOSTBAUD argument to switch to ``fast_baudrate``, or ``None`` to stay: only on a real serial port, only
    when the robot's CONFIG AutoBaud byte is 2 (as ARIA decides), only to a rate the protocol has a code for."""
    if fast_baudrate is None or fast_baudrate == baudrate or config is None or config.auto_baud != 2:
        return None
    if not is_local_serial_device(url):
        return None
    return next((code for code, rate in BAUD_CODES.items() if rate == fast_baudrate), None)


class P3AT:
    """A Pioneer P3-AT (or ARCOS simulator) at ``url``.

    ``params``: a :class:`RobotParams`, a path to a parameter file, or ``None`` to pick the built-in set from the
    SYNC2 subtype. ``fast_baudrate``: switch to this rate with HOSTBAUD on real serial ports when the robot's
    CONFIG AutoBaud byte is 2 (``None`` to stay at ``baudrate``). ``link_timeout``: seconds without any packet
    before the link counts as lost. ``reconnect``: reconnect after a lost link with backoff up to
    ``max_backoff`` seconds.
    """

    def __init__(self, url: str, *, params: RobotParams | str | os.PathLike | None = None,
                 clock: Callable[[], float] = time.monotonic, baudrate: int = 9600,
                 fast_baudrate: int | None = 38400, link_timeout: float = 4.0, pulse_interval: float = 0.5,
                 reconnect: bool = True, max_backoff: float = 8.0, handshake_tries: int = 10,
                 reply_timeout: float = 0.5, config_timeout: float = 1.0) -> None:
        self.url = url
        self._user_params = load_params(params) if isinstance(params, str | os.PathLike | Path) else params
        self.params: RobotParams | None = self._user_params
        self.clock = clock
        self.baudrate = baudrate
        self.fast_baudrate = fast_baudrate
        self.link_timeout = link_timeout
        self.pulse_interval = pulse_interval
        self.reconnect = reconnect
        self.max_backoff = max_backoff
        self.handshake_tries = handshake_tries
        self.reply_timeout = reply_timeout
        self.config_timeout = config_timeout

        self.identity: Identity | None = None
        self.config: Any = None  # RobotConfig from the last CONFIG packet, None if the robot sent none
        self.encoders: EncoderCounts | None = None
        self.io: IoPacket | None = None
        self.session = 0
        self.parser = PacketParser()
        self.bad_packets = 0  # packets with a good checksum that did not decode
        self.bytes_written = 0  # every byte handed to the port (a simulator's lockstep clock counts on it)
        self.unhandled_packets = 0  # packets of an ID the driver does not use

        self._port: Any = None
        self._write_lock = threading.Lock()
        self._cond = threading.Condition()
        self._state: RobotState | None = None
        self._tracker: StateTracker | None = None
        self._pending: collections.deque[bytes] = collections.deque()
        self._last_rx = 0.0
        self._last_tx = 0.0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closed = False
        self._link_up = False
        self._lost_reason = ""  # why the link was last lost, for NotConnectedError messages
        self._state_subscribers = _Subscribers("state")
        self._link_subscribers = _Subscribers("link")
        self._packet_subscribers = _Subscribers("packet")

    # ------------------------------------------------------------------ lifecycle
    def __enter__(self) -> P3AT:
        if not self._link_up:
            self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def connected(self) -> bool:
        return self._link_up and not self._closed

    @property
    def stats(self) -> ParserStats:
        return self.parser.stats

    def connect(self, *, enable_motors: bool = False) -> P3AT:
        """Open the port, SYNC0/1/2, OPEN, request CONFIG, optionally switch baud rate, wait for the first SIP.

        Raises :class:`DeviceNotFoundError` (no such device), :class:`NotConnectedError` (cannot open),
        :class:`DriverTimeoutError` (no handshake or no SIPs), :class:`ProtocolError`.
        """
        if self._closed:
            raise NotConnectedError(f"{self.url}: this P3AT was closed; make a new one")
        if self._link_up:  # already connected (e.g. by ``with P3AT(url) as robot``): still honour the request
            if enable_motors:
                self.motors_on()
            return self
        try:
            self._open_session()
        except BaseException:
            self._close_port()
            raise
        self._stop.clear()
        self._thread = threading.Thread(target=self._reader, name=f"arcos-reader {self.url}", daemon=True)
        self._thread.start()
        if enable_motors:
            self.motors_on()
        return self

    def close(self) -> None:
        """Stop the reader, send ENABLE 0 then CLOSE, close the port. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
        port = self._port
        if port is not None and self._link_up:
            try:
                self._write(encode_command(Command.ENABLE, 0))
                self._write(encode_command(Command.CLOSE, 1))
                port.flush()
            except (serial.SerialException, OSError, NotConnectedError) as exc:
                log.debug("%s: could not say goodbye: %s", self.url, exc)
        self._link_up = False
        self._close_port()
        with self._cond:
            self._cond.notify_all()

    # ------------------------------------------------------------------ subscribers and state
    def subscribe(self, callback: Callable[[RobotState], None]) -> Unsubscribe:
        """Call ``callback(state)`` on the reader thread after every SIP. Returns a function that unsubscribes."""
        return self._state_subscribers.add(callback)

    def subscribe_link(self, callback: Callable[[LinkEvent], None]) -> Unsubscribe:
        """Call ``callback(LinkEvent)`` when the link is lost or restored."""
        return self._link_subscribers.add(callback)

    def subscribe_packets(self, callback: Callable[[Any], None]) -> Unsubscribe:
        """Call ``callback(packet)`` for every CONFIG (RobotConfig), ENCODER (EncoderCounts) and IO (IoPacket)."""
        return self._packet_subscribers.add(callback)

    @property
    def state(self) -> RobotState | None:
        """The latest state (``None`` before the first SIP of a session that is up).

        Raises :class:`NotConnectedError` at once while the link is down (never connected, lost, reconnecting,
        closed): a stale state must not pass for the robot's present one. :attr:`last_state` keeps it.
        """
        with self._cond:
            self._require_link()
            s = self._state
            return s if s is not None and s.session == self.session else None

    @property
    def last_state(self) -> RobotState | None:
        """The last state received, even after the link was lost or closed (``None`` before any SIP); for
        reports and diagnostics, never for control."""
        with self._cond:
            return self._state

    def wait_for_state(self, timeout: float = 2.0,
                       predicate: Callable[[RobotState], bool] | None = None) -> RobotState:
        """Block until a state newer than the current one (and matching ``predicate``) arrives.

        Raises :class:`NotConnectedError` at once if the link is down when called or as soon as it is lost
        while waiting (closed, lost, reconnecting), :class:`DriverTimeoutError` after ``timeout`` seconds of a
        link that is up but brings no matching state (seconds of the driver's clock: simulated ones on a lockstep
        clock).
        """
        with self._cond:
            self._require_link()
            start = self._state
            start_key = (start.session, start.sequence) if start else None

            def ready() -> bool:
                s = self._state
                if not self.connected:
                    return True
                return (s is not None and (s.session, s.sequence) != start_key
                        and (predicate is None or predicate(s)))
            if self._lockstep:
                self._cond.release()  # the reader needs the condition to deliver the state
                try:
                    got = bool(self.clock.wait_for(ready, timeout=timeout))
                finally:
                    self._cond.acquire()
            else:
                got = self._cond.wait_for(ready, timeout)
            if not got:
                raise DriverTimeoutError(f"{self.url}: no matching robot state within {timeout:g} s")
            self._require_link()
            assert self._state is not None
            return self._state

    def _require_link(self) -> None:
        if self._closed:
            raise NotConnectedError(f"{self.url}: closed")
        if not self._link_up:
            why = f" ({self._lost_reason})" if self._lost_reason else ""
            raise NotConnectedError(f"{self.url}: link lost{why}" if self.session else f"{self.url}: not connected")

    # ------------------------------------------------------------------ commands
    def send_command(self, cmd: int, arg: int | str | bytes | None = None) -> None:
        """Send one raw ARCOS command (see :class:`~drivers.arcos.commands.Command`).

        Raises :class:`NotConnectedError` while the link is down (closed, lost, or reconnecting).
        """
        self._write(encode_command(cmd, arg), user=True)

    def motors_on(self) -> None:
        self.send_command(Command.ENABLE, 1)

    def motors_off(self) -> None:
        self.send_command(Command.ENABLE, 0)

    def set_velocity(self, v: float, w: float = 0.0) -> None:
        """Drive at ``v`` m/s forward and ``w`` rad/s counter-clockwise (VEL + RVEL), clamped to the limits."""
        self._send_motion(motion.velocity(self._params(), v, w))

    def set_wheel_velocities(self, left: float, right: float) -> None:
        """Independent wheel speeds in m/s (VEL2, resolution Vel2Divisor = 20 mm/s)."""
        self._send_motion(motion.wheel_velocities(self._params(), left, right))

    def move(self, distance: float) -> None:
        """Drive ``distance`` metres (negative backwards) under the robot's position control (MOVE)."""
        self._send_motion(motion.move(self._params(), distance))

    def set_heading(self, theta: float) -> None:
        """Turn to absolute heading ``theta`` rad in the odometry frame (HEAD)."""
        self._send_motion(motion.heading(self._params(), theta))

    def turn(self, dtheta: float) -> None:
        """Turn by ``dtheta`` rad relative to the current heading, positive counter-clockwise (DHEAD)."""
        self._send_motion(motion.delta_heading(self._params(), dtheta))

    def stop(self) -> None:
        """Stop moving (STOP); motors stay enabled."""
        self.send_command(Command.STOP)

    def emergency_stop(self) -> None:
        """E_STOP: stop at once with maximum deceleration."""
        self.send_command(Command.E_STOP, 1)

    def sonar(self, on: bool) -> None:
        """Sonars on or off (SONAR)."""
        self.send_command(Command.SONAR, 1 if on else 0)

    def reset_odometry(self) -> None:
        """SETO: the robot's odometry restarts at (0, 0, 0); the state follows once the robot has done it."""
        with self._cond:
            if self._tracker is not None:
                self._tracker.expect_reset()
        self.send_command(Command.SETO)

    def set_velocity_limits(self, max_v: float | None = None, max_w: float | None = None) -> None:
        """Maximum translational (m/s, SETV) and rotational (rad/s, SETRV) velocity."""
        self._send_motion(motion.velocity_limits(self._params(), max_v, max_w))

    def set_acceleration_limits(self, accel: float | None = None, decel: float | None = None,
                                rot_accel: float | None = None, rot_decel: float | None = None) -> None:
        """Translational (m/s², SETA) and rotational (rad/s², SETRA) acceleration and deceleration."""
        self._send_motion(motion.acceleration_limits(self._params(), accel, decel, rot_accel, rot_decel))

    def request_encoders(self, on: bool = True) -> None:
        """Stream ENCODER packets after each SIP (read ``encoders`` or subscribe_packets)."""
        self.send_command(Command.ENCODER, 1 if on else 0)

    def request_io(self, mode: int = 1) -> None:
        """IOREQUEST: 1 one IO packet, >1 continuous, 0 stop (read ``io`` or subscribe_packets)."""
        self.send_command(Command.IOREQUEST, mode)

    def request_config(self, timeout: float = 1.0) -> Any:
        """Ask for a CONFIG packet and return it (``RobotConfig``), or ``None`` if none came in ``timeout`` s (of the
        driver's clock, as :meth:`wait_for_state`)."""
        got: list[Any] = []
        done = threading.Event()

        def on_packet(packet: Any) -> None:
            if type(packet).__name__ == "RobotConfig":
                got.append(packet)
                done.set()
        unsubscribe = self.subscribe_packets(on_packet)
        try:
            self.send_command(Command.CONFIG, 1)
            if self._lockstep:
                self.clock.wait_for(done.is_set, timeout=timeout)
            else:
                done.wait(timeout)
        finally:
            unsubscribe()
        return got[0] if got else None

    @property
    def _lockstep(self) -> bool:
        """Is the clock a lockstep clock (it offers ``wait_for(predicate, timeout=...)``)? Waits then go through it."""
        return callable(getattr(self.clock, "wait_for", None))

    # ------------------------------------------------------------------ internals: writing
    def _params(self) -> RobotParams:
        if self.params is None:
            raise NotConnectedError(f"{self.url}: not connected (no parameter set yet)")
        return self.params

    def _send_motion(self, result: motion.Result) -> None:
        packets, notes = result
        for note in notes:
            log.warning("%s: %s", self.url, note)
            warnings.warn(note, ClampWarning, stacklevel=3)
        for packet in packets:
            self._write(packet, user=True)

    def _write(self, packet: bytes, user: bool = False) -> None:
        with self._write_lock:
            port = self._port
            if port is None or (user and (self._closed or not self._link_up)):
                raise NotConnectedError(f"{self.url}: not connected")
            try:
                port.write(packet)
            except (serial.SerialException, OSError) as exc:
                raise NotConnectedError(f"{self.url}: write failed: {exc}") from exc
            self.bytes_written += len(packet)
            self._last_tx = self.clock()

    # ------------------------------------------------------------------ internals: reading
    def _read_some(self) -> None:
        """One read, returning as soon as any byte is there with everything already waiting; parsed payloads go
        to ``_pending``.

        Prompt because the reader thread stamps each packet when it dispatches it: a batching ``read(4096)``
        returns only at READ_TIMEOUT, which stamped every SIP up to 50 ms late (the runtime saw a 100 ms cycle
        as gaps of 50 and 150 ms). At 9600 baud this wakes a few hundred times a second, as ARIA's reader does.
        """
        port = self._port
        try:
            data = port.read(max(1, port.in_waiting))
            if data and port.in_waiting:
                # more is waiting: take it all now, without waiting (a socket:// port reports 0 or 1 waiting bytes,
                # so the line above reads one byte; a reader that fell behind would catch up a byte per call, and
                # stamp a backlogged SIP seconds after it was sent)
                timeout, port.timeout = port.timeout, 0
                try:
                    data += port.read(1 << 16)
                finally:
                    port.timeout = timeout
        except (serial.SerialException, OSError) as exc:
            # the peer closed or reset the link (a bridge that drops the connection during the handshake): a lost
            # link, as the reader thread reports one, not pyserial's exception (`robot info`: 'internal error')
            raise _ReadFailedError(self.url, exc) from exc
        if data:
            self._pending.extend(self.parser.feed(data))

    def _next_packet(self, timeout: float) -> bytes | None:
        """The next packet, or None after ``timeout``; raises NotConnectedError once the driver is closing (the
        session's waits loop on this until their deadlines: returning None would spin them until then)."""
        deadline = self.clock() + timeout
        while not self._pending:
            if self._stop.is_set():
                raise NotConnectedError(f"{self.url}: closed")
            if self.clock() >= deadline:
                return None
            self._read_some()
        return self._pending.popleft()

    def _drain(self, quiet: float = 0.3, limit: float = 2.0) -> None:
        """Read and discard until the line has been quiet for ``quiet`` s (at most ``limit`` s)."""
        start = last = self.clock()
        while self.clock() - last < quiet and self.clock() - start < limit and not self._stop.is_set():
            if self._port.read(4096):
                last = self.clock()
        self._pending.clear()
        self.parser.reset()

    # ------------------------------------------------------------------ internals: session
    def _open_port(self) -> None:
        problem = url_problem(self.url)
        if problem is not None:
            raise DeviceNotFoundError(f"{self.url}: {problem}")
        try:
            self._port = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=READ_TIMEOUT,
                                               write_timeout=2.0)
        except serial.SerialException as exc:
            if getattr(exc, "errno", None) == errno.ENOENT or "No such file" in str(exc):
                raise DeviceNotFoundError(f"{self.url}: no such device ({exc}){tcp_address_hint(self.url)}") from exc
            raise NotConnectedError(f"{self.url}: cannot open: {exc}") from exc
        except ValueError as exc:  # pyserial's answer to a malformed URL
            raise DeviceNotFoundError(f"{self.url}: {exc}") from exc

    def _close_port(self, background: bool = False) -> None:
        """Close the port; ``background`` hands the closing to a short daemon thread, because pyserial's
        ``socket://`` close sleeps 0.3 s ("give the server some time"), which must not delay the news of a
        lost link nor ``close()`` joining the reader."""
        with self._write_lock:
            port, self._port = self._port, None
        if port is None:
            return
        if background:
            threading.Thread(target=_close_quietly, args=(port,), name=f"arcos-closer {self.url}", daemon=True).start()
        else:
            _close_quietly(port)

    def _handshake(self) -> Identity:
        for attempt in range(self.handshake_tries):
            if self._stop.is_set():
                break
            stage = SYNC0
            while stage <= SYNC2:
                self._write(encode_command(stage))
                reply = self._next_packet(self.reply_timeout)
                if reply is None:
                    log.debug("%s: no reply to SYNC%d (attempt %d)", self.url, stage, attempt + 1)
                    break
                if reply[0] in SIP_IDS:  # still streaming from an old session
                    log.info("%s: robot still streaming SIPs; sending CLOSE and draining", self.url)
                    self._write(encode_command(Command.CLOSE, 1))
                    self._drain()
                    break
                if reply[0] != stage:
                    log.debug("%s: SYNC%d answered with ID 0x%02X; restarting", self.url, stage, reply[0])
                    self._drain(quiet=0.15, limit=1.0)
                    break
                if stage == SYNC2:
                    return decode_identity(reply)
                stage += 1
        raise DriverTimeoutError(f"{self.url}: no ARCOS handshake after {self.handshake_tries} tries "
                                 "(is it a P3-AT or an ARCOS simulator, at the right baud rate?)")

    def _open_session(self) -> None:
        """Port + handshake + OPEN + CONFIG (+ HOSTBAUD) + first SIP. Runs with no reader thread active."""
        self._open_port()
        self.parser.reset()
        self._pending.clear()
        self.identity = self._handshake()
        params = self._user_params
        if params is None:
            params = builtin_params(self.identity.subtype)
        elif params.subtype.lower() != self.identity.subtype.lower():
            log.warning("%s: robot reports subtype %r but parameter set %s is for %r", self.url,
                        self.identity.subtype, params.source, params.subtype)
        self.params = params
        self.session += 1
        with self._cond:
            self._tracker = StateTracker(params, session=self.session)
        self._write(encode_command(Command.OPEN, 1))
        self._write(encode_command(Command.CONFIG, 1))
        now = self.clock()
        self._last_rx = now
        deadline = now + self.config_timeout
        config = None
        while config is None and self.clock() < deadline:
            payload = self._next_packet(deadline - self.clock())
            if payload is not None:
                self._dispatch(payload, self.clock())
                if payload[0] == PacketId.CONFIG:
                    config = self.config
        code = hostbaud_code(self.url, config, self.baudrate, self.fast_baudrate)
        if code is not None:
            self._switch_baud(code)
        self._link_up = True
        deadline = self.clock() + max(2.0, self.link_timeout / 2)
        while self._state is None or self._state.session != self.session:
            if self.clock() >= deadline:
                self._link_up = False
                raise DriverTimeoutError(f"{self.url}: handshake done but no SIP after OPEN")
            payload = self._next_packet(deadline - self.clock())
            if payload is not None:
                self._dispatch(payload, self.clock())

    def _switch_baud(self, code: int) -> None:
        self._write(encode_command(Command.HOSTBAUD, code))
        self._port.flush()
        time.sleep(0.05)
        self._port.baudrate = self.fast_baudrate
        self.parser.reset()
        self._pending.clear()
        deadline = self.clock() + 1.0
        while self.clock() < deadline:
            payload = self._next_packet(deadline - self.clock())
            if payload is not None and payload[0] in SIP_IDS:
                self._dispatch(payload, self.clock())
                log.info("%s: switched to %d baud", self.url, self.fast_baudrate)
                return
        log.warning("%s: no SIP at %d baud after HOSTBAUD; staying at %d", self.url, self.fast_baudrate,
                    self.baudrate)
        self._port.baudrate = self.baudrate
        self.parser.reset()

    def _dispatch(self, payload: bytes, now: float) -> None:
        self._last_rx = now
        ident = payload[0]
        try:
            if ident in SIP_IDS:
                sip = decode_sip(payload)
                with self._cond:
                    if self._tracker is None:
                        return
                    state = self._tracker.update(sip, now)
                    self._state = state
                    self._cond.notify_all()
                self._state_subscribers.call(state)
                return
            if ident == PacketId.CONFIG:
                packet: Any = decode_config(payload)
                self.config = packet
            elif ident == PacketId.ENCODER:
                packet = self.encoders = decode_encoder(payload)
            elif ident == PacketId.IO:
                packet = self.io = decode_io(payload)
            else:
                self.unhandled_packets += 1
                return
        except ProtocolError as exc:
            self.bad_packets += 1
            log.debug("%s: undecodable packet 0x%02X: %s", self.url, ident, exc)
            return
        self._packet_subscribers.call(packet)

    # ------------------------------------------------------------------ internals: the reader thread
    def _reader(self) -> None:
        while not self._stop.is_set():
            if not self._link_up:
                if not self._reconnect_loop():
                    return
                continue
            try:
                self._read_some()
                now = self.clock()
                while self._pending:
                    self._dispatch(self._pending.popleft(), now)
                if now - self._last_rx > self.link_timeout:
                    self._lose_link(f"no packet for {now - self._last_rx:.1f} s")
                elif now - self._last_tx >= self.pulse_interval:
                    self._write(encode_command(Command.PULSE))
            except _ReadFailedError as exc:   # a dropped read: the reason it carries (not its URL again)
                if not self._stop.is_set():
                    self._lose_link(exc.reason)
            except (serial.SerialException, OSError, NotConnectedError) as exc:
                if not self._stop.is_set():
                    self._lose_link(f"I/O error: {exc}")

    def _lose_link(self, reason: str) -> None:
        log.warning("%s: link lost (%s)", self.url, reason)
        self._lost_reason = reason
        self._link_up = False
        with self._cond:  # waiters first: they raise NotConnectedError now
            self._cond.notify_all()
        self._close_port(background=True)
        self._link_subscribers.call(LinkEvent("lost", self.clock(), self.session, reason))

    def _reconnect_loop(self) -> bool:
        """Reconnect with exponential backoff until it works (True) or the driver is closed (False)."""
        if not self.reconnect:
            return False
        backoff = 0.25
        while not self._stop.wait(backoff):
            try:
                self._open_session()
                self._write(encode_command(Command.ENABLE, 0))  # come back with motors disabled
            except (serial.SerialException, OSError, NotConnectedError, DriverTimeoutError, ProtocolError,
                    DeviceNotFoundError) as exc:
                self._link_up = False
                self._close_port()
                if self._stop.is_set():
                    return False
                log.info("%s: reconnect failed (%s); retrying in %.1f s", self.url, exc, backoff)
                backoff = min(backoff * 2, self.max_backoff)
                continue
            log.warning("%s: link restored (session %d)", self.url, self.session)
            self._link_subscribers.call(LinkEvent("restored", self.clock(), self.session, "reconnected"))
            return True
        return False


_HOST_PORT = re.compile(r"[A-Za-z0-9_.-]+:[0-9]+|\[[0-9A-Fa-f:.]+\]:[0-9]+")


def tcp_address_hint(url: str) -> str:
    """'; a TCP address is written socket://HOST:PORT' for a URL that is a bare HOST:PORT (pyserial takes it for a
    file name and says 'No such file or directory'); '' otherwise."""
    return f"; a TCP address is written socket://{url}" if _HOST_PORT.fullmatch(url) else ""


def url_problem(url: str) -> str | None:
    """What is wrong with a ``socket://`` URL pyserial would refuse with an error naming its internals (a missing
    port: "'<=' not supported between instances of 'int' and 'NoneType'"); None for any other URL."""
    if not url.startswith("socket://"):
        return None
    from urllib.parse import urlsplit

    try:
        port = urlsplit(url).port
    except ValueError:
        port = -1
    if port is None or not 0 < port < 65536:
        return "a TCP address needs a port from 1 to 65535: socket://HOST:PORT (MobileSim and AMRISim listen on 8101)"
    return None
