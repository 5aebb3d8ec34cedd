"""One bearing error shared by the sightings of one image (the problem's ``image_bearing_sigmas``,
``estimation.landmark_smoother.image_whitening``; τ = |ω| σ_t from ``estimation.image_timing``): the joint covariance
it whitens with is the covariance of an image exposed at an unknown instant of its stamp's period while the robot
turns (Monte-Carlo); it is an explicit per-image unknown marginalised; an image of one sighting is that bearing's σ
grown to √(σ² + τ²); the smoother's Jacobian is its residuals' derivative; no term, or τ 0, is the old solution."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.datasets import RangeBearingLog
from estimation.geometry import dead_reckoning, wrap_angle
from estimation.image_timing import image_bearing_sigmas, stamp_period, timing_sigma, turn_rates
from estimation.landmark_smoother import (
    LandmarkLogProblem,
    SmoothingError,
    _residuals,
    image_whitening,
    landmarks_from_first_sightings,
    normalised_residuals,
    solution_jacobian,
)
from estimation.noise_model import NoiseModel, OdometryNoise

from .frame_helpers import glimpses_then_lap, joint_frame_covariance, seen_from, solved

DRAWS = 4000


def _image(landmarks: np.ndarray, bearing_sigma: float, tau: float) -> LandmarkLogProblem:
    """One image of ``landmarks`` (N, 2) seen from pose 1 (the origin's pose, reached by a null increment)."""
    n = len(landmarks)
    r, b = seen_from(landmarks, 0.0, 0.0, 0.0)
    return LandmarkLogProblem(np.zeros((1, 3)), np.full((1, 3), 1e-6), np.ones(n, int), np.arange(n), r, b,
                              np.full(n, 0.05), np.full(n, bearing_sigma), image_bearing_sigmas=np.array([tau]))


@settings(max_examples=25, deadline=None)
@given(st.lists(st.tuples(st.floats(1.0, 6.0), st.floats(-0.6, 0.6)), min_size=1, max_size=5),
       st.floats(0.1, 1.0), st.floats(0.1, 0.5), st.floats(0.003, 0.03), st.integers(0, 2 ** 32 - 1))
def test_the_joint_covariance_is_that_of_an_image_exposed_anywhere_in_its_period_while_turning(
        seen, omega, period, bearing_sigma, seed):
    """A robot turning on the spot at ω exposes an image at an instant uniform over the period P about its stamp:
    every bearing of the image is off by the same −ω δ, plus its own noise. The whitened residuals of many such
    images have the identity covariance; the bearings taken as independent do not (when τ is not small)."""
    rng = np.random.default_rng(seed)
    ranges, bearings = np.array(seen).T
    landmarks = ranges[:, None] * np.column_stack([np.cos(bearings), np.sin(bearings)])
    tau = omega * timing_sigma(period)
    problem = _image(landmarks, bearing_sigma, tau)
    delta = rng.uniform(-period / 2, period / 2, DRAWS)
    # the exact bearings from the heading the robot had at the exposure, against the stamp's pose (heading 0)
    measured = np.stack([seen_from(landmarks, 0.0, 0.0, omega * d)[1] for d in delta])
    measured = measured + bearing_sigma * rng.standard_normal(measured.shape)
    z = wrap_angle(problem.bearings - measured) / bearing_sigma          # (DRAWS, N) the smoother's normalised
    whitened = z @ image_whitening(problem).toarray().T
    n = len(landmarks)
    sample = whitened.T @ whitened / DRAWS
    error = np.abs(sample - np.eye(n))
    se = np.where(np.eye(n, dtype=bool), np.sqrt(2.0 / DRAWS), np.sqrt(1.0 / DRAWS))
    assert np.all(error < 5.0 * se), (sample, tau / bearing_sigma)
    # the smoother's own residuals: one draw's normalised bearing residuals at the truth are these whitened ones
    _, sightings = _residuals(dataclasses.replace(problem, bearings=measured[0]), np.zeros((2, 3)), landmarks)
    np.testing.assert_allclose(sightings.reshape(-1, 2)[:, 1], whitened[0], atol=1e-9)
    if n >= 2 and tau > 2 * bearing_sigma:     # taken as independent, the shared error shows between the sightings
        plain = z.T @ z / DRAWS
        assert plain[0, 1] > 10.0 * np.sqrt(1.0 / DRAWS) * max(plain[0, 0], 1.0)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-0.2, 0.2), min_size=1, max_size=6), st.lists(st.floats(0.002, 0.05), min_size=6,
                                                                          max_size=6), st.floats(1e-4, 0.2))
