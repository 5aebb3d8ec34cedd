"""How old what the fusion node shows is (session 49).

On a saturated or lossy link a robot's statuses came 16-18 s late and its maps later still (session 48), and
``p3at fuse --live`` printed them as if they were current. Maps and statuses now carry the sender's clock when the
map was made or the status sent (mapwire header field ``wall``); the receiver takes the least delay a robot's
messages have shown as that robot's clock offset (no clock synchronisation assumed) and says, in each status line,
how long ago the status was sent and which map of the robot it fuses, made how long ago, and whether the robot's
status names a newer one. A present robot whose newest status grows old is said again with its age rather than
falling silent.

Here a bare Zenoh session plays a robot whose clock is 1000 s behind the node's and whose map arrives 12.4 s after it
was made (its put held back, as a slow link does): the node says the map is about 12 s old, not 1012 s and not 0.
"""
from __future__ import annotations

import json
import os
import time

import numpy as np
import pytest

pytest.importorskip("zenoh")

import zenoh  # noqa: E402

from runtime.fleet import mapwire  # noqa: E402
from runtime.fleet.processes import free_port  # noqa: E402
from runtime.fleet.status import StatusPrinter, status_line  # noqa: E402
from runtime.fleet.synthetic import SyntheticRobot  # noqa: E402
from runtime.fleet.zenoh_exchange import ZenohExchange  # noqa: E402
from tests.fleet.test_zenoh_fleet import wait_until  # noqa: E402  (a 30 s failure bound, polled)

pytestmark = pytest.mark.timeout(120)
SKEW = 1000.0     # s the robot's clock is behind the node's
LATE = 12.4       # s between the map's making and its put


def _health(t: float) -> dict:
    return {"clock": "wall", "mission_time": t, "frames_processed": 45, "frames_dropped": 0, "link": "up"}


