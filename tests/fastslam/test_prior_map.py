"""Starting from a known map: stored once for all particles, localises, re-uses the map's landmarks."""
from __future__ import annotations

import numpy as np
import pytest

from estimation.fastslam import FastSLAM, FastSLAMConfig
from estimation.geometry import compose
from estimation.landmark_map import LandmarkMap
from mocks.synthetic_stereo import OdometryErrorModel, SyntheticOdometry, SyntheticStereo


def test_prior_map_is_shared_and_localises(corridor):
    rng = np.random.default_rng(21)
    features, desc = corridor(rng)
    prior = LandmarkMap(features, np.tile(np.eye(3) * 0.02**2, (len(features), 1, 1)), desc,
                        counts=np.full(len(features), 5))
    start = np.array([1.0, 0.2, 0.0])
    slam = FastSLAM(FastSLAMConfig(n_particles=20, version=2), np.random.default_rng(1), initial_pose=start)
    slam.load_prior_map(prior)
    store = slam.store
    used = np.flatnonzero(store.refcount)
    assert np.all(store.refcount[used] == 20)                          # one copy, every particle holds it
    assert len(used) == int(np.ceil(len(features) / store.block_size))
    sensor = SyntheticStereo(features, desc, rng)
    odometry = SyntheticOdometry(rng, OdometryErrorModel(0.05, 0.05))
    pose, dead = start.copy(), start.copy()
    for _ in range(40):
        new = compose(pose, [0.12, 0.0, 0.0])
        increment = odometry.increment(pose, new)
        pose, dead = new, compose(dead, increment.delta)
        slam.predict(increment)
        report = slam.update(sensor.observe(pose)[0])
        assert report.new_landmarks <= 2                                # known corners are re-used
    assert np.hypot(*(slam.best_pose()[:2] - pose[:2])) < 0.05
    assert np.hypot(*(slam.best_pose()[:2] - pose[:2])) < 0.5 * np.hypot(*(dead[:2] - pose[:2]))
    # storage bookkeeping: reference counts are exactly the table's references, no block leaked
    held = store.table[store.table >= 0]
    assert np.array_equal(store.refcount, np.bincount(held, minlength=store.capacity))


def test_prior_map_only_before_the_first_landmark(corridor):
    rng = np.random.default_rng(0)
    features, desc = corridor(rng, n=10)
    prior = LandmarkMap(features, np.tile(np.eye(3) * 0.01, (10, 1, 1)), desc)
    slam = FastSLAM(FastSLAMConfig(n_particles=3), np.random.default_rng(0))
    slam.load_prior_map(prior)
    with pytest.raises(ValueError, match="before"):
        slam.load_prior_map(prior)
    other = FastSLAM(FastSLAMConfig(n_particles=3, descriptor_size=32), np.random.default_rng(0))
    with pytest.raises(ValueError, match="descriptor_size=32"):
        other.load_prior_map(prior)
