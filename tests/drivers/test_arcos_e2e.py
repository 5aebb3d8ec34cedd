"""The real P3AT driver against the virtual P3-AT (mocks.p3at) over a pty and over TCP, end to end.

Ground truth comes from the simulated world (``world.pose(name)``); odometry errors and sensor noise are
configured per test.

Two clocks. Every drive (velocity, turning, the long wrap, position control, collision, the watchdog) runs on a
lockstep ``SimClock`` (``on_a_simulated_clock``): the server, the driver's stamps, its keep-alive and its waits all
count simulated seconds, so the drive is the same however little CPU the machine gives it. On the wall clock, a
server at ``time_scale`` x needs that many times its CPU per simulated second for each wall second, and a process
given less falls behind without bound (session 46: drives at 10x and 25x failed at nice 10 and nice 19 beside busy
loops). The rest runs on the wall clock at 1x, because the wall clock is its subject: the handshake, the sonar, a
connected driver, a server closed mid-drive, a robot restarted (the driver's link, keep-alive and reconnection in
real time); at 1x their server's thread needs 1.6 % of a core (measured alone, session 47), and their waits are
failure bounds.

Speed independence: every real-time wait below is a failure bound (FAILURE_BOUND), never the expected duration.
Links are given a timeout no loaded machine reaches (LINK_TIMEOUT) unless the test is about losing the link, and
then the loss is made certain (the server is closed), not waited for.
"""
from __future__ import annotations

import contextlib
import math
import os
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from drivers.arcos.robot import P3AT, LinkEvent
from drivers.errors import NotConnectedError
from mocks.p3at import OdometryErrors, SensorOptions, serve_pty, serve_tcp
from mocks.world import World

QUIET = SensorOptions(sonar_noise_m=0.0, sonar_noise_fraction=0.0, sonar_beam_rad=0.0)
# 30 s: 300 SIP cycles, 15 times the robot's 2 s watchdog; a starved CI thread still passes, a broken driver fails.
FAILURE_BOUND = 30.0
# A link timeout for tests that are not about the link: a virtual robot starved for seconds is not a lost link.
LINK_TIMEOUT = 60.0


def box_world() -> World:
    """A 10 x 4 m room."""
    walls = [[0, 0, 10, 0], [10, 0, 10, 4], [10, 4, 0, 4], [0, 4, 0, 0]]
    return World("box", np.array(walls, float), np.full(4, 2.5))


def open_world(size: float = 60.0) -> World:
    walls = [[-size, -size, size, -size], [size, -size, size, size], [size, size, -size, size],
             [-size, size, -size, -size]]
    return World("open", np.array(walls, float), np.full(4, 3.0))


class VirtualRobot:
    """One served virtual robot with a stable URL: a TCP port, or for a pty a symlink (like a udev by-id link)
    that :meth:`restart` points at the new pty, so the driver reconnects to the same URL."""

    def __init__(self, transport: str, link_dir: Path, world: World, pose: tuple[float, float, float],
                 **options: object) -> None:
        self.transport, self.world, self.pose, self.options = transport, world, np.array(pose, float), options
        self.name = "vp3at"
        self._link = link_dir / f"ttyP3AT-{id(self)}"
        self.server = self._start(port=0)
        self.url = self.server.url if transport == "tcp" else str(self._link)

    def _start(self, port: int):
        if self.transport == "tcp":
            return serve_tcp(self.world, self.name, self.pose, port=port, **self.options)
        server = serve_pty(self.world, self.name, self.pose, **self.options)
        tmp = self._link.with_suffix(".new")
        os.symlink(server.url, tmp)
        os.replace(tmp, self._link)
        return server

    def truth(self) -> np.ndarray:
        return self.world.pose(self.name)

    def restart(self) -> None:
        """Power-cycle the robot: the old server goes away, a new one (fresh firmware session) comes up."""
        port = self.server.port
        self.pose = self.truth()
        self.server.close()
        self.server = self._start(port=port or 0)

    def close(self) -> None:
        self.server.close()


