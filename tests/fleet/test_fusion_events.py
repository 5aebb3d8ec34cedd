"""The fusion's event line (the demo's and `p3at fuse --live`'s) says why a pair does not overlap yet, in one line,
from the fusion's own figures: supports against the number needed and P(chance), or the alignment's reason."""
from __future__ import annotations

import numpy as np
import pytest

from estimation.landmark_map import LandmarkMap
from runtime.exchange import InProcessExchange
from runtime.fleet.fusion_node import FusionNode
from runtime.fleet.synthetic import SyntheticRobot
from runtime.report import fusion_event_line


def _fuse(m1: LandmarkMap, m2: LandmarkMap):
    exchange, lines = InProcessExchange(), []
    exchange.publish("robot1", m1)
    exchange.publish("robot2", m2)
    report = FusionNode(exchange, on_event=lines.append).fuse_now()
    assert report is not None and len(report.pairs) == 1 and len(lines) == 1
    return report.pairs[0], lines[0]


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
    assert ("ambiguous: a distinct transform gathers" in line) == pair.note.startswith("ambiguous")


def test_maps_without_common_landmarks_give_the_alignments_reason():
    m1 = _robot1()
    m2 = SyntheticRobot("robot2", 1, seed=1, landmarks=200, grow=200).step()  # another building altogether
    pair, line = _fuse(m1, m2)
    assert not pair.aligned and pair.required_supports == 0 and pair.note
    assert line == f"fusion at t=0s: robot2 does not overlap robot1 yet: {pair.note}"


def test_an_alignment_found_keeps_its_line():
    m1 = _robot1()
    m2 = SyntheticRobot("robot2", 1, landmarks=200, grow=200).step()
    pair, line = _fuse(m1, m2)
    assert pair.aligned
    assert line.startswith(f"fusion at t=0s: robot2 -> robot1 ({pair.supports} supports, {pair.common} common), "
                           f"error {pair.error_xy:.3f} m")


def test_a_reason_on_several_lines_is_printed_on_one():
    pair = {"reference": "a", "other": "b", "aligned": False, "supports": 0, "note": "first\nsecond  third"}
    assert fusion_event_line(12.4, pair) == "fusion at t=12s: b does not overlap a yet: first second third"
