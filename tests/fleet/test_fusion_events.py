"""The fusion's event line (the demo's and `p3at fuse --live`'s) says why a pair does not overlap yet, in one line,
from the fusion's own figures: supports against the number needed and P(chance), or the alignment's reason."""
from __future__ import annotations

import numpy as np
import pytest

from estimation.landmark_map import LandmarkMap
from runtime.exchange import InProcessExchange, MapMessage
from runtime.fleet.fusion_node import CLOCK_LAG, CLOCK_MAX_RATE, CLOCK_SLACK, FusionNode, FusionNodeConfig, RobotClock
from runtime.fleet.synthetic import SyntheticRobot
from runtime.report import fusion_event_line
from tests.fleet.live_node import ManualClock


def _fuse(m1: LandmarkMap, m2: LandmarkMap, final: bool = False):
    exchange, lines = InProcessExchange(), []
    exchange.publish("robot1", m1)
    exchange.publish("robot2", m2)
    report = FusionNode(exchange, on_event=lines.append).fuse_now(final=final)
    # each robot's first map is said as it comes (sorted by name), then the fusion's line
    first = [f"first map from {robot}: {len(m)} landmarks" for robot, m in (("robot1", m1), ("robot2", m2))]
    assert report is not None and len(report.pairs) == 1 and lines[:2] == first and len(lines) == 3, lines
    return report.pairs[0], lines[2]


def _robot1() -> LandmarkMap:
    return SyntheticRobot("robot1", 0, landmarks=200, grow=200).step()


@pytest.mark.parametrize("kept", [5, 8])
def test_too_few_supports_are_said_with_the_number_needed_and_the_chance(kept):
    """robot2 holds robot1's landmarks (same descriptors) but only ``kept`` of them where robot1 has them."""
    m1 = _robot1()
    positions = m1.positions.copy()
    positions[kept:, :2] = np.random.default_rng(1).uniform(-10, 10, (len(positions) - kept, 2))
    m2 = LandmarkMap(positions, m1.covariances, m1.descriptors, m1.ids, m1.counts, "robot2", "start")
    pair, line = _fuse(m1, m2)
    assert not pair.aligned and 0 < pair.supports < pair.required_supports
    assert line.startswith("fusion at t=0s: robot2 does not overlap robot1 yet: ") and "\n" not in line
    assert (f"{pair.supports} supports, {pair.required_supports} needed "
            f"(P(chance) {pair.false_alarm_probability:.1e})") in line
    # an ambiguous pair names what set the number needed: a rival transform, or a map's repeat of itself
    ambiguous = pair.note.startswith("ambiguous")
    repeat = ambiguous and pair.self_repeat_supports > pair.second_best_supports
    assert ("ambiguous: a distinct transform gathers" in line) == (ambiguous and not repeat)
    assert ("repeats itself" in line) == repeat


def test_maps_without_common_landmarks_give_the_alignments_reason():
    m1 = _robot1()
    m2 = SyntheticRobot("robot2", 1, seed=1, landmarks=200, grow=200).step()  # another building altogether
    pair, line = _fuse(m1, m2)
    assert not pair.aligned and pair.required_supports == 0 and pair.note
    assert line == f"fusion at t=0s: robot2 does not overlap robot1 yet: {pair.note}"


def test_an_alignment_found_keeps_its_line():
    m1 = _robot1()
    m2 = SyntheticRobot("robot2", 1, landmarks=200, grow=200).step()
    pair, line = _fuse(m1, m2, final=True)
    assert pair.aligned
    assert line.startswith(f"fusion at t=0s: robot2 -> robot1 ({pair.supports} supports, {pair.common} common), "
                           f"error {pair.error_xy:.3f} m")


def test_a_reason_on_several_lines_is_printed_on_one():
    pair = {"reference": "a", "other": "b", "aligned": False, "supports": 0, "note": "first\nsecond  third"}
    assert fusion_event_line(12.4, pair) == "fusion at t=12s: b does not overlap a yet: first second third"


