"""The P3AT driver against a protocol-level fake peer (conftest.FakePeer): corner cases the virtual robot in
mocks.p3at does not produce on demand (old session still streaming, no CONFIG, a peer that goes silent).

No test here depends on the machine's speed: the driver's clock is injected where a test needs time to pass
(a clock the test moves forward instead of sleeping), and every real-time wait is a failure bound
(FAILURE_BOUND), never the expected duration: it only decides how long a broken driver takes to fail.
"""
from __future__ import annotations

import threading
import time
import warnings

import pytest

from drivers.arcos.commands import Command
from drivers.arcos.robot import P3AT, ClampWarning, LinkEvent
from drivers.errors import DeviceNotFoundError, DriverTimeoutError, NotConnectedError

# Real-time waits are failure bounds only: 30 s is 300 SIP cycles, so a loaded CI machine that starves a thread
# for seconds still passes, and a broken driver still fails (only later).
FAILURE_BOUND = 30.0


class JumpClock:
    """time.monotonic plus an offset the test can jump forward: the driver sees time pass at once, and the
    real-time waits it does between reads (READ_TIMEOUT) still end."""

    def __init__(self) -> None:
        self.offset = 0.0

    def __call__(self) -> float:
        return time.monotonic() + self.offset

    def jump(self, seconds: float) -> None:
        self.offset += seconds


def wait_until(predicate, timeout: float = FAILURE_BOUND) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.02)
    return predicate()


def test_handshake_identity_config_and_state(fake_peer_factory) -> None:
    peer = fake_peer_factory()
    # The peer answers every SYNC and CONFIG: the waits for them are failure bounds here, not the driver's 0.5 s
    # and 1 s, which a peer thread starved for that long (seen: 1.75 s in a loaded run) would overrun: a SYNC
    # sent again, or no CONFIG, and the sequence asserted below differs.
    with P3AT(peer.url, reply_timeout=FAILURE_BOUND, config_timeout=FAILURE_BOUND) as robot:
        assert robot.identity.name == "FakePeer" and robot.identity.subtype == "p3at-sh"
        assert robot.params.subtype == "p3at-sh"
        assert robot.config.name == "FakePeer" and robot.config.trans_vel_top == 1200
        assert robot.config.watchdog is None  # the peer's CONFIG ends early; the reader accepts that
        state = robot.wait_for_state(FAILURE_BOUND)
        assert state.battery_volts == pytest.approx(13.0)
        assert state.sonars[7].range_m == pytest.approx(2.5) and state.sonars[7].pose[2] < 0
    assert wait_until(lambda: peer.commands[-1:] == [(Command.CLOSE, 1)])
    assert peer.commands[-2] == (Command.ENABLE, 0)
    assert [c for c, _ in peer.commands[:5]] == [0, 1, 2, Command.OPEN, Command.CONFIG]


def test_old_session_still_streaming_is_closed_and_restarted(fake_peer_factory) -> None:
    peer = fake_peer_factory(streaming_from_old_session=True)  # streams SIPs from the start, answers no SYNC
    with P3AT(peer.url) as robot:
        assert robot.identity.subtype == "p3at-sh"
    assert (Command.CLOSE, 1) in peer.commands[: peer.commands.index((2, None))]


def test_missing_config_is_optional(fake_peer_factory) -> None:
    peer = fake_peer_factory(send_config=False)
    with P3AT(peer.url, config_timeout=0.3) as robot:
        assert robot.config is None and robot.wait_for_state(FAILURE_BOUND) is not None


def test_pulse_keeps_a_quiet_client_alive(fake_peer_factory) -> None:
    # A pulse interval no real time reaches during the test: only the clock's jumps make pulses due.
    peer = fake_peer_factory()
    clock = JumpClock()
    sips: list[int] = []
    pulses = lambda: sum(c == (Command.PULSE, None) for c in peer.commands)  # noqa: E731
    with P3AT(peer.url, clock=clock, pulse_interval=1000.0, link_timeout=1e9) as robot:
        robot.subscribe(lambda s: sips.append(s.sequence))
        handshake = pulses()  # PULSE is command 0, which is also SYNC0
        for k in (1, 2):
            clock.jump(1000.0)  # nothing sent for one pulse interval: exactly one PULSE
            assert wait_until(lambda k=k: pulses() >= handshake + k)
            # Each reader iteration dispatches SIPs before it decides on a pulse; two more SIPs mean a whole
            # iteration ran after this pulse, where a driver that pulses too often would have sent another.
            seen = len(sips)
            assert wait_until(lambda seen=seen: len(sips) >= seen + 2)
            assert pulses() == handshake + k


