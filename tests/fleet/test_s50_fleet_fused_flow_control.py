"""The fused map to robots, bounded: one in flight per robot, the newest wins (session 50, N).

Session 49 found the fusion node's merged map (77-92 kB a fusion, every ~2.5 s with two robots) put to every robot with
nothing bounding it: over a 100-kbit link fused maps queued behind each other, and the node's acknowledgements and
Zenoh's keep-alives behind them, so robot1 was cut off three times and its maps 7-18 were lost. The node now puts only a
small status naming each new fused map (``p3at/<fleet>/fused/status``, at the statuses' priority), and each robot pulls
the newest by query, with one request open at a time: on a slow link the reply to that request is the one fused map in
flight, and what it carries is the newest at its answer.

Here the node's reply to robot1's request is held back (what a slow link does to it): the node makes fused maps 1 and 2
meanwhile, robot1 holds none of them and asks no second time; once the reply goes, robot1 holds fused map 2, whole.
"""
from __future__ import annotations

import json
import os

import numpy as np
import pytest

pytest.importorskip("zenoh")

from runtime.fleet.processes import free_port  # noqa: E402
from runtime.fleet.synthetic import SyntheticRobot  # noqa: E402
from runtime.fleet.zenoh_exchange import FUSED, ZenohExchange  # noqa: E402
from tests.fleet.test_zenoh_fleet import wait_until  # noqa: E402  (a 30 s failure bound, polled)

pytestmark = pytest.mark.timeout(120)


def test_a_robot_pulls_the_newest_fused_map_with_one_request_in_flight():
    port, fleet = free_port(), f"fusedflow{os.getpid()}"
    source = SyntheticRobot("robot1", 0, landmarks=200, grow=100)
    fused = [source.step() for _ in range(3)]   # the node's fused maps 0, 1, 2 (any maps do)
    # the robot first, so that every request it makes for the fused map is counted (it asks when the node joins)
    with ZenohExchange(fleet, json.dumps({"connect": {"endpoints": [f"tcp/127.0.0.1:{port}"]}}), "robot") as robot:
        asked: list[bool] = []              # the robot's requests for the fused map: whether each was sent
        request = robot.request_snapshot

        def counted(who: str = "*") -> bool:
            sent = request(who)
            if who == FUSED:
                asked.append(sent)
            return sent

        robot.request_snapshot = counted
        with ZenohExchange(fleet, json.dumps({"listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]}}), "fusion") as node:
            answer = node._answer
            held: list = []                 # the robot's requests for a fused map the node has not answered yet

            def holding(who: str, query) -> None:
                with node._lock:
                    has_fused = FUSED in node._encoders
                if who == FUSED and has_fused:
                    held.append(query)
                else:   # no fused map yet (the robot's ask as the node joins): answered as ever, with nothing
                    answer(who, query)

            node._answer = holding
            wait_until(lambda: "fused" in robot.present() and asked and not any(
                who == FUSED for *_, who in robot._replies), "the node at the robot, its first ask over")
            first = asked.count(True)
            node.publish(FUSED, fused[0], 0.0)
            wait_until(lambda: len(held) == 1, "the robot's request for fused map 0 at the node")
            node.publish(FUSED, fused[1], 1.0)
            node.publish(FUSED, fused[2], 2.0)
            wait_until(lambda: robot.status().get(FUSED, {}).get("sequence") == 2, "the node's word on fused map 2")
            # the robot wants map 2 and looks again: no second request while the first is open (its reply in flight)
            wait_until(lambda: asked.count(False) >= 1, "the robot's look for a second request")
            assert len(held) == 1 and asked.count(True) == first + 1, (len(held), asked)
            assert robot.fused() is None, "a fused map reached the robot without its request's reply"
            answer(FUSED, held.pop())       # the reply goes: the newest fused map at its answer
            wait_until(lambda: robot.held().get(FUSED, (None, -1))[1] == 2, "fused map 2 at the robot")
            got = robot.fused().landmark_map
            np.testing.assert_array_equal(got.ids, fused[2].ids)
            np.testing.assert_array_equal(got.positions, fused[2].positions)
            wait_until(lambda: FUSED not in robot._waits, "the robot's wait for the fused map over")
            assert held == [] and asked.count(True) == first + 1 and robot.dropped["gap"] == 0
            assert node.bytes_sent["full"] == node.bytes_sent["delta"] == 0   # no fused map was put