class _Confirming:
    """Two overlapping robots (the same building from two starts) and a live node confirming after 10 s, on a wall
    clock the test sets: ``fuse(wall, stamps)`` publishes each robot's grown map at its stamp and fuses."""

    def __init__(self) -> None:
        self.robots = [SyntheticRobot(n, k, landmarks=300, grow=60) for k, n in enumerate(["robot1", "robot2"])]
        self.exchange, self.lines, self.clock = InProcessExchange(), [], ManualClock(1000.0)
        self.node = FusionNode(self.exchange, FusionNodeConfig(interval=10.0), on_event=self.lines.append,
                               clock=self.clock)

    def fuse(self, wall: float, stamps: dict[str, float] | float | None):
        """``stamps``: robot -> its map's stamp (a number: both robots'), None: the unchanged maps fused again."""
        self.clock.now = 1000.0 + wall
        if stamps is None:
            self.node.sources = {}
        else:
            for r in self.robots:
                if not isinstance(stamps, dict) or r.name in stamps:
                    self.exchange.publish(r.name, r.step(), stamp=stamps if not isinstance(stamps, dict)
                                          else stamps[r.name])
        report = self.node.fuse_now()
        return report.pairs[0], self.lines[-1]


def test_a_live_found_is_confirmed_an_interval_later_on_the_robots_clock():
    """fusion/confirmation.py through the node, on the robots' mission clock (their maps' stamps), as the mission
    confirms on mission time: found once is said as a candidate with its supports and pose; the same maps again
    confirm nothing; grown maps too soon confirm nothing; grown maps an interval of the robots' time later do. The
    node's wall clock moves 0.1 s a fusion (robots in simulated time, many times faster): on it nothing would ever
    be confirmed before the end (session 50: the demo's node confirmed nothing)."""
    c = _Confirming()
    pair, line = c.fuse(0.0, 5.0)
    assert not pair.aligned and pair.supports >= pair.required_supports > 0
    assert line.startswith(f"fusion at t=5s: robot2 -> robot1 is a candidate, not yet found ({pair.supports} "
                           "supports at (") and "no earlier fusion of these maps found it" in line
    pair, line = c.fuse(0.1, None)
    assert not pair.aligned and "the maps have not changed since" in line
    pair, line = c.fuse(0.2, 10.0)
    assert not pair.aligned and "agrees with the fusion at t=5s, which is less than 10 s before" in line
    pair, line = c.fuse(0.3, {"robot1": 20.0, "robot2": 19.0})
    assert pair.aligned and pair.error_xy < 0.1, pair.note
    assert line.startswith("fusion at t=20s: robot2 -> robot1 (")
    pair, line = c.fuse(0.4, 30.0)                  # found while each agrees with its run's first found
    assert pair.aligned


def test_robots_that_send_no_time_are_timed_by_the_nodes_clock():
    """Maps stamped 0 (a sender with no clock): the node's own clock times them as they come, so such a fleet still
    confirms an interval of the node's time later (and not never)."""
    c = _Confirming()
    pair, line = c.fuse(0.0, 0.0)
    assert not pair.aligned and line.startswith("fusion at t=0s: robot2 -> robot1 is a candidate")
    pair, line = c.fuse(5.0, 0.0)
    assert not pair.aligned and "less than 10 s before" in line
    pair, line = c.fuse(20.0, 0.0)
    assert pair.aligned and line.startswith("fusion at t=20s: robot2 -> robot1 (")


def test_a_stamp_far_in_the_future_does_not_confirm_at_once():
    """robot2's clock jumps 10^9 s forward (a hostile or broken sender): the node's clock does not follow it, so the
    candidate stays a candidate; robot2's next maps move the clock by their own progress, and robot1's time, going on,
    confirms an interval after the first found."""
    c = _Confirming()
    pair, _ = c.fuse(0.0, 5.0)
    assert not pair.aligned
    pair, line = c.fuse(1.0, {"robot1": 8.0, "robot2": 1e9})
    assert not pair.aligned and "agrees with the fusion at t=5s, which is less than 10 s before" in line, line
    assert line.startswith("fusion at t=8s: ")
    pair, line = c.fuse(2.0, {"robot1": 12.0, "robot2": 1e9 + 4.0})    # in step with its own jumped clock
    assert not pair.aligned and line.startswith("fusion at t=12s: ")
    pair, line = c.fuse(3.0, {"robot1": 16.0, "robot2": 1e9 + 7.0})
    assert pair.aligned and line.startswith("fusion at t=16s: robot2 -> robot1 (")


