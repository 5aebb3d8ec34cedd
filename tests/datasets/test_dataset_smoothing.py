"""`run_landmark_log(..., smooth=True)` and `p3at slam dataset --smooth`: the whole log's MAP trajectory and map."""
from __future__ import annotations

import json

import numpy as np
import pytest

from estimation.dataset_slam import run_landmark_log
from estimation.dataset_smoothing import planar_landmarks
from estimation.datasets import read_mrclam
from estimation.fastslam import range_bearing_config
from estimation.landmark_map import LandmarkMap
from estimation.landmark_smoother import Smoothed
from estimation.noise_estimation import estimate_noise
from estimation.noise_model import NoiseModel, OdometryNoise, RangeBearingNoise
from runtime.rerun_read import read_recording
from tests.datasets.conftest import run_cli as _cli


def _small_noise(synthetic) -> NoiseModel:
    sensor = RangeBearingNoise(0.02, 0.0, 0.01, fov_rad=synthetic.SENSOR_FOV, max_range_m=synthetic.SENSOR_RANGE)
    return NoiseModel(OdometryNoise(0.01 ** 2, 0.01 ** 2, 0.01 ** 2), sensor)


def test_exact_data_smooths_to_the_truth_and_the_filter_figures_stay(tmp_path, synthetic):
    synthetic.write(tmp_path, seconds=60.0)
    log = read_mrclam(tmp_path, 1)
    run = run_landmark_log(log, range_bearing_config(n_particles=20), np.random.default_rng(1),
                           noise=_small_noise(synthetic), association="id", robot="robot1", smooth=True)
    m = run.metrics
    assert m["smoothed"] and m["smoother_converged"] and m["smoother_outliers"] == 0
    # exact odometry and sightings: the MAP estimate is the truth, whatever the filter wandered to
    assert m["ate_m"] < 1e-3 and m["landmark_error_median_m"] < 1e-3 and m["ate_m"] <= m["filter_ate_m"]
    assert m["smoother_chi2_per_dof"] < 1e-3
    seen = sorted(set(log.landmark_ids.tolist()))
    assert run.map.metadata["external_ids"] == seen and m["landmarks"] == len(seen)
    assert run.map.trajectory.shape == (m["frames"] + 1, 4)
    with pytest.raises(ValueError, match="nothing to smooth: no sightings before -1 s"):
        run_landmark_log(log, range_bearing_config(n_particles=5), np.random.default_rng(1),
                         noise=_small_noise(synthetic), association="id", until=-1.0, smooth=True)


def test_planar_landmarks_keep_the_landmarks_the_smoother_placed_on_the_floor():
    covariances = np.stack([np.diag([0.01, 0.04]), np.full((2, 2), np.inf), np.diag([0.09, 0.01])])
    solution = Smoothed(np.zeros((1, 3)), np.array([[1.0, 2.0], [np.nan, np.nan], [-3.0, 0.5]]), covariances,
                        np.zeros(0, np.int64), np.zeros((0, 3, 3)), np.ones(0, bool), 0.0, 0, 1, True)
    seen, positions, planar = planar_landmarks(solution)
    assert seen.tolist() == [True, False, True]     # a landmark no sighting pinned (infinite variance) is no landmark
    np.testing.assert_array_equal(positions, [[1.0, 2.0, 0.0], [-3.0, 0.5, 0.0]])
    np.testing.assert_array_equal(planar[:, :2, :2], covariances[[0, 2]])
    assert np.all(planar[:, 2, 2] > 0) and np.all(planar[:, 2, 2] < 1e-4) and np.all(planar[:, :2, 2] == 0)
    assert np.all(np.linalg.eigvalsh(planar) > 0)   # a covariance a map can invert


def test_cli_smooth_writes_the_smoothed_map_and_refuses_unknown_association(tmp_path, synthetic):
    synthetic.write(tmp_path / "data", seconds=30.0)
    noise = tmp_path / "noise.toml"
    _small_noise(synthetic).save(noise)
    out_map = tmp_path / "robot1.npz"
    status, out, err = _cli("slam", "dataset", "mrclam", str(tmp_path / "data"), "--robot", "1", "--out",
                            str(out_map), "--particles", "10", "--noise", str(noise), "--smooth")
    assert status == 0, err
    assert "smoothed over the whole log" in out and "trajectory ATE        smoothed" in out
    assert LandmarkMap.load(out_map).metadata["smoothed"] is True
    recording = tmp_path / "run.rrd"
    status, out, err = _cli("slam", "dataset", "mrclam", str(tmp_path / "data"), "--robot", "1", "--out",
                            str(out_map), "--particles", "10", "--noise", str(noise), "--smooth", "--rerun",
                            str(recording), "--json")
    assert status == 0, err
    contents = read_recording(recording)           # the recording holds the smoothed map and the smoother's fit
    np.testing.assert_array_equal(contents.maps["robot1"].positions, LandmarkMap.load(out_map).positions)
    assert contents.summary["smoothed"] is True
    assert contents.summary["smoother_chi2_per_dof"] == pytest.approx(json.loads(out)["smoother_chi2_per_dof"])
    status, out, err = _cli("slam", "dataset", "mrclam", str(tmp_path / "data"), "--robot", "1", "--out",
                            str(tmp_path / "u.npz"), "--association", "unknown", "--smooth", "--noise", str(noise))
    assert status == 2 and "association='id'" in err and err.count("\n") == 1
    assert not (tmp_path / "u.npz").exists()


