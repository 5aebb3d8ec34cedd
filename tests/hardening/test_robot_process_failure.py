"""`p3at demo --processes`: a robot process that dies without its summary is said in one line naming the signal
and the map it left (session 23). Before, a robot killed with SIGKILL read `robot1 (exit -9): ?`."""
from __future__ import annotations

import signal
from pathlib import Path

from estimation.landmark_map import LandmarkMap
from runtime.fleet.processes import failure_line


def test_a_killed_robot_is_named_with_its_signal_and_the_map_it_left(tmp_path) -> None:
    saved = tmp_path / "robot1" / "robot1.npz"
    saved.parent.mkdir()
    LandmarkMap([[0.0, 0.0, 0.0]], [[[1e-2, 0, 0], [0, 1e-2, 0], [0, 0, 1e-2]]], [[1.0]], robot="robot1").save(saved)
    line = failure_line("robot1", -signal.SIGKILL, "", saved)
    assert line.startswith("robot1 (exit -9): killed by SIGKILL, no summary") and str(saved) in line
    assert "\n" not in line and "?" not in line
    assert "killed by SIGTERM" in failure_line("robot2", -signal.SIGTERM, "a warning\n", tmp_path / "none.npz")
    assert failure_line("robot2", -200, "", tmp_path / "none.npz").endswith(
        "killed by signal 200, no summary; it saved no map")


def test_a_robot_that_failed_says_its_last_line() -> None:
    line = failure_line("robot1", 1, "starting\np3at run: mission failed: robot1 slam: boom\n",
                        Path("/nonexistent/robot1.npz"))
    assert line == "robot1 (exit 1): p3at run: mission failed: robot1 slam: boom; it saved no map"
    assert failure_line("robot1", 3, "", Path("/nonexistent")).startswith(
        "robot1 (exit 3): no summary, nothing on stderr")