@pytest.fixture(params=["pty", "tcp"])
def virtual_robot(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Callable[..., VirtualRobot]]:
    robots: list[VirtualRobot] = []

    def make(world: World, pose: tuple[float, float, float], **options: object) -> VirtualRobot:
        options.setdefault("seed", 1)
        robot = VirtualRobot(request.param, tmp_path, world, pose, **options)
        robots.append(robot)
        return robot
    yield make
    for robot in robots:
        robot.close()
    assert not [t.name for t in threading.enumerate() if t.name.startswith("arcos-reader")]


@contextlib.contextmanager
def on_a_simulated_clock(transport: str, world: World, pose: tuple[float, float, float], *,
                         driver_options: dict | None = None,
                         **options: object) -> Iterator[tuple[P3AT, object, list, object]]:
    """The real driver, connected with its motors on, to a virtual robot on a SimClock (lockstep server and driver,
    as test_p3at_servers' lockstep drive): yields (driver, clock, states received); the body runs as the clock's
    participant, so simulated time moves only while it waits on the clock (``clock.wait_for``, ``clock.sleep``, or
    the driver's own ``wait_for_state`` and ``request_config``, which wait on its clock), and each SIP reaches the
    driver first. The fourth: the robot's model (its counters). ``driver_options`` go to :class:`P3AT`, the others
    to the server.

    For drives: on the wall clock at ``time_scale`` x, the server needs that many times its CPU per simulated second
    (6.8-10 ms) for each wall second (17 % of a core at 25x, 8 % at 10x, measured), and a process given less falls
    behind without bound (each late step has more simulated time to catch up, and its SIPs leave only when it has):
    at nice 10 beside busy loops, drives at 25x and 10x waited 30 s for a state that never came (session 46)."""
    from mocks.simclock import SimClock

    with SimClock() as clock:
        at = np.array(pose, float)
        server = serve_tcp(world, "vp3at", at, port=0, clock=clock, **options) if transport == "tcp" \
            else serve_pty(world, "vp3at", at, clock=clock, **options)
        with server:
            p3at = P3AT(server.url, clock=clock, **{"link_timeout": LINK_TIMEOUT, **(driver_options or {})})
            server.client_sent = lambda: p3at.bytes_written
            states: list = []
            p3at.subscribe(states.append)
            model = server.model
            try:
                with clock.hold():
                    with clock.gate(lambda: model.is_open and model.stats.sips == 0):
                        p3at.connect(enable_motors=True)
                    clock.add_quiescence("SIPs reach the test",
                                         lambda: not p3at.connected or states[-1].stamp >= server.last_sip_sent)
                    token = clock.add_participant("test")
                with clock.participant(token):
                    yield p3at, clock, states, model
            finally:
                p3at.close()


def driver(robot: VirtualRobot, **kwargs: object) -> P3AT:
    kwargs.setdefault("link_timeout", LINK_TIMEOUT)
    return P3AT(robot.url, **kwargs)


def test_handshake_identity_and_config(virtual_robot) -> None:
    robot = virtual_robot(box_world(), (5.0, 2.0, 0.0))
    # the robot answers CONFIG: waited for as a failure bound, not the driver's 1 s a starved server thread overruns
    with driver(robot, config_timeout=FAILURE_BOUND) as p3at:
        assert (p3at.identity.name, p3at.identity.type, p3at.identity.subtype) == ("vp3at", "Pioneer", "p3at-sh")
        assert p3at.params.subtype == "p3at-sh"
        assert p3at.config.sip_cycle == 100 and p3at.config.watchdog == 2000
        assert p3at.config.trans_vel_top == 1200
        state = p3at.wait_for_state(FAILURE_BOUND)
        assert (state.x, state.y, state.theta) == (0.0, 0.0, 0.0) and not state.motors_enabled
        assert 10.0 < state.battery_volts <= 13.0


def test_connect_on_a_connected_driver_still_enables_the_motors_when_asked(virtual_robot) -> None:
    robot = virtual_robot(box_world(), (5.0, 2.0, 0.0))
    with driver(robot) as p3at:  # the with statement connected it, motors off
        assert not p3at.wait_for_state(FAILURE_BOUND).motors_enabled
        assert p3at.connect(enable_motors=True) is p3at
        assert p3at.wait_for_state(FAILURE_BOUND, lambda s: s.motors_enabled).motors_enabled


