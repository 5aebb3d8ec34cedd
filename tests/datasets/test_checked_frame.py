"""A data set run's map in a frame chosen by its data (``run_landmark_log(..., frame="checked")``, ``p3at slam dataset
--frame checked``; estimation.map_frame): on a log that starts turning on the spot with one landmark in view at a time
the map is the same smoothed solution seen from the first pose no single sighting can move unseen, scored against the
truth at that pose, with or without a truth; the option is refused where there is no smoothed solution to choose on;
MRCLAM robot 1's frame moves off its first glimpse."""
from __future__ import annotations

import json

import numpy as np
import pytest

from estimation.dataset_slam import run_landmark_log
from estimation.datasets import RangeBearingLog
from estimation.fastslam import range_bearing_config
from estimation.geometry import between, compose
from estimation.landmark_map import LandmarkMap
from estimation.landmark_scores import ate

from .conftest import run_cli
from .turning_start import NOISE, turning_start_log


def _log(with_truth: bool = True) -> RangeBearingLog:
    """The turning start with a glimpse every 1.5 s of the turn, each the lone tie of its pose."""
    return turning_start_log(1, glimpses_in_turn=True, with_truth=with_truth)


def _run(log: RangeBearingLog, frame: str):
    return run_landmark_log(log, range_bearing_config(n_particles=10), np.random.default_rng(0), noise=NOISE,
                            association="id", robot="robot1", smooth=True, frame=frame)


def test_the_checked_frame_is_the_same_map_seen_from_the_first_pose_no_sighting_moves_unseen(tmp_path):
    log = _log()
    first, checked = _run(log, "first-sighting"), _run(log, "checked")
    f, c = first.metrics, checked.metrics
    assert f["frame_reliability_unchecked"] and "map_frame" not in f
    assert c["map_frame"] == "checked" and c["map_frame_found"] and c["map_frame_pose"] > 0
    assert not c["frame_reliability_unchecked"]
    assert max(c["frame_reliability_effect_sd"]) <= c["frame_reliability_delta0"]
    np.testing.assert_allclose(c["map_frame_first_sighting_effect_sd"], f["frame_reliability_effect_sd"], rtol=1e-8)
    # the turn's glimpses, each its pose's lone tie, are passed over: the frame is on the circle
    assert c["map_frame_time_s"] >= 8.5 and c["map_frame_poses_tried"] > 2
    # the same solution: the first sighting's map and path seen from the chosen pose
    k = c["map_frame_pose"]
    origin = first.map.trajectory[k, 1:]
    assert checked.map.trajectory[k, 0] == pytest.approx(c["map_frame_time_s"])
    points = np.column_stack([first.map.positions[:, :2], np.zeros(len(first.map.positions))])
    np.testing.assert_allclose(checked.map.positions[:, :2], between(origin, points)[:, :2], atol=1e-8)
    np.testing.assert_allclose(checked.map.trajectory[:, 1:], between(origin, first.map.trajectory[:, 1:]),
                               atol=1e-8)
    # scored in that frame: its true pose is the map's true_start_pose, the path is placed from it
    true_k = log.true_pose([c["map_frame_time_s"]])[0]
    np.testing.assert_allclose(c["true_start_pose"], true_k)
    np.testing.assert_allclose(checked.map.metadata["true_start_pose"], true_k)
    assert checked.map.metadata["map_frame"] == "checked"
    placed = compose(true_k, checked.map.trajectory[1:, 1:])
    np.testing.assert_allclose(checked.estimated_trajectory[:, 1:], placed, atol=1e-12)
    assert c["ate_m"] == pytest.approx(ate(placed, log.true_pose(checked.estimated_trajectory[:, 0])))
    assert c["start_time"] == f["start_time"] == pytest.approx(1.0)           # the log's first sighting still
    # the file keeps the frame
    checked.map.save(tmp_path / "map.npz")
    again = LandmarkMap.load(tmp_path / "map.npz")
    assert again.metadata["map_frame"] == "checked"
    assert again.metadata["map_frame_time_s"] == pytest.approx(c["map_frame_time_s"])


def test_the_frame_is_chosen_without_the_truth():
    checked = _run(_log(), "checked")
    blind = _run(_log(with_truth=False), "checked")
    assert "unscored" in blind.metrics and "true_start_pose" not in blind.metrics
    assert "true_start_pose" not in blind.map.metadata
    for key in ("map_frame_pose", "map_frame_time_s", "map_frame_found"):
        assert blind.metrics[key] == checked.metrics[key]
    np.testing.assert_allclose(blind.map.positions, checked.map.positions, atol=1e-9)


def test_a_frame_other_than_the_first_sighting_s_needs_the_smoother():
    with pytest.raises(ValueError, match="needs smoothing"):
        run_landmark_log(_log(), range_bearing_config(n_particles=10), np.random.default_rng(0), noise=NOISE,
                         association="id", frame="checked")
    with pytest.raises(ValueError, match="must be one of first-sighting, checked"):
        _run(_log(), "best")


@pytest.mark.parametrize("options, says", [
    (["--association", "unknown"], "it needs --association id and the smoother"),
    (["--no-smooth"], "it needs --association id and the smoother"),
    (["--association", "unknown", "--chain"], "the chain's map keeps its own frame"),
])
def test_the_command_refuses_a_checked_frame_without_the_smoother_before_reading_anything(tmp_path, options, says):
    status, out, err = run_cli("slam", "dataset", "mrclam", str(tmp_path / "nothing-here"), "--robot", "1", "--out",
                               str(tmp_path / "map.npz"), "--frame", "checked", *options)
    assert status == 2 and out == ""
    assert err.startswith("p3at slam dataset: --frame checked") and says in err
    assert not (tmp_path / "map.npz").exists()


@pytest.mark.slow   # one whole MRCLAM log, a filter and the smoother (~15 s CPU)
@pytest.mark.timeout(1200)
def test_real_dataset2_robot1_s_checked_frame_leaves_its_first_glimpse(mrclam_dir, tmp_path):
    """`p3at slam dataset mrclam DIR --robot 1 --frame checked --json` (the log's own fitted model): the first
    sighting's frame (7.00 s, landmark 11, the lone glimpse) is flagged, the chosen one is a later pose that passes,
    with no frame warning, and the map's true_start_pose is the truth at that pose."""
    status, out, err = run_cli("slam", "dataset", "mrclam", str(mrclam_dir), "--robot", "1", "--frame", "checked",
                               "--out", str(tmp_path / "robot1.npz"), "--json")
    assert status == 0, err
    m = json.loads(out)
    assert m["start_time"] == pytest.approx(7.0) and m["map_frame_time_s"] > 7.0 and m["map_frame_found"]
    assert max(m["map_frame_first_sighting_effect_sd"]) > m["frame_reliability_delta0"]
    assert not m["frame_reliability_unchecked"] and "frame rests" not in err
    stored = LandmarkMap.load(tmp_path / "robot1.npz")
    from estimation.datasets import read_mrclam
    truth = read_mrclam(mrclam_dir, 1).true_pose([m["map_frame_time_s"]])[0]
    np.testing.assert_allclose(stored.metadata["true_start_pose"], truth)
    np.testing.assert_allclose(m["true_start_pose"], truth)
