"""Robots block each other by their bodies (``FirmwareDefaults(robot_contact="footprint")``): the rectangle geometry,
and virtual P3-ATs driven at and past each other by the real ARCOS driver, in simulated time (lockstep, so the
runs are the same however busy the machine) and served from a process of their own (wall clock, no timing
asserted: only where the robots end up and what their SIPs say)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.arcos.robot import P3AT
from mocks.p3at import FirmwareDefaults, RobotSpec, serve_tcp, serve_tcp_process
from mocks.simclock import SimClock
from mocks.world import World, footprint_corners, footprint_gap, footprint_overlap, polygon_area

P3AT_SIZE = (0.626, 0.505)
FOOTPRINT = FirmwareDefaults(robot_contact="footprint")
MIDDLE_FRONT = 1 << 2  # the driver's front_bumpers mask: bit k = segment k of five, 0 leftmost
# For drivers on the wall clock, of robots in another process: not about the link. The default (4 s without a packet)
# counts a robot process starved that long as lost, and the driver comes back in a new session with the motors
# off (tests/mocks/test_p3at_process.py failed so beside other busy processes).
LINK_TIMEOUT_S = 600.0


# ------------------------------------------------------------------ the geometry
coordinate = st.floats(-3.0, 3.0, allow_nan=False)
heading = st.floats(-math.pi, math.pi, allow_nan=False)
pose = st.tuples(coordinate, coordinate, heading).map(np.array)
size = st.tuples(st.floats(0.1, 1.0), st.floats(0.1, 1.0))


def _inside(points: np.ndarray, pose_: np.ndarray, size_: tuple[float, float]) -> np.ndarray:
    """(n,) bool: points strictly inside the body (by its own frame: |u| < l/2, |v| < w/2)."""
    c, s = math.cos(pose_[2]), math.sin(pose_[2])
    d = points - pose_[:2]
    u, v = c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]
    return (np.abs(u) < size_[0] / 2) & (np.abs(v) < size_[1] / 2)


def _samples(pose_: np.ndarray, size_: tuple[float, float], n: int = 80) -> tuple[np.ndarray, float]:
    """A dense grid of points over the body (n × n cell centres) and the area each stands for."""
    u = (np.arange(n) + 0.5) / n - 0.5
    uu, vv = np.meshgrid(u * size_[0], u * size_[1])
    c, s = math.cos(pose_[2]), math.sin(pose_[2])
    pts = np.column_stack([pose_[0] + c * uu.ravel() - s * vv.ravel(), pose_[1] + s * uu.ravel() + c * vv.ravel()])
    return pts, size_[0] * size_[1] / n**2


@settings(max_examples=200, deadline=None)
@given(pose, size, pose, size)
def test_the_gap_is_symmetric(pa, sa, pb, sb) -> None:
    assert footprint_gap(pa, sa, pb, sb) == pytest.approx(footprint_gap(pb, sb, pa, sa), abs=1e-9)
    assert polygon_area(footprint_overlap(pa, sa, pb, sb)) == pytest.approx(
        polygon_area(footprint_overlap(pb, sb, pa, sa)), abs=1e-9)


@settings(max_examples=200, deadline=None)
@given(pose, size, pose, size, st.tuples(coordinate, coordinate, heading))
def test_the_gap_does_not_change_when_both_bodies_are_moved_together(pa, sa, pb, sb, motion) -> None:
    tx, ty, rot = motion
    c, s = math.cos(rot), math.sin(rot)

    def moved(p: np.ndarray) -> np.ndarray:
        return np.array([tx + c * p[0] - s * p[1], ty + s * p[0] + c * p[1], p[2] + rot])

    assert footprint_gap(moved(pa), sa, moved(pb), sb) == pytest.approx(footprint_gap(pa, sa, pb, sb), abs=1e-9)
    assert polygon_area(footprint_overlap(moved(pa), sa, moved(pb), sb)) == pytest.approx(
        polygon_area(footprint_overlap(pa, sa, pb, sb)), abs=1e-9)


@settings(max_examples=40, deadline=None)
@given(pose, size, st.tuples(st.floats(-1.2, 1.2), st.floats(-1.2, 1.2), heading), size)
def test_the_geometry_matches_a_dense_sampling_of_the_bodies(pa, sa, offset, sb) -> None:
    pb = np.array([pa[0] + offset[0], pa[1] + offset[1], offset[2]])
    gap = footprint_gap(pa, sa, pb, sb)
    grid_a, cell = _samples(pa, sa)
    in_both = _inside(grid_a, pb, sb)
    # the overlap's area against the share of A's cells inside B (each cell at most ~1/80 of a side wide)
    area = polygon_area(footprint_overlap(pa, sa, pb, sb))
    perimeter = 2 * (sa[0] + sa[1])
    assert area == pytest.approx(in_both.sum() * cell, abs=perimeter * max(sa) / 80 + 1e-9)
    if gap > 1e-9:  # apart: no point of A inside B, and the nearest points of the outlines are `gap` apart
        assert not in_both.any() and area == 0.0
        edge_a = _outline(pa, sa)
        edge_b = _outline(pb, sb)
        nearest = np.min(np.linalg.norm(edge_a[:, None, :] - edge_b[None, :, :], axis=2))
        assert nearest == pytest.approx(gap, abs=2 * max(max(sa), max(sb)) / 400 + 1e-9)
    elif gap < -0.02 * max(max(sa), max(sb)):  # clearly overlapping: the sampling finds shared points
        assert in_both.any() and area > 0.0
        # pushing B out by the penetration depth along the best direction separates them (SAT: depth is minimal)
        assert _separating_push(pa, sa, pb, sb, -gap)


def _outline(pose_: np.ndarray, size_: tuple[float, float], per_side: int = 200) -> np.ndarray:
    corners = footprint_corners(pose_, size_)
    f = np.linspace(0.0, 1.0, per_side, endpoint=False)[:, None]
    return np.concatenate([corners[i] + f * (corners[(i + 1) % 4] - corners[i]) for i in range(4)])


def _separating_push(pa, sa, pb, sb, depth: float) -> bool:
    """B pushed by the depth (+ a hair) along one of the bodies' edge normals parts them, and no push of 90 % of the
    depth in any of 720 directions does: the depth is the shortest separating push."""
    normals = [pa[2], pb[2]] + [pa[2] + math.pi / 2, pb[2] + math.pi / 2]
    axes = [a + k * math.pi for a in normals for k in (0, 1)]
    everywhere = np.linspace(-math.pi, math.pi, 720, endpoint=False)

    def best_gap(push: float, angles) -> float:
        return max(footprint_gap(pa, sa, pb + push * np.array([math.cos(a), math.sin(a), 0.0]), sb) for a in angles)

    return best_gap(depth * (1 + 1e-6) + 1e-9, axes) >= 0.0 and best_gap(depth * 0.9, everywhere) < 0.0


def test_the_p3at_bodies_touch_at_their_lengths_and_widths() -> None:
    a = np.zeros(3)
    assert footprint_gap(a, P3AT_SIZE, np.array([0.7, 0.0, math.pi]), P3AT_SIZE) == pytest.approx(0.7 - 0.626)
    assert footprint_gap(a, P3AT_SIZE, np.array([0.0, 0.55, 0.0]), P3AT_SIZE) == pytest.approx(0.55 - 0.505)
    assert footprint_gap(a, P3AT_SIZE, np.array([0.6, 0.0, 0.0]), P3AT_SIZE) == pytest.approx(0.6 - 0.626)
    # corner to corner: the bodies reach 0.402 m each along their diagonals, further than the old 0.33 m discs
    diagonal = math.atan2(0.505, 0.626)
    gap = footprint_gap(a, P3AT_SIZE, np.array([0.78 * math.cos(diagonal), 0.78 * math.sin(diagonal), 0.0]),
                        P3AT_SIZE)
    assert gap < 0.0


# ------------------------------------------------------------------ the robots, through the driver, in lockstep
class WatchedWorld(World):
    """An open square room that records, at every move of every robot (each 10 ms physics step), the smallest
    gap between any two robots' bodies."""

    def __init__(self, half: float = 20.0) -> None:
        h = half
        walls = [[-h, -h, h, -h], [h, -h, h, h], [h, h, -h, h], [-h, h, -h, -h]]
        super().__init__("open", np.array(walls, float), np.full(4, 3.0))
        self.min_gap = math.inf
        self.moves = 0

    def set_pose(self, name: str, pose: np.ndarray) -> None:
        super().set_pose(name, pose)
        poses, sizes = self.robot_poses(), self.footprints()
        names = sorted(poses)
        for i, a in enumerate(names):
            for b in names[i + 1:]:
                self.min_gap = min(self.min_gap, footprint_gap(poses[a], sizes[a], poses[b], sizes[b]))
        self.moves += 1