def test_the_image_s_chi2_is_that_of_an_explicit_shared_error_marginalised(errors, sigmas, tau):
    """min over ε of Σ ((e_i − ε) / σ_i)² + (ε / τ)² is the whitened residuals' squared norm: the joint covariance is
    the explicit per-image unknown (its prior ε / τ) eliminated."""
    e = np.array(errors)
    s = np.array(sigmas[:len(e)])
    landmarks = np.column_stack([np.full(len(e), 3.0), np.linspace(-1.0, 1.0, len(e))])
    problem = _image(landmarks, 0.01, tau)
    problem = dataclasses.replace(problem, bearing_sigmas=s)
    whitened = image_whitening(problem) @ (e / s)
    information = np.sum(1 / s ** 2) + 1 / tau ** 2
    epsilon = np.sum(e / s ** 2) / information
    explicit = np.sum(((e - epsilon) / s) ** 2) + (epsilon / tau) ** 2
    assert np.sum(whitened ** 2) == pytest.approx(explicit, rel=1e-9, abs=1e-12)


def _problem(rng, per_glimpse: int = 2) -> LandmarkLogProblem:
    problem = glimpses_then_lap(rng, 2, per_glimpse=per_glimpse)
    return dataclasses.replace(problem, image_bearing_sigmas=np.abs(0.02 * rng.standard_normal(problem.n_poses)))


def test_the_smoother_s_jacobian_is_the_derivative_of_its_whitened_residuals():
    problem = _problem(np.random.default_rng(3))
    solution = solved(problem)
    assert np.bincount(problem.pose_index[solution.inliers]).max() >= 3          # images of several sightings
    jac, width = solution_jacobian(problem, solution)
    t, n = problem.n_poses, len(solution.landmarks)
    jac = jac.toarray()
    kept = np.flatnonzero(solution.inliers)
    rows = np.concatenate([np.arange(3 * t), 3 * t + np.column_stack([2 * kept, 2 * kept + 1]).ravel()])

    def residuals(x):
        poses = solution.poses.copy()
        poses[1:] = x[:3 * t].reshape(t, 3)
        moved = dataclasses.replace(solution, poses=poses, landmarks=x[3 * t:].reshape(n, 2))
        odometry, sightings, _ = normalised_residuals(problem, moved)
        return np.concatenate([odometry.ravel(), sightings[kept].ravel()])

    x = np.concatenate([solution.poses[1:].ravel(), solution.landmarks.ravel()])
    h = 1e-6
    numeric = np.column_stack([(residuals(x + h * e) - residuals(x - h * e)) / (2 * h) for e in np.eye(len(x))])
    # the sightings' rows, relative to their size (the odometry's are unchanged by the term and scaled by 1/√1e-8)
    sighting_rows = slice(3 * t, None)
    scale = np.abs(jac[rows][sighting_rows]).max()
    np.testing.assert_allclose(jac[rows][sighting_rows], numeric[sighting_rows], atol=1e-6 * scale)


def test_an_image_of_one_sighting_is_its_bearing_with_the_shared_variance_added():
    problem = glimpses_then_lap(np.random.default_rng(5), 1, per_glimpse=1)
    one = np.flatnonzero(np.bincount(problem.pose_index, minlength=problem.n_poses + 1) == 1)   # poses of one
    tau = np.zeros(problem.n_poses)
    tau[one - 1] = 0.03
    shared = dataclasses.replace(problem, image_bearing_sigmas=tau)
    single = np.isin(problem.pose_index, one)
    grown = dataclasses.replace(problem, bearing_sigmas=np.where(single, np.hypot(problem.bearing_sigmas, 0.03),
                                                                 problem.bearing_sigmas))
    a, b = solved(shared), solved(grown)
    assert single.sum() >= 5 and np.array_equal(a.inliers, b.inliers)
    np.testing.assert_allclose(a.landmarks, b.landmarks, atol=1e-6)
    np.testing.assert_allclose(a.landmark_covariances, b.landmark_covariances, rtol=1e-6, atol=1e-12)
    assert a.chi2 == pytest.approx(b.chi2, rel=1e-6)


def test_no_shared_error_is_the_solution_without_the_term_bit_for_bit():
    problem = glimpses_then_lap(np.random.default_rng(7), 2, per_glimpse=2)
    plain = solved(problem)
    zero = solved(dataclasses.replace(problem, image_bearing_sigmas=np.zeros(problem.n_poses)))
    for name in ("poses", "landmarks", "landmark_covariances", "pose_covariances", "inliers"):
        assert np.array_equal(getattr(plain, name), getattr(zero, name)), name
    assert plain.chi2 == zero.chi2
    assert image_whitening(problem) is None


def test_the_shared_error_widens_the_landmarks_an_image_of_several_sightings_ties_to_the_frame():
    problem = glimpses_then_lap(np.random.default_rng(11), 3, per_glimpse=3, noise=0.0)
    tau = np.full(problem.n_poses, 0.05)
    plain, shared = solved(problem), solved(dataclasses.replace(problem, image_bearing_sigmas=tau))
    np.testing.assert_allclose(shared.landmarks, plain.landmarks, atol=1e-6)     # exact data: the same MAP
    seen = np.isfinite(plain.landmark_covariances[:, 0, 0])
    grown = np.linalg.det(shared.landmark_covariances[seen]) / np.linalg.det(plain.landmark_covariances[seen])
    assert np.all(grown > 1.0)


