"""Shared scenes for the FastSLAM tests: a straight corridor of known features and a driven run along it; unit
descriptors at chosen distances from each other (the appearance tests)."""
from __future__ import annotations

import numpy as np
import pytest

from estimation.fastslam import FastSLAM, FastSLAMConfig
from estimation.geometry import compose
from mocks.synthetic_stereo import OdometryErrorModel, SyntheticOdometry, SyntheticStereo


def orthonormal_descriptors(n: int, seed: int = 0) -> np.ndarray:
    """n orthonormal 64-element rows (float32 unit descriptors 2^0.5 apart)."""
    q, _ = np.linalg.qr(np.random.default_rng(seed).standard_normal((64, n)))
    return q.T.astype(np.float32)


def turned(a: np.ndarray, b: np.ndarray, angle: float) -> np.ndarray:
    """The unit vector at ``angle`` from a towards b (orthonormal a, b): 2 sin(angle / 2) from a."""
    return (np.cos(angle) * a + np.sin(angle) * b).astype(np.float32)


def corridor_features(rng: np.random.Generator, n: int = 240, length: float = 24.0):
    """Feature points (n, 3) on the two walls (y = ±1.5 m) of a straight corridor, and unit descriptors."""
    x = rng.uniform(-2.0, length, n)
    y = np.where(np.arange(n) % 2 == 0, 1.5, -1.5)
    z = rng.uniform(0.3, 2.4, n)
    desc = rng.standard_normal((n, 64))
    return np.column_stack([x, y, z]), (desc / np.linalg.norm(desc, axis=1, keepdims=True)).astype(np.float32)


def drive_straight(slam: FastSLAM, seed: int, frames: int = 80, step: float = 0.1):
    """Drive the corridor's centre line; returns (true poses (T, 3), dead-reckoned poses (T, 3), feature map)."""
    rng = np.random.default_rng(seed)
    features, desc = corridor_features(rng)
    sensor = SyntheticStereo(features, desc, rng)
    odometry = SyntheticOdometry(rng, OdometryErrorModel(distance_scale_sigma=0.0, turn_scale_sigma=0.0))
    odometry.distance_scale, odometry.turn_scale = 1.04, 1.0  # a known, sizeable odometry scale error
    pose, dead = np.zeros(3), np.zeros(3)
    truth, dr, feature_of = [], [], {}
    for i in range(frames):
        new = compose(pose, [step, 0.0, 0.01 * np.sin(i / 10.0)])
        increment = odometry.increment(pose, new)
        pose, dead = new, compose(dead, increment.delta)
        slam.predict(increment)
        obs, index = sensor.observe(pose, timestamp=0.2 * (i + 1))
        report = slam.update(obs)
        for j in np.flatnonzero(report.new_landmark_ids >= 0):
            feature_of[int(report.new_landmark_ids[j])] = int(index[j])
        truth.append(pose)
        dr.append(dead)
    return np.array(truth), np.array(dr), features, feature_of


@pytest.fixture(scope="module")
def straight_run_v2():
    slam = FastSLAM(FastSLAMConfig(n_particles=10, version=2), np.random.default_rng(5))
    truth, dead, features, feature_of = drive_straight(slam, seed=11, frames=30)
    return slam, truth, dead, features, feature_of


@pytest.fixture
def drive():
    """The :func:`drive_straight` helper, for tests that run their own filter."""
    return drive_straight


@pytest.fixture
def corridor():
    return corridor_features
