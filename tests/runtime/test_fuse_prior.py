"""``p3at fuse --start-pose``: a rough start pose per map gives each pair a prior on its relative start."""
from __future__ import annotations

import json

import numpy as np
import pytest

from estimation.geometry import compose
from estimation.landmark_map import LandmarkMap
from runtime.cli import main
from tests.fusion.test_fusion_prior import HALF_TURN, TRUE_POSE, twin_pair


def _files(tmp_path):
    m1, m2 = twin_pair(0, common=30, twins=24)       # ambiguous without a prior: the half turn is nearly as good
    paths = [tmp_path / "a.npz", tmp_path / "b.npz"]
    m1.save(paths[0])
    m2.save(paths[1])
    return [str(p) for p in paths]


def _start(pose) -> str:
    return ",".join(f"{v:.6f}" for v in pose)


def test_starts_resolve_the_half_turn_and_the_json_says_a_prior_was_used(tmp_path, capsys):
    files = _files(tmp_path)
    out = str(tmp_path / "merged.npz")
    assert main(["fuse", *files, "--out", out, "--json"]) == 1
    capsys.readouterr()
    start2 = compose(np.array([1.0, 2.0, 0.3]), TRUE_POSE)          # map 1's robot at (1, 2, 0.3) in the lab
    code = main(["fuse", *files, "--out", out, "--json", "--start-pose", "0=1,2,0.3", "--start-pose",
                 f"robot2={_start(start2)}", "--start-sigma", "1,0.3"])
    report = json.loads(capsys.readouterr().out)
    assert code == 0
    a = report["alignments"][0]
    assert a["found"] and a["prior"]["source"] == "given start poses"
    assert np.hypot(*(np.array(a["pose"][:2]) - TRUE_POSE[:2])) < 0.1
    assert a["statistics"]["outside_prior_supports"] >= 20


def test_a_half_turned_start_is_reported_as_contradicting(tmp_path, capsys):
    files = _files(tmp_path)
    wrong = compose(HALF_TURN, TRUE_POSE)
    code = main(["fuse", *files, "--out", str(tmp_path / "m.npz"), "--start-pose", "0=0,0,0,1,0.3",
                 "--start-pose", f"1={_start(wrong)},1,0.3"])
    out = capsys.readouterr().out
    assert code == 1
    assert "contradicts the prior" in out


def test_bad_starts_are_one_line_errors(tmp_path, capsys):
    files = _files(tmp_path)
    for args in (["--start-pose", "0=1,2"], ["--start-pose", "robot9=1,2,3,1,1"], ["--start-pose", "0=1,2,3"],
                 ["--start-pose", "no-equals-sign"]):
        code = main(["fuse", *files, "--out", str(tmp_path / "m.npz"), *args, "--start-pose", "1=0,0,0,1,0.3"])
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1 and "start" in err[0], (args, err)


def test_the_mission_s_start_prior_needs_virtual_robots_and_two_positive_sigmas():
    import argparse

    import pytest

    from runtime.commands.options import start_sigmas
    from runtime.mission import MissionConfig

    assert start_sigmas("1,0.3") == (1.0, 0.3)
    for bad in ("1", "1,0", "-1,0.3", "a,b", "1,0.3,2", "inf,1"):
        with pytest.raises(argparse.ArgumentTypeError):
            start_sigmas(bad)
    assert MissionConfig(start_prior=(1.0, 0.3)).start_prior == (1.0, 0.3)
    assert MissionConfig().start_prior is None                     # off by default: the demo is unchanged
    with pytest.raises(ValueError, match="start-prior"):
        MissionConfig(robots=1, robot_url="tcp://10.0.0.2:8101", camera="usb", start_prior=(1.0, 0.3))


def test_the_live_fusion_line_says_the_best_alignment_contradicts_the_prior():
    from runtime.report import not_aligned_reason

    pair = {"supports": 12, "required_supports": 48, "false_alarm_probability": 1.0,
            "note": "the maps' best alignment contradicts the prior: 12 supports at tx=+14.42 m ..."}
    assert "contradicts the start prior" in not_aligned_reason(pair)
    assert "contradicts" not in not_aligned_reason({**pair, "note": "only 3 supports"})


def test_start_poses_from_a_file_and_a_malformed_file(tmp_path, capsys):
    files = _files(tmp_path)
    good = tmp_path / "starts.json"
    good.write_text(json.dumps({"sigma_xy": 1.0, "sigma_yaw": 0.3,
                                "starts": {"robot1": [0, 0, 0], "1": [*[float(v) for v in TRUE_POSE], 1.0, 0.3]}}))
    assert main(["fuse", *files, "--out", str(tmp_path / "m.npz"), "--json", "--start-poses", str(good)]) == 0
    assert json.loads(capsys.readouterr().out)["alignments"][0]["prior"] is not None
    bad = tmp_path / "bad.json"
    bad.write_text('{"starts": [1, 2]}')
    assert main(["fuse", *files, "--out", str(tmp_path / "m.npz"), "--start-poses", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "start-pose file" in err[0]


def test_a_start_for_one_map_of_a_pair_is_a_one_line_error_not_silently_no_prior(tmp_path, capsys):
    files = _files(tmp_path)
    for args in (["--start-pose", "robot1=0,0,0,1,0.3"], ["--start-pose", "1=5,0,3.1416", "--start-sigma", "1,0.3"]):
        code = main(["fuse", *files, "--out", str(tmp_path / "m.npz"), *args])
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1 and "alone gives no prior" in err[0], (args, err)


def test_maps_without_a_start_among_maps_with_one_are_named_in_a_warning(tmp_path, capsys):
    files = _files(tmp_path)
    third = tmp_path / "c.npz"
    m3 = LandmarkMap.load(files[1])        # a third robot's map of robot2's landmarks, its own estimates (σ 3 cm)
    moved = m3.positions + np.random.default_rng(3).normal(0, 0.03, m3.positions.shape)
    LandmarkMap(moved, m3.covariances, m3.descriptors, robot="robot3").save(third)
    start2 = compose(np.array([1.0, 2.0, 0.3]), TRUE_POSE)
    main(["fuse", *files, str(third), "--out", str(tmp_path / "m.npz"), "--json", "--start-pose", "0=1,2,0.3",
          "--start-pose", f"robot2={_start(start2)}", "--start-sigma", "1,0.3"])
    captured = capsys.readouterr()
    warnings = [line for line in captured.err.splitlines() if "no start pose" in line]
    assert len(warnings) == 1 and "map 2 (robot3)" in warnings[0] and "without a prior" in warnings[0]
    priors = {(a["map1"], a["map2"]): a["prior"] for a in json.loads(captured.out)["alignments"]}
    assert priors[(0, 1)] is not None and priors[(0, 2)] is None and priors[(1, 2)] is None


@pytest.mark.parametrize(("starts", "said"), [
    (["0=0,0,0,1,0.3", "1=5,0,3.14,1,0.3"], "by robot name, not by index"),   # live maps come by robot
    (["robot1=0,0,0,1,0.3"], "alone gives no prior"),
    (["robot1=0,0,0", "robot2=5,0,3.14"], "no standard deviations"),
])
def test_the_live_node_refuses_starts_it_cannot_use_in_one_line_before_it_listens(starts, said, capsys):
    args = [arg for start in starts for arg in ("--start-pose", start)]
    code = main(["fuse", "--live", "--exchange", "zenoh:not json", *args])  # the exchange is never opened
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and said in err[0], err