def test_cli_by_default_fits_the_logs_calibrations_and_smooths_known_id_runs(tmp_path, synthetic):
    """Without --noise, `p3at slam dataset` fits the log's own noise model with its calibrations, and smooths
    a known-ID run; unknown association and --no-smooth give the filter alone. On an exact log every calibration
    is the identity, so the smoothed path is the truth."""
    synthetic.write(tmp_path / "data", seconds=60.0)
    out_map = tmp_path / "robot1.npz"

    def run(*args) -> dict:
        status, out, err = _cli("slam", "dataset", "mrclam", str(tmp_path / "data"), "--robot", "1", "--out",
                                str(out_map), "--particles", "10", "--json", *args)
        assert status == 0, err
        return json.loads(out)

    scores = run()
    assert scores["smoothed"] and ("range calibration, heading bias, odometry lag, turns' variance and the stall after "
                                   "the command's dips") in scores["noise"]
    metadata = LandmarkMap.load(out_map).metadata
    noise = metadata["noise_model"]
    assert metadata["smoothed"] is True and noise["lag_s"] == 0.0 and noise["turn_xy_inflation"] == 1.0
    assert noise["stall_sigma_s"] == 0.0                              # a steady command: no dip, no stall term
    assert noise["range_scale"] == pytest.approx(1.0) and noise["range_offset_m"] == pytest.approx(0.0, abs=1e-6)
    assert scores["ate_m"] < 0.01 and scores["landmarks"] == scores["true_landmarks"]
    for args in (["--association", "unknown"], ["--no-smooth"]):
        scores = run(*args)
        assert not scores.get("smoothed") and "filter_ate_m" not in scores
        assert LandmarkMap.load(out_map).metadata.get("smoothed") is not True


@pytest.mark.slow  # robot 4's whole log, as a user runs it (~15 s CPU)
def test_real_dataset2_the_default_run_meets_the_known_id_targets(mrclam_dir, tmp_path):
    """`p3at slam dataset mrclam DIR --robot 4` with no option: the log's calibrated noise model and the smoother
    give issue 13's known-ID targets (ATE ≤ 0.25 m, rigid landmark error ≤ 0.15 m, ≥ 90 % of the landmarks within
    χ²₂ 95 % in the start frame); the filter alone, with that model, does not hold its frame as well."""
    status, out, err = _cli("slam", "dataset", "mrclam", str(mrclam_dir), "--robot", "4", "--out",
                            str(tmp_path / "robot4.npz"), "--json")
    assert status == 0, err
    m = json.loads(out)
    assert m["smoothed"] and m["smoother_converged"] and m["landmarks"] == m["true_landmarks"] == 15
    assert m["ate_m"] <= 0.25 and m["landmark_error_rigid_median_m"] <= 0.15
    assert m["landmark_nees_within_bound"] >= 0.9 and m["pose_nees_median"] < 7.815
    assert m["ate_m"] < m["filter_ate_m"]


@pytest.mark.slow  # two filter runs over robot 3's first 300 s (~10 s CPU)
def test_real_dataset2_smoothing_forgets_the_filters_lottery(mrclam_dir):
    """The smoothed map is the MAP of the log, not of the particle the filter kept: two filter seeds give one
    map (to a millimetre), better than the filter's and than dead reckoning (robot 3: 0.08 vs 0.15 m ATE)."""
    log = read_mrclam(mrclam_dir, 3, until=300.0)
    noise = estimate_noise([log]).model
    runs = [run_landmark_log(log, range_bearing_config(n_particles=30), np.random.default_rng(seed), noise=noise,
                             association="id", robot="robot3", smooth=True) for seed in (0, 1)]
    np.testing.assert_allclose(runs[0].map.positions, runs[1].map.positions, atol=1e-3)
    assert runs[0].map.metadata["external_ids"] == runs[1].map.metadata["external_ids"]
    for run in runs:
        m = run.metrics
        assert m["smoother_converged"] and m["ate_m"] < m["filter_ate_m"] and m["ate_m"] < m["dead_reckoning_ate_m"]
        assert m["landmark_error_rigid_median_m"] < m["filter_landmark_error_rigid_median_m"]
    assert json.dumps(runs[0].metrics)          # the scores are JSON (`--json`)


@pytest.mark.slow  # robot 1's whole log: a filter of 30 particles and the smoother (~15 s CPU)
def test_real_dataset2_robot1_smoothed_with_the_turns_inflation_is_honest_in_its_start_frame(mrclam_dir):
    """Robot 1 is MRCLAM's hardest frame (a stall and forward creep in its first turn). With the three
    calibrations and the turns' x/y inflation the smoothed map's start-frame covariance holds its errors (≥ 90 % of
    the landmarks within χ²₂ 95 %; 13 % without the inflation), and the known-ID targets of issue 13 hold, even
    from a filter that lost its frame (docs/fastslam-history.md, session 16)."""
    log = read_mrclam(mrclam_dir, 1)
    fit = dict(range_calibration=True, heading_bias=True, odometry_lag=True)
    with_turns = estimate_noise([log], turn_variance=True, **fit).model
    assert with_turns.odometry.turn_xy_inflation > 3.0
    m = run_landmark_log(log, range_bearing_config(n_particles=30), np.random.default_rng(0), noise=with_turns,
                         association="id", robot="robot1", smooth=True).metrics
    assert m["smoother_converged"] and m["landmarks"] == m["true_landmarks"] == 15
    assert m["landmark_nees_within_bound"] >= 0.9 and m["landmark_nees_rigid_within_bound"] >= 0.9
    assert m["ate_m"] <= 0.5 and m["landmark_error_rigid_median_m"] <= 0.05
    assert m["ate_m"] < m["filter_ate_m"]
