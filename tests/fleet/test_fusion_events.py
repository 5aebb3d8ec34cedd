"""The fusion's event line (the demo's and `p3at fuse --live`'s) says why a pair does not overlap yet, in one line,
from the fusion's own figures: supports against the number needed and P(chance), or the alignment's reason."""
from __future__ import annotations

import numpy as np
import pytest

from estimation.landmark_map import LandmarkMap
from runtime.exchange import InProcessExchange
from runtime.fleet.fusion_node import FusionNode, FusionNodeConfig
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


def test_a_live_found_is_a_candidate_until_a_fusion_an_interval_later_on_grown_maps_agrees():
    """fusion/confirmation.py through the node: found once is said as a candidate with its supports and pose; the
    same maps again confirm nothing; grown maps too soon confirm nothing; grown maps an interval later do."""
    robots = [SyntheticRobot(n, k, landmarks=300, grow=60) for k, n in enumerate(["robot1", "robot2"])]
    exchange, lines, clock = InProcessExchange(), [], ManualClock()
    node = FusionNode(exchange, FusionNodeConfig(interval=10.0), on_event=lines.append, clock=clock)

    def grow_and_fuse(at: float, grow: bool = True):
        clock.now = at
        if grow:
            for r in robots:
                exchange.publish(r.name, r.step())
        else:
            node.sources = {}          # fuse the unchanged maps again
        report = node.fuse_now()
        return report.pairs[0], lines[-1]

    pair, line = grow_and_fuse(0.0)
    assert not pair.aligned and pair.supports >= pair.required_supports > 0
    assert line.startswith(f"fusion at t=0s: robot2 -> robot1 is a candidate, not yet found ({pair.supports} "
                           "supports at (") and "no earlier fusion of these maps found it" in line
    pair, line = grow_and_fuse(20.0, grow=False)
    assert not pair.aligned and "the maps have not changed since" in line
    pair, line = grow_and_fuse(25.0)
    assert not pair.aligned and "less than 10 s before" in line
    pair, line = grow_and_fuse(40.0)
    assert pair.aligned and pair.error_xy < 0.1, pair.note
    assert line.startswith("fusion at t=40s: robot2 -> robot1 (")
    pair, line = grow_and_fuse(60.0)                  # found while each agrees with its run's first found
    assert pair.aligned


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