def test_link_loss_is_reported_and_the_driver_reconnects_with_motors_off(fake_peer_factory) -> None:
    peer = fake_peer_factory()
    events: list[LinkEvent] = []
    restored = threading.Event()
    clock = JumpClock()
    with P3AT(peer.url, link_timeout=1000.0, clock=clock) as robot:
        robot.subscribe_link(lambda e: (events.append(e), e.kind == "restored" and restored.set()))
        robot.motors_on()
        peer.silent = True

        def silence_outlasted_the_link_timeout() -> bool:
            # The clock jumps past the link timeout at every poll, not once: a SIP the peer wrote just before it
            # went silent may be read after a jump, and it restarts the silence at the jumped time (1 run in 150
            # under load missed the loss that way).
            clock.jump(2000.0)
            return not robot.connected
        assert wait_until(silence_outlasted_the_link_timeout)
        with pytest.raises(NotConnectedError):
            robot.set_velocity(0.1, 0.0)
        with pytest.raises(NotConnectedError, match="link lost"):
            _ = robot.state
        with pytest.raises(NotConnectedError, match="link lost"):  # at once: not after the timeout
            robot.wait_for_state(FAILURE_BOUND)
        n_before = len(peer.commands)
        peer.silent = False
        assert restored.wait(FAILURE_BOUND)
        assert [e.kind for e in events] == ["lost", "restored"] and events[1].session == 2
        state = robot.wait_for_state(FAILURE_BOUND, lambda s: s.session == 2)
        assert not state.motors_enabled and robot.state.session == 2
        assert (Command.ENABLE, 0) in peer.commands[n_before:]


def test_tcp_peer_hanging_up_is_a_lost_link_and_the_driver_reconnects(tcp_peer) -> None:
    peer = tcp_peer
    restored = threading.Event()
    with P3AT(peer.url, link_timeout=FAILURE_BOUND) as robot:  # the hang-up itself must be noticed
        robot.subscribe_link(lambda e: e.kind == "restored" and restored.set())
        peer.drop_client()
        assert restored.wait(FAILURE_BOUND)
        assert robot.wait_for_state(FAILURE_BOUND).session == 2



def test_a_dropped_read_is_lost_in_pyserials_words_and_a_session_step_names_the_port(tcp_peer) -> None:
    """The link's "lost" event says why in pyserial's words ("I/O error: read failed: ..."), not the port again;
    a session step that meets the drop raises NotConnectedError naming the port (tests/hardening/test_link_dropped.py
    for the commands). Session 26 (C): the error carries the event's text (no unwrapping of its cause)."""
    peer = tcp_peer
    events: list = []
    with P3AT(peer.url, link_timeout=FAILURE_BOUND) as robot:
        robot.subscribe_link(events.append)
        peer.drop_client()
        assert wait_until(lambda: any(e.kind == "lost" for e in events))
    (lost,) = [e for e in events if e.kind == "lost"][:1]
    assert lost.reason.startswith("I/O error: ") and peer.url not in lost.reason and "link dropped" not in lost.reason


def test_close_during_a_reconnect_that_waits_for_its_first_sip_stops_the_reader_at_once(tcp_peer) -> None:
    """A reconnect whose handshake passed but whose first SIP has not come (a robot that opens mute) is cut short
    by close(): the reader ends with it. It spun in the SIP wait until its deadline (link_timeout / 2: here 500 s
    of the reader's busy loop) after close() had given up joining it."""
    peer = tcp_peer
    clock = JumpClock()
    robot = P3AT(peer.url, link_timeout=1000.0, clock=clock).connect()
    try:
        peer.sips = False

        def lost() -> bool:
            clock.jump(2000.0)  # at every poll (see the link-loss test above)
            return not robot.connected
        assert wait_until(lost)
        # the reconnect's handshake and OPEN pass (a new TCP client is a new session for the peer) ...
        assert wait_until(lambda: peer.commands.count((Command.OPEN, 1)) == 2 and robot.connected)
    finally:
        robot.close()  # ... and it waits for a SIP that never comes
    assert not any(t.name.startswith("arcos-reader") and t.is_alive() for t in threading.enumerate())


