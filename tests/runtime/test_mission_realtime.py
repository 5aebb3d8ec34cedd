"""``--realtime`` missions: the virtual robots are served from a process of their own (issue 15's SIP timing).

No figure here depends on the machine's speed: the SIP cycle itself is measured by benchmarks/bench_sip_timing.py.
"""

from __future__ import annotations

import os

import numpy as np

from runtime.mission import Mission, MissionConfig


def test_a_realtime_mission_drives_robots_served_from_another_process_and_scores_against_their_shared_pose(
        tmp_path) -> None:
    config = MissionConfig(robots=2, seconds=4.0, seed=1, camera="synthetic", camera_rate=5.0, particles=10,
                           fusion_interval=0.0, map_save_interval=0.0, out=tmp_path, rerun="none", realtime=True)
    mission = Mission(config)
    result = mission.run()
    assert result.summary["clock"] == "wall" and not result.failures
    pids = {server._process.pid for server in mission._servers.values()}
    assert len(pids) == 1 and os.getpid() not in pids  # both robots in one child: they share one world
    for robot in mission.robots:
        server = mission._servers[robot.name]
        assert server.error is None and len(server.sip_wall_times) >= 5  # the child streamed SIPs to the driver
        # the truth the mission scored against is the child's pose, shared: the robot drove along its route
        moved = robot.onboard.final_true_pose[:2] - robot.true_start[:2]
        assert np.hypot(*moved) > 0.05, (robot.name, moved)