def drive_in_lockstep(world: World, starts: dict[str, tuple[float, float, float]],
                      commands: dict[str, tuple[float, float]], seconds: float,
                      firmware: FirmwareDefaults = FOOTPRINT) -> dict[str, list]:
    """Serve one virtual P3-AT per start pose on a SimClock, connect the real driver to each, send each its
    (v, ω) at once and let ``seconds`` of simulated time pass; returns every state each driver received (and
    the true poses at the end as ``world.final``)."""
    with SimClock() as clock:
        servers, drivers, states = {}, {}, {}
        try:
            for name, start in starts.items():
                servers[name] = serve_tcp(world, name, np.array(start, float), port=0, clock=clock, seed=1,
                                          firmware=firmware)
            with clock.hold():
                for name, server in servers.items():
                    driver = drivers[name] = P3AT(server.url, clock=clock)
                    server.client_sent = lambda driver=driver: driver.bytes_written
                    states[name] = []
                    driver.subscribe(states[name].append)
                    model = server.model
                    with clock.gate(lambda model=model: model.is_open and model.stats.sips == 0):
                        driver.connect(enable_motors=True)
                    clock.add_quiescence(f"SIPs reach {name}", lambda driver=driver, server=server, got=states[name]:
                                         not driver.connected or (got and got[-1].stamp >= server.last_sip_sent))
                token = clock.add_participant("test")
            with clock.participant(token):
                t0 = clock()
                for name, (v, w) in commands.items():
                    drivers[name].set_velocity(v, w)
                clock.sleep_until(t0 + seconds)
                world.final = world.robot_poses()
                world.touching = {name: server.touching for name, server in servers.items()}
        finally:
            for driver in drivers.values():
                driver.close()
            for server in servers.values():
                server.close()
    return states


