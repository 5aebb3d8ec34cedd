"""Map exchange, motion controllers and the runtime's other parts, through their public interfaces."""
from __future__ import annotations

import re

import numpy as np
import pytest

from estimation.geometry import compose
from estimation.landmark_map import LandmarkMap
from mocks.world import World
from runtime.exchange import InProcessExchange
from runtime.motion import PurePursuit, RouteFileError, WallFollower, keep_right, load_route, save_route


def _map(robot: str, n: int, rng: np.random.Generator) -> LandmarkMap:
    return LandmarkMap(rng.normal(size=(n, 3)), np.tile(np.eye(3) * 0.01, (n, 1, 1)),
                       rng.normal(size=(n, 64)).astype(np.float32), robot=robot)


def test_exchange_hands_out_copies_of_the_others_latest_maps():
    rng = np.random.default_rng(1)
    exchange = InProcessExchange()
    m1 = _map("robot1", 5, rng)
    exchange.publish("robot1", m1, stamp=1.0)
    exchange.publish("robot1", _map("robot1", 7, rng), stamp=2.0)
    exchange.publish("robot2", _map("robot2", 3, rng), stamp=2.5)
    received = exchange.receive(excluding="robot2")
    assert list(received) == ["robot1"]
    message = received["robot1"]
    assert (message.sequence, message.stamp, len(message.landmark_map)) == (1, 2.0, 7)
    message.landmark_map.positions[:] = 99.0  # a receiver cannot reach into the publisher's map
    assert not np.any(exchange.receive(excluding="robot2")["robot1"].landmark_map.positions == 99.0)
    assert set(exchange.receive()) == {"robot1", "robot2"}


def _drive(controller, world: World, pose: np.ndarray, seconds: float, dt: float = 0.1):
    """Unicycle kinematics in the building, sonar by ray casting; returns the poses and the minimum clearance."""
    sonar_poses = np.array([[0.1, 0.0, a] for a in np.radians([-90, -50, -30, -10, 10, 30, 50, 90])])
    poses, clearance = [pose], np.inf
    for _ in range(int(seconds / dt)):
        mounts = compose(pose, sonar_poses)
        ranges, _ = world.raycast(mounts[:, :2], mounts[:, 2], 5.0)
        cmd = controller.command(pose, sonar_poses, ranges)
        if cmd.done:
            break
        pose = compose(pose, np.array([cmd.v * dt, 0.0, cmd.w * dt]))
        clearance = min(clearance, float(world.distance_to_walls(pose[None, :2])[0]))
        poses.append(pose)
    return np.array(poses), clearance


def test_pure_pursuit_follows_the_building_route_to_its_end_without_touching_a_wall():
    world = World.load()
    route = world.routes["robot1"]
    poses, clearance = _drive(PurePursuit(route, speed=0.4), world, world.start_poses["robot1"].copy(), 200.0)
    assert np.linalg.norm(poses[-1, :2] - route[-1]) < 0.35
    # it visited every waypoint on the way
    for waypoint in route:
        assert np.min(np.linalg.norm(poses[:, :2] - waypoint, axis=1)) < 0.5
    assert clearance > 0.25


def test_wall_follower_explores_and_keeps_clear_of_the_walls():
    world = World.load()
    start = world.start_poses["robot1"].copy()
    poses, clearance = _drive(WallFollower(side="right", distance=0.8), world, start, 60.0)
    assert clearance > 0.25
    assert np.max(np.linalg.norm(poses[:, :2] - start[:2], axis=1)) > 4.0  # it went somewhere


def test_route_file_round_trip_and_errors(tmp_path):
    route = np.array([[0.0, 0.0], [1.5, -2.25], [3.0, 4.0]])
    save_route(tmp_path / "a.route", route)
    np.testing.assert_allclose(load_route(tmp_path / "a.route"), route)
    (tmp_path / "b.route").write_text("# comment\n1 2\n3, oops\n")
    with pytest.raises(RouteFileError, match=r"b.route:3"):
        load_route(tmp_path / "b.route")
    with pytest.raises(RouteFileError, match="no such"):
        load_route(tmp_path / "missing.route")


