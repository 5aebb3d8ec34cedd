"""run_landmark_log writes each landmark's sightings' spread into the map (estimation.sighting_spread)."""
from __future__ import annotations

import numpy as np

from estimation.dataset_slam import run_landmark_log
from estimation.datasets import read_mrclam
from estimation.fastslam import range_bearing_config
from estimation.landmark_map import LandmarkMap
from estimation.noise_model import NoiseModel, OdometryNoise, RangeBearingNoise


def test_exact_data_gives_every_landmark_a_small_spread_and_the_file_keeps_it(tmp_path, synthetic):
    synthetic.write(tmp_path, seconds=30.0)
    log = read_mrclam(tmp_path, 1)
    sensor = RangeBearingNoise(0.02, 0.0, 0.01, fov_rad=synthetic.SENSOR_FOV, max_range_m=synthetic.SENSOR_RANGE)
    noise = NoiseModel(OdometryNoise(0.01 ** 2, 0.01 ** 2, 0.01 ** 2), sensor)
    run = run_landmark_log(log, range_bearing_config(n_particles=50), np.random.default_rng(1), noise=noise,
                           association="id", robot="robot1")
    S = run.map.sighting_covariances
    assert S is not None and S.shape == (len(run.map), 3, 3)
    per_axis = np.sqrt(np.trace(S[:, :2, :2], axis1=1, axis2=2) / 2)
    # exact sightings placed by a path that wanders a few centimetres (the filter is told σ_r 2 cm, σ_φ 0.01 rad)
    assert np.all(per_axis < 0.05) and np.all(per_axis[run.map.counts >= 2] > 0)
    run.map.save(tmp_path / "robot1.npz")
    np.testing.assert_array_equal(LandmarkMap.load(tmp_path / "robot1.npz").sighting_covariances, S)
