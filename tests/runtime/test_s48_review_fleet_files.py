"""``p3at review`` of a fleet's files (the fusion node's and each robot's) gives the mission's figures: the node's.

Session 48: each robot process of ``p3at demo --processes`` fuses the maps it receives and records its own alignment,
fused map and summary, on its own simulated time (robot2's at t = 141 s, while the node's final fusion was at 24 s).
The rows were ordered by time across the files, so review printed robot2's alignment (184 supports, 9 needed) beside
a demo table that said 8 needed. The files here are written as those processes write them (MissionLog, one
recording id), with the figures of that run."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from estimation.landmark_map import LandmarkMap
from runtime.cli import main
from runtime.rerun_log import MissionLog
from runtime.rerun_read import read_recording
from runtime.rerun_sink import open_recording

RECORDING_ID = "s48-fleet-review"


def _map(robot: str, n: int, seed: int) -> LandmarkMap:
    rng = np.random.default_rng(seed)
    return LandmarkMap(rng.uniform(0, 10, (n, 3)), np.tile(np.eye(3) * 1e-3, (n, 1, 1)),
                       rng.standard_normal((n, 8)).astype(np.float32), robot=robot, robots=[robot])


def _pair(supports: int, needed: int) -> dict:
    return {"reference": "robot1", "other": "robot2", "aligned": True, "tx": 4.986, "ty": -0.016, "theta": 3.1398,
            "supports": supports, "required_supports": needed, "false_alarm_probability": 3.2e-299,
            "common": supports}


def _write(path, robots, t, maps, pair, summary) -> None:
    log = MissionLog(open_recording(str(path), recording_id=RECORDING_ID), robots, blueprint=False)
    for key, m in maps.items():
        log.log_map(key, t - 1.0, m)
    log.log_alignment(t, "robot1", "robot2", pair)
    if summary is not None:
        log.log_summary(summary)
    log.close()


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """The node's file (received maps of both robots, an older robot1 map; its final fusion at 24 s: 8 needed; its
    fused map of 224), robot1's (its own map, its own fusion at 120 s) and robot2's (its own fusion at 141 s: 9
    needed, its fused map of 230); with and without the node's summary (a node killed before it)."""
    folder = tmp_path_factory.mktemp("fleet")
    own1, own2 = _map("robot1", 209, 1), _map("robot2", 199, 2)
    files = {}
    for summary in ("summary", "no summary"):
        node = folder / summary.replace(" ", "-") / "mission.rrd"
        node.parent.mkdir()
        node_summary = {"processes": True, "fusion": {"pairs": [_pair(184, 8)]}, "fusions_during_mission": 4}
        _write(node, ["robot1", "robot2"], 24.0, {"robot1": _map("robot1", 150, 3), "robot2": own2,
                                                  "fused": _map("robot1", 224, 4)}, _pair(184, 8),
               node_summary if summary == "summary" else None)
        robot1, robot2 = node.parent / "robot1.rrd", node.parent / "robot2.rrd"
        _write(robot1, ["robot1"], 120.0, {"robot1": own1, "fused": _map("robot1", 212, 5)}, _pair(106, 10),
               {"robots": {"robot1": {"landmarks": 209}}, "fusion": {"pairs": [_pair(106, 10)]}})
        _write(robot2, ["robot2"], 141.0, {"robot2": own2, "fused": _map("robot1", 230, 6)}, _pair(184, 9),
               {"robots": {"robot2": {"landmarks": 199}}, "fusion": {"pairs": [_pair(184, 9)]}})
        files[summary] = [node, robot1, robot2]
    return files


@pytest.mark.parametrize("summary", ["summary", "no summary"])
def test_the_node_s_alignment_and_fused_map_and_each_robot_s_own_map_in_any_order_of_the_files(fleet, summary):
    node, robot1, robot2 = fleet[summary]
    for order in itertools.permutations([node, robot1, robot2]):
        contents = read_recording(*order)
        assert contents.alignments["robot1_robot2"]["required_supports"] == 8, order
        assert {k: len(m) for k, m in contents.maps.items()} == {"robot1": 209, "robot2": 199, "fused": 224}
        if summary == "summary":
            assert contents.summary["processes"] is True and contents.summary["fusions_during_mission"] == 4
    assert read_recording(robot2, node).alignments["robot1_robot2"]["required_supports"] == 8


def test_review_prints_the_figures_the_node_printed(fleet, capsys):
    node, robot1, robot2 = fleet["summary"]
    assert main(["review", str(node), str(robot1), str(robot2), "--no-export"]) == 0
    out = capsys.readouterr().out
    assert "184 supports (8 needed" in out and "9 needed" not in out and "10 needed" not in out
    assert "  map fused         224 landmarks" in out.splitlines()


def test_the_robots_files_alone_are_read_as_before(fleet):
    """Without the node's file nothing tells whose word counts: the latest row in time, as before."""
    _, robot1, robot2 = fleet["summary"]
    assert read_recording(robot1, robot2).alignments["robot1_robot2"]["required_supports"] == 9