def test_two_robots_on_head_on_routes_pass_each_other_and_finish():
    """The world's two routes meet head on in the corridor: kept to the right, both pass and reach their goals."""
    world = World.load()
    sonar_poses = np.array([[0.1, 0.0, a] for a in np.radians([-90, -50, -30, -10, 10, 30, 50, 90])])
    robots = {name: [world.start_poses[name].copy(), PurePursuit(keep_right(world.routes[name]), speed=0.4), False]
              for name in ("robot1", "robot2")}
    dt, closest = 0.1, np.inf
    for _ in range(3000):
        for name, state in robots.items():
            pose, controller, _ = state
            other = next(s[0] for n, s in robots.items() if n != name)
            mounts = compose(pose, sonar_poses)
            ranges, _ = world.raycast(mounts[:, :2], mounts[:, 2], 5.0)
            # the other robot as a disc of radius 0.3 m seen by the sonar rays
            rel = other[:2] - mounts[:, :2]
            direction = np.column_stack([np.cos(mounts[:, 2]), np.sin(mounts[:, 2])])
            along = np.sum(rel * direction, axis=1)
            across = np.abs(rel[:, 0] * direction[:, 1] - rel[:, 1] * direction[:, 0])
            hit = (along > 0) & (across < 0.3)
            ranges = np.where(hit, np.minimum(ranges, along - np.sqrt(np.maximum(0.09 - across**2, 0))), ranges)
            cmd = controller.command(pose, sonar_poses, ranges)
            state[2] = cmd.done
            if not cmd.done:
                state[0] = compose(pose, np.array([cmd.v * dt, 0.0, cmd.w * dt]))
        closest = min(closest, float(np.linalg.norm(robots["robot1"][0][:2] - robots["robot2"][0][:2])))
        if all(state[2] for state in robots.values()):
            break
    assert all(state[2] for state in robots.values()), {n: s[0] for n, s in robots.items()}
    assert closest > 0.5  # they never touched (two 0.3 m discs... with a margin)


def test_covariance_ellipsoids_logged_to_rerun_rebuild_the_covariances():
    from runtime.rerun_log import _ellipsoids

    rng = np.random.default_rng(4)
    a = rng.normal(size=(200, 3, 3))
    covariances = a @ np.swapaxes(a, 1, 2) + 1e-3 * np.eye(3)
    covariances[0] = np.diag([4.0, 1.0, 0.25])[[1, 0, 2]][:, [1, 0, 2]]  # a rotation by about π among the axes
    half_sizes, q = _ellipsoids(covariances, sigmas=2.0)
    x, y, z, w = q.T
    rotation = np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], -2)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-9)
    rebuilt = rotation @ (np.eye(3) * (half_sizes[:, None, :] / 2.0) ** 2) @ np.swapaxes(rotation, 1, 2)
    np.testing.assert_allclose(rebuilt, covariances, atol=1e-8)


def test_mission_log_writes_a_recording_that_reads_back(tmp_path):
    from runtime.rerun_log import MissionLog
    from runtime.rerun_read import read_recording
    from runtime.rerun_sink import open_recording
    from runtime.rerun_style import mission_blueprint

    rng = np.random.default_rng(5)
    rrd = tmp_path / "m.rrd"
    log = MissionLog(open_recording(str(rrd), blueprint=mission_blueprint(["robot1", "robot2"])),
                     ["robot1", "robot2"])
    log.log_building(np.array([[0.0, 0.0, 5.0, 0.0]]), np.array([2.5]))
    log.log_camera_model("robot1", 520, 520, 319.5, 239.5, 640, 480, 0.09)
    for frame in range(6):
        log.log_pose("robot1", 0.1 * frame, frame, np.array([0.1 * frame, 0, 0]), np.zeros(3), (0.12, 0.045, 0.5))
        log.log_scalars("robot1", 0.1 * frame, {"ess": 90.0, "time/update": 12.0}, frame)
        log.log_stereo("robot1", 0.1 * frame, frame, rng.integers(0, 255, (48, 64), np.uint8),
                       rng.integers(0, 255, (48, 64), np.uint8), rng.uniform(0, 40, (5, 2)), rng.uniform(0, 40, (5, 2)))
    m = _map("robot1", 10, rng)
    log.log_map("robot1", 0.5, m)
    log.log_map("robot2", 0.7, _map("robot2", 0, rng))  # an empty map survives too
    log.log_scalars("robot2", 0.9, {"ess": 50.0})
    log.log_alignment(0.5, "robot1", "robot2", {"tx": 1.0, "error_xy": 0.1})
    log.log_summary({"robots": {}})
    log.close()
    contents = read_recording(rrd)
    assert contents.robots == ["robot1", "robot2"] and contents.duration == pytest.approx(0.9)
    np.testing.assert_array_equal(contents.maps["robot1"].covariances, m.covariances)
    assert len(contents.maps["robot2"]) == 0
    assert contents.alignments == {"robot1_robot2": {"tx": 1.0, "error_xy": 0.1}}
    assert contents.summary == {"robots": {}}