def test_clamped_command_warns(fake_peer_factory) -> None:
    peer = fake_peer_factory()
    with P3AT(peer.url) as robot:
        robot.motors_on()
        with pytest.warns(ClampWarning, match="clamped"):
            robot.set_velocity(9.0, 0.0)
        assert wait_until(lambda: (Command.VEL, 1200) in peer.commands)


def test_close_is_idempotent_and_commands_after_close_raise(fake_peer_factory) -> None:
    peer = fake_peer_factory()
    robot = P3AT(peer.url).connect()
    robot.close()
    robot.close()
    with pytest.raises(NotConnectedError):
        robot.stop()
    with pytest.raises(NotConnectedError, match="closed"):
        _ = robot.state
    with pytest.raises(NotConnectedError, match="closed"):
        robot.wait_for_state(FAILURE_BOUND)
    assert robot.last_state is not None  # kept for reports
    assert not any(t.name.startswith("arcos-reader") and t.is_alive() for t in threading.enumerate())


def test_subscriber_errors_do_not_stop_the_reader(fake_peer_factory) -> None:
    peer = fake_peer_factory()
    seen: list[int] = []
    with P3AT(peer.url) as robot, warnings.catch_warnings():
        robot.subscribe(lambda s: 1 / 0)
        robot.subscribe(lambda s: seen.append(s.sequence))
        assert wait_until(lambda: len(seen) >= 3)


def test_errors_for_missing_device_and_silent_peer(tmp_path) -> None:
    with pytest.raises(DeviceNotFoundError):
        P3AT(str(tmp_path / "ttyNothing")).connect()
    server = __import__("socket").socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    try:
        robot = P3AT(f"socket://127.0.0.1:{server.getsockname()[1]}", handshake_tries=2, reply_timeout=0.2)
        with pytest.raises(DriverTimeoutError, match="handshake"):
            robot.connect()
        robot.close()
    finally:
        server.close()


def test_every_command_method_sends_the_reference_command(fake_peer_factory) -> None:
    import math

    from drivers.arcos.codec import pack_vel2

    peer = fake_peer_factory()
    with P3AT(peer.url) as robot:
        start = len(peer.commands)
        robot.motors_on()
        robot.set_velocity(0.2, math.radians(-10))
        robot.set_wheel_velocities(0.1, 0.2)
        robot.move(-0.3)
        robot.set_heading(math.radians(90))
        robot.turn(math.radians(-30))
        robot.stop()
        robot.emergency_stop()
        robot.sonar(False)
        robot.reset_odometry()
        robot.set_velocity_limits(0.5, math.radians(60))
        robot.set_acceleration_limits(accel=0.4, decel=0.6, rot_accel=math.radians(50), rot_decel=math.radians(70))
        robot.request_encoders(True)
        robot.request_io(2)
        robot.motors_off()
        expected = [(Command.ENABLE, 1), (Command.VEL, 200), (Command.RVEL, -10), (Command.VEL2, pack_vel2(5, 10)),
                    (Command.MOVE, -300), (Command.HEAD, 90), (Command.DHEAD, -30), (Command.STOP, None),
                    (Command.E_STOP, 1), (Command.SONAR, 0), (Command.SETO, None), (Command.SETV, 500),
                    (Command.SETRV, 60), (Command.SETA, 400), (Command.SETA, -600), (Command.SETRA, 50),
                    (Command.SETRA, -70), (Command.ENCODER, 1), (Command.IOREQUEST, 2), (Command.ENABLE, 0)]
        assert wait_until(lambda: [c for c in peer.commands[start:] if c[0] != Command.PULSE][:len(expected)]
                          == expected)


def test_user_parameter_file_is_used_even_if_the_subtype_differs(fake_peer_factory, caplog) -> None:
    from drivers.arcos.params import BUILTIN_DIR

    peer = fake_peer_factory()
    with P3AT(peer.url, params=BUILTIN_DIR / "p3at.json") as robot:
        assert robot.params.subtype == "p3at" and robot.identity.subtype == "p3at-sh"
    assert "parameter set" in caplog.text