@pytest.mark.parametrize("transport", ["pty", "tcp"])
def test_velocity_moves_the_robot_and_odometry_matches_truth_within_the_configured_error(transport: str) -> None:
    scale_error = 0.98  # the wheels measure 2 % short
    world = open_world()
    with on_a_simulated_clock(transport, world, (1.0, 2.0, 0.0), seed=1,
                              odometry=OdometryErrors(distance_scale=scale_error)) as (p3at, clock, states, _):
        p3at.set_velocity(0.5, 0.0)
        assert clock.wait_for(lambda: states[-1].x > 1.5, timeout=60.0)
        p3at.stop()
        assert clock.wait_for(lambda: not states[-1].moving and states[-1].v == 0.0, timeout=60.0)
        clock.sleep(0.2)  # more SIPs: the position is final
        state, truth = states[-1], world.pose("vp3at")
    travelled = truth[0] - 1.0
    assert travelled > 1.5
    assert state.x == pytest.approx(scale_error * travelled, abs=0.005)
    assert state.y == pytest.approx(0.0, abs=0.005) and state.theta == pytest.approx(0.0, abs=0.01)
    assert abs(state.x - travelled) > 0.02  # the configured error is really there


@pytest.mark.parametrize("transport", ["pty", "tcp"])
def test_turning_matches_truth(transport: str) -> None:
    world = open_world()
    with on_a_simulated_clock(transport, world, (0.0, 0.0, 0.0), seed=1) as (p3at, clock, states, _):
        p3at.set_velocity(0.3, math.radians(30))
        assert clock.wait_for(lambda: states[-1].theta > 1.0, timeout=60.0)
        p3at.stop()
        assert clock.wait_for(lambda: states[-1].v == 0.0 and states[-1].w == 0.0, timeout=60.0)
        clock.sleep(0.2)
        state, (x, y, th) = states[-1], world.pose("vp3at")
    assert (state.x, state.y, state.theta) == pytest.approx((x, y, th), abs=0.01)


def test_sonar_sees_the_walls_at_the_right_distance(virtual_robot) -> None:
    robot = virtual_robot(box_world(), (5.0, 2.0, 0.0), sensors=QUIET)
    with driver(robot) as p3at:
        state = p3at.wait_for_state(FAILURE_BOUND, lambda s: all(r is not None for r in s.sonar_ranges()))
        sonars = state.sonars
        # sonar 0 looks left from y = +0.136: the wall y = 4 is 4 - 2.136 m away; sonar 7 mirrors it.
        assert sonars[0].range_m == pytest.approx(4.0 - 2.136, abs=0.01)
        assert sonars[7].range_m == pytest.approx(2.0 - 0.136, abs=0.01)
        # sonar 3 (x 0.245, y 0.027, 10 deg) hits the wall x = 10.
        assert sonars[3].range_m == pytest.approx((10.0 - 5.245) / math.cos(math.radians(10)), abs=0.01)
        assert sonars[3].pose == pytest.approx((0.245, 0.027, math.radians(10)), abs=1e-6)
        assert sonars[3].stamp <= state.stamp


@pytest.mark.parametrize("transport", ["pty", "tcp"])
def test_watchdog_stops_a_robot_whose_client_went_silent(transport: str) -> None:
    """A client that hangs after commanding (no PULSE): the robot's watchdog stops it, motors still enabled, after
    its 2 s of silence, and it stays stopped. The silence is counted in the robot's own time, as a real P3-AT's
    firmware counts it: here the simulated clock, on which the driver's keep-alive counts too (a pulsing driver
    drives 36 s without a watchdog stop in the wrap test). At 10x the wall clock this needed 10 % of a core and
    failed at about 1 % (session 46); that the wall-clock server counts the silence in wall seconds is
    test_p3at_servers' (a clock moved by hand)."""
    world = open_world()
    with on_a_simulated_clock(transport, world, (0.0, 0.0, 0.0), seed=1,
                              driver_options={"pulse_interval": 1e9}) as (p3at, clock, states, model):
        p3at.set_velocity(0.4, 0.0)
        silent_from = clock()  # the last bytes the client sends
        p3at.wait_for_state(FAILURE_BOUND, lambda s: s.v > 0.3)
        clock.sleep_until(silent_from + 1.9)
        assert states[-1].v > 0.3 and model.stats.watchdog_stops == 0  # still driving after 1.9 s of silence
        state = p3at.wait_for_state(FAILURE_BOUND, lambda s: s.v == 0.0)
        assert state.motors_enabled  # stopped by the watchdog, not disabled
        assert model.stats.watchdog_stops == 1 and state.stamp > silent_from + 2.0
        x_stopped = world.pose("vp3at")[0]
        p3at.wait_for_state(FAILURE_BOUND)
        p3at.wait_for_state(FAILURE_BOUND)
        assert world.pose("vp3at")[0] == pytest.approx(x_stopped, abs=1e-9)


