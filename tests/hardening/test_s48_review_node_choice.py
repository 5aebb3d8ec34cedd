"""Which file of a fleet's recording ``p3at review`` reads the mission's figures from (runtime/rerun_read.py,
session 48), given hostile sets of files (session 48, H): two files whose summaries both say they are the fusion
node's, a robot's file holding more robots' maps than the node's, summaries of wrong types, one file given twice.
Two claimers tied on their maps fell back to ordering rows by time across files, so a robot's own fusion (later on
its own clock: 9 needed) was printed over both nodes' (8 and 7 needed); now one of the claimers is read (the one with
most robots' maps, of a tie the first given), never a robot's file."""
from __future__ import annotations

import numpy as np
import pytest

from estimation.landmark_map import LandmarkMap
from runtime.cli import main
from runtime.rerun_log import MissionLog
from runtime.rerun_read import read_recording
from runtime.rerun_sink import open_recording


def _map(robot: str, n: int, seed: int) -> LandmarkMap:
    rng = np.random.default_rng(seed)
    return LandmarkMap(rng.uniform(0, 10, (n, 3)), np.tile(np.eye(3) * 1e-3, (n, 1, 1)),
                       rng.standard_normal((n, 8)).astype(np.float32), robot=robot, robots=[robot])


def _pair(needed: int) -> dict:
    return {"reference": "robot1", "other": "robot2", "aligned": True, "tx": 4.986, "ty": -0.016, "theta": 3.1398,
            "supports": 184, "required_supports": needed, "false_alarm_probability": 3.2e-299, "common": 184}


def _write(path, robots, t, maps, needed, summary):
    log = MissionLog(open_recording(str(path), recording_id="s48-hostile-review"), robots, blueprint=False)
    for key, m in maps.items():
        log.log_map(key, t - 1.0, m)
    log.log_alignment(t, "robot1", "robot2", _pair(needed))
    if summary is not None:
        log.log_summary(summary)
    log.close()
    return path


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("hostile-review")
    own1, own2 = _map("robot1", 209, 1), _map("robot2", 199, 2)
    node_maps = {"robot1": _map("robot1", 150, 3), "robot2": own2, "fused": _map("robot1", 224, 4)}
    out = {"node": _write(d / "node.rrd", ["robot1", "robot2"], 24.0, node_maps, 8, {"processes": True}),
           "node2": _write(d / "node2.rrd", ["robot1", "robot2"], 30.0, node_maps, 7, {"fusion_node": True}),
           "robot2": _write(d / "robot2.rrd", ["robot2"], 141.0, {"robot2": own2, "fused": _map("robot1", 230, 6)},
                            9, {"robots": {"robot2": {"landmarks": 199}}}),
           "wide robot": _write(d / "robot3.rrd", ["robot2"], 141.0,
                                {"robot2": own2, "robot1": own1, "robot3": _map("robot3", 50, 9)}, 9, {})}
    for i, bad in enumerate([{"fusion_node": "yes"}, {"processes": 1, "robots": "x"},
                             {"fusion_node": True, "robots": [1, 2], "fusion": "x"},
                             {"fusion_node": True, "fusion": {"pairs": [1, "a"]}}]):
        out[f"bad{i}"] = _write(d / f"bad{i}.rrd", ["robot1", "robot2"], 24.0, node_maps, 8, bad)
    return out


def _needed(*paths) -> int:
    return read_recording(*paths).alignments["robot1_robot2"]["required_supports"]


def test_two_files_that_say_they_are_the_node_s_one_of_them_never_the_robot_s(files):
    assert _needed(files["node"], files["node2"], files["robot2"]) == 8        # the first given
    assert _needed(files["node2"], files["robot2"], files["node"]) == 7
    assert _needed(files["robot2"], files["node"], files["node2"]) == 8
    assert len(read_recording(files["node"], files["node2"], files["robot2"]).maps["fused"]) == 224


def test_a_robot_file_with_more_maps_does_not_outvote_the_node_s_summary(files):
    assert _needed(files["wide robot"], files["node"]) == 8


@pytest.mark.parametrize("bad", ["bad0", "bad1", "bad2", "bad3"])
def test_summaries_of_wrong_types_are_read_without_a_traceback(files, bad, capsys):
    assert main(["review", str(files[bad]), str(files["robot2"]), "--no-export"]) == 0
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err and "(8 needed" in captured.out


def test_the_same_file_twice(files):
    assert _needed(files["node"], files["node"]) == 8
    assert _needed(files["node"], files["robot2"], files["node"]) == 8
