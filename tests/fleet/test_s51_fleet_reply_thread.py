"""Queries answered by a thread of their own (session 51, N): a reply that waits never holds the node's receiving.

Zenoh's query replies block (its default congestion control for them): a reply larger than the link's queue (two
64-kB batches; a fused map of ~300+ landmarks) waits in Zenoh until the link has carried enough, and after 5 s of
waiting Zenoh closes the link (session 49). The fusion node answered the robots' pulls of the fused map from its pump
thread, the one that moves every map, status, acknowledgement and join out of Zenoh's channels: while a reply waited,
the node heard nothing of any robot. The exchange now hands queries to a replier thread (at most REPLY_QUEUE waiting).

Here the node's reply to the robot's pull is held (a slow consumer: the reply waits as it would for room on a slow
link), and the robot's maps must still reach the node meanwhile; then the reply goes and the robot holds the fused
map. And a replier that ends says so in one line while the node goes on receiving.
"""
from __future__ import annotations

import logging
import os
import threading

import pytest

pytest.importorskip("zenoh")

from runtime.fleet.processes import free_port  # noqa: E402
from runtime.fleet.synthetic import SyntheticRobot  # noqa: E402
from runtime.fleet.zenoh_exchange import FUSED, ZenohExchange  # noqa: E402
from tests.fleet.test_zenoh_fleet import endpoint_config, wait_until  # noqa: E402  (30 s failure bounds, polled)

pytestmark = pytest.mark.timeout(120)


def _pair(tag: str):
    port, fleet = free_port(), f"{tag}{os.getpid()}"
    return (ZenohExchange(fleet, endpoint_config(port, "robot"), "robot"),
            ZenohExchange(fleet, endpoint_config(port, "fusion"), "fusion"))


def test_a_reply_that_waits_does_not_hold_the_nodes_receiving():
    source = SyntheticRobot("robot1", 0, landmarks=200, grow=100)
    robot, node = _pair("replywait")
    answering, release = threading.Event(), threading.Event()
    answer = node._answer

    def slow(who: str, query) -> None:   # the fused map's reply waits, as for room on a slow link
        with node._lock:
            has_fused = FUSED in node._encoders
        if who == FUSED and has_fused:
            answering.set()
            release.wait(timeout=90)   # a failure bound only: the test releases it
        answer(who, query)

    node._answer = slow
    try:
        with robot, node:
            wait_until(lambda: FUSED in robot.present(), "the node at the robot")
            node.publish(FUSED, source.step(), 1.0)   # its status makes the robot pull it
            wait_until(answering.is_set, "the robot's pull of the fused map at the node, its reply waiting")
            for k in range(2):   # meanwhile the robot maps on: each map reaches the node (its next goes on its ack)
                robot.publish("robot1", source.step(), float(k))
                wait_until(lambda k=k: node.held().get("robot1", (None, -1))[1] == k, f"robot1's map {k} at the node")
            assert robot.fused() is None and not release.is_set()   # the reply still waits
            release.set()
            wait_until(lambda: robot.fused() is not None, "the fused map at the robot once its reply went")
            assert node.replies >= 1 and node.reply_failure is None
    finally:
        release.set()


def test_a_replier_that_ends_is_said_in_one_line_and_the_node_goes_on(caplog):
    source = SyntheticRobot("robot1", 0, landmarks=200, grow=100)
    robot, node = _pair("replydead")

    def ends(who: str, query) -> None:
        query.drop()
        raise SystemExit("a stand-in for anything that ends a thread")

    node._answer = ends
    with caplog.at_level(logging.ERROR, logger="runtime.fleet.zenoh_exchange"), robot, node:
        wait_until(lambda: FUSED in robot.present(), "the node at the robot")
        node.publish(FUSED, source.step(), 1.0)
        wait_until(lambda: node.reply_failure is not None, "the replier ended")
        assert not node._replier.is_alive()
        robot.publish("robot1", source.step(), 0.0)   # the node still hears the robot
        wait_until(lambda: "robot1" in node.held(), "robot1's map at the node")
        robot.publish("robot1", source.step(), 1.0)
        wait_until(lambda: node.held().get("robot1", (None, -1))[1] == 1, "robot1's next map at the node")
    said = [r.getMessage() for r in caplog.records if "reply thread" in r.getMessage()]
    assert said == ["fleet exchange: the reply thread ended (SystemExit: a stand-in for anything that ends a thread): "
                    "this process answers no more snapshot requests; maps and statuses still come and go"], said
