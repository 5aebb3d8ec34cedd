"""``p3at demo --processes``'s final fusion waits (bounded) for the map each robot's last status names: a robot's
last map still in the fusion node's queue is fused; one lost on the wire is reported (runtime/fleet/processes.py).

A bare Zenoh session plays the robot (its messages sent by hand), the fusion node's exchange is a real one whose
worker the test holds, so that the last map is in the queue, or lost, for certain."""
from __future__ import annotations

import json
import os
import threading
import time

import pytest

pytest.importorskip("zenoh")

from runtime.fleet import mapwire  # noqa: E402
from runtime.fleet.processes import await_last_maps, free_port  # noqa: E402
from runtime.fleet.synthetic import SyntheticRobot  # noqa: E402
from runtime.fleet.zenoh_exchange import ZenohExchange  # noqa: E402

DEADLINE = 30.0
pytestmark = pytest.mark.timeout(120)


def endpoint(port: int, role: str) -> str:
    return json.dumps({"listen" if role == "fusion" else "connect": {"endpoints": [f"tcp/127.0.0.1:{port}"]}})


def wait_until(condition, what: str, deadline: float = DEADLINE):
    end = time.monotonic() + deadline
    while time.monotonic() < end:
        if condition():
            return
        time.sleep(0.05)
    pytest.fail(f"not within {deadline:g} s: {what}")


def bare_session(port: int):
    import zenoh

    config = zenoh.Config.from_json5(endpoint(port, "robot"))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    return zenoh.open(config)


def test_the_final_fusion_waits_for_a_last_map_still_queued_and_reports_one_that_never_came():
    import zenoh

    port, fleet = free_port(), f"final{os.getpid()}"
    key, status_key = f"p3at/{fleet}/robot1/map", f"p3at/{fleet}/robot1/status"
    session = mapwire.new_session()
    source = SyntheticRobot("robot1", 0)
    first, second = source.step(), source.step()
    gate, held = threading.Event(), []

    def hook(robot: str) -> None:  # the node's worker waits here after each map it handles
        held.append(robot)
        gate.wait(DEADLINE)

    map_1 = mapwire.encode_full("robot1", session, 1, 1.0, second)
    status_1 = mapwire.encode_status("robot1", session, 1, 1.0, landmarks=len(second))
    with ZenohExchange(fleet, endpoint(port, "fusion"), "fusion", on_update=hook) as node, \
            bare_session(port) as robot:
        try:
            queryable = robot.declare_queryable(key, zenoh.handlers.RingChannel(16))

            def reached() -> bool:  # the node's query reached the robot: so had its subscribers' declarations
                node.request_snapshot("*")
                came = False
                while (query := queryable.try_recv()) is not None:
                    came = True
                    query.drop()
                return came

            # map 0 put once the route exists, and once: a copy put again while the first was on its way would sit
            # in the node's queue, which then held bytes before map 1 and its status had come
            wait_until(reached, "the node's query at robot1's queryable")
            robot.put(key, mapwire.encode_full("robot1", session, 0, 0.0, first))
            wait_until(lambda: bool(held), "robot1's map 0 holding the node's worker")
            robot.put(key, map_1)  # the last map, queued
            robot.put(status_key, status_1)
            wait_until(lambda: node.pending_bytes == len(map_1) + len(status_1) and len(held) == 1,
                       "map 1 and its status queued")
            # fused now (as before session 20), the final fusion would have map 0
            assert node.receive()["robot1"].sequence == 0
            threading.Timer(0.5, gate.set).start()
            assert await_last_maps(node, timeout=DEADLINE) == {}
            assert node.receive()["robot1"].sequence == 1
            # a status naming map 2, which never comes: reported after the bound, with the map held
            status_2 = mapwire.encode_status("robot1", session, 2, 2.0, landmarks=len(second))

            def status_2_handled() -> bool:  # put until handled: a put is CongestionControl.DROP
                robot.put(status_key, status_2)
                return node.status().get("robot1", {}).get("sequence") == 2

            wait_until(status_2_handled, "the status naming map 2")
            start = time.monotonic()
            assert await_last_maps(node, timeout=1.0) == {"robot1": {"named": 2, "held": 1}}
            assert time.monotonic() - start >= 1.0
        finally:
            gate.set()


