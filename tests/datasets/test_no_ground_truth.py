"""A range-bearing log without ground truth (a lab's own, no motion capture) is a first-class input: `p3at slam
dataset` (known-ID and unknown association, smoothed or not), the chained names and their smoothing run on it and
give the very map and names they give with the truth (the truth only scores: equal bit for bit proves it decided
nothing); every figure that needs the truth is left out and the output says so; the map has no true start pose and
`p3at fuse` fuses such maps without scoring them; what truly needs the truth refuses in one line."""
from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from estimation.chained_names import chain_log
from estimation.dataset_slam import UNSCORED, UNSCORED_LANDMARKS, run_landmark_log
from estimation.datasets import read_mrclam
from estimation.fastslam import range_bearing_config
from estimation.landmark_map import LandmarkMap
from estimation.named_smoothing import smooth_named
from estimation.noise_model import NoiseModel, OdometryNoise, RangeBearingNoise
from runtime.rerun_read import read_recording
from tests.datasets import conftest
from tests.datasets.conftest import run_cli as _cli

TRUTH_FILES = ("Robot1_Groundtruth.dat.gz", "Robot2_Groundtruth.dat.gz", "Landmark_Groundtruth.dat.gz")
TRUTH_METADATA = ("true_start_pose", "truth_heading")   # the map keys only the truth can give
# every figure that needs the truth (`slam dataset --json` of a scored run has each)
SCORES = ("ate_m", "dead_reckoning_ate_m", "final_position_error_m", "pose_nees_mean", "pose_nees_median",
          "pose_nees_within_chi2_95", "pose_nees_frames", "true_start_pose", "true_landmarks", "mapped_true_landmarks",
          "unattributed_landmarks", "duplicate_landmarks", "duplicate_fraction", "landmark_error_median_m",
          "landmark_error_rms_m", "landmark_nees_within_bound", "landmark_nees_median",
          "landmark_error_rigid_median_m", "landmark_nees_rigid_within_bound")
MORE_POSTS = {11: (-3.0, 3.0), 12: (1.5, 4.5), 13: (-2.5, -1.5), 14: (2.5, -1.5)}   # subject -> (x, y)


def _noise(tmp_path: Path) -> Path:
    """A model from elsewhere (the synthetic camera's footprint, a little noise), as a user gives one: a file."""
    sensor = RangeBearingNoise(0.02, 0.0, 0.01, fov_rad=conftest.SENSOR_FOV, max_range_m=conftest.SENSOR_RANGE)
    path = tmp_path / "noise.toml"
    NoiseModel(OdometryNoise(0.01 ** 2, 0.01 ** 2, 0.01 ** 2), sensor).save(path)
    return path


def _with_and_without(tmp_path: Path, synthetic, robots=(1,), seconds: float = 60.0) -> tuple[Path, Path]:
    """The same synthetic folder twice, under one name (the log's name is the folder's): with its ground truth, and
    with every ground-truth file removed."""
    with_truth, without = tmp_path / "with" / "data", tmp_path / "without" / "data"
    for robot in robots:
        synthetic.write(with_truth, robot=robot, seconds=seconds)
    shutil.copytree(with_truth, without)
    for name in TRUTH_FILES:
        (without / name).unlink(missing_ok=True)
    return with_truth, without


def _maps_equal(a: LandmarkMap, b: LandmarkMap) -> None:
    for field in ("positions", "covariances", "ids", "counts", "trajectory", "sighting_covariances"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)
    assert ({k: v for k, v in a.metadata.items() if k not in TRUTH_METADATA}
            == {k: v for k, v in b.metadata.items() if k not in TRUTH_METADATA})


@pytest.mark.parametrize(("association", "smooth"), [("id", "--smooth"), ("id", "--no-smooth"),
                                                     ("unknown", "--no-smooth")])
