"""The virtual P3-AT's TCP and pty servers, spoken to by a raw pyserial client.

Most cases run the servers on the wall clock, which is their subject (the wall-clock server's thread, its I/O and
its deadlines); the lockstep server has its own cases at the end. On the wall clock at 1x a server's thread needs
1.6 % of a core, driven (measured alone, session 47: a 0.6 % floor of wake-ups and ~9 ms of physics per simulated
second); the cases with a clock moved by hand need only what one step costs. Every wait is a failure bound
(FAILURE_BOUND, 30 s, against well under 2 s of need).
"""

from __future__ import annotations

import os
import select
import socket
import threading
import time

import numpy as np
import pytest
import serial

from drivers.arcos.codec import PacketParser, decode_identity, decode_sip, encode_command, encode_packet
from drivers.arcos.commands import Command
from mocks.p3at import serve_pty, serve_tcp
from mocks.world import World


@pytest.fixture
def world() -> World:
    return World.load()


# A failure bound only (wall s): what the tests wait for takes well under a second of an idle machine's time, and
# a loaded 2-core machine may leave the server's thread unscheduled for a while; a passing run never waits it out.
FAILURE_BOUND = 30.0


def read_packets(port: serial.SerialBase, parser: PacketParser, want, timeout: float = FAILURE_BOUND) -> list[bytes]:
    """Read until ``want(packets)`` is true or the timeout passes; returns every packet read."""
    packets: list[bytes] = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not want(packets):
        packets += parser.feed(port.read(256))
    return packets


def handshake(port: serial.SerialBase, parser: PacketParser) -> str:
    """SYNC0..2 and OPEN; returns the robot's name from SYNC2."""
    name = None
    for sync in (0, 1, 2):
        port.write(encode_packet(bytes([sync])))
        got = read_packets(port, parser, lambda p, s=sync: any(x[0] == s for x in p))
        reply = next(x for x in got if x[0] == sync)
        if sync == 2:
            name = decode_identity(reply).name
    port.write(encode_command(Command.OPEN, 1))
    return name


def sips(packets: list[bytes]):
    return [decode_sip(p) for p in packets if p[0] in (0x32, 0x33)]


