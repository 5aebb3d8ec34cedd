"""The innovations' consistency tests (``estimation/fastslam/innovation_consistency.py``): the NIS, the a-posteriori
variance factor and the whiteness of a landmark's innovations, on a Kalman filter of a fixed point fed independent
readings (consistent: factor 1, white) and readings whose errors are an AR(1) process (the filter takes them as
independent: the innovations are correlated, the ratio near the Bartlett factor)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.fastslam.innovation_consistency import (
    block_variance_ratio,
    lag1_correlation,
    normalised_innovations,
    variance_factor,
)
from estimation.fastslam.lever_drift import correlated_mean_factor


def point_filter(readings: np.ndarray, noise: np.ndarray, prior: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A Kalman filter of a fixed 2-D point (H = I, readings (N, 2) with covariance noise (2, 2)), started at the
    first reading: its innovations (N − 1, 2) and their claimed covariances S = Σ + R (N − 1, 2, 2)."""
    mean, cov = readings[0].copy(), prior.copy()
    nus, covs = [], []
    for z in readings[1:]:
        s = cov + noise
        nu = z - mean
        gain = cov @ np.linalg.inv(s)
        mean = mean + gain @ nu
        cov = (np.eye(2) - gain) @ cov
        nus.append(nu)
        covs.append(s)
    return np.array(nus), np.array(covs)


NOISE = np.array([[0.04, 0.01], [0.01, 0.02]])


def readings(n: int, rho: float, rng: np.random.Generator) -> np.ndarray:
    """n readings of the point (1, 2) whose errors are AR(1) with lag-1 correlation rho and covariance NOISE."""
    white = rng.standard_normal((n, 2)) @ np.linalg.cholesky(NOISE).T
    errors = np.empty_like(white)
    errors[0] = white[0]
    for i in range(1, n):
        errors[i] = rho * errors[i - 1] + np.sqrt(1.0 - rho ** 2) * white[i]
    return np.array([1.0, 2.0]) + errors


def test_a_consistent_filter_has_factor_one_and_white_innovations():
    nu, s = point_filter(readings(4000, 0.0, np.random.default_rng(3)), NOISE, NOISE)
    w, nis = normalised_innovations(nu, s)
    assert abs(variance_factor(nis, 2) - 1.0) < 0.1             # E[NIS] = dof; sd of the factor ~0.016
    assert abs(lag1_correlation(w)) < 0.06                      # sd ~0.011
    assert 0.75 < block_variance_ratio(w, 20) < 1.3             # 199 blocks: sd ~0.07


def test_readings_correlated_over_time_give_correlated_innovations_not_a_large_nis():
    rho = 0.6
    nu, s = point_filter(readings(20000, rho, np.random.default_rng(4)), NOISE, NOISE)
    w, nis = normalised_innovations(nu, s)
    # each reading alone is as noisy as claimed: the NIS does not see the correlation ...
    assert abs(variance_factor(nis, 2) - 1.0) < 0.15
    # ... the whiteness test does, and a mean of 50 readings is as unsure as the AR(1) model says
    assert lag1_correlation(w) > 0.45
    bartlett = float(correlated_mean_factor(np.array([50]), rho)[0])
    assert 0.7 * bartlett < block_variance_ratio(w, 50) < 1.3 * bartlett


@settings(max_examples=50, deadline=None)
@given(a=st.floats(-2.0, 2.0), b=st.floats(-2.0, 2.0), c=st.floats(-2.0, 2.0), x=st.floats(-5.0, 5.0),
       y=st.floats(-5.0, 5.0), k=st.floats(0.1, 10.0))
def test_nis_is_the_quadratic_form_and_scales_inversely_with_the_covariance(a, b, c, x, y, k):
    root = np.array([[1.0 + abs(a), 0.0], [b, 0.5 + abs(c)]])
    s = root @ root.T
    nu = np.array([[x, y]])
    w, nis = normalised_innovations(nu, s[None])
    assert nis[0] == pytest.approx(float(nu[0] @ np.linalg.solve(s, nu[0])), rel=1e-9, abs=1e-12)
    assert np.sum(w * w) == pytest.approx(nis[0], rel=1e-9, abs=1e-12)
    assert normalised_innovations(nu, k * s[None])[1][0] == pytest.approx(nis[0] / k, rel=1e-9, abs=1e-12)


def test_short_and_malformed_input():
    assert np.isnan(lag1_correlation(np.zeros((1, 2))))
    assert np.isnan(block_variance_ratio(np.ones((3, 2)), 5))
    assert np.isnan(variance_factor([], 2))
    with pytest.raises(ValueError):
        block_variance_ratio(np.ones((3, 2)), 0)
    with pytest.raises(ValueError):
        normalised_innovations(np.ones((3, 2)), np.ones((3, 3, 3)))
    with pytest.raises(np.linalg.LinAlgError):
        normalised_innovations(np.ones((1, 2)), -np.eye(2)[None])