def test_slam_dataset_maps_a_log_without_ground_truth_as_with_it_and_scores_nothing(tmp_path, synthetic, association,
                                                                                     smooth):
    with_truth, without = _with_and_without(tmp_path, synthetic)
    noise = _noise(tmp_path)
    runs = {}
    for name, folder in (("with", with_truth), ("without", without)):
        out_map = tmp_path / f"{name}.npz"
        status, out, err = _cli("slam", "dataset", "mrclam", str(folder), "--robot", "1", "--out", str(out_map),
                                "--particles", "20", "--noise", str(noise), "--barcodes", "table",
                                "--association", association, smooth, "--json")
        assert status == 0, err
        runs[name] = (json.loads(out), LandmarkMap.load(out_map))
    (scored, with_map), (unscored, without_map) = runs["with"], runs["without"]
    _maps_equal(with_map, without_map)
    assert set(TRUTH_METADATA) <= set(with_map.metadata) and not set(TRUTH_METADATA) & set(without_map.metadata)
    assert all(key in scored for key in SCORES) and "unscored" not in scored
    assert not any(key in unscored or f"filter_{key}" in unscored for key in SCORES)
    assert unscored["unscored"] == UNSCORED and unscored["warnings"] == []
    assert any("no ground truth (Robot1_Groundtruth.dat absent)" in note for note in unscored["notes"])
    # what does not need the truth is the same figure
    for key in ("landmarks", "frames", "seconds", "start_time", "smoother_chi2_per_dof", "smoother_outliers"):
        assert scored.get(key) == unscored.get(key), key
    assert unscored["landmarks"] == len(without_map) > 0
    status, out, err = _cli("slam", "dataset", "mrclam", str(without), "--robot", "1", "--out",
                            str(tmp_path / "text.npz"), "--particles", "20", "--noise", str(noise), "--barcodes",
                            "table", "--association", association, smooth)
    assert status == 0, err
    assert f"landmarks {len(without_map)}; not scored: {UNSCORED}" in out and "trajectory ATE" not in out


@pytest.mark.parametrize("smooth", ["--smooth", "--no-smooth"])
def test_a_log_with_the_robots_truth_but_not_the_landmarks_is_scored_on_its_path_only(tmp_path, synthetic, smooth):
    with_truth, _ = _with_and_without(tmp_path, synthetic, seconds=40.0)
    shutil.copytree(with_truth, tmp_path / "path" / "data")
    (tmp_path / "path" / "data" / "Landmark_Groundtruth.dat.gz").unlink()
    noise = _noise(tmp_path)
    runs = {}
    for name, folder in (("with", with_truth), ("path", tmp_path / "path" / "data")):
        out_map = tmp_path / f"{name}.npz"
        status, out, err = _cli("slam", "dataset", "mrclam", str(folder), "--robot", "1", "--out", str(out_map),
                                "--particles", "20", "--noise", str(noise), "--barcodes", "table", smooth, "--json")
        assert status == 0, err
        runs[name] = (json.loads(out), LandmarkMap.load(out_map))
    _maps_equal(runs["with"][1], runs["path"][1])
    scored, path = runs["with"][0], runs["path"][0]
    assert path["unscored"] == UNSCORED_LANDMARKS and "true_start_pose" in runs["path"][1].metadata
    for key in SCORES:   # the path's figures as with the landmarks' truth, the map's left out
        assert path.get(key) == (scored[key] if key.startswith(("ate", "dead", "final", "pose", "true_start"))
                                 else None), key
    status, out, err = _cli("slam", "dataset", "mrclam", str(tmp_path / "path" / "data"), "--robot", "1", "--out",
                            str(tmp_path / "text.npz"), "--particles", "20", "--noise", str(noise), "--barcodes",
                            "table", smooth)
    assert status == 0, err
    assert "trajectory ATE" in out and "pose NEES over" in out and f"not scored: {UNSCORED_LANDMARKS}" in out


