"""``p3at robot drive`` stamps its last line, the robot at rest, with the time the robot reported it stood: the
stamp was taken before the wait for the stop, so a robot that needed seconds to brake printed its resting pose at
the instant the stop was sent (e.g. ``1.004  0.134 ... v 0.20`` then ``1.004  0.200 ... v 0``: 6.6 cm in no time)."""
from __future__ import annotations

import json

import numpy as np

from mocks.p3at import FirmwareDefaults, serve_tcp
from mocks.world import World
from runtime.cli import main

LINK = ["--link-timeout", "600"]   # not about the link: no starved thread may count as a lost robot


def test_the_line_of_the_robot_at_rest_is_stamped_after_its_braking(capsys) -> None:
    # 100 mm/s² in the robot's CONFIG: from ~0.6 m/s it needs ~6 s of its own time to stop, as many of the wall's
    # (more on a loaded machine, never less). The wall clock is the command's subject; at 1x (2x until session 47) the
    # robot's thread needs 1.6 % of a core to keep up (2.3 % at 2x).
    walls = np.array([[-60, -60, 60, -60], [60, -60, 60, 60], [60, 60, -60, 60], [-60, 60, -60, -60]], float)
    with serve_tcp(World("open", walls, np.full(4, 3.0)), "robot1", np.zeros(3), port=0, seed=3,
                   firmware=FirmwareDefaults(trans_accel=2000, trans_decel=100)) as server:
        assert main(["robot", "drive", server.url, "--vel", "0.6", "--seconds", "1", "--every", "0.25", "--json",
                     *LINK]) == 0, capsys.readouterr().err
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    moving, rest = lines[-2], lines[-1]
    assert moving["v"] > 0.3 and rest["v"] == 0.0        # it drove fast, and stopped
    assert rest["t"] - moving["t"] > 1.5, (moving, rest)  # braking took seconds, and the stamp says so