def test_two_robots_driven_at_each_other_stop_with_their_front_bumpers_pressed_and_never_overlap() -> None:
    world = WatchedWorld()
    states = drive_in_lockstep(world, {"robot1": (0.0, 0.0, 0.0), "robot2": (3.0, 0.0, math.pi)},
                               {"robot1": (0.4, 0.0), "robot2": (0.4, 0.0)}, seconds=8.0)
    for name in ("robot1", "robot2"):
        last = states[name][-1]
        assert last.front_bumpers == MIDDLE_FRONT and last.rear_bumpers == 0  # head on: the middle segment
        assert last.left_stall and last.right_stall and last.v == 0.0
        assert 1.1 < last.x < 1.25  # each drove ~1.19 m (the 1.3 m to the meeting point less half the body)
    assert world.moves > 1000  # every physics step of both robots was watched
    assert 0.0 <= world.min_gap < 0.02  # they met, bodies touching within one step's travel, never overlapping
    assert world.touching == {"robot1": "robot2", "robot2": "robot1"}  # each server says what its robot touches


def test_robots_passing_side_by_side_at_0_55_m_do_not_stop() -> None:
    """Centres 0.55 m apart sideways: bodies 0.505 m wide pass 45 mm apart. The old 0.33 m discs (contact at
    0.66 m) would have stopped both."""
    world = WatchedWorld()
    states = drive_in_lockstep(world, {"robot1": (0.0, 0.0, 0.0), "robot2": (3.0, 0.55, math.pi)},
                               {"robot1": (0.4, 0.0), "robot2": (0.4, 0.0)}, seconds=8.0)
    for name in ("robot1", "robot2"):
        assert not any(s.bumped or s.stalled for s in states[name])
        assert states[name][-1].x > 2.5  # drove on past the other
    assert world.min_gap == pytest.approx(0.55 - 0.505, abs=1e-6)


