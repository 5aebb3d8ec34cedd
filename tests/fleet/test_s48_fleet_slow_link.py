"""A robot's publish never waits for the network (session 48).

Over a 100 kbit link between two network namespaces, a robot's ``ZenohExchange.publish`` (called by its mapping
stage) waited up to 9.9 s inside Zenoh's put: a large query reply (the node asking for a full snapshot) held the
link's queue, and a put of the same priority waits behind it, CongestionControl.DROP or not; the robot dropped 47
camera frames. Maps are now put into Zenoh by the exchange's sender thread; ``publish`` encodes and hands over, and
a map still unsent when the next one comes is replaced by it, sent as a full snapshot (the receivers never held the
replaced one, so a delta would leave them a gap to ask for).

Here the put is made to wait for certain: the robot's map publisher is wrapped so that its put blocks until the test
lets it go (what a congested link does, for as long as the test wants). Loopback, one Zenoh session each.
"""
from __future__ import annotations

import json
import os
import threading

import numpy as np
import pytest

pytest.importorskip("zenoh")

from runtime.fleet.processes import free_port  # noqa: E402
from runtime.fleet.synthetic import SyntheticRobot  # noqa: E402
from runtime.fleet.zenoh_exchange import ZenohExchange  # noqa: E402
from tests.fleet.test_zenoh_fleet import wait_until  # noqa: E402  (a 30 s failure bound, polled)

DEADLINE = 30.0          # s, as tests/fleet/test_zenoh_fleet.py's wait_until
pytestmark = pytest.mark.timeout(120)


class CongestedPublisher:
    """A Zenoh publisher whose put waits until ``release`` is set (a slow link's full queue), then puts."""

    def __init__(self, publisher) -> None:
        self.publisher = publisher
        self.release = threading.Event()
        self.waiting = threading.Event()

    def put(self, data) -> None:
        self.waiting.set()
        self.release.wait(DEADLINE * 4)
        self.publisher.put(data)

    def undeclare(self) -> None:
        self.publisher.undeclare()


def test_publish_returns_while_zenoh_waits_and_the_newest_map_arrives_whole():
    port, fleet = free_port(), f"slow{os.getpid()}"
    source = SyntheticRobot("robot1", 0)
    maps = [source.step() for _ in range(4)]
    with ZenohExchange(fleet, json.dumps({"listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]}}), "fusion") as node, \
            ZenohExchange(fleet, json.dumps({"connect": {"endpoints": [f"tcp/127.0.0.1:{port}"]}}),
                          "robot") as robot:
        robot.publish_status("robot1", 0.0)             # declares the robot's publishers and liveliness token
        wait_until(lambda: "robot1" in node.present(), "robot1 present at the node")
        robot.publish("robot1", maps[0], 0.0)
        wait_until(lambda: node.held().get("robot1", (None, -1))[1] == 0, "map 0 at the node")
        publisher, *rest = robot._own["robot1"]
        congested = CongestedPublisher(publisher)
        robot._own["robot1"] = (congested, *rest)

        returned: list[int] = []

        def mapping_stage() -> None:   # the robot's stage publishes three maps while the link holds the first
            for k in (1, 2, 3):
                robot.publish("robot1", maps[k], float(k))
                returned.append(k)
                if k == 1:
                    congested.waiting.wait(DEADLINE)   # map 1 is inside the put: maps 2 and 3 find the link busy

        stage = threading.Thread(target=mapping_stage, daemon=True)
        stage.start()
        stage.join(DEADLINE)
        assert returned == [1, 2, 3], f"publish waited for the network: returned {returned} of maps 1-3"
        assert robot.superseded == 1   # map 2, replaced by map 3 before the link took it
        congested.release.set()
        wait_until(lambda: node.held().get("robot1", (None, -1))[1] == 3, "map 3 at the node")
        received = node.receive()["robot1"].landmark_map
        np.testing.assert_array_equal(received.ids, maps[3].ids)
        np.testing.assert_array_equal(received.positions, maps[3].positions)
        assert node.dropped["gap"] == 0   # map 3 came as a full snapshot: nothing to ask for
