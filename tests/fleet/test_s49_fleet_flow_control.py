"""A robot's map stream larger than its link: one map in flight (session 49).

Over 100 kbit between two network namespaces, robot1's maps (up to 73 kB every 5 s) filled TCP's send buffer: every
map waited behind all the earlier ones, the node's view of robot1 grew 48 s old, Zenoh's keep-alives waited too, so
the session was dropped at its lease (10 s) three times with whatever the buffer held, and maps 10-18 of 19 never
reached the node. The robot's sender now puts a map into Zenoh only when the fusion node has said it holds the last
one (an acknowledgement on ``p3at/<fleet>/<robot>/ack``, at most ACK_TIMEOUT s, and only while a node that
acknowledges is connected); maps made meanwhile replace each other (the newest wins, sent whole), the robot says once
that its link carries fewer maps than it makes, and its statuses name the map last sent (the node does not ask for
one still waiting: the query's reply would go around the flow control).

Here the node's acknowledgement of map 1 is held back (what a slow link does to map 1 itself): maps 2 and 3 wait,
3 replaces 2, and once the word comes map 3 goes, whole.
"""
from __future__ import annotations

import json
import logging
import os

import numpy as np
import pytest

pytest.importorskip("zenoh")

from runtime.fleet.processes import free_port  # noqa: E402
from runtime.fleet.synthetic import SyntheticRobot  # noqa: E402
from runtime.fleet.zenoh_exchange import ZenohExchange  # noqa: E402
from tests.fleet.test_zenoh_fleet import wait_until  # noqa: E402  (a 30 s failure bound, polled)

pytestmark = pytest.mark.timeout(120)


def test_a_robots_next_map_waits_until_the_node_holds_the_last(caplog):
    caplog.set_level(logging.WARNING, logger="runtime.fleet.zenoh_exchange")
    port, fleet = free_port(), f"flow{os.getpid()}"
    source = SyntheticRobot("robot1", 0)
    maps = [source.step() for _ in range(4)]
    with ZenohExchange(fleet, json.dumps({"listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]}}), "fusion") as node, \
            ZenohExchange(fleet, json.dumps({"connect": {"endpoints": [f"tcp/127.0.0.1:{port}"]}}),
                          "robot") as robot:
        wait_until(lambda: "fused" in robot.present(), "the node at the robot")
        robot.publish("robot1", maps[0], 0.0)
        wait_until(lambda: robot._acked.get("robot1") == 0, "the node's word that it holds map 0")
        withheld: list[tuple] = []
        acknowledge = node._acknowledge
        node._acknowledge = lambda *args: withheld.append(args)   # the word on map 1 does not come (yet)
        robot.publish("robot1", maps[1], 1.0)
        wait_until(lambda: node.held().get("robot1", (None, -1))[1] == 1, "map 1 at the node")
        robot.publish("robot1", maps[2], 2.0)
        robot.publish("robot1", maps[3], 3.0)
        assert robot.superseded == 1, "map 2 went without waiting for the node's word on map 1"
        said = [r.getMessage() for r in caplog.records if "carries fewer maps than it makes" in r.getMessage()]
        assert len(said) == 1 and said[0].startswith("fleet exchange: robot1's link to the fusion node carries "
                                                     "fewer maps than it makes: its map 1, sent "), said
        robot.publish_status("robot1", 3.5)   # names the map last sent, not the one waiting
        wait_until(lambda: node.status().get("robot1", {}).get("stamp") == 3.5, "the robot's status at the node")
        assert node.status()["robot1"]["sequence"] == 1
        for args in withheld:
            acknowledge(*args)
        wait_until(lambda: node.held().get("robot1", (None, -1))[1] == 3, "map 3 at the node")
        received = node.receive()["robot1"].landmark_map
        np.testing.assert_array_equal(received.ids, maps[3].ids)
        np.testing.assert_array_equal(received.positions, maps[3].positions)
        assert node.dropped["gap"] == 0 and node.held()["robot1"][1] == 3
    said = [r.getMessage() for r in caplog.records if "maps and sent" in r.getMessage()]
    assert said == ["fleet exchange: robot1 made 4 maps and sent 3: 1 skipped, its link to the fusion node carried "
                    "fewer than it made"], said