def test_with_the_old_discs_the_same_pass_stops_both() -> None:
    """The former default contact (``robot_contact="disc"``) still meets at 0.66 m between centres."""
    world = WatchedWorld()
    states = drive_in_lockstep(world, {"robot1": (0.0, 0.0, 0.0), "robot2": (3.0, 0.55, math.pi)},
                               {"robot1": (0.4, 0.0), "robot2": (0.4, 0.0)}, seconds=8.0,
                               firmware=FirmwareDefaults(robot_contact="disc"))
    assert all(states[name][-1].bumped for name in ("robot1", "robot2"))


def test_a_robot_turning_on_the_spot_beside_another_stops_with_the_bumper_on_that_side() -> None:
    """Side by side 0.55 m apart, robot 1 turns left: its front-left corner swings into robot 2 (the turning
    body reaches 0.402 m), so the turn stops, the wheels stall and a left front bumper is pressed; robot 2,
    standing, is not pushed."""
    world = WatchedWorld()
    states = drive_in_lockstep(world, {"robot1": (0.0, 0.0, 0.0), "robot2": (0.0, 0.55, 0.0)},
                               {"robot1": (0.0, 0.5)}, seconds=4.0)
    last = states["robot1"][-1]
    assert last.left_stall and last.right_stall
    assert last.front_bumpers and last.front_bumpers & 0b00011 == last.front_bumpers  # a left segment only
    assert 0.05 < last.theta < 0.6  # it turned a little, then stopped
    assert world.min_gap >= 0.0
    np.testing.assert_allclose(world.final["robot2"], [0.0, 0.55, 0.0])


def test_backing_away_from_the_other_robot_releases_the_bumper() -> None:
    world = WatchedWorld()
    with SimClock() as clock:
        servers = {n: serve_tcp(world, n, np.array(p, float), port=0, clock=clock, seed=1, firmware=FOOTPRINT)
                   for n, p in {"robot1": (0.0, 0.0, 0.0), "robot2": (0.8, 0.0, 0.0)}.items()}
        driver = P3AT(servers["robot1"].url, clock=clock)
        got: list = []
        try:
            with clock.hold():
                server = servers["robot1"]
                server.client_sent = lambda: driver.bytes_written
                driver.subscribe(got.append)
                with clock.gate(lambda: server.model.is_open and server.model.stats.sips == 0):
                    driver.connect(enable_motors=True)
                clock.add_quiescence("SIPs", lambda: not driver.connected
                                     or (got and got[-1].stamp >= server.last_sip_sent))
                token = clock.add_participant("test")
            with clock.participant(token):
                driver.set_velocity(0.3, 0.0)
                clock.sleep(3.0)
                pressed = got[-1]
                driver.set_velocity(-0.2, 0.0)
                clock.sleep(2.0)
                released = got[-1]
        finally:
            driver.close()
            for s in servers.values():
                s.close()
    assert pressed.front_bumpers == MIDDLE_FRONT and pressed.stalled
    assert pressed.x == pytest.approx(0.8 - 0.626, abs=0.015)  # stopped at the other's rear within one step
    assert not released.bumped and not released.stalled and released.x < pressed.x - 0.2
    assert servers["robot1"].model.stats.collisions == 1


