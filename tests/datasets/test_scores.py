"""The score functions of landmark SLAM runs: rigid fit, NEES, duplicates and errors in the start frame."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from estimation.geometry import compose
from estimation.landmark_scores import ate, attribute_landmarks, map_scores, points_nees, rigid_fit_2d

finite = st.floats(-20, 20, allow_nan=False)


@given(x=finite, y=finite, theta=st.floats(-3.1, 3.1), seed=st.integers(0, 1000))
def test_rigid_fit_recovers_a_transform(x, y, theta, seed):
    points = np.random.default_rng(seed).uniform(-5, 5, (6, 2))
    moved = compose(np.array([x, y, theta]), np.column_stack([points, np.zeros(6)]))[:, :2]
    fit = rigid_fit_2d(points, moved)
    np.testing.assert_allclose(compose(fit, np.column_stack([points, np.zeros(6)]))[:, :2], moved, atol=1e-7)


def test_points_nees_is_the_mahalanobis_square():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(20, 2, 2))
    cov = a @ a.transpose(0, 2, 1) + 0.1 * np.eye(2)
    e = rng.normal(size=(20, 2))
    expected = np.einsum("ni,ni->n", e, np.linalg.solve(cov, e[:, :, None])[:, :, 0])
    np.testing.assert_allclose(points_nees(e, cov), expected)
    assert points_nees(np.ones((1, 2)), np.zeros((1, 2, 2)))[0] == np.inf


def test_map_scores_count_duplicates_and_measure_in_the_start_frame():
    start = np.array([1.0, 2.0, np.pi / 2])
    truth_ids, truth = np.array([6, 7, 8]), np.array([[1.0, 4.0], [0.0, 2.0], [3.0, 2.0]])
    # a perfect map in the start frame: the robot faces +y, so world (1, 4) is 2 m straight ahead
    positions = np.array([[2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -2.0, 0.0], [0.1, -2.0, 0.0]])
    covs = np.tile(np.diag([0.01, 0.01, 1e-6]), (4, 1, 1))
    attributed = attribute_landmarks({0: {6: 5}, 1: {7: 3, 8: 1}, 2: {8: 4}, 3: {8: 2}}, np.arange(4))
    np.testing.assert_array_equal(attributed, [6, 7, 8, 8])
    s = map_scores(positions, covs, attributed, start, truth_ids, truth, np.array([6, 7, 8, 8]))
    assert s["landmarks"] == 4 and s["true_landmarks"] == 3 and s["duplicate_landmarks"] == 1
    assert s["duplicate_fraction"] == 0.25
    # three exact, one 0.1 m off with σ 0.1 m: NEES 1, inside χ²₂ 95 % = 5.99
    assert s["landmark_error_median_m"] < 1e-12 and s["landmark_nees_within_bound"] == 1.0
    assert abs(s["landmark_error_rms_m"] - 0.05) < 1e-12
    assert s["landmark_error_rigid_median_m"] < 0.05


def test_ate_is_the_rms_position_error():
    truth = np.zeros((4, 3))
    estimate = np.array([[3.0, 4.0, 0.0], [0, 0, 0], [0, 0, 0], [0, 0, 1.0]])
    assert ate(estimate, truth) == 2.5


def test_ate_agrees_with_evo():
    """The hand-written ATE (the product must not need evo, a dev dependency) equals evo's APE rmse."""
    evo_metrics = pytest.importorskip("evo.core.metrics")
    from evo.core.trajectory import PoseTrajectory3D

    rng = np.random.default_rng(2)
    t = np.arange(50.0)
    truth = np.column_stack([np.cumsum(rng.normal(0, 0.1, (50, 2)), axis=0), rng.uniform(-3, 3, 50)])
    estimate = truth + rng.normal(0, 0.05, (50, 3))

    def evo_trajectory(poses):
        xyz = np.column_stack([poses[:, :2], np.zeros(len(poses))])
        quat = np.column_stack([np.cos(poses[:, 2] / 2), np.zeros((len(poses), 2)), np.sin(poses[:, 2] / 2)])
        return PoseTrajectory3D(positions_xyz=xyz, orientations_quat_wxyz=quat, timestamps=t)

    ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    ape.process_data((evo_trajectory(truth), evo_trajectory(estimate)))
    assert ate(estimate, truth) == pytest.approx(ape.get_statistic(evo_metrics.StatisticsType.rmse), rel=1e-12)
