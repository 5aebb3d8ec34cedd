"""`p3at slam simulate` refuses a start pose or a route waypoint outside the building, in one line, exit 2.

The simulated robot does not collide with walls, so `--start-pose 100,100,0` (a typo, or a pose in another building's
coordinates) ran, mapped nothing and printed nan figures with exit 0 (session 48's walkthrough of docs/fastslam.md).
"""
from __future__ import annotations

import contextlib
import io

import pytest

from runtime.cli import main


def _run(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main(list(argv))
    return status, out.getvalue(), err.getvalue()


@pytest.mark.parametrize(("args", "complaint"), [
    (["--start-pose", "100,100,0"], "--start-pose: (100, 100) is outside the world 'office-corridor-35x10' "
                                    "(x 0 to 35 m, y 0 to 10 m)"),
    (["--start-pose", "3,-0.5,0"], "--start-pose: (3, -0.5) is outside the world"),
    (["--world-route", "ROUTE"], "--world-route: waypoint 2 (200, 5) is outside the world 'office-corridor-35x10'"),
])
def test_a_start_or_waypoint_outside_the_building_is_refused(tmp_path, args, complaint):
    route = tmp_path / "far.route"
    route.write_text("3 5\n200 5\n")
    out_map = tmp_path / "m.npz"
    status, out, err = _run("slam", "simulate", "--out", str(out_map), "--seconds", "1",
                            *[str(route) if a == "ROUTE" else a for a in args])
    assert status == 2 and out == "" and err.count("\n") == 1 and complaint in err, err
    assert not out_map.exists()


def test_a_start_inside_the_building_still_runs(tmp_path):
    status, out, err = _run("slam", "simulate", "--out", str(tmp_path / "m.npz"), "--seconds", "1",
                            "--start-pose", "3,5,0", "--particles", "5")
    assert status == 0 and "map written to" in out, err
