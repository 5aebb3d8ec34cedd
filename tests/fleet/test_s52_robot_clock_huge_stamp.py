"""The fusion node's clock (runtime.fleet.fusion_node.RobotClock) and a stamp so large that a float no longer holds a
robot's progress beside it (session 52, D's review of session 51).

The first maps the node sees set its clock. A broken or hostile sender's first map stamped 1e300 s (a finite number:
the wire takes it) set the clock there, and every robot after it was placed on it: 1e300 + 2 s is 1e300, so no robot's
progress moved the clock again, and the node confirmed no found until its final fusion (its decisions are on that
clock), against RobotClock's promise that a map's stamp can neither throw the clock forward nor hold it still. The
same from ~1e16 s on (a float's step there is 2 s; 256 s at 1.8e18, a time in nanoseconds sent as seconds).
"""
from __future__ import annotations

import pytest

from runtime.exchange import InProcessExchange, MapMessage
from runtime.fleet.fusion_node import FusionNode, FusionNodeConfig, RobotClock
from runtime.fleet.synthetic import SyntheticRobot
from tests.fleet.live_node import ManualClock


def _messages(**stamps) -> dict:
    return {r: MapMessage(r, q, s, None) for r, (q, s) in stamps.items()}


@pytest.mark.parametrize("huge", [1e300, 1.8e18, 1e17])
def test_a_huge_first_stamp_does_not_hold_the_clock_still(huge):
    wall = ManualClock(100.0)
    clock = RobotClock(wall)
    clock.observe(_messages(robot1=(0, huge)))      # a broken sender's first map, alone
    wall.now = 101.0
    before = clock.observe(_messages(robot2=(0, 10.0)))
    wall.now = 102.0
    after = clock.observe(_messages(robot2=(1, 12.5)))
    assert after - before == pytest.approx(2.5, abs=1e-3)    # robot2's progress moves the clock
    wall.now = 103.0
    assert clock.observe(_messages(robot1=(1, huge), robot2=(2, 13.0))) - after == pytest.approx(0.5, abs=1e-3)


def test_a_node_whose_first_map_is_stamped_1e300_still_confirms_during_the_mission():
    """Through the node: robot2's maps all stamped 1e300 s, robot1's in its mission time; robot1's first found is
    confirmed by a fusion an interval (10 s) of robot1's time later, not never."""
    robots = [SyntheticRobot(n, k, landmarks=300, grow=60) for k, n in enumerate(["robot1", "robot2"])]
    exchange, lines, wall = InProcessExchange(), [], ManualClock(1000.0)
    node = FusionNode(exchange, FusionNodeConfig(interval=10.0), on_event=lines.append, clock=wall)
    robot1, robot2 = robots
    exchange.publish("robot2", robot2.step(), stamp=1e300)
    assert node.fuse_now() is None                   # one robot's map: nothing to fuse yet
    found = []
    for k, stamp in enumerate((5.0, 10.0, 20.0)):
        wall.now = 1000.1 + 0.1 * k                   # robots many times faster than the node's wall clock
        exchange.publish("robot1", robot1.step(), stamp=stamp)
        exchange.publish("robot2", robot2.step(), stamp=1e300)
        report = node.fuse_now()
        found.append((report.t, report.pairs[0].aligned))
    assert found[-1][1], lines[-1]
    assert [t for t, _ in found][1:] == pytest.approx([found[0][0] + 5.0, found[0][0] + 15.0], abs=1e-3)
