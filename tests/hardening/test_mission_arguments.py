"""Mission arguments the option types take but the virtual robots cannot honour, said before anything starts (one
line, exit 2; session 25, C). Before: `run --name nobody` started and ended 'mission failed: the world ... has no
robot' (exit 1); `robot serve --time-scale 1e9 --duration 1` never ended (its physics ran 1e9 s per wall second)
and `run --realtime --time-scale 1e308` ended 'no ARCOS handshake after 10 tries' (exit 1); `demo --speed 100`
drove at the robot's top speed with a clamp warning on stderr for every command (a hundred lines in 3 s)."""
from __future__ import annotations

import pytest

from tests.datasets.conftest import run_cli

QUICK = ["--camera", "synthetic", "--seconds", "1", "--quiet", "--rerun", "none"]


def _refused(argv: list[str], says: str) -> None:
    status, _, err = run_cli(*argv)
    assert status == 2 and err.count("\n") == 1 and says in err, (status, err)


def test_run_names_only_a_robot_the_world_has(tmp_path) -> None:
    _refused(["run", *QUICK, "--out", str(tmp_path / "o"), "--name", "nobody"],
             "--name nobody: the world 'office-corridor-35x10' has no robot 'nobody'")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("value", ["1001", "1e9", "1e308"])
def test_a_time_scale_the_virtual_robot_cannot_keep_is_refused(value, tmp_path) -> None:
    _refused(["robot", "serve", "--tcp", "0", "--duration", "1", "--time-scale", value], "at most 1000")
    _refused(["run", *QUICK, "--realtime", "--out", str(tmp_path / "o"), "--time-scale", value], "at most 1000")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("command", ["demo", "run"])
def test_a_route_speed_above_the_robots_top_speed_is_refused(command, tmp_path) -> None:
    _refused([command, *QUICK, "--out", str(tmp_path / "o"), "--speed", "100"], "top speed, 1.2 m/s")
    status, _, err = run_cli(command, *QUICK, "--out", str(tmp_path / "o"), "--speed", "1.2")
    assert status == 0 and err == "", err
