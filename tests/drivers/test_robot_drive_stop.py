"""``p3at robot drive`` waits for the robot to stop in the robot's own time (its state packets), not this
process's seconds: a robot whose clock runs slower than the wall's (a starved simulator, here one run at a quarter
of the wall clock's speed) still stops within its deceleration, and the drive ends with it at rest."""
from __future__ import annotations

import json
from collections.abc import Iterator

import pytest

from mocks.p3at import serve_tcp
from mocks.world import World
from runtime.cli import main

SLOW = 0.25           # the robot's seconds per wall-clock second
LINK = ["--link-timeout", "600"]   # not about the link: no starved thread may count as a lost robot


@pytest.fixture
def slow_robot() -> Iterator:
    server = serve_tcp(World.load(), "robot1", port=0, time_scale=SLOW, seed=3)
    yield server
    server.close()


def test_a_robot_slower_than_the_wall_clock_is_waited_for_until_it_stops(slow_robot, capsys) -> None:
    # 6 s of wall clock are 1.5 s of the robot's: it reaches ~0.4 m/s (ARIA's default 0.3 m/s² acceleration), and
    # decelerating from there takes it ~1.3 s of its own time, ~5 s of the wall's: more than the 2 s of wall clock
    # the command used to wait, within its 30 state packets
    assert main(["robot", "drive", slow_robot.url, "--vel", "0.4", "--rvel", "0", "--seconds", "6", "--every", "1",
                 "--json", *LINK]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert max(line["v"] for line in lines) > 0.2   # it did drive fast enough to need the time to stop
    assert lines[-1]["v"] == 0.0 and lines[-1]["w"] == 0.0