def test_the_node_says_how_old_a_late_map_is_whatever_the_robots_clock():
    port, fleet = free_port(), f"age{os.getpid()}"
    session = mapwire.new_session()
    m = SyntheticRobot("robot1", 0).step()
    config = json.dumps({"connect": {"endpoints": [f"tcp/127.0.0.1:{port}"]}, "listen": {"endpoints": []},
                         "scouting": {"multicast": {"enabled": False}}, "mode": "peer"})
    with ZenohExchange(fleet, json.dumps({"listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]}}), "fusion") as node:
        robot = zenoh.open(zenoh.Config.from_json5(config))
        try:
            token = robot.liveliness().declare_token(f"p3at/{fleet}/robot1/alive")
            wait_until(lambda: "robot1" in node.present(), "robot1 present at the node")

            def status(sequence: int, has_map: bool) -> None:
                robot.put(f"p3at/{fleet}/robot1/status",
                          mapwire.encode_status("robot1", session, sequence, 1.0, None, len(m), _health(1.0),
                                                has_map=has_map, wall=time.time() - SKEW))

            status(0, False)   # on an idle link: the node learns the robot's clock from it
            wait_until(lambda: node.status().get("robot1", {}).get("age") is not None, "the status's age")
            first = node.status()["robot1"]
            assert first["map_held"] is None and first["age"] < LATE   # sent just now, whatever the robot's clock
            assert status_line("robot1", first).endswith("link up")   # no map published yet: nothing to say of one
            made = time.time() - SKEW - LATE   # the map made LATE s ago, on the robot's clock, and put only now
            robot.put(f"p3at/{fleet}/robot1/map", mapwire.encode_full("robot1", session, 0, 1.0, m, wall=made))
            status(1, True)    # the robot's newest is map 1, which never comes
            wait_until(lambda: node.status().get("robot1", {}).get("map_held") == 0 and
                       node.status()["robot1"]["sequence"] == 1, "map 0 and the status naming map 1")
            seen = node.status()["robot1"]
            np.testing.assert_array_equal(node.receive()["robot1"].landmark_map.ids, m.ids)
            # LATE s old less the status's own transit (the offset the node learnt): not 0, not SKEW + LATE
            assert LATE - 2.0 < seen["map_age"] < SKEW / 2, seen
            assert seen["age"] < seen["map_age"] and seen["present"] is True
            line = status_line("robot1", seen)
            assert f"; fusing its map 0, made {seen['map_age']:.1f} s ago (its newest, map 1, not here yet)" in line
            assert line.startswith("status robot1: t=1.0 s wall, sent ")
            token.undeclare()
        finally:
            robot.close()


def test_a_status_line_says_how_old_the_status_and_the_map_fused_are():
    status = {"stamp": 7.2, "session": "a" * 16, "sequence": 9, "pose": [1.49, -0.21, 0.84], "landmarks": 37,
              "health": {"clock": "simulated", "mission_time": 7.2, "frames_processed": 108, "frames_dropped": 0,
                         "ms_update": 12.3, "battery_volts": 13.0, "link": "up"},
              "present": True, "age": 16.24, "map_held": 5, "map_age": 12.43}
    assert status_line("robot2", status) == (
        "status robot2: t=7.2 s simulated, sent 16.2 s ago, 108 frames (0 dropped), 37 landmarks, "
        "pose (1.49, -0.21, 0.84), update 12.3 ms, battery 13.0 V, link up; fusing its map 5, made 12.4 s ago "
        "(its newest, map 9, not here yet)")
    assert status_line("robot2", {**status, "map_held": 9, "map_age": 0.5}).endswith(
        "; fusing its map 9, made 0.5 s ago")
    assert status_line("robot2", {**status, "map_held": None, "map_age": None}).endswith("; no map of it here yet")
    # a sender without clock stamps (before session 49): no ages, the map held still named
    assert status_line("robot2", {**status, "age": None, "map_age": None}).endswith(
        "link up; fusing its map 5 (its newest, map 9, not here yet)")


class ManualClock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_a_present_robot_whose_status_grows_old_is_said_again_with_its_age():
    clock, lines = ManualClock(), []
    status = {"stamp": 3.0, "session": "a" * 16, "sequence": 0, "pose": None, "landmarks": 4,
              "health": {"clock": "wall", "mission_time": 3.0, "frames_processed": 15}, "present": True,
              "age": 0.1, "map_held": 0, "map_age": 1.0}
    statuses = {"robot1": status}
    printer = StatusPrinter(lambda: {r: dict(s) for r, s in statuses.items()}, lines.append, period=10.0,
                            clock=clock, stale_after=20.0)
    printer.poll()
    assert len(lines) == 1 and "sent 0.1 s ago" in lines[0]
    clock.now, status["age"] = 10.0, 10.1
    printer.poll()
    assert len(lines) == 1                                  # nothing new, and not yet old
    clock.now, status["age"], status["map_age"] = 20.0, 20.1, 21.0
    printer.poll()
    assert len(lines) == 2 and "sent 20.1 s ago" in lines[1] and "made 21.0 s ago" in lines[1]
    clock.now = 25.0
    printer.poll()
    assert len(lines) == 2                                  # at most once a period
    status["present"] = False                               # it left: said by the leave line, not repeated here
    clock.now, status["age"] = 40.0, 40.1
    printer.poll()
    assert len(lines) == 2
    status["present"], status["health"] = True, {**status["health"], "mission_over": True}
    printer.poll()
    assert len(lines) == 2                                  # its last status: no newer one is coming


@pytest.mark.parametrize("wall", ['"12"', "true", "1e999", "[1]"])
def test_a_clock_stamp_that_is_not_a_finite_number_is_refused(wall):
    data = mapwire.encode_status("robot1", "a" * 16, 0, 1.0, wall=5.0)
    data = data.replace(b'"wall":5.0', b'"wall":' + wall.encode())
    data = data[:8] + (len(data) - 12).to_bytes(4, "little") + data[12:]   # the header's new length
    with pytest.raises(mapwire.WireError, match="'wall'"):
        mapwire.decode(data)
    assert mapwire.decode(mapwire.encode_status("robot1", "a" * 16, 0, 1.0, wall=5.0)).wall == 5.0
    assert mapwire.decode(mapwire.encode_status("robot1", "a" * 16, 0, 1.0)).wall is None
