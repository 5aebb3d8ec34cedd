"""A live fusion that raises does not end the fusion node's thread (session 52, D's review of session 51's ``run``).

``FusionNode.run`` is the thread ``fusion-node`` of ``p3at demo --processes`` (and the main loop of ``p3at fuse
--live``). A fusion that raised (a bug on some maps) ended it: the demo went on without a live fusion, a traceback of
the thread on its stderr in the middle of its progress lines, and ``p3at fuse --live`` ended. Now the failure is said
in one line and the node goes on with the next maps; the same failure again is not said again.
"""
from __future__ import annotations

import threading
import time

import runtime.fleet.fusion_node as fusion_node
from runtime.exchange import InProcessExchange
from runtime.fleet.fusion_node import FusionNode, FusionNodeConfig
from runtime.fleet.synthetic import SyntheticRobot
from tests.fleet.live_node import ManualClock


def test_a_live_fusion_that_raises_is_said_in_one_line_and_the_node_goes_on(monkeypatch):
    robots = [SyntheticRobot(n, k, landmarks=200, grow=40) for k, n in enumerate(["robot1", "robot2"])]
    exchange, lines = InProcessExchange(), []
    node = FusionNode(exchange, FusionNodeConfig(interval=10.0, min_period=0.0), on_event=lines.append,
                      clock=ManualClock(1000.0))
    fuse, calls = fusion_node.fuse_maps, []

    def fails_twice(*args, **kwargs):
        calls.append(args[3])
        if len(calls) <= 2:
            raise ValueError("a stand-in for a bug\non two lines")
        return fuse(*args, **kwargs)

    monkeypatch.setattr(fusion_node, "fuse_maps", fails_twice)

    def publish(stamp: float) -> None:
        for r in robots:
            exchange.publish(r.name, r.step(), stamp=stamp)
        node.notify("robot2")

    def until(condition) -> None:
        end = time.monotonic() + 30.0    # a failure bound: the node looks every 0.2 s
        while not condition() and time.monotonic() < end:
            time.sleep(0.05)

    stop = threading.Event()
    runner = threading.Thread(target=node.run, args=(stop,), daemon=True)
    publish(1.0)
    runner.start()
    try:
        until(lambda: len(calls) >= 1)
        publish(2.0)
        until(lambda: len(calls) >= 2)
        publish(3.0)
        until(lambda: len(node.history) >= 1)
        assert runner.is_alive()
        assert [r.t for r in node.history] == [3.0]
    finally:
        stop.set()
        runner.join(timeout=30)
    failed = [line for line in lines if "failed" in line]
    assert failed == ["fusion at t=1s failed (ValueError: a stand-in for a bug on two lines); the node goes on with "
                      "the next maps"], lines