def test_the_api_run_of_a_log_stripped_of_its_truth_is_the_run_with_it(tmp_path, synthetic):
    """The truth taken off a log in memory (any reader's log): the filter and the smoother give the same map and
    path; the run's trajectory is in the map's frame and its pose NEES undefined."""
    synthetic.write(tmp_path, seconds=60.0)
    log = read_mrclam(tmp_path, 1)
    bare = dataclasses.replace(log, ground_truth=np.zeros((0, 4)), truth_ids=np.zeros(0, np.int64),
                               truth_positions=np.zeros((0, 2)))
    noise = NoiseModel.load(_noise(tmp_path))
    runs = [run_landmark_log(x, range_bearing_config(n_particles=20), np.random.default_rng(3), noise=noise,
                             smooth=True) for x in (log, bare)]
    _maps_equal(runs[0].map, runs[1].map)
    np.testing.assert_array_equal(runs[1].estimated_trajectory[:, 1:], runs[1].map.trajectory[1:, 1:])
    assert runs[1].true_trajectory.shape == (0, 4) and np.isnan(runs[1].pose_nees).all()
    assert len(runs[1].pose_nees) == len(runs[0].pose_nees)
    with pytest.raises(ValueError, match="known_map needs the log's ground truth"):
        run_landmark_log(bare, range_bearing_config(n_particles=5), np.random.default_rng(0), noise=noise,
                         known_map=True)


def test_chained_names_and_their_smoothing_do_not_need_the_truth(tmp_path, synthetic):
    """chain_log on the log read without its truth files names every sighting as on the log with them (each window
    in its own first pose's frame), and the named smoothing gives the same solution."""
    with_truth, without = _with_and_without(tmp_path, synthetic, seconds=90.0)
    noise = NoiseModel.load(_noise(tmp_path))
    config = range_bearing_config(n_particles=10)
    logs = (read_mrclam(with_truth, 1), read_mrclam(without, 1, barcodes="table"))
    assert logs[0].has_ground_truth and not logs[1].has_ground_truth and not len(logs[1].truth_ids)
    chained = [chain_log(log, noise, config, seed=2) for log in logs]
    a, b = chained
    assert len(a.windows) == len(b.windows) >= 3 and (a.names >= 0).mean() > 0.9
    np.testing.assert_array_equal(a.names, b.names)
    assert [n.tolist() for n in a.window_names] == [n.tolist() for n in b.window_names]
    assert (a.links, a.unlinked) == (b.links, b.unlinked)
    for u, v in zip(a.windows, b.windows, strict=True):
        np.testing.assert_array_equal(u.sighting_landmark, v.sighting_landmark)
        np.testing.assert_array_equal(u.map.positions, v.map.positions)
    smoothed = [smooth_named(log, c.names, noise, config)[1] for log, c in zip(logs, chained, strict=True)]
    np.testing.assert_array_equal(smoothed[0].poses, smoothed[1].poses)
    np.testing.assert_array_equal(smoothed[0].landmarks, smoothed[1].landmarks)


def test_fuse_fuses_maps_without_a_true_start_and_scores_only_maps_with_one(tmp_path, synthetic, monkeypatch):
    """Two robots (the synthetic circle, nine posts so that an alignment can be found), mapped with and without
    their truth: fuse finds the same alignment and merged map; only the maps with a true start get an error."""
    for subject, position in MORE_POSTS.items():
        monkeypatch.setitem(conftest.LANDMARKS, subject, position)
        monkeypatch.setitem(conftest.BARCODES, subject, 100 + subject)
    with_truth, without = _with_and_without(tmp_path, synthetic, robots=(1, 2), seconds=65.0)
    noise = _noise(tmp_path)
    reports = {}
    for name, folder in (("with", with_truth), ("without", without)):
        maps = [tmp_path / f"{name}{robot}.npz" for robot in (1, 2)]
        for robot, out_map in zip((1, 2), maps, strict=True):
            status, _, err = _cli("slam", "dataset", "mrclam", str(folder), "--robot", str(robot), "--out",
                                  str(out_map), "--particles", "20", "--noise", str(noise), "--barcodes", "table",
                                  "--seed", str(robot))
            assert status == 0, err
        status, out, err = _cli("fuse", *map(str, maps), "--out", str(tmp_path / f"{name}-merged.npz"), "--json")
        assert status == 0, err
        reports[name] = json.loads(out)["alignments"][0]
    scored, unscored = reports["with"], reports["without"]
    assert scored["found"] and unscored["found"] and scored["pose"] == unscored["pose"]
    assert scored["error_xy"] is not None and scored["true_pose"] is not None
    assert "true_pose" not in unscored and unscored.get("error_xy") is None
    merged = [LandmarkMap.load(tmp_path / f"{name}-merged.npz") for name in ("with", "without")]
    np.testing.assert_array_equal(merged[0].positions, merged[1].positions)
    np.testing.assert_array_equal(merged[0].covariances, merged[1].covariances)