def _maps_seen_from(starts: dict[str, np.ndarray], rng: np.random.Generator) -> dict[str, LandmarkMap]:
    """One map per robot: the building's features within 9 m of its start, in its start frame, 1 cm noise."""
    from estimation.geometry import inverse, transform_points

    world = World.load()
    maps = {}
    for name, start in starts.items():
        near = np.linalg.norm(world.features[:, :2] - start[:2], axis=1) < 9.0
        local = transform_points(inverse(start), world.features[near]) + rng.normal(0, 0.01, (near.sum(), 3))
        maps[name] = LandmarkMap(local, np.tile(np.eye(3) * 1e-4, (near.sum(), 1, 1)),
                                 world.feature_descriptors[near], robot=name,
                                 metadata={"true_start_pose": start.tolist()})
    return maps


TWO_STARTS = {"robot1": np.array([3.0, 5.0, 0.0]), "robot2": np.array([6.0, 5.2, 1.0])}


@pytest.mark.parametrize("n_robots", [2, 3])
def test_fuse_maps_aligns_every_map_to_the_first_and_scores_it_against_the_truth(n_robots):
    from runtime.fusion_report import fuse_maps

    starts = [np.array([3.0, 5.0, 0.0]), np.array([8.0, 5.0, np.pi]), np.array([6.0, 5.2, 1.0])][:n_robots]
    maps = _maps_seen_from({f"robot{k + 1}": start for k, start in enumerate(starts)}, np.random.default_rng(6))
    report = fuse_maps(maps, "robust", 2, t=1.0, rng=np.random.default_rng(0))
    assert [p.other for p in report.pairs] == [f"robot{k}" for k in range(2, n_robots + 1)]
    for pair in report.pairs:
        assert pair.aligned and pair.error_xy < 0.05 and pair.error_theta < 0.01, pair
        assert pair.common > 20
    assert len(report.merged) < sum(len(m) for m in maps.values())
    assert sorted(report.merged.robots) == sorted(maps)


def test_a_fusion_history_keeps_every_report_but_only_the_latest_merged_map():
    from runtime.fusion_report import fuse_maps, keep_latest_map

    maps = _maps_seen_from(TWO_STARTS, np.random.default_rng(3))
    history = []
    for t in (1.0, 2.0, 3.0):
        keep_latest_map(history, fuse_maps(maps, "robust", 2, t=t, rng=np.random.default_rng(0)))
    assert [r.t for r in history] == [1.0, 2.0, 3.0]
    assert [r.merged is None for r in history] == [True, True, False]
    assert all(r.pairs and r.pairs[0].aligned for r in history)  # the figures stay


def test_the_summary_table_shows_each_alignment_with_its_start_frame_uncertainty_beside_its_error():
    from runtime.fusion_report import fuse_maps
    from runtime.report import format_summary

    maps = _maps_seen_from(TWO_STARTS, np.random.default_rng(5))
    pair = fuse_maps(maps, "robust", 2, t=1.0, rng=np.random.default_rng(0)).pairs[0]
    assert pair.aligned and pair.start_sigma_xy > 0 and pair.start_sigma_theta > 0
    text = format_summary({"duration": 1.0, "camera": "synthetic", "particles": 1, "seed": 0, "robots": {},
                           "fusion": {"pairs": [pair.as_dict()], "merged_landmarks": 1}})
    header, _, row = text.splitlines()[-5:-2]
    columns = re.split(r"\s{2,}", header.strip())
    cells = dict(zip(columns, re.split(r"\s{2,}", row.strip()), strict=True))
    assert float(cells["1σ xy (m)"]) == pytest.approx(pair.start_sigma_xy, abs=1e-3)
    assert float(cells["1σ θ (rad)"]) == pytest.approx(pair.start_sigma_theta, abs=1e-4)
    assert float(cells["error xy (m)"]) == pytest.approx(pair.error_xy, abs=1e-3)


FRAME_WAIT_S = 60.0  # s of wall clock for a frame or a state packet that comes in a fraction of a second when idle


def test_videre_camera_comes_back_after_the_head_is_unplugged():
    from drivers.errors import DriverError
    from drivers.videre.head import StereoHead
    from mocks.stereo_head import VirtualStereoHead
    from runtime.adapters import VidereCamera

    virtual = VirtualStereoHead(rng=np.random.default_rng(0))  # test pattern, no world
    camera = VidereCamera(StereoHead.open(backend=virtual), rate=15.0)
    try:  # wall-clock waits: generous bounds (a frame comes in 1/15 s on an idle machine; these only end a broken run)
        first = camera.read(timeout=FRAME_WAIT_S)
        assert first.left.shape == (480, 640) and first.left.dtype == np.uint8
        virtual.unplug()
        with pytest.raises(DriverError):
            camera.read(timeout=0.2)
        virtual.replug()
        frames = [camera.read(timeout=FRAME_WAIT_S) for _ in range(3)]
        assert camera.reconnects >= 1
        assert any(f is not None and f.left.shape == (480, 640) for f in frames)
    finally:
        camera.close()


