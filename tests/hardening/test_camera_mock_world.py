"""`camera info/grab --mock` with a building file that cannot be read, or a robot it does not have, is the user's
input: exit 2, one line (session 25, C). It was exit 1, the status of a head that does not answer."""
from __future__ import annotations

import os

import pytest

from tests.datasets.conftest import run_cli


@pytest.mark.parametrize("action", ["info", "grab"])
@pytest.mark.parametrize("world", ["binary", "folder", "fifo", "missing", "robot"])
def test_a_bad_building_or_robot_for_the_virtual_head_is_exit_2(action, world, tmp_path) -> None:
    path = tmp_path / "world.json"
    if world == "binary":
        path.write_bytes(bytes(range(256)))
    elif world == "folder":
        path.mkdir()
    elif world == "fifo":
        os.mkfifo(path)
    argv = ["camera", action, "--mock"] + (["--name", "nobody"] if world == "robot" else ["--world", str(path)])
    argv += ["--out", str(tmp_path / "pair")] if action == "grab" else []
    status, _, err = run_cli(*argv)
    assert status == 2 and err.count("\n") == 1 and err.startswith(f"p3at camera {action}: "), (status, err)
    assert not (tmp_path / "pair").exists()
