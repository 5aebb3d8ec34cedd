"""``p3at slam simulate`` end to end: map file, scores, the loop, and clear errors."""
from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import pytest

from estimation.landmark_map import LandmarkMap
from mocks.world import World
from runtime.cli import main


@pytest.fixture(scope="module")
def full_run(tmp_path_factory):
    """robot1's whole route with 10 particles at 3 frames/s: (map path, exit status, scores)."""
    out = tmp_path_factory.mktemp("slam") / "robot1.npz"
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        status = main(["slam", "simulate", "--particles", "10", "--camera-rate", "3", "--seed", "1", "--out", str(out),
                       "--json"])
    return out, status, json.loads(buffer.getvalue())


def test_simulate_writes_a_scored_map_in_the_start_frame(full_run):
    out, status, _ = full_run
    assert status == 0
    landmark_map = LandmarkMap.load(out)
    world = World.load()
    start = world.start_poses["robot1"]
    assert landmark_map.metadata["true_start_pose"] == pytest.approx(list(start))
    assert landmark_map.robot == "robot1" and len(landmark_map) > 100
    assert np.allclose(landmark_map.trajectory[0, 1:], 0.0)  # the start frame: the robot starts at its origin


def test_loop_closes_instead_of_doubling_the_corridor(full_run):
    """robot1's route goes down the corridor, into a room and back: re-seen features must be re-used."""
    scores = full_run[2]
    assert scores["seconds"] > 60                           # the whole route, there and back
    assert scores["duplicate_landmarks"] <= 0.03 * scores["landmarks"]
    assert scores["ate_m"] < scores["dead_reckoning_ate_m"]
    assert scores["landmark_median_error_m"] < 0.3  # stereo depth σ is 0.2 m at 6 m


def test_pose_nees_is_reported_against_the_cloud_and_against_the_map_frames_drift(full_run):
    """The resampled cloud keeps only the local spread of the pose, so its NEES runs far above 3 as the map frame
    drifts; the drift tracker's D_r (what the map's export claims) covers that drift, so its NEES is lower."""
    scores = full_run[2]
    assert scores["pose_nees_frames"] > 100
    assert 0.0 <= scores["pose_nees_drift_within_chi2_95"] <= 1.0
    assert scores["pose_nees_drift_median"] < scores["pose_nees_median"]
    assert scores["pose_nees_drift_within_chi2_95"] > scores["pose_nees_within_chi2_95"]


def test_human_readable_output(tmp_path, capsys):
    out = tmp_path / "short.npz"
    assert main(["slam", "simulate", "--seconds", "8", "--particles", "5", "--out", str(out),
                 "--ply", str(tmp_path / "short.ply")]) == 0
    text = capsys.readouterr().out
    assert "trajectory ATE" in text and "dead reckoning" in text and str(out) in text
    assert "against the particle cloud" in text and "against the map frame's drift" in text
    assert (tmp_path / "short.ply").read_text().startswith("ply")


def test_route_file_and_start(tmp_path, capsys):
    route = tmp_path / "r.route"
    route.write_text("# along the corridor\n5 5\n9 5\n")
    out = tmp_path / "r.npz"
    assert main(["slam", "simulate", "--world-route", str(route), "--start-pose", "5,5,0", "--particles", "5",
                 "--out", str(out), "--json"]) == 0
    scores = json.loads(capsys.readouterr().out)
    assert scores["start"] == [5.0, 5.0, 0.0] and 9 < scores["seconds"] < 20


@pytest.mark.parametrize(("args", "message"), [
    (["--start-pose", "1,2"], "X,Y,THETA"),
    (["--world-route", "/nonexistent/x.route"], "x.route"),
    (["--particles", "0"], "--particles"),
    (["--name", "robot9"], "robot9"),
])
def test_bad_arguments_give_one_clear_line(tmp_path, capsys, args, message):
    status = main(["slam", "simulate", "--out", str(tmp_path / "x.npz"), *args])
    err = capsys.readouterr().err
    assert status == 2 and message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x.npz").exists()


def test_old_option_spellings_still_work_and_say_what_replaces_them(tmp_path, capsys):
    route = tmp_path / "r.route"
    route.write_text("5 5\n7 5\n")
    out = tmp_path / "r.npz"
    assert main(["slam", "simulate", "--route", str(route), "--start", "5,5,0", "--frame-rate", "3",
                 "--particles", "5", "--out", str(out), "--json"]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["start"] == [5.0, 5.0, 0.0]
    for old, new in (("--route", "--world-route"), ("--start", "--start-pose"), ("--frame-rate", "--camera-rate")):
        assert f"{old} is deprecated" in captured.err and f"use {new}" in captured.err
