"""The mission summary's final pose and odometry errors are those of the trajectories the run writes (the TUM files
evo reads): the estimate, dead reckoning and truth at one instant, the last frame's. The truth at the stop is later
when a robot still moves, and compared with the last frame's estimate it charged the robot for the motion between."""
from __future__ import annotations

import numpy as np
import pytest

from runtime.mission import Mission, MissionConfig
from runtime.trajectories import read_tum


def test_final_errors_compare_the_last_frames_estimate_odometry_and_truth_at_its_instant(tmp_path):
    # moving at the stop (an explored route, 12 s): the truth at the stop is not the last frame's
    config = MissionConfig(robots=1, seconds=12.0, seed=2, camera="synthetic", camera_rate=5.0, particles=20,
                           fusion_interval=5.0, out=tmp_path, rerun="none")
    result = Mission(config).run()
    (name, figures), = result.summary["robots"].items()
    files = {kind: read_tum(tmp_path / f"{name}{suffix}.tum")
             for kind, suffix in (("estimated", ""), ("odometry", "-odometry"), ("truth", "-truth"))}
    t_last = files["truth"][-1, 0]
    at = {kind: rows[rows[:, 0] == t_last][-1] for kind, rows in files.items()}
    expected = np.hypot(*(at["estimated"][1:3] - at["truth"][1:3]))
    expected_odometry = np.hypot(*(at["odometry"][1:3] - at["truth"][1:3]))
    # the TUM files hold the floats exactly (shortest round-trip repr)
    assert figures["final_position_error"] == pytest.approx(expected, abs=1e-9)
    assert figures["odometry_position_error"] == pytest.approx(expected_odometry, abs=1e-9)