class ManualClock:
    """A wall clock the test moves by hand (a plain callable: the server runs on it as on ``time.monotonic``)."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


@pytest.mark.parametrize("transport", ["tcp", "pty"])
def test_handshake_sips_and_driving(world: World, transport: str) -> None:
    server = serve_tcp(world, "robot1", port=0) if transport == "tcp" else serve_pty(world, "robot1")
    with server:
        assert (server.port is None) == (transport == "pty")
        with serial.serial_for_url(server.url, baudrate=9600, timeout=0.05) as port:
            parser = PacketParser()
            assert handshake(port, parser) == "robot1"
            got = sips(read_packets(port, parser, lambda p: len(sips(p)) >= 5))
            assert len(got) >= 5 and not got[-1].moving
            start = world.pose("robot1")
            port.write(encode_command(Command.ENABLE, 1) + encode_command(Command.VEL, 300))
            got = sips(read_packets(port, parser, lambda p: any(s.lvel == 300 for s in sips(p))))
            assert got[-1].lvel == 300 and got[-1].moving
            assert world.pose("robot1")[0] > start[0] + 0.1
            port.write(encode_command(Command.CLOSE, 1))
    assert world.robot_names() == []  # close() took the robot out


def test_tcp_reconnect_gets_a_fresh_session(world: World) -> None:
    with serve_tcp(world, "robot1", port=0) as server:
        with serial.serial_for_url(server.url, timeout=0.05) as port:
            parser = PacketParser()
            handshake(port, parser)
            port.write(encode_command(Command.ENABLE, 1) + encode_command(Command.VEL, 200))
            read_packets(port, parser, lambda p: len(sips(p)) >= 3)
        # the server notices the hang-up in its own time: reconnect once it has (a new client arriving in the same
        # select() as the old one's hang-up is another case, not this test's)
        assert wait_until(lambda: not server.model.is_open)
        with serial.serial_for_url(server.url, timeout=0.05) as port:
            parser = PacketParser()
            # a fresh session: the motion stopped, and silence until the handshake (no SIPs from the old one).
            # Waited for (the server's thread accepts in its own time), then 0.4 s of listening for stray SIPs.
            assert wait_until(lambda: server.connections == 2 and server.model.v == 0.0)
            assert read_packets(port, parser, lambda p: False, timeout=0.4) == []
            assert handshake(port, parser) == "robot1"
            assert sips(read_packets(port, parser, lambda p: len(sips(p)) >= 2))


def test_two_robots_in_one_world(world: World) -> None:
    with serve_tcp(world, "robot1", port=0) as a, serve_tcp(world, "robot2", port=0) as b:
        assert a.port != b.port and sorted(world.robot_names()) == ["robot1", "robot2"]
        for server, name in ((a, "robot1"), (b, "robot2")):
            with serial.serial_for_url(server.url, timeout=0.05) as port:
                assert handshake(port, PacketParser()) == name


def test_pty_survives_client_reopen(world: World) -> None:
    with serve_pty(world, "robot2", np.array([8.0, 5.0, 0.0])) as server:
        with serial.serial_for_url(server.url, timeout=0.05) as port:
            handshake(port, PacketParser())
        with serial.serial_for_url(server.url, timeout=0.05) as port:
            parser = PacketParser()
            # a serial line does not tell the robot the client left: it is still streaming SIPs
            assert sips(read_packets(port, parser, lambda p: len(sips(p)) >= 2))
            port.write(encode_command(Command.CLOSE))
            time.sleep(0.3)
            port.reset_input_buffer()
            assert handshake(port, parser) == "robot2"


def test_garbage_over_tcp_does_not_stop_the_server(world: World) -> None:
    with serve_tcp(world, "robot1", port=0) as server:
        with serial.serial_for_url(server.url, timeout=0.05) as port:
            rng = np.random.default_rng(5)
            port.write(bytes(rng.integers(0, 256, 5000, dtype=np.uint8)))
            port.write(b"\xfa\xfb\x05\x63\x3b\x01\x00")  # truncated
            port.write(encode_packet(bytes([99])))  # unknown command before OPEN
            parser = PacketParser()
            port.write(encode_packet(b"\x00"))
            time.sleep(0.3)
            port.reset_input_buffer()
            assert handshake(port, parser) == "robot1"
            assert sips(read_packets(port, parser, lambda p: len(sips(p)) >= 2))
        assert server.error is None and server.model.parser.stats.dropped_bytes > 1000


def test_close_is_idempotent_and_joins_its_thread(world: World) -> None:
    def servers() -> set[str]:  # only the servers' threads: another test's thread may start meanwhile
        return {t.name for t in threading.enumerate() if t.name.startswith(("p3at-tcp-", "p3at-pty-"))}

    before = servers()
    server = serve_tcp(world, "robot1", port=0, time_scale=4.0)
    assert any(t.name.startswith("p3at-tcp-robot1") for t in threading.enumerate())
    server.close()
    server.close()
    assert servers() <= before
    with pytest.raises(OSError), serial.serial_for_url(server.url, timeout=0.1):
        pass
    pty = serve_pty(world, "robot1")
    assert any(t.name.startswith("p3at-pty-robot1") for t in threading.enumerate())
    pty.close()
    pty.close()
    assert servers() <= before



@pytest.mark.parametrize("transport", ["tcp", "pty"])
def test_a_thread_still_running_at_close_closes_its_port_itself_as_it_ends(world: World, transport: str) -> None:
    """close() waits join_timeout for the server's thread; one still running then (starved, or waiting for a
    lockstep baton) keeps its port or pty until it ends: closed under it, the numbers went to the next server's
    descriptors, which the old thread would read and write."""
    server = serve_tcp(world, "robot1", port=0) if transport == "tcp" else serve_pty(world, "robot1")
    fd = server._fds()[0]
    number = fd.fileno() if isinstance(fd, socket.socket) else fd
    held, resume = threading.Event(), threading.Event()
    emit = server._emit

    def hold(data: bytes) -> bool:  # the thread stops between steps (holding no lock), as a starved thread would
        held.set()
        resume.wait(FAILURE_BOUND)
        return emit(data)
    server._emit = hold
    assert held.wait(FAILURE_BOUND)
    server.join_timeout = 0.05
    server.close()
    os.fstat(number)  # still open: the thread may still use it
    assert world.robot_names() == []
    resume.set()
    assert wait_until(lambda: not server._thread.is_alive())
    with pytest.raises(OSError):
        os.fstat(number)


def wait_until(predicate, bound: float = FAILURE_BOUND) -> bool:
    """Poll ``predicate`` until it holds; ``bound`` (wall s) only limits how long a broken run hangs."""
    deadline = time.monotonic() + bound
    while not predicate() and time.monotonic() < deadline:
        time.sleep(0.005)
    return predicate()


def test_time_scale_speeds_up_the_sip_stream(world: World) -> None:
    clock = ManualClock()
    with serve_tcp(world, "robot1", port=0, time_scale=5.0, clock=clock) as server:
        with serial.serial_for_url(server.url, timeout=0.05) as port:
            parser = PacketParser()
            handshake(port, parser)
            assert wait_until(lambda: server.model.is_open)  # OPEN lands at clock 0
            clock.t = 1.0  # one wall second = 5 simulated seconds: 50 SIPs
            got = sips(read_packets(port, parser, lambda p: len(sips(p)) >= 50))
            assert [s.uc_time for s in got] == [100_000 * k for k in range(1, 51)]


def test_duplicate_name_and_bad_port_leave_nothing_behind(world: World) -> None:
    with serve_tcp(world, "robot1", port=0) as server:
        with pytest.raises(ValueError, match="already"):
            serve_tcp(world, "robot1", port=0)
        with pytest.raises(OSError):
            serve_tcp(world, "robot2", port=server.port)
        assert world.robot_names() == ["robot1"]


def test_time_scale_keeps_the_watchdog_in_wall_time(world: World) -> None:
    clock = ManualClock()
    with serve_tcp(world, "robot1", port=0, time_scale=5.0, clock=clock) as server:
        with serial.serial_for_url(server.url, timeout=0.05) as port:
            parser = PacketParser()
            handshake(port, parser)
            port.write(encode_command(Command.ENABLE, 1) + encode_command(Command.RVEL, 10))
            assert wait_until(lambda: server.model.motors_enabled)
            for k in range(1, 4):  # ARIA's keep-alive: a PULSE every 0.5 s of wall time (2.5 s simulated)
                clock.t = 0.5 * k
                assert wait_until(lambda: server.model.time >= 5.0 * clock.t - 0.01)
                sent = server.rx_bytes
                port.write(encode_command(Command.PULSE))
                assert wait_until(lambda sent=sent: server.rx_bytes > sent)
            assert server.model.w > 0 and server.model.stats.watchdog_stops == 0
            clock.t += 2.1  # then 2.1 s of wall time in silence: the watchdog stops the robot
            assert wait_until(lambda: server.model.stats.watchdog_stops == 1)



@pytest.mark.parametrize("transport", ["tcp", "pty"])
def test_a_server_thread_that_ran_late_does_not_take_waiting_pulses_for_silence(world: World, transport: str) -> None:
    """The watchdog counts the client's silence, not the server thread's: a thread that did not run for 2.5 s of
    wall time (a loaded machine; here a hook holds it after a step) and then finds the client's PULSE waiting
    cannot know when in those 2.5 s it came, and the robot drives on. It stopped the robot: the thread stepped
    the physics to its late 'now' before it looked at the link (seen as a CLI drive's robot going 1.75 s without
    a SIP beside two busy loops, 0.25 s short of a false watchdog stop)."""
    clock = ManualClock()
    server = serve_tcp(world, "robot1", port=0, time_scale=5.0, clock=clock) if transport == "tcp" \
        else serve_pty(world, "robot1", time_scale=5.0, clock=clock)
    with server, serial.serial_for_url(server.url, timeout=0.05) as port:
        handshake(port, PacketParser())
        port.write(encode_command(Command.ENABLE, 1) + encode_command(Command.RVEL, 10))
        assert wait_until(lambda: server.model.motors_enabled)
        sent = server.rx_bytes
        held, resume = threading.Event(), threading.Event()

        def hold(_model) -> None:  # the server's thread stops after a step, as a starved thread would
            held.set()
            resume.wait(FAILURE_BOUND)
        server.on_moved = hold
        assert held.wait(FAILURE_BOUND)
        clock.t = 2.5  # 12.5 s simulated, 2.5 s of wall time: past the 2 s watchdog
        port.write(encode_command(Command.PULSE))
        assert select.select(server._fds()[-1:], [], [], FAILURE_BOUND)[0]  # the PULSE waits on the link
        server.on_moved = None
        resume.set()
        assert wait_until(lambda: server.rx_bytes > sent and server.model.time >= 12.5 - 1e-6)
        assert server.model.stats.watchdog_stops == 0 and server.model.w > 0
        clock.t += 2.1  # and a silence the thread sees still stops the robot
        assert wait_until(lambda: server.model.stats.watchdog_stops == 1)


def _drive_in_lockstep(world: World, transport: str) -> tuple[list[float], np.ndarray, np.ndarray]:
    """The real ARCOS driver drives a lockstep server for 3 simulated seconds (accelerating, then turning);
    returns the SIP stamps, the final odometry and the final true pose."""
    from drivers.arcos.robot import P3AT
    from mocks.simclock import SimClock

    with SimClock() as clock:
        server = serve_tcp(world, "robot1", port=0, clock=clock, seed=1) if transport == "tcp" \
            else serve_pty(world, "robot1", clock=clock, seed=1)
        with server:
            driver = P3AT(server.url, clock=clock)
            server.client_sent = lambda: driver.bytes_written
            stamps: list[float] = []
            driver.subscribe(lambda state: stamps.append(state.stamp))
            model = server.model
            with clock.hold():
                with clock.gate(lambda: model.is_open and model.stats.sips == 0):
                    driver.connect(enable_motors=True)
                clock.add_quiescence("SIPs reach the test",
                                     lambda: not driver.connected or stamps[-1] >= server.last_sip_sent)
                token = clock.add_participant("test")
            with clock.participant(token):
                t0 = clock()
                driver.set_velocity(0.4, 0.0)
                clock.sleep_until(t0 + 1.55)
                driver.set_velocity(0.2, 0.5)
                clock.sleep_until(t0 + 3.05)
                odometry = model.odometry.copy()
                truth = world.pose("robot1")
                seen = list(stamps)
            driver.close()
    return seen, odometry, truth


@pytest.mark.parametrize("transport", ["tcp", "pty"])
def test_a_lockstep_server_gives_one_trajectory_however_busy_the_machine(world: World, transport: str) -> None:
    """On a SimClock the SIPs leave at exact 100 ms instants of simulated time and each command acts at the
    instant it was sent, so a run beside a busy-loop process is the same run, to the bit."""
    import subprocess
    import sys

    alone = _drive_in_lockstep(world, transport)
    busy = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        loaded = _drive_in_lockstep(world, transport)
    finally:
        busy.kill()
        busy.wait()
    stamps, odometry, truth = alone
    np.testing.assert_allclose(np.diff(stamps), 0.1, atol=1e-9)
    assert len(stamps) >= 30 and np.hypot(*truth[:2] - world.start_poses["robot1"][:2]) > 0.5
    assert stamps == loaded[0]
    np.testing.assert_array_equal(odometry, loaded[1])
    np.testing.assert_array_equal(truth, loaded[2])


@pytest.mark.parametrize("transport", ["tcp", "pty"])
def test_a_wall_clock_server_keeps_absolute_sip_deadlines_however_late_it_wakes(world: World, transport: str) -> None:
    """Each jump of the clock stands for a wake-up 37 ms late. SIPs fall at OPEN + k·100 ms of the clock however
    late the server ran: 13 SIPs in 1.37 s, each built at its own instant (the SIP's microcontroller time), where a
    loop sleeping 100 ms after each SIP would have sent 10, each later than the last."""
    clock = ManualClock()
    server = serve_tcp(world, "robot1", port=0, clock=clock) if transport == "tcp" \
        else serve_pty(world, "robot1", clock=clock)
    with server, serial.serial_for_url(server.url, timeout=0.05) as port:
        parser = PacketParser()
        handshake(port, parser)
        deadline = time.monotonic() + FAILURE_BOUND  # a bound, not a timing: OPEN lands at clock 0
        while not server.model.is_open and time.monotonic() < deadline:
            time.sleep(0.005)
        assert server.model.is_open
        got = []
        for k in range(1, 11):
            clock.t = 0.137 * k
            due = int(clock.t / 0.1 + 1e-9)
            want = due - len(got)
            got += sips(read_packets(port, parser, lambda p, want=want: len(sips(p)) >= want))
            assert len(got) == due
        assert [s.uc_time for s in got] == [100_000 * k for k in range(1, 14)]
        assert server.model.stats.sips == 13
