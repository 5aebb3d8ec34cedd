"""The Rerun log shows a robot's self-check (runtime/rerun_log.py): its CUSUM beside its threshold per snapshot, and
one warning event when the map says it lost its place."""
from __future__ import annotations

import numpy as np
import rerun as rr

from runtime.rerun_log import MissionLog
from tests.fastslam.conftest import corridor_features
from tests.fastslam.test_self_check import KICK, _run
from tests.runtime.rerun_helpers import landmark_map


class _Stream:
    """Records what MissionLog logs (entity path, archetype) instead of sending it."""

    def __init__(self) -> None:
        self.rows: list[tuple[str, object]] = []

    def log(self, path, entity, static=False) -> None:
        self.rows.append((path, entity))

    def set_time(self, *args, **kwargs) -> None:
        pass

    def disable_timeline(self, *args) -> None:
        pass

    def is_enabled(self) -> bool:
        return False


def _events(stream: _Stream) -> list[str]:
    return [str(e.text.as_arrow_array()[0]) for p, e in stream.rows if p == "mission/events"
            and isinstance(e, rr.TextLog)]


def test_a_snapshot_that_lost_its_place_logs_one_warning_and_its_statistic():
    verdicts = {kick: _run(corridor_features, kick)[0].best_map().metadata["self_check"] for kick in (0.0, KICK)}
    stream = _Stream()
    log = MissionLog(stream, ["robot1", "robot2"], blueprint=False)
    rng = np.random.default_rng(0)
    for t in (1.0, 2.0):   # two snapshots of each robot: the warning once
        for robot, kick in (("robot1", 0.0), ("robot2", KICK)):
            m = landmark_map(robot, 8, rng)
            m.metadata = {"self_check": verdicts[kick]}
            log.log_map(robot, t, m)
    events = _events(stream)
    assert len(events) == 1 and events[0].startswith("robot2: map may have lost its place at t≈")
    plotted = {p for p, _ in stream.rows}
    assert {"plots/robot1/self_check", "plots/robot2/self_check", "plots/robot2/self_check/threshold"} <= plotted
    old = landmark_map("robot1", 8, rng)   # a map without the key: nothing about it
    before = len(stream.rows)
    log.log_map("robot1", 3.0, old)
    assert not any(p.endswith("self_check") for p, _ in stream.rows[before:])


def test_the_split_of_a_flagged_map_is_one_event_per_decision():
    """fusion/split.py's decision travels in the pair's result (PairResult.self_check): one event per pair and
    decision however often the mission fuses; a warning unless the map was used whole; none for a pair without it."""
    stream = _Stream()
    log = MissionLog(stream, ["robot1", "robot2"], blueprint=False)
    pair = {"aligned": True, "tx": 0.0, "ty": 0.0, "theta": 0.0, "supports": 30, "common": 30, "self_check": "",
            "split_decision": None}
    log.log_alignment(1.0, "robot1", "robot2", pair)
    split = {**pair, "self_check": "robot2 flagged itself: ... the parts disagree", "split_decision": "parts"}
    for t in (2.0, 3.0):
        log.log_alignment(t, "robot1", "robot2", split)
    log.log_alignment(4.0, "robot1", "robot2", {**split, "self_check": "robot2 ... agree", "split_decision": "whole"})
    levels = [str(e.level.as_arrow_array()[0]) for p, e in stream.rows if p == "mission/events"]
    assert _events(stream) == ["fusion: robot2 flagged itself: ... the parts disagree", "fusion: robot2 ... agree"]
    assert levels == ["WARN", "INFO"]


def test_a_live_candidate_is_an_event_and_places_nothing_in_the_fused_map():
    """fusion/confirmation.py: an alignment found once and not yet confirmed is told in the event log (its supports,
    pose and why), and robot2's path is not placed in the fused map until it is found."""
    stream = _Stream()
    log = MissionLog(stream, ["robot1", "robot2"], blueprint=False)
    note = ("candidate: 26 supports at (0.15 m, -0.01 m, -0.001 rad); no earlier fusion of these maps found it; "
            "the maps are still growing, so a fusion at least 20 s later must agree")
    log.log_alignment(20.0, "robot1", "robot2", {"aligned": False, "supports": 26, "note": note})
    assert _events(stream) == ["fusion: robot2 -> robot1 is a candidate, not yet found (26 supports at (0.15 m, "
                               "-0.01 m, -0.001 rad); no earlier fusion of these maps found it)"]
    assert not any(p.startswith("fused") or "/fused/" in p for p, _ in stream.rows)
    log.log_alignment(40.0, "robot1", "robot2", {"aligned": False, "supports": 5, "note": "only 5 supports"})
    assert len(_events(stream)) == 1          # a plain "not found" is no candidate event
