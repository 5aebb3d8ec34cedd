"""A robot's leave is said after the messages that came before it (session 49).

In a namespace run with bursty loss, robot1's last map (12) and its last status (its mission over) reached the node
together with its leave, after a burst: the node said 'robot1 left the fleet without a word (its link lost or its
process ended); the fusion keeps its map 11' and handled map 12 and the status 1 ms later. The exchange's pump said
the leave as soon as it saw it, while the map and status it had queued just before were still waiting for the
worker. Joins and leaves are now queued with the messages and said by the worker in turn.

A bare Zenoh session plays the robot: its last map and its last status go on the wire, then its liveliness token
goes. The node's worker is made slow (each message waits 0.3 s before it is handled, as a loaded machine's worker
behind a queue of large maps), so without the ordering the leave is said before map 1 for certain.
"""
from __future__ import annotations

import json
import os
import time

import pytest

pytest.importorskip("zenoh")

import zenoh  # noqa: E402

from runtime.fleet import mapwire  # noqa: E402
from runtime.fleet.processes import free_port  # noqa: E402
from runtime.fleet.status import PresenceLines  # noqa: E402
from runtime.fleet.synthetic import SyntheticRobot  # noqa: E402
from runtime.fleet.zenoh_exchange import ZenohExchange  # noqa: E402
from tests.fleet.test_zenoh_fleet import wait_until  # noqa: E402  (a 30 s failure bound, polled)

pytestmark = pytest.mark.timeout(120)


def test_a_robots_leave_is_said_after_its_last_map_and_status():
    port, fleet = free_port(), f"order{os.getpid()}"
    session, source = mapwire.new_session(), SyntheticRobot("robot1", 0)
    lines: list[str] = []
    said: list[PresenceLines] = []
    config = json.dumps({"connect": {"endpoints": [f"tcp/127.0.0.1:{port}"]}, "listen": {"endpoints": []},
                         "scouting": {"multicast": {"enabled": False}}, "mode": "peer"})
    with ZenohExchange(fleet, json.dumps({"listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]}}), "fusion",
                       on_event=lambda line: lines.append(said[0](line) if said else line)) as node:
        said.append(PresenceLines(node.status, node.held))
        robot = zenoh.open(zenoh.Config.from_json5(config))
        try:
            token = robot.liveliness().declare_token(f"p3at/{fleet}/robot1/alive")

            def send(sequence: int, over: bool) -> None:
                robot.put(f"p3at/{fleet}/robot1/map",
                          mapwire.encode_full("robot1", session, sequence, float(sequence), source.step()))
                robot.put(f"p3at/{fleet}/robot1/status",
                          mapwire.encode_status("robot1", session, sequence, float(sequence), None, 10,
                                                {"mission_time": float(sequence), "mission_over": over}))

            send(0, False)
            wait_until(lambda: node.held().get("robot1", (None, -1))[1] == 0, "map 0 at the node")
            handle = node._handle

            def slow_handle(*args):   # a worker behind: each message waits before it is handled
                time.sleep(0.3)
                return handle(*args)

            node._handle = slow_handle
            send(1, True)         # the robot's last map and status, its mission over ...
            token.undeclare()     # ... then it goes
            wait_until(lambda: any(" left the fleet" in x for x in lines), "robot1's leave at the node")
        finally:
            robot.close()
    leave = [x for x in lines if " left the fleet" in x]
    assert leave == ["robot1 left the fleet: its mission is over; the fusion keeps its map 1"], lines
    assert lines.index("robot1 joined the fleet") < lines.index(leave[0])