def test_driver_reconnects_after_the_robot_restarts_with_motors_disabled(virtual_robot) -> None:
    """On the wall clock, which is its subject: the driver notices the closed port and reconnects in real time (its
    backoff, the handshake's replies). At 1x (it ran at 2x until session 47) the served robot needs 1.6 % of a
    core; every wait is a failure bound."""
    robot = virtual_robot(open_world(), (0.0, 0.0, 0.0))
    events: list[LinkEvent] = []
    restored = threading.Event()

    refused: list[bool] = []

    def on_link(event: LinkEvent) -> None:
        events.append(event)
        if event.kind == "lost":
            try:
                _ = p3at.state
            except NotConnectedError:
                refused.append(True)  # as documented: no state while the link is down
        if event.kind == "restored":
            restored.set()
    with driver(robot) as p3at:  # the restart closes the port: noticed at once, whatever the timeout
        p3at.subscribe_link(on_link)
        p3at.motors_on()
        p3at.wait_for_state(FAILURE_BOUND, lambda s: s.motors_enabled)
        robot.restart()
        assert restored.wait(FAILURE_BOUND), events
        assert [e.kind for e in events] == ["lost", "restored"] and refused == [True]
        state = p3at.wait_for_state(FAILURE_BOUND, lambda s: s.session == 2)
        assert not state.motors_enabled
        p3at.motors_on()  # and it is usable again
        assert p3at.wait_for_state(FAILURE_BOUND, lambda s: s.motors_enabled).session == 2


def test_state_readers_raise_not_connected_at_once_when_the_server_closes_mid_drive(virtual_robot) -> None:
    robot = virtual_robot(open_world(), (0.0, 0.0, 0.0))
    lost = threading.Event()
    in_callback: list[BaseException] = []

    def on_link(event: LinkEvent) -> None:
        try:
            _ = p3at.state  # already refused while the "lost" event is delivered
        except NotConnectedError as exc:
            in_callback.append(exc)
        lost.set()
    with driver(robot, reconnect=False) as p3at:
        p3at.subscribe_link(on_link)
        p3at.motors_on()
        p3at.set_velocity(0.2, 0.0)
        moving = p3at.wait_for_state(FAILURE_BOUND, lambda s: s.v > 0.1)
        waiter_error: list[BaseException] = []

        def wait_forever() -> None:  # a reader blocked in wait_for_state when the link goes
            try:
                p3at.wait_for_state(10 * FAILURE_BOUND, lambda s: False)
            except BaseException as exc:  # noqa: BLE001 - the test inspects the type
                waiter_error.append(exc)
        waiter = threading.Thread(target=wait_forever)
        waiter.start()
        robot.server.close()
        assert lost.wait(FAILURE_BOUND)
        waiter.join(FAILURE_BOUND)
        assert not waiter.is_alive() and type(waiter_error[0]) is NotConnectedError
        assert len(in_callback) == 1 and "link lost" in str(in_callback[0])
        with pytest.raises(NotConnectedError, match="link lost"):
            _ = p3at.state  # not the stale state
        with pytest.raises(NotConnectedError, match="link lost"):
            p3at.wait_for_state(10 * FAILURE_BOUND)  # at once, not a DriverTimeoutError later
        assert p3at.last_state.sequence >= moving.sequence and p3at.last_state.v > 0.1  # kept for reports


