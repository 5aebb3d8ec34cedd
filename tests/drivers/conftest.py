"""A small ARCOS peer built from the codec, for driver tests that need protocol corner cases on demand
(a robot still streaming from an old session, one that goes silent, one that never sends CONFIG).
The full virtual robot in ``mocks.p3at`` is tested against separately (test_arcos_e2e.py)."""
from __future__ import annotations

import math
import os
import select
import socket
import threading
import time
import tty
from collections.abc import Iterator

import pytest

from drivers.arcos.codec import (
    Identity,
    PacketParser,
    RobotConfig,
    Sip,
    decode_command,
    encode_config,
    encode_identity,
    encode_packet,
    encode_sip,
)
from drivers.arcos.commands import Command
from drivers.errors import ProtocolError


class FakePeer:
    """Robot side of ARCOS over a pty or a TCP socket on 127.0.0.1 (one client at a time)."""

    def __init__(self, transport: str, *, streaming_from_old_session: bool = False, send_config: bool = True,
                 subtype: str = "p3at-sh") -> None:
        self.transport = transport
        self.identity = Identity("FakePeer", "Pioneer", subtype)
        self.send_config = send_config
        self.streaming = streaming_from_old_session  # SIPs before any handshake
        self.silent = False  # when True, reads are discarded and nothing is sent
        self.sips = True  # when False, commands are answered but no SIP is sent (a session that opens mute)
        self.commands: list[tuple[int, object]] = []
        self.x = self.y = self.th = 0.0
        self.v = self.w = 0.0
        self.motors = False
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._conn: socket.socket | None = None
        self._drop = False
        self._synced = 0
        if transport == "pty":
            self._master, slave = os.openpty()
            tty.setraw(slave)
            self.url = os.ttyname(slave)
            self._slave = slave  # keep open so the master never sees EIO between clients
        else:
            self._server = socket.socket()
            self._server.bind(("127.0.0.1", 0))
            self._server.listen(1)
            self.url = f"socket://127.0.0.1:{self._server.getsockname()[1]}"
        self._thread = threading.Thread(target=self._run, name="fake-arcos-peer", daemon=True)
        self._thread.start()

    # -- transport
    def _recv(self, timeout: float) -> bytes:
        if self.transport == "pty":
            ready, _, _ = select.select([self._master], [], [], timeout)
            return os.read(self._master, 4096) if ready else b""
        if self._conn is None:
            ready, _, _ = select.select([self._server], [], [], timeout)
            if ready:
                self._conn, _ = self._server.accept()
            return b""
        ready, _, _ = select.select([self._conn], [], [], timeout)
        if not ready:
            return b""
        data = self._conn.recv(4096)
        if not data:  # the client hung up: a new client starts a new session
            self._hang_up()
        return data

    def _send(self, payload: bytes) -> None:
        if self.silent:
            return
        packet = encode_packet(payload)
        try:
            if self.transport == "pty":
                os.write(self._master, packet)
            elif self._conn is not None:
                self._conn.sendall(packet)
        except OSError:
            pass

    # -- robot behaviour
    def _handle(self, cmd: int, arg: object) -> None:
        self.commands.append((cmd, arg))
        if not self.streaming and cmd in (0, 1, 2) and self._synced < 3:
            if cmd == self._synced:
                self._send(encode_identity(self.identity) if cmd == 2 else bytes([cmd]))
                self._synced += 1
            else:
                self._synced = 0
            return
        if cmd == Command.OPEN:
            self.streaming = True
        elif cmd == Command.CLOSE:
            self.streaming = False
            self._synced = 0
            self.v = self.w = 0.0
        elif cmd == Command.CONFIG and self.send_config:
            self._send(encode_config(RobotConfig(type="Pioneer", subtype=self.identity.subtype, serial_num="F1",
                                                 unused=0, rot_vel_top=300, trans_vel_top=1200, rot_accel_top=500,
                                                 trans_accel_top=2000, pwm_max=500, name="FakePeer", sip_cycle=100,
                                                 host_baud=0, aux1_baud=0)))
        elif cmd == Command.ENABLE:
            self.motors = bool(arg)
        elif cmd == Command.VEL and self.motors:
            self.v = int(arg) / 1000.0
        elif cmd == Command.RVEL and self.motors:
            self.w = math.radians(int(arg))
        elif cmd in (Command.STOP, Command.E_STOP):
            self.v = self.w = 0.0
        elif cmd == Command.SETO:
            self.x = self.y = self.th = 0.0

    def _sip(self) -> bytes:
        mm = lambda m: round(m * 1000) & 0x7FFF  # noqa: E731
        return encode_sip(Sip(moving=bool(self.v or self.w), xpos=mm(self.x), ypos=mm(self.y),
                              thpos=round(self.th / 0.001534), lvel=round(self.v * 1000), rvel=round(self.v * 1000),
                              battery=130, flags=int(self.motors), sonars=((0, 1500), (7, 2500))))

    def _run(self) -> None:
        parser = PacketParser()
        next_sip = time.monotonic()
        while not self._stop.is_set():
            if self._drop:
                self._hang_up()
            try:
                data = self._recv(0.02)
            except OSError:
                data = b""
            if self.silent:
                continue
            with self._lock:
                for payload in parser.feed(data):
                    try:
                        self._handle(*decode_command(payload))
                    except ProtocolError:
                        pass
                now = time.monotonic()
                if now >= next_sip:
                    next_sip = now + 0.1
                    if self.streaming and self.sips:
                        self.x += self.v * 0.1 * math.cos(self.th)
                        self.y += self.v * 0.1 * math.sin(self.th)
                        self.th += self.w * 0.1
                        self._send(self._sip())

    def send_burst(self, n: int, x0: float) -> None:
        """n SIPs in one write (x = x0, x0 + 1 mm, ...): SIPs that queued while the client was not reading."""
        with self._lock:
            packets = []
            for k in range(n):
                self.x = x0 + 0.001 * k
                packets.append(encode_packet(self._sip()))
            data = b"".join(packets)
            if self.transport == "pty":
                os.write(self._master, data)
            elif self._conn is not None:
                self._conn.sendall(data)

    def drop_client(self) -> None:
        """TCP: hang up on the client (the robot was restarted); done by the peer's own thread."""
        self._drop = True

    def _hang_up(self) -> None:
        self._drop = False
        if self._conn is not None:
            self._conn.close()
            self._conn = None
        self.streaming = False
        self._synced = 0

    def close(self) -> None:
        self._stop.set()
        # The descriptors close only once the thread has ended: closed under it, their numbers go to the next
        # test's pty or socket (the lowest free numbers), and a thread still running would read that test's bytes.
        # It ends within one 20 ms poll of running; the bound is a failure bound (a starved thread once did not
        # run for 1.75 s; this waited 2 s and then closed the descriptors anyway).
        self._thread.join(timeout=60.0)
        assert not self._thread.is_alive(), "the fake peer's thread did not stop"
        if self.transport == "pty":
            os.close(self._master)
            os.close(self._slave)
        else:
            if self._conn is not None:
                self._conn.close()
            self._server.close()


@pytest.fixture
def fake_peer_factory() -> Iterator:
    """FakePeer over a pty (the transports themselves are covered end to end against mocks.p3at)."""
    peers: list[FakePeer] = []

    def make(**kwargs: object) -> FakePeer:
        peer = FakePeer("pty", **kwargs)
        peers.append(peer)
        return peer
    yield make
    for peer in peers:
        peer.close()


@pytest.fixture
def tcp_peer() -> Iterator[FakePeer]:
    peer = FakePeer("tcp")
    yield peer
    peer.close()
