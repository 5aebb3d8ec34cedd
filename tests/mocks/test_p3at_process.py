"""Virtual P3-ATs served from their own process (``serve_tcp_process``), spoken to by the real ARCOS driver."""

from __future__ import annotations

import os

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.arcos.robot import P3AT
from mocks.p3at import RobotProcessError, RobotSpec, serve_tcp_process
from mocks.p3at.process import PoseTable
from mocks.world import World

# Generous wall-clock bounds on a loaded 2-core machine: each only limits how long a broken run hangs; the
# robot needs ~1 s of wall time to cover the distances below at 0.3 m/s.
STATE_TIMEOUT_S = 20.0
# Not about the link: the driver's default (4 s without a packet) counted a robot process starved for that long as
# lost (seen beside the other helpers' runs: "link lost (no packet for 4.3 s)", then a new session with the motors
# off, and the drive never reached its distance); reproduced by stopping the robot's process for 5 s.
LINK_TIMEOUT_S = 600.0


@pytest.fixture
def world() -> World:
    return World.load()


def drive_until(driver: P3AT, predicate) -> None:
    driver.wait_for_state(timeout=STATE_TIMEOUT_S, predicate=predicate)


def test_a_robot_in_its_own_process_is_driven_by_the_driver_and_its_true_pose_is_shared(world: World) -> None:
    start = np.asarray(world.start_poses["robot1"], float)
    with serve_tcp_process(world, [RobotSpec("robot1", seed=3), RobotSpec("robot2")]) as robots:
        server = robots.servers["robot1"]
        assert robots.pid != os.getpid() and server.url.startswith("socket://127.0.0.1:")
        assert sorted(world.robot_names()) == ["robot1", "robot2"]
        np.testing.assert_allclose(world.pose("robot1"), start)  # published before the child says it is ready
        with P3AT(server.url, link_timeout=LINK_TIMEOUT_S) as driver:
            driver.connect()
            driver.motors_on()
            driver.set_velocity(0.3, 0.0)
            drive_until(driver, lambda s: s.x >= 0.25)
            driver.set_velocity(0.0, 0.0)
            stopped = driver.wait_for_state(timeout=STATE_TIMEOUT_S, predicate=lambda s: not s.moving and s.v == 0)
            # exact odometry (the default): the robot's report and the pose its process shares agree to the
            # SIP's resolution (1 mm); the robot stands still, so the shared pose is final
            travelled = world.pose("robot1") - start
            assert travelled[0] >= 0.25 and abs(travelled[0] - stopped.x) <= 0.002 and abs(travelled[1]) < 1e-6
            np.testing.assert_allclose(server.true_pose(), world.pose("robot1"))
        other, other_start = world.pose("robot2"), world.start_poses["robot2"]  # nobody drove it
        assert np.allclose(other[:2], other_start[:2]) and np.isclose(np.cos(other[2] - other_start[2]), 1.0)
        assert server.error is None
    assert world.robot_names() == []  # close() took the robots out
    times = np.asarray(server.sip_wall_times)
    assert len(times) >= 3 and np.all(np.diff(times) >= 0)  # the child's SIP send times came back
    with pytest.raises(ProcessLookupError):
        os.kill(robots.pid, 0)  # the child has exited (and was reaped)


def test_the_virtual_head_renders_from_the_pose_the_robots_process_shares(world: World) -> None:
    from drivers.videre.head import StereoHead
    from mocks.stereo_head import VirtualStereoHead
    from runtime.adapters import VidereCamera

    start = np.asarray(world.start_poses["robot1"], float)
    with serve_tcp_process(world, [RobotSpec("robot1")]) as robots, \
            P3AT(robots.servers["robot1"].url, link_timeout=LINK_TIMEOUT_S) as driver:
        virtual = VirtualStereoHead(world, "robot1", rng=np.random.default_rng(0))
        camera = VidereCamera(StereoHead.open(backend=virtual), width=320, height=240, rate=7.5)
        try:
            camera.read(timeout=STATE_TIMEOUT_S)
            np.testing.assert_allclose(virtual.last_frame_pose, start)
            driver.connect()
            driver.motors_on()
            driver.set_velocity(0.3, 0.0)
            drive_until(driver, lambda s: s.x >= 0.2)
            # a frame may already be on its way, rendered a moment before the odometry said 0.2 m (seen under load:
            # 0.1995 m); the robot keeps driving, so one of the next few frames is rendered beyond it
            for _ in range(5):
                camera.read(timeout=STATE_TIMEOUT_S)
                if virtual.last_frame_pose[0] - start[0] >= 0.2:
                    break
            assert virtual.last_frame_pose[0] - start[0] >= 0.2  # the frame was rendered where the robot went
        finally:
            camera.close()


