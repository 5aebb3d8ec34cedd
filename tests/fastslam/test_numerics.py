"""Numerical health of FastSLAM 2.0: the proposal and the landmark updates on ill-conditioned inputs (issue 12)."""
from __future__ import annotations

import numpy as np
import pytest

from estimation.fastslam import FastSLAM, FastSLAMConfig
from estimation.landmark_map import LandmarkMap
from estimation.observations import OdometryIncrement, StereoObservations


def _rotation(yaw: float, pitch: float) -> np.ndarray:
    cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    return np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]]) @ np.array(
        [[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])


def _one_landmark_filter(position, covariance, n_particles=20, seed=1) -> FastSLAM:
    prior = LandmarkMap(np.asarray(position, float)[None], np.asarray(covariance, float)[None],
                        np.zeros((1, 0), np.float32), counts=np.array([5]))
    # observation_correlation 0: these tests read the EKF's own covariance, not the export's AR(1) widening of it
    config = FastSLAMConfig(n_particles=n_particles, descriptor_size=0, observation_correlation=0.0)
    slam = FastSLAM(config, np.random.default_rng(seed))
    slam.load_prior_map(prior)
    return slam


def _observe(points, sigma=0.01) -> StereoObservations:
    points = np.asarray(points, float).reshape(-1, 3)
    return StereoObservations(points, np.tile(np.eye(3) * sigma**2, (len(points), 1, 1)),
                              np.zeros((len(points), 0), np.float32))


@pytest.mark.parametrize("yaw", np.linspace(1.9, 2.3, 9))
def test_near_singular_landmark_covariance_never_breaks_the_proposal(yaw):
    # The failing case of issue 12: a landmark covariance blown up along one axis (eigenvalues 2.9e6, 1e-6,
    # 1e-6 m²; condition 3e12, what the old rotated-gain update produced after a few frames). Its S⁻¹ comes
    # out numerically indefinite, and the proposal's Cholesky raised "Matrix is not positive definite".
    axes = _rotation(yaw, 0.99)
    covariance = axes @ np.diag([2.95e6, 1e-6, 1e-6]) @ axes.T
    slam = _one_landmark_filter([4.0, 1.0, 1.0], covariance)
    slam.predict(OdometryIncrement(0.0, 0.0, 0.666))
    slam.update(_observe([4.0, 1.0, 1.0]))
    assert np.all(np.isfinite(slam.poses))
    # a particle that fell back drew from its motion model: still near the predicted pose (heading σ ≈ 0.04 rad)
    assert np.all(np.abs(slam.poses[:, 2] - 0.666) < 0.3)
    assert slam.stats.proposal_fallbacks in range(0, 21)


def test_some_near_singular_case_takes_the_motion_model_fallback_and_counts_it():
    fallbacks = 0
    for yaw in np.linspace(1.9, 2.3, 9):
        axes = _rotation(yaw, 0.99)
        slam = _one_landmark_filter([4.0, 1.0, 1.0], axes @ np.diag([2.95e6, 1e-6, 1e-6]) @ axes.T)
        slam.predict(OdometryIncrement(0.0, 0.0, 0.666))
        report = slam.update(_observe([4.0, 1.0, 1.0]))
        fallbacks += slam.stats.proposal_fallbacks
        assert report.proposal_fallbacks == slam.stats.proposal_fallbacks
    assert fallbacks > 0


def test_elongated_landmark_only_shrinks_when_the_proposal_turns_the_robot():
    # The root cause: a landmark first seen from afar is elongated along the ray (depth σ 0.7 m, lateral 2 cm).
    # After a turn the proposal samples headings ~0.07 rad apart; the landmark update must still be an EKF
    # update at the sampled pose (gain ≤ 1): its covariance may only shrink and its mean move by less than
    # the innovation allows. (Rotating the gate's S⁻¹ by the proposal's turn gave gains of 10-20 here.)
    ray = np.array([np.cos(2.0), np.sin(2.0), 0.0])         # the robot will face the landmark after its turn
    across = np.array([-ray[1], ray[0], 0.0])
    axes = np.column_stack([ray, across, [0.0, 0.0, 1.0]])
    covariance = axes @ np.diag([0.5, 0.02**2, 0.02**2]) @ axes.T
    position = 6.0 * ray + [0.0, 0.0, 1.0]
    slam = _one_landmark_filter(position, covariance, n_particles=30)
    slam.predict(OdometryIncrement(0.0, 0.0, 2.0))        # heading variance 5e-3 rad² (σ 0.07 rad)
    before = slam.poses.copy()
    report = slam.update(_observe([6.0, 0.05, 1.0], sigma=0.02))
    assert report.matched == 1.0
    assert np.ptp(slam.poses[:, 2] - before[:, 2]) > 0.005   # the proposal did spread the headings
    for m in range(len(slam.poses)):
        landmark = slam.particle_map(m)
        shrink = covariance - landmark.covariances[0]
        assert np.linalg.eigvalsh(shrink).min() > -1e-9
        assert np.linalg.norm(landmark.positions[0] - position) < 0.2


def test_exported_covariances_grow_with_the_map_frames_drift_and_shrink_back_on_old_landmarks():
    # the drift tracker through the public filter: a landmark made after a long blind stretch carries more
    # drift than one made at the start; re-observing the first landmark pins the robot back to its level
    from estimation.fastslam import range_bearing_config, range_bearing_observations
    slam = FastSLAM(range_bearing_config(n_particles=10, association="id"), np.random.default_rng(0))
    slam.update(range_bearing_observations([3.0], [0.0], 0.05, 0.01, ids=[1]))
    for _ in range(20):                                    # 10 m blind: dead reckoning
        slam.predict(OdometryIncrement(0.5, 0.0, 0.0))
    drift_after_blind = np.trace(slam.drift.robot)
    slam.update(range_bearing_observations([2.0], [0.5], 0.05, 0.01, ids=[2]))
    landmark_map = slam.best_map(min_count=1)
    by_external = dict(zip(slam.external_ids(landmark_map.ids).tolist(), landmark_map.covariances, strict=True))
    assert np.trace(by_external[2]) > 10 * np.trace(by_external[1])
    particle_only = slam.best_map(min_count=1, covariance="particle").covariances
    assert np.all(np.linalg.eigvalsh(landmark_map.covariances - particle_only) > -1e-12)   # only ever adds
    for _ in range(20):                                    # back to the start, where landmark 1 is
        slam.predict(OdometryIncrement(-0.5, 0.0, 0.0))
    drift_back = np.trace(slam.drift.robot)
    assert drift_back > drift_after_blind
    slam.update(range_bearing_observations([3.0], [0.0], 0.05, 0.01, ids=[1]))
    # pinned to landmark 1 (no drift of its own) up to what one range-bearing reading leaves open
    assert np.trace(slam.drift.robot) < 0.3 * drift_back
    assert np.allclose(slam.drift.robot, slam.pose_mean_and_covariance()[1], atol=0.05)


def test_mixture_covariance_is_the_weighted_second_moment_over_the_particles():
    from estimation.fastslam import range_bearing_config, range_bearing_observations
    slam = FastSLAM(range_bearing_config(n_particles=8, version=1), np.random.default_rng(3))
    slam.update(range_bearing_observations([3.0, 4.0], [0.2, -0.4], 0.05, 0.01))
    for _ in range(3):
        slam.predict(OdometryIncrement(0.3, 0.0, 0.05))      # FastSLAM 1.0: every particle a different pose ...
        slam.update(range_bearing_observations([2.8, 3.8], [0.15, -0.45], 0.05, 0.01))
    best = slam.best_index
    exported = slam.best_map(min_count=1, covariance="mixture")
    w = slam.weights
    for row, lid in enumerate(exported.ids):                   # ... so each holds its own copy of the landmark
        means, covs, weights = [], [], []
        for m in range(len(slam.poses)):
            own = slam.particle_map(m, min_count=1)
            if lid in own.ids:
                k = int(np.flatnonzero(own.ids == lid)[0])
                means.append(own.positions[k])
                covs.append(own.covariances[k])
                weights.append(w[m])
        weights = np.array(weights) / np.sum(weights)
        dev = np.array(means) - slam.particle_map(best, min_count=1).positions[row]
        expected = np.einsum("m,mij->ij", weights, np.array(covs) + dev[:, :, None] * dev[:, None, :])
        np.testing.assert_allclose(exported.covariances[row], expected, rtol=1e-9, atol=1e-15)