@pytest.mark.parametrize("transport", ["pty", "tcp"])
def test_collision_sets_bumpers_and_stall(transport: str) -> None:
    """On a simulated clock: at 10x the wall clock it needed 6-11 % of a core (session 47)."""
    world = box_world()
    with on_a_simulated_clock(transport, world, (8.5, 2.0, 0.0), seed=1) as (p3at, clock, states, _):
        p3at.set_velocity(0.5, 0.0)
        state = p3at.wait_for_state(FAILURE_BOUND, lambda s: s.stalled)
        truth = world.pose("vp3at")
    assert state.front_bumpers and not state.rear_bumpers and state.bumped
    assert truth[0] == pytest.approx(10.0 - 0.33, abs=0.05)  # stopped at the wall


@pytest.mark.slow
def test_position_wraps_around_over_a_long_drive() -> None:
    """p3at-sh reports mm in 15 bits: the field wraps every 32.768 m. Drive 34 m straight (TCP; the wrap is
    transport-independent), on a simulated clock: at 25x the wall clock it needed 17 % of a core (session 46)."""
    world = open_world(60.0)
    with on_a_simulated_clock("tcp", world, (-25.0, 0.0, 0.0), seed=1) as (p3at, clock, states, model):
        t0 = clock()
        p3at.set_velocity_limits(max_v=1.2)
        p3at.set_velocity(1.2, 0.0)
        clock.sleep_until(t0 + 32.0)   # 1.2 m/s after its ramp: past 34 m
        moving = states[-1]
        p3at.stop()
        clock.sleep_until(t0 + 36.0)
        state, truth = states[-1], world.pose("vp3at")
    travelled = truth[0] + 25.0
    assert moving.x > 34.0 and moving.v > 1.0 and state.v == 0.0 and model.stats.watchdog_stops == 0
    assert travelled > 34.0 and state.x == pytest.approx(travelled, abs=0.01)


@pytest.mark.parametrize("transport", ["pty", "tcp"])
def test_position_control_odometry_reset_and_requested_packets(transport: str) -> None:
    """On a simulated clock (at 10x the wall clock it needed 6-11 % of a core and failed at about 1 %, session 46):
    the driver's own waits, ``wait_for_state`` and ``request_config``, wait on its clock (on the wall clock they
    held simulated time still and waited out their timeouts)."""
    world = open_world()
    packets: list[object] = []
    with on_a_simulated_clock(transport, world, (0.0, 0.0, 0.0), seed=1) as (p3at, clock, states, _):
        p3at.subscribe_packets(packets.append)
        p3at.move(0.5)  # MOVE: the robot's own position control
        state = p3at.wait_for_state(FAILURE_BOUND, lambda s: s.x > 0.45 and not s.moving)
        assert world.pose("vp3at")[0] == pytest.approx(0.5, abs=0.03) and state.x == pytest.approx(0.5, abs=0.03)
        p3at.set_heading(math.pi / 2)  # HEAD: absolute heading in the odometry frame
        state = p3at.wait_for_state(FAILURE_BOUND, lambda s: abs(s.theta - math.pi / 2) < 0.03 and s.w == 0.0)
        assert world.pose("vp3at")[2] == pytest.approx(math.pi / 2, abs=0.05)
        p3at.reset_odometry()  # SETO
        state = p3at.wait_for_state(FAILURE_BOUND, lambda s: abs(s.x) < 0.01 and abs(s.theta) < 0.01)
        assert (state.x, state.y) == pytest.approx((0.0, 0.0), abs=0.01)
        p3at.request_encoders(True)
        p3at.request_io(1)
        p3at.wait_for_state(FAILURE_BOUND, lambda s: p3at.encoders is not None and p3at.io is not None)
        assert p3at.encoders.left > 0 and p3at.encoders.right > 0  # ticks since OPEN: it drove forward
        config = p3at.request_config(FAILURE_BOUND)  # returns when the packet comes
        assert config is not None and config.name == "vp3at"
        assert {type(p).__name__ for p in packets} >= {"RobotConfig", "EncoderCounts", "IoPacket"}