@pytest.mark.parametrize("status_came", [True, False, "same map"],
                         ids=["named-by-a-status", "lost-with-its-status", "lost-map-equal-to-the-one-held"])
def test_a_last_map_lost_on_the_wire_is_read_from_the_file_its_robot_wrote(tmp_path, status_came):
    """robot1's last map (its map 1) never reaches the node; its process wrote it to its map file at its end. The
    final fusion had fused map 0: now it reads map 1 from the file, whether a status named map 1 (the map alone was
    lost) or not (lost with its status: nothing told the node). robot2's file holds the map the node has: not read.
    A lost map 1 equal to map 0 (published again with nothing new): the node holds the final map, nothing missing."""
    from estimation.landmark_map import LandmarkMap
    from runtime.fleet.fusion_node import FusionNode, FusionNodeConfig
    from runtime.fleet.processes import final_fusion

    port, fleet = free_port(), f"file{os.getpid()}_{str(status_came).replace(' ', '')}"
    session = mapwire.new_session()
    robot1, robot2 = SyntheticRobot("robot1", 0), SyntheticRobot("robot2", 1)
    map1_0, map1_1 = robot1.step(), robot1.step()
    if status_came == "same map":
        map1_1 = map1_0
    map2 = [robot2.step() for _ in range(2)][-1]
    summaries = {}
    for name, last, seconds in (("robot1", map1_1, 2.0), ("robot2", map2, 1.5)):   # as `p3at run --json` gives them
        (tmp_path / name).mkdir()
        last.save(tmp_path / name / f"{name}.npz")
        summaries[name] = {"clock": "simulated", "sim_seconds": seconds, "robots": {name: {
            "map_file": str(tmp_path / name / f"{name}.npz"), "landmarks": len(last)}}}
    with ZenohExchange(fleet, endpoint(port, "fusion"), "fusion") as exchange, bare_session(port) as robot:
        def sent(name: str, m: LandmarkMap, stamp: float) -> bool:   # puts before the route to the node exist are lost
            robot.put(f"p3at/{fleet}/{name}/map", mapwire.encode_full(name, session, 0, stamp, m))
            return name in exchange.receive()

        wait_until(lambda: sent("robot1", map1_0, 1.0), "robot1's map 0 at the node")
        wait_until(lambda: sent("robot2", map2, 1.5), "robot2's map at the node")
        named = 1 if status_came else 0
        status = mapwire.encode_status("robot1", session, named, 2.0, landmarks=len(map1_1))

        def status_handled() -> bool:  # put until handled: a put is CongestionControl.DROP
            robot.put(f"p3at/{fleet}/robot1/status", status)
            return exchange.status().get("robot1", {}).get("sequence") == named

        wait_until(status_handled, "robot1's status")
        node = FusionNode(exchange, FusionNodeConfig())
        final, missing, read = final_fusion(node, summaries, timeout=1.0)
    assert missing == {}
    if status_came == "same map":
        assert read == {} and {r: q for r, (q, _) in node.sources.items()} == {"robot1": 0, "robot2": 0}
        return
    assert read == {"robot1": {"file": str(tmp_path / "robot1" / "robot1.npz"), "landmarks": len(map1_1),
                               "named": 1 if status_came else None, "held": 0}}
    assert final is not None and {r: q for r, (q, _) in node.sources.items()} == {"robot1": 1, "robot2": 0}
    # what was fused is the file's map, as the wire would have carried it
    assert node.sources["robot1"][1] == 2.0 and len(map1_1) > len(map1_0)
