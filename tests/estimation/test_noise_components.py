"""Variance components of a least-squares problem (estimation.noise_components): each group's share of the unknowns
(tr(H⁻¹ H_g), from two log-determinants) against a dense inverse, the truncated χ² means, and when an estimate is
refused."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.landmark_smoother import LandmarkLogProblem, _jacobian
from estimation.noise_components import NoiseComponents, information_shares, truncated_means, variance_factors


def _problem(rng, steps: int, n_landmarks: int) -> tuple[LandmarkLogProblem, np.ndarray, np.ndarray]:
    s = 3 * steps
    problem = LandmarkLogProblem(rng.normal(0, 0.4, (steps, 3)), rng.uniform(0.01, 0.1, (steps, 3)),
                                 rng.integers(1, steps + 1, s), np.arange(s) % n_landmarks, rng.uniform(0.5, 4, s),
                                 rng.uniform(-0.6, 0.6, s), rng.uniform(0.02, 0.2, s), rng.uniform(0.01, 0.1, s))
    poses = rng.normal(0, 0.5, (steps + 1, 3))
    poses[0] = 0
    landmarks = rng.uniform(-3, 3, (n_landmarks, 2)) + np.array([5.0, 0.0])
    return problem, poses, landmarks


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), steps=st.integers(2, 12), n_landmarks=st.integers(1, 4))
def test_each_group_s_share_of_the_unknowns_is_the_trace_of_h_inverse_h_g(seed, steps, n_landmarks):
    """tr(H⁻¹ H_g) for the odometry's, the ranges' and the bearings' rows, against a dense inverse; the shares add
    up to the number of unknowns (3 per pose after the first, 2 per landmark)."""
    rng = np.random.default_rng(seed)
    problem, poses, landmarks = _problem(rng, steps, n_landmarks)
    jac = _jacobian(problem, poses, landmarks, n_landmarks, np.ones(len(problem.ranges)))
    t, s = steps, len(problem.ranges)
    groups = [np.arange(3 * t), 3 * t + 2 * np.arange(s), 3 * t + 2 * np.arange(s) + 1]
    shares = information_shares(jac, groups, t, np.ones(jac.shape[1], bool))
    dense = jac.toarray()
    normal = dense.T @ dense
    expected = [np.trace(np.linalg.solve(normal, dense[g].T @ dense[g])) for g in groups]
    np.testing.assert_allclose(shares, expected, rtol=1e-5, atol=1e-6)
    assert shares.sum() == pytest.approx(3 * t + 2 * n_landmarks, rel=1e-5)


def test_a_step_gives_each_group_s_chi2_and_its_redundancy():
    rng = np.random.default_rng(1)
    problem, poses, landmarks = _problem(rng, 10, 3)
    jac = _jacobian(problem, poses, landmarks, 3, np.ones(len(problem.ranges)))
    t, s = 10, len(problem.ranges)
    groups = [np.arange(3 * t), 3 * t + 2 * np.arange(s), 3 * t + 2 * np.arange(s) + 1]
    residuals = rng.normal(0, 1, jac.shape[0])
    chi2, r = variance_factors(jac, residuals, groups, t, np.ones(jac.shape[1], bool))
    shares = information_shares(jac, groups, t, np.ones(jac.shape[1], bool))
    np.testing.assert_allclose(r, [3 * t - shares[0], s - shares[1], s - shares[2]])
    np.testing.assert_allclose(chi2, [np.sum(residuals[g] ** 2) for g in groups])


@pytest.mark.parametrize("cut", [2.0, 5.99, 9.21, 20.0])
def test_the_truncated_mean_of_two_equal_residuals_is_the_closed_form(cut):
    closed = (2.0 - cut * math.exp(-cut / 2) / (1.0 - math.exp(-cut / 2))) / 2.0
    np.testing.assert_allclose(truncated_means(cut, [1.0, 1.0]), [closed, closed], rtol=1e-6)
    np.testing.assert_allclose(truncated_means(cut, [4.0, 4.0]), truncated_means(cut / 4.0, [1.0, 1.0]), rtol=1e-6)
    assert truncated_means(math.inf, [1.0, 0.3]).tolist() == [1.0, 1.0]


def test_the_truncated_means_of_two_unequal_residuals_match_a_sample():
    rng = np.random.default_rng(0)
    variances = np.array([1.0, 0.3])
    e = rng.normal(0, 1, (400_000, 2)) * np.sqrt(variances)
    kept = np.sum(e ** 2, axis=1) <= 5.0
    sample = np.mean(e[kept] ** 2, axis=0) / variances
    np.testing.assert_allclose(truncated_means(5.0, variances), sample, atol=4e-3)


def _components(**changes) -> NoiseComponents:
    values = dict(estimated=("range", "bearing"), factors=np.array([1.0, 0.8, 1.2]),
                  redundancies=np.array([500.0, 800.0, 700.0]), rows=np.array([900.0, 1000.0, 1000.0]),
                  correlations=np.array([0.0, 0.4, 0.5]), rounds=5, converged=True)
    return NoiseComponents(**{**values, **changes})


def test_the_standard_errors_are_those_of_a_chi2_widened_for_the_correlation():
    se = _components().standard_errors
    assert se[0] == 0.0    # the odometry's factor is not estimated here
    assert se[1] == pytest.approx(0.8 * math.sqrt(2 / 800 * (1 + 0.16) / (1 - 0.16)))
    assert se[2] == pytest.approx(1.2 * math.sqrt(2 / 700 * (1 + 0.25) / (1 - 0.25)))
    assert _components().problem() is None


@pytest.mark.parametrize(("changes", "complaint"), [
    ({"converged": False}, "did not reach their fixed point in 5 rounds"),
    ({"redundancies": np.array([500.0, 3.0, 700.0])}, "the range noise is not determined"),
    ({"factors": np.array([1.0, 0.8, np.inf])}, "the bearing noise's variance factor came out inf"),
    ({"estimated": ("odometry", "range", "bearing"), "redundancies": np.array([-1.0, 800.0, 700.0])},
     "the odometry noise is not determined"),
])
def test_an_estimate_the_data_do_not_determine_says_why(changes, complaint):
    assert complaint in _components(**changes).problem()