# ------------------------------------------------------------------ served from a process of their own
def test_robots_in_their_own_process_block_each_other_by_their_bodies() -> None:
    """The robots' process runs one world with every robot (wall clock): driven head on, both stop with the
    middle front bumper pressed, their bodies apart; the parent's world knows their footprints."""
    world = World.load()
    specs = [RobotSpec("robot1", pose=(3.0, 5.0, 0.0), firmware=FOOTPRINT),
             RobotSpec("robot2", pose=(5.0, 5.0, math.pi), firmware=FOOTPRINT)]
    with serve_tcp_process(world, specs) as robots:
        assert world.footprints() == {"robot1": P3AT_SIZE, "robot2": P3AT_SIZE}
        drivers = [P3AT(robots.servers[s.name].url, link_timeout=LINK_TIMEOUT_S) for s in specs]
        try:
            for driver in drivers:
                driver.connect(enable_motors=True)
            for driver in drivers:
                driver.set_velocity(0.3, 0.0)
            last = [d.wait_for_state(timeout=30.0, predicate=lambda s: s.bumped and s.v == 0.0) for d in drivers]
            a, b = world.pose("robot1"), world.pose("robot2")
            touching = {name: server.touching for name, server in robots.servers.items()}
        finally:
            for driver in drivers:
                driver.close()
    for state in last:
        assert state.front_bumpers == MIDDLE_FRONT and state.stalled
    assert 0.0 <= footprint_gap(a, P3AT_SIZE, b, P3AT_SIZE) < 0.03
    assert touching == {"robot1": "robot2", "robot2": "robot1"}  # through the pose table's contact word


# ------------------------------------------------------------------ the mission reports a contact
def test_a_mission_reports_a_robot_running_into_another_in_its_events_and_in_rerun(tmp_path) -> None:
    """Robot 2 stands 0.45 m to the left of robot 1's line, 0.5 m ahead, out of its forward sonars' sector: robot 1
    drives on and its front-left corner runs into robot 2's side (the default footprint contact: the bodies are
    505 mm wide). The mission says so, naming both robots and the bumper the driver reports (the second front
    segment from the left, facing the middle of the overlap), in its events and as a WARN line of the recording's
    mission/events."""
    import json

    import rerun.chunk as rrchunk

    from runtime.mission import Mission, MissionConfig

    poster = [{"kind": "poster", "s0": s, "s1": s + 0.6, "z0": 1.1, "z1": 1.9, "side": 1} for s in (1, 3, 5)]
    doc = {"version": 1, "name": "two robots",
           "walls": [{"from": [0, 0], "to": [8, 0], "decorations": poster}, {"from": [8, 0], "to": [8, 4]},
                     {"from": [8, 4], "to": [0, 4]}, {"from": [0, 4], "to": [0, 0]}],
           "start_poses": {"robot1": [2.0, 2.0, 0.0], "robot2": [2.5, 2.45, 0.0]},
           "routes": {"robot1": [[2.0, 2.0], [5.0, 2.0]], "robot2": [[2.5, 2.45], [2.51, 2.45]]}}
    (tmp_path / "world.json").write_text(json.dumps(doc))
    events: list[str] = []
    config = MissionConfig(robots=2, seconds=4.0, camera="synthetic", camera_rate=5.0, particles=10,
                           fusion_interval=0.0, out=tmp_path, rerun="file", world=tmp_path / "world.json")
    Mission(config, events=events.append).run()
    contact = "robot1 ran into robot2 and stopped: front bumpers 0x02, rear 0x00"
    assert contact in events
    logged = []
    for chunk in rrchunk.RrdReader(tmp_path / "mission.rrd").stream().filter(content=["+ /mission/events"]):
        batch = chunk.to_record_batch()
        logged += list(zip([t[0] for t in batch.column("TextLog:text").to_pylist()],
                           [v[0] for v in batch.column("TextLog:level").to_pylist()], strict=True))
    assert (contact, "WARN") in logged


def test_a_robot_run_alone_says_it_cannot_touch_the_fleets_other_robots(tmp_path) -> None:
    """``p3at run --robot mock --name robot2`` (each robot process of ``p3at demo --processes``) builds a world of its
    own with that robot only: the mission says so in its events rather than pretending the robots can meet."""
    from runtime.mission import Mission, MissionConfig

    events: list[str] = []
    config = MissionConfig(robots=1, robot_name="robot2", seconds=0.5, camera="synthetic", camera_rate=5.0,
                           particles=10, motion="none", fusion_interval=0.0, out=tmp_path, rerun="none")
    Mission(config, events=events.append).run()
    assert ("robot2 is alone in its copy of the world: the fleet's other robots are not in it, so it can neither "
            "touch them nor hear them on its sonar") in events
