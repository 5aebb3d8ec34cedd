"""The simulated stereo sensor and odometry (mocks/synthetic_stereo.py) against their ground truth."""
from __future__ import annotations

import numpy as np

from estimation.geometry import between, compose, rot_z
from mocks.synthetic_stereo import OdometryErrorModel, SyntheticOdometry, SyntheticStereo
from mocks.world import World


def test_points_are_the_true_features_within_their_covariance(corridor):
    rng = np.random.default_rng(1)
    features, desc = corridor(rng)
    sensor = SyntheticStereo(features, desc, rng)
    nees, n = [], 0
    for i in range(40):
        pose = np.array([0.2 * i, 0.1 * np.sin(i), 0.05 * np.cos(i)])
        obs, index = sensor.observe(pose, timestamp=i)
        n += len(obs)
        truth = (features[index] - [pose[0], pose[1], 0.0]) @ rot_z(pose[2])
        err = obs.points - truth
        nees.extend(np.einsum("ni,nij,nj->n", err, np.linalg.inv(obs.covariances), err))
        assert obs.frame == "base_link" and obs.timestamp == i
        assert np.all(obs.points[:, 0] > 0.12) and np.all(np.linalg.norm(obs.points[:, :2], axis=1) < 13.0)
        assert np.all((obs.pixels >= -2) & (obs.pixels <= [642, 482]))
        assert np.allclose(np.linalg.norm(obs.descriptors, axis=1), 1.0, atol=1e-5)
        assert np.all(np.linalg.norm(obs.descriptors - desc[index], axis=1) < 0.3)
    assert n > 1000
    # first-order covariances of a non-linear triangulation: the mean NEES is near 3 (χ², 3 dof)
    assert 2.5 < np.mean(nees) < 3.6


def test_walls_hide_features_and_only_visible_ones_are_reported():
    world = World.load()
    sensor = SyntheticStereo.from_world(world, np.random.default_rng(0))
    pose = np.asarray(world.start_poses["robot1"], float)
    _, index = sensor.observe(pose)
    assert len(index) > 10
    camera = compose(pose, [0.12, 0.0, 0.0])
    visible = world.visible_features(camera, 0.5, np.pi, 20.0)
    assert np.all(visible[index])
    # looking straight at a wall from 0.7 m, nothing behind it is seen
    sensor_close = SyntheticStereo.from_world(world, np.random.default_rng(0))
    _, index = sensor_close.observe(np.array([pose[0], pose[1], np.pi / 2]))
    in_front = between(pose, np.column_stack([world.features[index, :2], np.zeros(len(index))]))
    assert np.all(in_front[:, 1] > 0)


def test_odometry_error_model():
    rng = np.random.default_rng(3)
    exact = SyntheticOdometry(rng, OdometryErrorModel(0.0, 0.0, 0.0, 0.0, 0.0))
    a, b = np.array([1.0, 2.0, 0.3]), np.array([1.5, 2.2, 0.5])
    inc = exact.increment(a, b, 1.0, 1.2)
    assert np.allclose(compose(a, inc.delta), b) and (inc.t0, inc.t1) == (1.0, 1.2)
    scaled = SyntheticOdometry(rng, OdometryErrorModel(0.0, 0.0, 0.0, 0.0, 0.0))
    scaled.distance_scale = 1.1
    assert np.isclose(scaled.increment(np.zeros(3), np.array([2.0, 0.0, 0.0])).dx, 2.2)
    noisy = SyntheticOdometry(np.random.default_rng(4))
    deltas = np.array([noisy.increment(np.zeros(3), np.array([1.0, 0.0, 0.0])).delta for _ in range(400)])
    assert 0.003 < deltas[:, 1].std() < 0.02 and abs(deltas[:, 0].mean() - noisy.distance_scale) < 0.003
