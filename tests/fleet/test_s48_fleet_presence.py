"""Who hears whom in a fleet (session 48): a robot knows whether a fusion node is connected, from the node's start
(not from its first fused map), says at its end which of its maps reached no node, and ``p3at fuse --live`` says
of a leave whether the robot's mission was over or it went without a word, and which of its maps the fusion keeps.

On loopback, each exchange a Zenoh session of the test process (random free ports). Waits have deadlines far above
what they need; nothing asserts a duration.
"""
from __future__ import annotations

import json
import logging
import os
import re

import pytest

pytest.importorskip("zenoh")

from runtime.fleet.processes import free_port  # noqa: E402
from runtime.fleet.status import PresenceLines  # noqa: E402
from runtime.fleet.synthetic import SyntheticRobot  # noqa: E402
from runtime.fleet.zenoh_exchange import ZenohExchange  # noqa: E402
from tests.fleet.test_zenoh_fleet import wait_until  # noqa: E402  (a 30 s failure bound, polled)

pytestmark = pytest.mark.timeout(120)


def listen(port: int) -> str:
    return json.dumps({"listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]}})


def connect(port: int) -> str:
    return json.dumps({"connect": {"endpoints": [f"tcp/127.0.0.1:{port}"]}})


def unheard_lines(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if "reached no fusion node" in r.getMessage()]


def test_a_robot_hears_the_fusion_node_before_the_node_has_fused_anything():
    """The node's liveliness token came with its first fused map (two robots' maps aligned): until then a robot
    could not tell a node that hears it from none."""
    port, fleet = free_port(), f"hear{os.getpid()}"
    events: list[str] = []
    with ZenohExchange(fleet, listen(port), "fusion") as node, \
            ZenohExchange(fleet, connect(port), "robot", on_event=events.append) as robot:
        wait_until(lambda: "fused" in robot.present(), "the fusion node present at the robot")
        wait_until(lambda: "the fusion node joined the fleet" in events, "the robot's line for the node's join")
        assert node.fused() is None and "fused" not in node.present()   # nothing fused; a node does not hear itself
        node.close()
        wait_until(lambda: "the fusion node left the fleet" in events, "the robot's line for the node's leave")


def test_a_robot_that_ends_with_no_fusion_node_says_which_maps_reached_none(caplog):
    """Its maps went nowhere: the robot says so at its end, naming them, instead of ending as if the fleet had
    them. Maps published while a node was there, or before a node joined (the node then asks for the latest),
    are not named, except those of the lease before the node was seen leaving, named as perhaps received."""
    caplog.set_level(logging.WARNING, logger="runtime.fleet.zenoh_exchange")
    port, fleet = free_port(), f"alone{os.getpid()}"
    source = SyntheticRobot("robot1", 0)
    with ZenohExchange(fleet, connect(port), "robot") as robot:   # nobody listens on the port
        robot.publish("robot1", source.step(), 1.0)
        robot.publish("robot1", source.step(), 2.0)
    [line] = unheard_lines(caplog)
    assert "robot1's maps 0-1" in line and "no fusion node was connected" in line, line

    caplog.clear()
    port, fleet = free_port(), f"late{os.getpid()}"
    events: list[str] = []
    with ZenohExchange(fleet, connect(port), "robot", on_event=events.append) as robot:
        robot.publish("robot1", source.step(), 1.0)             # before any node
        with ZenohExchange(fleet, listen(port), "fusion") as node:
            wait_until(lambda: "fused" in robot.present(), "the late node present at the robot")
            robot.publish("robot1", source.step(), 2.0)          # heard
            wait_until(lambda: node.held().get("robot1", (None, -1))[1] == 1, "map 1 at the node")
        wait_until(lambda: "the fusion node left the fleet" in events, "the node's leave at the robot")
        assert unheard_lines(caplog) == []
        robot.publish("robot1", source.step(), 3.0)              # after the node left
    [line] = unheard_lines(caplog)   # maps 0-1, sent within the lease (10 s) before the leave, perhaps reached it
    assert re.match(r"fleet exchange: robot1's (map 2|maps [01]-2 \([01](-1)? perhaps did: sent within Zenoh's "
                    r"lease, 10 s, before the node was seen leaving\)), of the last \d+ s, reached no fusion node: "
                    r"the fusion node left \d+ s ago", line), line


def test_p3at_fuse_live_says_how_a_robot_left_and_which_map_the_fusion_keeps():
    """A robot whose last status said its mission was over left cleanly; one that went without a word (a link
    lost, a process killed) is said so, with the map the fusion keeps; its return says how long it was gone.
    (The lines the exchange gives stay 'robot1 left the fleet', which callers match.)"""
    port, fleet = free_port(), f"says{os.getpid()}"
    lines: list[str] = []
    source = SyntheticRobot("robot1", 0)
    with ZenohExchange(fleet, listen(port), "fusion") as node:
        say = PresenceLines(node.status, node.held)
        node.on_event = lambda line: lines.append(say(line))
        with ZenohExchange(fleet, connect(port), "robot") as robot:
            robot.publish_status("robot1", 0.0)   # declares its liveliness token
            wait_until(lambda: "robot1" in node.present(), "robot1 present at the node")
            robot.publish("robot1", source.step(), 1.0)
            # a put before the route to the node exists is lost: a status naming map 0 has it asked for
            wait_until(lambda: "robot1" in node.held() or robot.publish_status("robot1", 1.0) or False,
                       "robot1's map 0 at the node")
        left = wait_until(lambda: [x for x in lines if x.startswith("robot1 left the fleet")], "robot1's leave")
        assert left == ["robot1 left the fleet without a word (its link lost or its process ended); the fusion "
                        "keeps its map 0"], left

        with ZenohExchange(fleet, connect(port), "robot") as robot:  # back, a new session: its mission ends
            robot.publish_status("robot1", 0.0)   # its liveliness token comes with its first status or map
            joined = wait_until(lambda: [x for x in lines if x.startswith("robot1 joined the fleet again")],
                                "robot1's return")
            assert re.fullmatch(r"robot1 joined the fleet again, \d+ s after it left", joined[0]), joined
            robot.publish("robot1", source.step(), 1.0)

            def last_status_and_map_at_the_node() -> bool:   # sent again until seen: a put may precede the route
                robot.publish_status("robot1", 2.0, health={"mission_over": True})
                status = node.status().get("robot1") or {}
                return bool((status.get("health") or {}).get("mission_over")) \
                    and node.held().get("robot1") == (status.get("session"), 0)

            wait_until(last_status_and_map_at_the_node, "robot1's last status and its new map 0 at the node")
        wait_until(lambda: len([x for x in lines if " left the fleet" in x]) == 2, "robot1's second leave")
    assert lines[-1] == "robot1 left the fleet: its mission is over; the fusion keeps its map 0", lines