def test_a_robot_that_cannot_be_built_is_one_clear_error_and_nothing_is_left(world: World) -> None:
    with pytest.raises(RobotProcessError, match="did not start: .*nosuch"):
        serve_tcp_process(world, [RobotSpec("robot1", subtype="nosuch")])
    assert world.robot_names() == []
    with pytest.raises(ValueError, match="start pose"):
        serve_tcp_process(world, [RobotSpec("robot9")])
    with pytest.raises(ValueError, match="each once"):
        serve_tcp_process(world, [RobotSpec("robot1"), RobotSpec("robot1")])
    with pytest.raises(ValueError, match="from a file"):
        serve_tcp_process(World("box", np.array([[0.0, 0, 1, 0]]), np.array([1.0])), [RobotSpec("a", (0, 0, 0))])


def test_an_attached_robot_is_read_from_its_source_and_cannot_be_set_here(world: World) -> None:
    pose = np.array([1.0, 2.0, 0.5])
    world.attach_robot("far", lambda: pose)
    pose[0] = 4.0  # the source is asked at every read
    np.testing.assert_array_equal(world.pose("far"), [4.0, 2.0, 0.5])
    np.testing.assert_array_equal(world.robot_poses()["far"], [4.0, 2.0, 0.5])
    with pytest.raises(ValueError, match="kept elsewhere"):
        world.set_pose("far", np.zeros(3))
    with pytest.raises(ValueError, match="already"):
        world.add_robot("far", np.zeros(3))
    world.remove_robot("far")
    assert world.robot_names() == []


@given(st.lists(st.tuples(st.integers(0, 2), st.floats(allow_nan=False), st.floats(allow_nan=False),
                          st.floats(-4, 4), st.floats(0, 1e6)), max_size=20))
def test_a_pose_table_gives_back_each_slots_last_write(writes) -> None:
    table = PoseTable.create(3)
    reader = PoseTable(table.path, 3)  # as another process opens it
    try:
        last = {}
        for slot, x, y, th, t in writes:
            table.write(slot, np.array([x, y, th]), t)
            last[slot] = ([x, y, th], t)
        for slot in range(3):
            pose, t = reader.read(slot)
            if slot in last:
                np.testing.assert_array_equal(pose, last[slot][0])
                assert t == last[slot][1]
            else:
                assert np.all(np.isnan(pose)) and t == -np.inf
    finally:
        reader.close()
        table.close(unlink=True)
    assert not table.path.exists()


A_PARENT_THAT_DIES = """
import os, signal, sys
from mocks.p3at import RobotSpec, serve_tcp_process
from mocks.world import World

robots = serve_tcp_process(World.load(), [RobotSpec("robot1")])
print(robots.pid, flush=True)
os.kill(os.getpid(), signal.SIGKILL)  # as a killed p3at run --realtime: the child's pipes lose their other end
"""


@pytest.mark.timeout(600)
def test_a_robots_process_whose_parent_was_killed_ends_quietly() -> None:
    """Its goodbye to the dead parent's pipe raised BrokenPipeError: a 7-line traceback on the user's terminal
    (the child shares the parent's stderr) after a killed ``p3at run --realtime`` (session 47, F's audit)."""
    import subprocess
    import sys
    import time
    from pathlib import Path

    repo = Path(__file__).resolve().parents[2]
    env = dict(os.environ, PYTHONPATH=str(repo))
    parent = subprocess.Popen([sys.executable, "-c", A_PARENT_THAT_DIES], cwd=repo, env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    # stderr ends when its last writer, the child, has exited (it notices the closed stdin within 0.1 s)
    stdout, stderr = parent.communicate(timeout=300)
    assert parent.returncode == -9 and stdout.strip().isdigit()
    assert stderr == "", stderr
    stat, deadline = Path(f"/proc/{int(stdout)}/stat"), time.monotonic() + 120  # bounds a broken run only
    while stat.exists() and stat.read_text().rsplit(")", 1)[1].split()[0] != "Z" and time.monotonic() < deadline:
        time.sleep(0.05)  # it ends (gone, or a zombie where the container's init reaps no orphans)
    assert not stat.exists() or stat.read_text().rsplit(")", 1)[1].split()[0] == "Z"