def test_p3at_link_keeps_odometry_continuous_across_a_reconnection():
    import dataclasses

    from drivers.arcos.robot import P3AT
    from mocks.p3at import serve_tcp
    from runtime.adapters import P3ATLink

    world = World.load()
    samples = []
    with serve_tcp(world, "robot1", port=0, seed=1) as server:
        driver = P3AT(server.url)
        driver.connect()
        link = P3ATLink(driver)
        link.subscribe(samples.append)
        state = driver.wait_for_state(timeout=FRAME_WAIT_S)  # the first SIP, on the wall clock (a generous bound)
        link.close()
    # what the driver delivers: a pose in session 1, then the same place reported by a new session from zero
    moved = dataclasses.replace(state, x=2.0, y=1.0, theta=0.5)
    link._on_state(moved)
    link._on_state(dataclasses.replace(state, session=state.session + 1, x=0.0, y=0.0, theta=0.0))
    link._on_state(dataclasses.replace(state, session=state.session + 1, x=1.0, y=0.0, theta=0.0))
    assert link.reconnects == 1
    np.testing.assert_allclose(samples[-2].pose, [2.0, 1.0, 0.5], atol=1e-12)
    np.testing.assert_allclose(samples[-1].pose, [2.0 + np.cos(0.5), 1.0 + np.sin(0.5), 0.5], atol=1e-12)


def test_frames_get_the_odometry_of_the_instant_they_were_exposed():
    """Virtual robot turning on the spot, virtual head, the real drivers, in simulated time: the odometry the
    runtime interpolates at a frame's timestamp is the pose at which the head exposed that frame, not the pose
    when the frame arrived (a 60 ms exposure-to-arrival delay is ~2° at this rate of turn)."""
    from drivers.arcos.robot import P3AT
    from drivers.videre.head import StereoHead
    from estimation.geometry import between, wrap_angle
    from mocks.p3at import serve_tcp
    from mocks.p3at.model import STEP_S
    from mocks.simclock import SimClock
    from mocks.stereo_head import VirtualStereoHead
    from runtime.adapters import P3ATLink, VidereCamera
    from runtime.onboard import OdometryBuffer

    world = World.load()
    start = np.asarray(world.start_poses["robot1"], float)
    buffer = OdometryBuffer()
    errors, turn_rates = [], []
    with SimClock() as clock, serve_tcp(world, "robot1", start, port=0, seed=1, clock=clock) as server:
        driver = P3AT(server.url, clock=clock)
        server.client_sent = lambda: driver.bytes_written
        model = server.model
        with clock.hold():
            with clock.gate(lambda: model.is_open and model.stats.sips == 0):  # time moves to the first SIP
                driver.connect(enable_motors=True)
            link = P3ATLink(driver)
            clock.add_quiescence("SIPs reach the test", lambda: link.delivered(server.last_sip_sent))
            link.subscribe(lambda sample: buffer.add(sample.t, sample.pose))
            virtual = VirtualStereoHead(world, "robot1", rng=np.random.default_rng(0), realtime=True, latency=0.06,
                                        clock=clock)
            camera = VidereCamera(StereoHead.open(backend=virtual, latency=virtual.latency, clock=clock),
                                  width=320, height=240, rate=7.5)
            token = clock.add_participant("test")
        try:
            with clock.participant(token):
                driver.set_velocity(0.0, 0.6)
                assert clock.wait_for(lambda: abs(driver.state.w) > 0.55, timeout=5.0)
                for _ in range(6):
                    frame = camera.read(timeout=1.0)
                    exposed_at = between(start, virtual.last_frame_pose)
                    assert clock.wait_for(lambda frame=frame: buffer.latest_time >= frame.t, timeout=1.0)
                    errors.append(abs(wrap_angle(buffer.interpolate(frame.t)[2] - exposed_at[2])))
                    turn_rates.append(abs(driver.state.w))
                driver.set_velocity(0.0, 0.0)
        finally:
            camera.close()
            link.close()
    # What is left: the world moves in physics steps (a frame shows the last 10 ms step at or before its
    # exposure: at most w·STEP_S of turn), and the SIP reports the heading in whole angle units. Arrival stamps
    # would be 0.6 rad/s x 60 ms = 0.036 rad off.
    bound = max(turn_rates) * STEP_S + driver.params.angle_conv_factor
    assert len(errors) == 6 and max(errors) <= bound < 0.036 / 3, (errors, bound)


