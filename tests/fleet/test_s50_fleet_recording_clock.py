"""A fleet's recording on one clock (session 50, N): the fusion node logs each fusion at the newest snapshot time it
fused (the robots' mission clock, which their own files are on), not on its own wall clock; and a robot process of the
fleet's shared recording logs no fusion of its own on the node's entities, where the latest of either was shown.
Since session 51 the node's decisions, lines and reports are on that clock too (runtime.fleet.fusion_node.RobotClock).

Before: ``p3at demo --processes``'s node logged its final fusion at t = 18 s of its wall clock while the robots' files
end at 141 s of simulated time, and robot2's own fusion at 141 s ("9 needed") was what the merged view's fusion
status showed, not the node's ("8 needed"). Read back from the saved files as the viewer resolves them
(tests/runtime/rerun_helpers.py) and with the project's reader (runtime/rerun_read.py)."""
from __future__ import annotations

import numpy as np

from runtime.exchange import InProcessExchange
from runtime.fleet.fusion_node import FusionNode, FusionNodeConfig
from runtime.fleet.synthetic import SyntheticRobot
from runtime.rerun_log import NO_FUSION_YET, MissionLog
from runtime.rerun_read import read_recording
from runtime.rerun_sink import open_recording
from runtime.rerun_style import FUSION_STATUS
from tests.fleet.live_node import NODE_ENTITIES, ManualClock
from tests.runtime.rerun_helpers import entity_columns, entity_rows, viewer_state

NS = 1_000_000_000
FLEET = "fleet-s50"
def _maps():
    """Two overlapping robots' maps (the same synthetic building seen from two starts)."""
    return (SyntheticRobot("robot1", 0, landmarks=200, grow=200).step(),
            SyntheticRobot("robot2", 1, landmarks=200, grow=200).step())


def _times(rrd, entity: str) -> list[float]:
    return sorted(r["sim_time"].value / NS for r in entity_rows(rrd, entity) if r.get("sim_time") is not None)


def _node_file(path, stamps: list[dict[str, float]], wall: list[float]):
    """A fusion node's file: at each step the robots named publish their map at the stamp given (their own mission
    clock), and the node (its own clock at ``wall``) fuses. Returns the node's reports."""
    exchange, clock = InProcessExchange(), ManualClock(1000.0)
    logger = MissionLog(open_recording(str(path), recording_id=FLEET), [])
    node = FusionNode(exchange, FusionNodeConfig(), logger=logger, clock=clock)
    maps = dict(zip(("robot1", "robot2"), _maps(), strict=True))
    reports = []
    for step, w in zip(stamps, wall, strict=True):
        for robot, stamp in step.items():
            exchange.publish(robot, maps[robot], stamp=stamp)
        clock.now = 1000.0 + w
        reports.append(node.final_fusion())
    logger.close()
    return reports


def test_the_nodes_fusions_are_recorded_at_the_newest_snapshot_time_they_fused(tmp_path):
    rrd = tmp_path / "mission.rrd"
    # the robots run in simulated time, faster than the node's wall clock: 120.8 / 141 s of theirs at 10 s of the node's
    reports = _node_file(rrd, [{"robot1": 120.8, "robot2": 141.0}, {"robot1": 150.0}, {"robot1": 20.0, "robot2": 30.0}],
                         [10.0, 12.0, 14.0])
    assert all(r is not None and r.merged is not None and r.pairs[0].aligned for r in reports)
    # the fusions' time (their lines, reports, the confirmation interval) is the robots' clock: the newest stamp fused,
    # never going back (robots restarted at 20 s / 30 s: they go on from where the clock is)
    assert [r.t for r in reports] == [141.0, 150.0, 150.0]
    for entity in ("maps/fused", "fusion/alignment/robot1_robot2", "world/fused/landmarks", "map/fused/landmarks"):
        assert _times(rrd, entity) == [141.0, 150.0, 150.0], entity
    # each robot's map once, at the time its robot made it (its own file has it at that time too)
    assert _times(rrd, "maps/robot1") == [20.0, 120.8, 150.0]
    assert _times(rrd, "maps/robot2") == [30.0, 141.0]
    shown = viewer_state(rrd, "sim_time", [100 * NS, 141 * NS])[FUSION_STATUS]
    assert "fusion at t = 141 s" in str(shown[141 * NS]["TextDocument:text"][0])
    assert str(shown[100 * NS]["TextDocument:text"][0]) == NO_FUSION_YET   # before the first fusion, none yet
    assert read_recording(rrd).alignments["robot1_robot2"]["supports"] == reports[-1].pairs[0].supports


