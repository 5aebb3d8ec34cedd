"""Playing a landmark log through FastSLAM (`p3at slam dataset`, `p3at slam noise`): maps, scores and errors."""
from __future__ import annotations

import gzip
import json

import numpy as np
import pytest

from estimation.dataset_slam import run_landmark_log
from estimation.datasets import read_mrclam
from estimation.fastslam import range_bearing_config
from estimation.landmark_map import LandmarkMap
from estimation.noise_estimation import estimate_noise
from estimation.noise_model import NoiseModel, OdometryNoise, RangeBearingNoise
from tests.datasets.conftest import run_cli as _cli

KEYS = ("ate_m", "dead_reckoning_ate_m", "landmarks", "true_landmarks", "duplicate_fraction",
        "landmark_error_median_m", "landmark_error_rigid_median_m", "landmark_nees_within_bound",
        "pose_nees_mean", "pose_nees_median", "pose_nees_within_chi2_95")


def _small_noise(synthetic) -> NoiseModel:
    """Little noise, and the synthetic camera's footprint (negative evidence must not count beyond it)."""
    sensor = RangeBearingNoise(0.02, 0.0, 0.01, fov_rad=synthetic.SENSOR_FOV, max_range_m=synthetic.SENSOR_RANGE)
    return NoiseModel(OdometryNoise(0.01 ** 2, 0.01 ** 2, 0.01 ** 2), sensor)


@pytest.mark.parametrize("association", ["id", "unknown"])
def test_exact_data_gives_an_exact_map_in_the_first_sighting_frame(tmp_path, synthetic, association):
    truth = synthetic.write(tmp_path, seconds=60.0)
    log = read_mrclam(tmp_path, 1)
    # 50 particles: with 10, one or two sightings a frame let the cloud collapse and drift (pose NEES ~ 9, measured)
    run = run_landmark_log(log, range_bearing_config(n_particles=50), np.random.default_rng(1),
                           noise=_small_noise(synthetic), association=association, robot="robot1")
    m = run.metrics
    seen = set(log.landmark_ids.tolist())
    assert m["true_landmarks"] == len(seen) and m["landmarks"] == len(seen) and m["duplicate_fraction"] == 0.0
    # exact data, but the filter is told σ_r 2 cm and σ_φ 0.01 rad (3 cm at 3 m): it wanders on that scale
    assert m["ate_m"] < 0.05 and m["landmark_error_median_m"] < 0.05 and m["landmark_error_rigid_median_m"] < 0.05
    assert m["pose_nees_median"] < 7.815                     # χ²₃ 95 %: the cloud's spread covers its error
    # the frame is the robot's pose at its first sighting (t = 0 here), as the metadata says
    start = log.true_pose([log.sighting_times[0]])[0]
    np.testing.assert_allclose(run.map.metadata["true_start_pose"], start)
    np.testing.assert_allclose(start, truth["start"], atol=1e-9)
    assert run.map.metadata["association"] == association


def test_cli_writes_a_scored_map_and_the_noise_command_a_model_it_reads(tmp_path, synthetic):
    synthetic.write(tmp_path / "data", seconds=40.0)
    noise = tmp_path / "noise.toml"
    status, out, err = _cli("slam", "noise", "mrclam", str(tmp_path / "data"), "--robot", "1", "--out", str(noise),
                            "--window", "2")
    assert status == 0 and "written to" in out, err
    model = NoiseModel.load(noise)
    assert model.range_bearing is not None and model.odometry.translation_scale == pytest.approx(1.0, abs=1e-3)
    # the heading bias is fitted only when asked (--heading-bias)
    assert model.odometry.heading_bias_per_m == 0.0 and "heading bias" not in out
    assert not any(key.startswith("heading_bias") for key in model.fit)
    out_map = tmp_path / "robot1.npz"
    status, out, err = _cli("slam", "dataset", "mrclam", str(tmp_path / "data"), "--robot", "1", "--out",
                            str(out_map), "--particles", "10", "--noise", str(noise), "--json")
    assert status == 0, err
    scores = json.loads(out)
    assert all(k in scores for k in KEYS) and scores["noise"] == str(noise)
    landmark_map = LandmarkMap.load(out_map)
    assert len(landmark_map) == scores["landmarks"] and "true_start_pose" in landmark_map.metadata


def test_a_log_whose_turn_rate_never_varies_fits_no_odometry_lag(tmp_path, synthetic):
    """A circle at constant speeds: every lag fits it alike, so none is fitted. The grid's minimum was rounding noise
    (0.19 s), which read the exact odometry 4 cm off and put the default's smoothed map far outside its covariance."""
    synthetic.write(tmp_path, seconds=60.0)
    model = estimate_noise([read_mrclam(tmp_path, 1)], odometry_lag=True).model
    assert model.odometry.lag_s == 0.0 and "not fitted" in model.fit["odometry_lag_note"]