def test_the_recording_of_a_run_without_truth_has_no_true_path(tmp_path, synthetic):
    _, without = _with_and_without(tmp_path, synthetic, seconds=30.0)
    recording, out_map = tmp_path / "run.rrd", tmp_path / "robot1.npz"
    status, out, err = _cli("slam", "dataset", "mrclam", str(without), "--robot", "1", "--out", str(out_map),
                            "--particles", "10", "--noise", str(_noise(tmp_path)), "--barcodes", "table", "--rerun",
                            str(recording), "--json")
    assert status == 0, err
    contents = read_recording(recording)
    assert contents.robots == ["robot1"] and contents.ended
    np.testing.assert_array_equal(contents.maps["robot1"].positions, LandmarkMap.load(out_map).positions)
    assert contents.summary["unscored"] == UNSCORED and "ate_m" not in contents.summary


@pytest.mark.parametrize(("command", "args", "complaint"), [
    ("dataset", ["--barcodes", "table"], "noise estimation needs ground truth, and the log has none (give one with "
                                         "--noise FILE)"),
    ("dataset", ["--noise", "NOISE"], "Barcodes.dat cannot be verified without ground truth "
                                      "(Landmark_Groundtruth.dat and Robot1_Groundtruth.dat absent); pass "
                                      "barcodes='table'"),
    ("noise", ["--barcodes", "table", "--window", "2"], "noise estimation needs ground truth, and the log has none"),
    ("noise", ["--window", "2"], "Barcodes.dat cannot be verified without ground truth"),
])
def test_what_needs_the_truth_says_so_in_one_line(tmp_path, synthetic, command, args, complaint):
    _, without = _with_and_without(tmp_path, synthetic, seconds=30.0)
    noise = str(_noise(tmp_path))
    out_file = tmp_path / ("m.npz" if command == "dataset" else "n.toml")
    status, out, err = _cli("slam", command, "mrclam", str(without), "--robot", "1", "--out", str(out_file),
                            *[noise if a == "NOISE" else a for a in args])
    assert status == 2 and out == "" and err.count("\n") == 1 and complaint in err, err
    assert not out_file.exists()


def _bare_copy(source: Path, target: Path) -> Path:
    """The real data set's files (linked) without any ground truth."""
    target.mkdir()
    for path in source.iterdir():
        if "Groundtruth" not in path.name:
            (target / path.name).symlink_to(path.resolve())
    return target


@pytest.mark.slow   # robot 1's noise fit (whole log) and two 200-s smoothed runs, ~8 s
def test_real_dataset2_without_its_truth_maps_as_with_it(mrclam_dir, tmp_path):
    noise = tmp_path / "noise.toml"
    status, _, err = _cli("slam", "noise", "mrclam", str(mrclam_dir), "--robot", "1", "--out", str(noise))
    assert status == 0, err
    bare = _bare_copy(mrclam_dir, tmp_path / mrclam_dir.name)
    runs = {}
    for name, folder in (("with", mrclam_dir), ("without", bare)):
        out_map = tmp_path / f"{name}.npz"
        status, out, err = _cli("slam", "dataset", "mrclam", str(folder), "--robot", "1", "--out", str(out_map),
                                "--noise", str(noise), "--barcodes", "table", "--particles", "20", "--until", "200",
                                "--json")
        assert status == 0, err
        runs[name] = (json.loads(out), LandmarkMap.load(out_map))
    _maps_equal(runs["with"][1], runs["without"][1])
    assert runs["with"][0]["ate_m"] < 1.0 and "ate_m" not in runs["without"][0]
    assert runs["without"][0]["unscored"] == UNSCORED