def test_a_fleet_robots_own_fusion_stays_off_the_nodes_entities(tmp_path):
    """robot2's process logs as runtime/mission.py does in a fleet's shared recording: its map, its frame, and the
    fusion it makes at its end of the maps it received (at 141 s, later than the node's on any clock before)."""
    node = tmp_path / "mission.rrd"
    (final,) = _node_file(node, [{"robot1": 120.8, "robot2": 141.0}], [18.0])
    robot = tmp_path / "robot2.rrd"
    log = MissionLog(open_recording(str(robot), recording_id=FLEET), ["robot2"], blueprint=False,
                     records_fusion=False)
    log.log_robot_frame("robot2", np.array([8.0, 5.0, np.pi]))
    log.log_robot_frame("fused", np.array([8.0, 5.0, np.pi]))   # mission.py: its first robot's start
    _, m2 = _maps()
    log.log_pose("robot2", 141.0, 529, np.zeros(3))
    log.log_map("robot2", 141.0, m2)
    own = {"aligned": True, "tx": 4.98, "ty": 0.0, "theta": 3.14, "supports": 184, "required_supports": 9,
           "merged": 224}
    log.log_alignment(141.0, "robot1", "robot2", own)   # its own fusion: 9 needed
    log.log_map("fused", 141.0, final.merged)
    log.close()

    on_node_entities = [e for e in entity_columns(robot) if e.startswith(NODE_ENTITIES)]
    assert on_node_entities == []
    assert _times(robot, "maps/robot2") == [141.0]   # its own rows are there
    # the files read together: the node's fusion, robot2's map from its own file
    both = read_recording(node, robot)
    assert both.alignments["robot1_robot2"]["required_supports"] == final.pairs[0].required_supports
    assert both.alignments["robot1_robot2"]["supports"] == final.pairs[0].supports
    assert set(both.maps) == {"robot1", "robot2", "fused"}
    # what a viewer opening both shows at the robots' last instant: the node's fusion, at 141 s, from the node's file
    at_end = viewer_state(node, "sim_time", [141 * NS])[FUSION_STATUS][141 * NS]
    assert "fusion at t = 141 s" in str(at_end["TextDocument:text"][0])
    assert FUSION_STATUS not in viewer_state(robot, "sim_time", [141 * NS])


def test_a_candidates_earlier_fusion_is_named_on_the_recordings_clock(tmp_path):
    """The node confirms a found an interval later on the robots' clock (fusion/confirmation.py), the recording's: a
    candidate's note names the earlier fusion at its time in the recording. Session 50 confirmed on the node's wall
    clock, and said so in the recording ('agrees with the fusion at t=0s of the node's clock (this one: t=5s)' at
    t = 52 s of the robots' clock); before that the note named a time the recording did not show."""
    rrd = tmp_path / "mission.rrd"
    robots = [SyntheticRobot(n, k, landmarks=300, grow=60) for k, n in enumerate(["robot1", "robot2"])]
    exchange, clock = InProcessExchange(), ManualClock(1000.0)
    logger = MissionLog(open_recording(str(rrd), recording_id=FLEET), [])
    node = FusionNode(exchange, FusionNodeConfig(interval=10.0), logger=logger, clock=clock)
    lines = []
    for node_t, stamp in ((0.0, 20.0), (0.5, 26.0)):   # the robots' clock runs ahead of the node's
        clock.now = 1000.0 + node_t
        for r in robots:
            exchange.publish(r.name, r.step(), stamp=stamp)
        report = node.fuse_now()
        lines.append(report.pairs[0].note)
    logger.close()
    assert "agrees with the fusion at t=20s, which is less than 10 s before" in lines[1]
    status = str(viewer_state(rrd, "sim_time", [26 * NS])[FUSION_STATUS][26 * NS]["TextDocument:text"][0])
    assert "(fusion at t = 26 s)" in status and "not yet aligned" in status
    assert "agrees with the fusion at t=20s, which is less than 10 s before" in status
    assert "node's clock" not in status
    earlier = str(viewer_state(rrd, "sim_time", [20 * NS])[FUSION_STATUS][20 * NS]["TextDocument:text"][0])
    assert "(fusion at t = 20 s)" in earlier