def test_a_long_trajectory_is_logged_in_segments_that_rebuild_the_path(tmp_path):
    """Each frame re-logs only the open segment (the recording grows with the path, not its square), and the
    last state of every segment, joined, is the whole path."""
    import rerun.chunk as rrchunk

    from runtime.rerun_log import TRAJECTORY_SEGMENT, MissionLog
    from runtime.rerun_sink import open_recording

    rrd = tmp_path / "t.rrd"
    log = MissionLog(open_recording(str(rrd)), ["robot1"])
    n = 2 * TRAJECTORY_SEGMENT + 57
    path = np.column_stack([0.01 * np.arange(n), np.sin(np.arange(n) / 50.0), np.zeros(n)])
    for i, pose in enumerate(path):
        log.log_pose("robot1", 0.1 * i, i, pose, None)
    log.close()
    last: dict[str, list] = {}
    logged_points = 0
    for chunk in rrchunk.RrdReader(rrd).stream().filter(content=["+ /world/robot1/trajectory/**"]):
        if chunk.is_static:  # the segment's style, logged once (static)
            continue
        batch = chunk.to_record_batch()
        order = np.argsort(batch.column("frame").to_numpy())
        strips = batch.column("LineStrips3D:strips").to_pylist()
        logged_points += sum(len(s[0]) for s in strips)
        last[chunk.entity_path] = strips[order[-1]][0]
    segments = [np.array(last[k]) for k in sorted(last)]
    assert len(segments) == 3
    joined = np.vstack([segments[0]] + [s[1:] for s in segments[1:]])  # each segment starts where the last ended
    np.testing.assert_allclose(joined[:, :2], path[:, :2], atol=1e-6)
    assert logged_points < n * (TRAJECTORY_SEGMENT + 1) / 2 + n


def _drive_blocked(controller, world: World, pose: np.ndarray, steps: int, bias: np.ndarray | None = None,
                   jitter: float = 0.0, radius: float = 0.33):
    """Like _drive, but the world blocks moves into walls (only the turn happens, as on the virtual P3-AT) and
    the controller steers on the true pose plus ``bias`` (a localisation error) plus ``jitter`` (σ, m: an
    estimate's frame-to-frame corrections). Returns the last command and the true poses."""
    sonar_poses = np.array([[0.1, 0.0, a] for a in np.radians([-90, -50, -30, -10, 10, 30, 50, 90, 150, 180, -150])])
    poses, bias, rng = [pose], np.zeros(3) if bias is None else bias, np.random.default_rng(0)
    for _ in range(steps):
        mounts = compose(pose, sonar_poses)
        ranges, _ = world.raycast(mounts[:, :2], mounts[:, 2], 5.0)
        noise = np.append(rng.normal(0.0, jitter, 2), 0.0)
        cmd = controller.command(pose + bias + noise, sonar_poses, ranges)
        if cmd.done:
            break
        moved = compose(pose, np.array([cmd.v * 0.1, 0.0, cmd.w * 0.1]))
        clearance_new, clearance_old = world.distance_to_walls(np.array([moved[:2], pose[:2]]))
        if clearance_new < radius and clearance_new < clearance_old:
            moved = np.array([pose[0], pose[1], moved[2]])
        pose = moved
        poses.append(pose)
    return cmd, np.array(poses)


def test_pure_pursuit_gives_a_waypoint_up_rather_than_stay_stuck():
    """Steering on a pose 0.45 m off (it believes it is on the doorway's centre line, it is on the frame), the
    robot meets the frame every time: after max_recoveries it gives the room up and finishes the route. The pose
    jitters by 4 mm a step, as FastSLAM's corrections make a standing robot's estimate do."""
    world = World.load()
    route = np.array([[15.0, 5.0], [15.0, 8.3], [15.0, 5.0], [12.0, 5.0]])
    controller = PurePursuit(route, speed=0.35)
    cmd, poses = _drive_blocked(controller, world, np.array([15.45, 5.3, np.pi / 2]), 1500,
                                bias=np.array([-0.45, 0.0, 0.0]), jitter=0.004)
    # each recovery backed it off the frame (it was stuck, not creeping along)
    assert controller.recoveries == controller.max_recoveries + 1 and controller.skipped == 1
    assert cmd.done and np.linalg.norm(poses[-1, :2] - [12.45, 5.0]) < 0.4