def test_a_stamp_going_back_does_not_hold_the_nodes_clock_still():
    """robot1 has finished (its map no longer changes) and robot2 restarts its clock from 0 (a restarted robot, a clock
    reset): the node's clock goes on from where it was by robot2's progress, and confirms an interval later. Had the
    node kept the newest stamp it received, it would wait for robot2's clock to pass 100 s."""
    c = _Confirming()
    pair, line = c.fuse(0.0, {"robot1": 90.0, "robot2": 100.0})
    assert not pair.aligned and line.startswith("fusion at t=100s: robot2 -> robot1 is a candidate")
    pair, line = c.fuse(1.0, {"robot2": 1.0})
    assert not pair.aligned and line.startswith("fusion at t=100s: ")
    pair, line = c.fuse(2.0, {"robot2": 6.0})
    assert not pair.aligned and line.startswith("fusion at t=105s: ") and "less than 10 s before" in line
    pair, line = c.fuse(3.0, {"robot2": 12.0})
    assert pair.aligned and line.startswith("fusion at t=111s: robot2 -> robot1 (")


def test_the_running_node_fuses_on_the_robots_clock():
    """``run``: fuses on new data once ``min_period`` of the robots' time has passed, while its wall clock stands still
    (robots many times faster than real time); before, it waited for ``min_period`` of its own wall time."""
    import threading
    import time

    c = _Confirming()
    node = FusionNode(c.exchange, FusionNodeConfig(interval=10.0, min_period=5.0), clock=c.clock)
    stop = threading.Event()
    runner = threading.Thread(target=node.run, args=(stop,), daemon=True)

    def publish(stamp: float) -> None:
        for r in c.robots:
            c.exchange.publish(r.name, r.step(), stamp=stamp)
        node.notify(r.name)

    def fusions(n: int) -> list[float]:
        end = time.monotonic() + 30.0   # a failure bound: the node looks every 0.2 s
        while len(node.history) < n and time.monotonic() < end:
            time.sleep(0.05)
        return [r.t for r in node.history]

    publish(1.0)
    runner.start()
    try:
        assert fusions(1) == [1.0]
        publish(3.0)     # 2 s of the robots' time later: no fusion (min_period 5 s)
        publish(7.0)     # 6 s later: fused (the maps of 3 s, if the node saw them, were not)
        assert fusions(2) == [1.0, 7.0]
    finally:
        stop.set()
        runner.join(timeout=30)


def _messages(**stamps) -> dict:
    """robot -> (sequence, stamp) as MapMessages (the clock reads nothing else)."""
    return {r: MapMessage(r, q, s, None) for r, (q, s) in stamps.items()}


def test_the_robot_clock_rules():
    """RobotClock alone (docs/fleet.md): the newest plausible stamp, never back, jumps bounded, a robot placed on the
    node's clock when its own is out of step."""
    wall = ManualClock(50.0)
    clock = RobotClock(wall)
    assert clock.observe({}) == 0.0
    # robots started together (on one clock) whose first maps come at once: the newest
    assert clock.observe(_messages(robot1=(0, 120.8), robot2=(0, 141.0))) == 141.0
    assert clock.observe(_messages(robot1=(1, 130.0), robot2=(0, 141.0))) == 141.0   # an older stamp: never back
    # not finite, below 0: not taken
    assert clock.observe(_messages(robot1=(2, float("nan")), robot2=(1, -5.0))) == 141.0
    wall.now = 51.0   # a second later: a map may lead the clock by CLOCK_SLACK + CLOCK_MAX_RATE s at most
    assert clock.observe(_messages(robot1=(3, 141.0 + CLOCK_SLACK + CLOCK_MAX_RATE + 1), robot2=(1, -5.0))) == 141.0
    assert clock.observe(_messages(robot1=(4, 141.0 + CLOCK_SLACK + CLOCK_MAX_RATE + 4))) == 144.0  # from there on
    wall.now = 52.0
    assert clock.observe(_messages(robot2=(2, 170.0))) == 170.0    # robot2 in step, within the bound: taken
    # a robot new to the node: on the clock if within CLOCK_LAG behind, else placed at it
    assert clock.observe(_messages(robot3=(0, 170.0 - CLOCK_LAG + 1))) == 170.0
    assert clock.observe(_messages(robot3=(1, 170.0 - CLOCK_LAG + 5))) == 170.0
    assert clock.observe(_messages(robot4=(0, 3.0))) == 170.0
    assert clock.observe(_messages(robot4=(1, 5.5))) == 172.5
    # a robot's first map at the start of its mission (stamp 0), long after the node started (robots' start-up):
    # on the robots' clock, at 0 (it had been timed by the node's clock since its start, 18 s: the demo's clock 13 s
    # ahead of its robots' from then on)
    wall.now = 1000.0
    late = RobotClock(wall)
    wall.now = 1018.5
    assert late.observe(_messages(robot2=(0, 0.0))) == 0.0
    wall.now = 1018.6
    assert late.observe(_messages(robot1=(0, 0.0))) == 0.0
    wall.now = 1020.0
    assert late.observe(_messages(robot2=(1, 5.1), robot1=(1, 5.1))) == 5.1
    # a first map far in the future starts the clock there; the others are placed on it and move it as they go
    wall.now = 60.0
    hostile = RobotClock(wall)
    assert hostile.observe(_messages(robot1=(0, 1e12))) == 1e12
    assert hostile.observe(_messages(robot2=(0, 10.0))) == 1e12
    assert hostile.observe(_messages(robot2=(1, 12.0))) == 1e12 + 2.0
    # a node's first maps far apart: the oldest sets the clock, one far after it is placed on it
    split = RobotClock(wall)
    assert split.observe(_messages(robot1=(0, 10.0), robot2=(0, 1e12))) == 10.0
    assert split.observe(_messages(robot2=(1, 1e12 + 3.0))) == 13.0


