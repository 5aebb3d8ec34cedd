"""A Zenoh peer publishing garbage on the fleet's keys at full rate (session 23): the fusion node's exchange drops
every message, keeps receiving a robot's maps, and says so once, then in one counting line at most every
DROP_REPORT_INTERVAL, and at its close what the last interval counted. Before, it logged one warning line per
message: 326,429 lines on `p3at fuse --live`'s stderr for 10 s of 200-byte garbage."""
from __future__ import annotations

import json
import logging
import os
import re
import time

import pytest

pytest.importorskip("zenoh")

from runtime.fleet import mapwire  # noqa: E402
from runtime.fleet.processes import free_port  # noqa: E402
from runtime.fleet.synthetic import SyntheticRobot  # noqa: E402
from runtime.fleet.zenoh_exchange import DROP_REPORT_INTERVAL, ZenohExchange  # noqa: E402

DEADLINE = 60.0
GARBAGE = 3000
pytestmark = pytest.mark.timeout(180)


def _endpoint(port: int, role: str) -> str:
    return json.dumps({"listen" if role == "fusion" else "connect": {"endpoints": [f"tcp/127.0.0.1:{port}"]}})


def _wait_until(condition, what: str) -> None:
    end = time.monotonic() + DEADLINE
    while time.monotonic() < end:
        if condition():
            return
        time.sleep(0.05)
    pytest.fail(f"not within {DEADLINE:g} s: {what}")


def test_garbage_at_full_rate_is_counted_not_logged_per_message(caplog) -> None:
    import zenoh

    port, fleet = free_port(), f"garbage{os.getpid()}"
    config = zenoh.Config.from_json5(_endpoint(port, "robot"))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    robot = SyntheticRobot("robot1", 0)
    session_id = mapwire.new_session()
    caplog.set_level(logging.WARNING, logger="runtime.fleet.zenoh_exchange")
    started = time.monotonic()
    with ZenohExchange(fleet, _endpoint(port, "fusion"), "fusion") as node, zenoh.open(config) as peer:
        sent = 0

        def flood() -> bool:   # puts before the route to the node exists are lost: put until counted
            nonlocal sent
            for _ in range(500):
                peer.put(f"p3at/{fleet}/robot{sent % 3}/{'map' if sent % 2 else 'status'}", os.urandom(64))
                sent += 1
            return node.dropped["malformed"] >= GARBAGE

        _wait_until(flood, f"{GARBAGE} garbage messages dropped")
        # a robot's map still comes through after the flood. Put until received: a put is CongestionControl.DROP
        # (Zenoh's default), and one that waits behind the flood's batches in the sender's queue is dropped there
        robot_map = mapwire.encode_full("robot1", session_id, 0, 1.0, robot.step())

        def map_received() -> bool:
            peer.put(f"p3at/{fleet}/robot1/map", robot_map)
            return "robot1" in node.receive()

        _wait_until(map_received, "robot1's map received after the garbage")
        _wait_until(lambda: node.pending_bytes == 0, "the queue drained")   # every garbage message counted
    elapsed = time.monotonic() - started
    total = node.dropped["malformed"]
    lines = [r.getMessage() for r in caplog.records if "malformed" in r.getMessage() or "dropped a message" in
             r.getMessage()]
    assert total >= GARBAGE
    assert 2 <= len(lines) <= 2 + elapsed / DROP_REPORT_INTERVAL, lines[:5]
    assert "further malformed messages are counted" in lines[0]
    counted = 1 + sum(int(m.group(1)) for m in (re.search(r"dropped (\d+) more", line) for line in lines[1:]) if m)
    assert counted == total        # nothing dropped goes unsaid: the close reports the last interval's count