def test_refusals():
    problem = glimpses_then_lap(np.random.default_rng(1), 1)
    for bad in (np.full(problem.n_poses, -0.1), np.full(problem.n_poses + 1, 0.1), np.full(problem.n_poses, np.nan)):
        with pytest.raises(SmoothingError, match="image_bearing_sigmas"):
            dataclasses.replace(problem, image_bearing_sigmas=bad)


def _turning_log(period: float, omega: float) -> RangeBearingLog:
    t = np.arange(0.0, 10.0, 0.02)
    odometry = np.column_stack([t, np.zeros_like(t), np.zeros_like(t), wrap_angle(omega * t)])
    stamps = np.arange(1.0, 9.0, period)
    return RangeBearingLog("turning", odometry, stamps, np.full(len(stamps), 2.0), np.zeros(len(stamps)),
                           np.zeros(len(stamps), np.int64))


@settings(max_examples=30, deadline=None)
@given(st.floats(0.1, 0.6), st.floats(-1.5, 1.5), st.floats(0.8, 1.2), st.floats(0.0, 0.3))
def test_tau_is_the_odometry_s_turn_rate_times_the_period_over_root_12(period, omega, scale, lag):
    log = _turning_log(period, omega)
    noise = NoiseModel(OdometryNoise(0.01, 0.01, 0.0, rotation_scale=scale, lag_s=lag))
    assert stamp_period(log.sighting_times) == pytest.approx(period, rel=1e-6)
    tau, sigma_t = image_bearing_sigmas(log, noise, log.sighting_times)
    assert sigma_t == pytest.approx(period / np.sqrt(12.0), rel=1e-6)
    np.testing.assert_allclose(tau, abs(scale * omega) * sigma_t, rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(turn_rates(log, noise, log.sighting_times, period), scale * omega, rtol=1e-6,
                               atol=1e-12)


def test_a_still_robot_or_a_log_of_one_stamp_has_no_shared_error():
    still = _turning_log(0.24, 0.0)
    noise = NoiseModel(OdometryNoise(0.01, 0.01, 0.0))
    tau, _ = image_bearing_sigmas(still, noise, still.sighting_times)
    assert np.all(tau == 0.0)
    one = dataclasses.replace(still, sighting_times=np.full(len(still.sighting_times), 2.0))
    tau, sigma_t = image_bearing_sigmas(one, noise, np.array([2.0]))
    assert sigma_t == 0.0 and np.all(tau == 0.0)


def test_the_smoother_refuses_the_term_with_extra_unknowns():
    from estimation.landmark_smoother import _jacobian

    class _Nothing:
        def columns(self, *args, **kwargs):
            import scipy.sparse as sp
            problem = args[0]
            return sp.csr_matrix((3 * problem.n_poses + 2 * len(problem.ranges), 0))

        def rows(self, problem, landmarks, values, n_columns):
            import scipy.sparse as sp
            return sp.csr_matrix((0, n_columns))

    problem = _problem(np.random.default_rng(2))
    poses = dead_reckoning(problem.increments)
    landmarks = landmarks_from_first_sightings(problem, poses)
    with pytest.raises(SmoothingError, match="not combined with extra unknowns"):
        _jacobian(problem, poses, landmarks, problem.n_landmarks, np.ones(len(problem.ranges)), extra=_Nothing(),
                  extra_values=np.zeros(0))


def test_the_frame_of_an_image_of_several_sightings_keeps_the_shared_error_s_sigma():
    """The map's frame is pose 1's image of four landmarks (pose 0 a null increment before it). Its heading's σ is
    at least the shared error's τ with the joint covariance; with τ² added to each bearing as if independent (session
    41's variant) the four average it down to about τ / 2."""
    problem = glimpses_then_lap(np.random.default_rng(13), 4, lone_glimpses=False, noise=0.0)
    assert np.sum(problem.pose_index == 1) == 4
    tau = 0.05
    shared = np.zeros(problem.n_poses)
    shared[0] = tau
    joint = dataclasses.replace(problem, image_bearing_sigmas=shared)
    first = problem.pose_index == 1
    independent = dataclasses.replace(problem, bearing_sigmas=np.where(
        first, np.hypot(problem.bearing_sigmas, tau), problem.bearing_sigmas))
    heading_sd = [float(np.sqrt(joint_frame_covariance(p, solved(p))[2, 2])) for p in (joint, independent, problem)]
    assert heading_sd[0] >= 0.9 * tau
    assert heading_sd[1] < 0.6 * tau
    assert heading_sd[2] < heading_sd[1]
