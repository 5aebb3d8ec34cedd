"""A sensor log whose folder vanishes says why (session 47, F).

The writer thread keeps running after a fault (a logging fault must not stop the robot) and kept the *last* error:
with the log's folder removed mid-run the mission reported ``writing the log failed (write to closed file)``, a
consequence, where the cause was ``No such file or directory`` on the segment it could not finish. It now keeps
the first.
"""
from __future__ import annotations

import shutil

import numpy as np
import pytest

from runtime.sensorlog import SensorLogError, SensorLogWriter


def _odometry(t: float) -> dict:
    return {"t": t, "x": 0.1 * t, "y": 0.0, "theta": 0.0, "v": 0.1, "w": 0.0, "stalled": False,
            "sonar": np.full(8, 2.0), "sonar_poses": np.zeros((8, 3)), "raw": np.zeros(40, np.uint8)}


def test_a_log_whose_folder_is_removed_names_the_first_fault_not_its_consequences(tmp_path):
    folder = tmp_path / "out" / "robot1-log"
    writer = SensorLogWriter(folder, {"robot": "robot1"}, segment_seconds=0.5, flush_interval=0.1)
    for k in range(4):
        writer.write("odometry", _odometry(0.1 * k))
    writer.flush()
    shutil.rmtree(tmp_path / "out")  # the output folder removed under a running mission
    for k in range(4, 30):  # on through two segment ends: each close and open fails
        writer.write("odometry", _odometry(0.1 * k))
    with pytest.raises(SensorLogError) as failed:
        writer.close()
    message = str(failed.value)
    assert "No such file or directory" in message, message
    assert "closed file" not in message