def test_the_final_fusion_is_decided_on_the_maps_alone():
    robots = [SyntheticRobot(n, k, landmarks=300, grow=60) for k, n in enumerate(["robot1", "robot2"])]
    exchange = InProcessExchange()
    for r in robots:
        exchange.publish(r.name, r.step())
    node = FusionNode(exchange, FusionNodeConfig(interval=10.0))
    assert not node.fuse_now().pairs[0].aligned          # live: a candidate
    final = node.final_fusion()
    assert final.pairs[0].aligned and final.merged is not None


def _twin_node(starts: dict) -> tuple[FusionNode, list[str]]:
    """robot1 and robot2 whose maps are ambiguous under a half turn (tests/fusion/test_fusion_prior.twin_pair)."""
    from tests.fusion.test_fusion_prior import twin_pair

    m1, m2 = twin_pair(0, common=30, twins=24)
    exchange, lines = InProcessExchange(), []
    exchange.publish("robot1", m1)
    exchange.publish("robot2", m2)
    return FusionNode(exchange, FusionNodeConfig(starts=starts), on_event=lines.append), lines


LAB_START1 = np.array([1.0, 2.0, 0.3])   # robot1's start in the lab's frame


def _starts(pose_of_robot2_in_robot1) -> dict:
    from estimation.geometry import compose

    return {"robot1": (LAB_START1, (1.0, 0.3)), "robot2": (compose(LAB_START1, pose_of_robot2_in_robot1), (1.0, 0.3))}


def test_the_live_node_with_the_robots_start_poses_resolves_a_half_turn_it_cannot_resolve_blind():
    from tests.fusion.test_fusion_prior import TRUE_POSE

    blind, _ = _twin_node({})
    assert not blind.final_fusion().pairs[0].aligned
    node, lines = _twin_node(_starts(TRUE_POSE))
    node.fuse_now()
    (pair,) = node.final_fusion().pairs
    assert pair.aligned and pair.prior and np.hypot(pair.tx - TRUE_POSE[0], pair.ty - TRUE_POSE[1]) < 0.1
    said = [line for line in lines if line.startswith("fusion uses a start prior")]
    assert said == [f"fusion uses a start prior for robot2 in robot1's frame: {node.priors['robot1', 'robot2'].text()}"]


def test_the_live_node_reports_a_best_alignment_that_contradicts_the_start_poses_as_not_found():
    from tests.fusion.test_fusion_prior import WRONG_HALF_TURN

    node, lines = _twin_node(_starts(WRONG_HALF_TURN))
    (pair,) = node.final_fusion().pairs
    assert not pair.aligned and "contradicts the prior" in pair.note
    assert lines[-1].endswith("the best alignment contradicts the start prior")