def test_cli_warns_when_the_truth_says_the_map_is_confidently_wrong_or_duplicated(tmp_path, synthetic):
    """A map whose landmarks sit 0.5 m from the truth's, with covariances of a few cm: the text and the JSON say
    that its covariances do not hold its errors; a map that agrees with the truth gets no warning."""
    synthetic.write(tmp_path / "data", seconds=40.0)
    noise = tmp_path / "noise.toml"
    _small_noise(synthetic).save(noise)
    args = ("slam", "dataset", "mrclam", str(tmp_path / "data"), "--robot", "1", "--out", str(tmp_path / "m.npz"),
            "--particles", "20", "--noise", str(noise), "--barcodes", "table")
    status, out, err = _cli(*args, "--json")
    assert status == 0 and json.loads(out)["warnings"] == [], err
    table = tmp_path / "data" / "Landmark_Groundtruth.dat.gz"
    with gzip.open(table, "rt") as f:
        rows = [line if line.startswith("#") else " ".join(
            str(float(v) + (0.5 if k in (1, 2) else 0.0)) for k, v in enumerate(line.split())) + "\n" for line in f]
    with gzip.open(table, "wt") as f:
        f.writelines(rows)
    status, out, err = _cli(*args)
    assert status == 0, err
    warnings = [line for line in out.splitlines() if line.strip().startswith("WARNING:")]
    assert len(warnings) == 1 and "within their covariance's χ²₂ 95 % bound" in warnings[0]
    assert json.loads(_cli(*args, "--json")[1])["warnings"][0] == warnings[0].split("WARNING: ", 1)[1]


@pytest.mark.parametrize(("args", "complaint"), [
    (["--robot", "3"], "neither Robot3_Odometry.dat nor"),
    (["--robot", "1", "--noise", "missing.toml"], "no such noise-model file"),
    (["--robot", "1"], "fitting this log's own noise model: only 1 odometry windows"),   # 10 s: give --noise
])
def test_cli_bad_input_is_one_line_and_exit_2(tmp_path, synthetic, args, complaint):
    synthetic.write(tmp_path / "data", seconds=10.0)   # the map beside the data set: never inside it (session 23)
    status, out, err = _cli("slam", "dataset", "mrclam", str(tmp_path / "data"), "--out", str(tmp_path / "m.npz"),
                            *args)
    assert status == 2 and complaint in err and err.count("\n") == 1 and not (tmp_path / "m.npz").exists()


@pytest.mark.slow  # the whole log of robot 1 (~3 s CPU)
def test_real_dataset2_noise_command_fits_robot1s_heading_bias_when_asked(mrclam_dir, tmp_path):
    """`p3at slam noise --heading-bias` on robot 1's whole log: the robot curves right (-56 ± 13 mrad/m in
    docs/fastslam-history.md, Session 5), the file carries the bias and its standard error, and the text says it."""
    noise = tmp_path / "noise.toml"
    status, out, err = _cli("slam", "noise", "mrclam", str(mrclam_dir), "--robot", "1", "--heading-bias", "--out",
                            str(noise))
    assert status == 0, err
    model = NoiseModel.load(noise)
    bias, se = model.odometry.heading_bias_per_m, model.fit["heading_bias_per_m_standard_error"]
    assert bias < -2.5 * se and 0 < se < 0.05
    assert f"heading bias: {bias:+.4f} rad/m ± {se:.4f}" in out


@pytest.mark.slow  # the whole log of robot 2 (~10 s CPU)
def test_real_dataset2_noise_command_fits_the_odometry_lag_and_range_calibration_when_asked(mrclam_dir, tmp_path):
    """`p3at slam noise --odometry-lag --range-calibration` on robot 2: the file carries the lag (the robots follow
    their commanded velocities ~0.17 s late, docs/fastslam-history.md Session 9) and the depth-not-range calibration
    (b2 ~ b0 / 2, Session 8); without the flags, neither."""
    noise = tmp_path / "noise.toml"
    status, out, err = _cli("slam", "noise", "mrclam", str(mrclam_dir), "--robot", "2", "--odometry-lag",
                            "--range-calibration", "--out", str(noise))
    assert status == 0, err
    model = NoiseModel.load(noise)
    assert 0.1 <= model.odometry.lag_s <= 0.3 and f"odometry lag: {model.odometry.lag_s:.2f} s" in out
    assert model.range_bearing.range_scale_per_rad2 == pytest.approx(0.5 * model.range_bearing.range_scale, abs=0.1)
    plain = tmp_path / "plain.toml"
    assert _cli("slam", "noise", "mrclam", str(mrclam_dir), "--robot", "2", "--out", str(plain))[0] == 0
    model = NoiseModel.load(plain)
    assert model.odometry.lag_s == 0.0 and model.range_bearing.range_scale_per_rad2 == 0.0


def test_real_dataset2_fastslam_beats_dead_reckoning(mrclam_dir):
    """Robot 3's first 200 s: the map holds the landmarks it saw, SLAM's trajectory is better than odometry's."""
    log = read_mrclam(mrclam_dir, 3, until=200.0)
    noise = estimate_noise([log], window_s=5.0).model
    run = run_landmark_log(log, range_bearing_config(n_particles=30), np.random.default_rng(0), noise=noise,
                           association="id", robot="robot3")
    m = run.metrics
    assert m["ate_m"] < m["dead_reckoning_ate_m"]
    assert 0 < m["landmarks"] <= m["true_landmarks"] + 2
