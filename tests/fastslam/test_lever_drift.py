"""Honest exported covariances (docs/fastslam-history.md, "Session 8"): the drift's heading lever arm and the correlated
observations' variance inflation (``estimation/fastslam/lever_drift.py``), through the public filter."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.fastslam import FastSLAM, range_bearing_config, range_bearing_observations
from estimation.fastslam.lever_drift import correlated_mean_factor, lever_mean
from estimation.geometry import between, compose, wrap_angle
from estimation.observations import OdometryIncrement

CHI2_2_95 = 5.991
SIGMA_RANGE, SIGMA_BEARING = 0.05, 0.01


def _observe(rng, pose, landmarks, ids):
    """Range-bearing readings of world points (K, 2) from ``pose``, with the noise they claim."""
    local = between(pose, np.column_stack([landmarks, np.zeros(len(landmarks))]))[:, :2]
    r = np.hypot(local[:, 0], local[:, 1]) + rng.normal(0.0, SIGMA_RANGE, len(local))
    phi = np.arctan2(local[:, 1], local[:, 0]) + rng.normal(0.0, SIGMA_BEARING, len(local))
    return range_bearing_observations(r, phi, SIGMA_RANGE, SIGMA_BEARING, ids=ids)


def turn_then_drive(seed: int, **overrides) -> tuple[FastSLAM, np.ndarray]:
    """A robot turns a quarter on the spot seeing nothing (its odometry's heading error is drawn from the filter's
    own motion model), makes four landmarks, drives 10 m ahead re-observing them, then makes four more, with
    ``range_bearing_config(n_particles=10, association="id", **overrides)``. Returns the filter and the 2-D NEES (4,)
    of the last four against their truth: the map frame turned by the heading error puts them ~10 m × δθ off, which
    only a drift that carries the heading's lever can cover (tests/estimation/test_export_drift.py uses it too)."""
    rng = np.random.default_rng(seed)
    config = range_bearing_config(n_particles=10, association="id", **overrides)
    slam = FastSLAM(config, rng.spawn(1)[0])
    turn = np.pi / 2
    heading_error = rng.normal(0.0, np.sqrt(config.odom_theta_var_per_rad * turn))
    slam.predict(OdometryIncrement(0.0, 0.0, turn + heading_error))
    pose = np.array([0.0, 0.0, turn])
    first = np.array([[-2.0, 1.0], [2.0, 1.5], [-2.5, 3.0], [2.5, 2.5]])
    for _ in range(20):                                          # 10 m along +y, the old landmarks always in view
        slam.update(_observe(rng, pose, first, [1, 2, 3, 4]))
        slam.predict(OdometryIncrement(0.5, 0.0, 0.0))
        pose = compose(pose, [0.5, 0.0, 0.0])
    second = np.array([[-2.0, 11.0], [2.0, 11.5], [-2.5, 12.0], [2.5, 10.5]])
    for _ in range(3):
        slam.update(_observe(rng, pose, np.vstack([first, second]), [1, 2, 3, 4, 5, 6, 7, 8]))
    landmarks = slam.best_map(min_count=1)
    ids = slam.external_ids(landmarks.ids)
    err = landmarks.positions[ids >= 5, :2] - second
    cov = landmarks.covariances[ids >= 5][:, :2, :2]
    return slam, np.einsum("ni,ni->n", err, np.linalg.solve(cov, err[..., None])[..., 0])


def _turn_then_drive(seed: int, lever: bool) -> np.ndarray:
    # without the lever: the plain tracker (range_bearing_config's export would carry the lever itself)
    return turn_then_drive(seed, id_relative_drift="off", drift_lever=lever, drift_export="plain")[1]


def test_the_heading_lever_makes_far_landmarks_honest_and_without_it_they_are_overconfident():
    # one heading error per run, shared by its four far landmarks: score one landmark per run (independent runs)
    with_lever = np.array([_turn_then_drive(seed, True)[0] for seed in range(40)])
    without = np.array([_turn_then_drive(seed, False)[0] for seed in range(16)])
    # honest: NEES ~ χ²₂, 95 % under the bound; of 40 runs ≥ 32 (P(≥ 9 of 40 above | 5 %) ≈ 0.1 %), and the
    # median near χ²₂'s 1.39 (0.7-2.5 holds for 40 draws with > 99 %): neither overconfident nor inflated
    assert np.mean(with_lever < CHI2_2_95) >= 0.8
    assert 0.7 < np.median(with_lever) < 2.5
    # without the lever the 10 m × δθ offset (σ ≈ 0.2 m) is claimed at the creation pose's σ (≈ a few cm)
    assert np.mean(without < CHI2_2_95) < 0.5
    assert np.median(without) > 10 * np.median(with_lever)


@settings(max_examples=60, deadline=None)
@given(pose=st.tuples(st.floats(-20, 20), st.floats(-20, 20), st.floats(-np.pi, np.pi)),
       moved=st.tuples(st.floats(-15, 15), st.floats(-15, 15), st.floats(-np.pi, np.pi)),
       error=st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)))
def test_lever_is_the_first_order_effect_of_the_creation_poses_error_on_the_robot(pose, moved, error):
    # the robot is `moved` from the pose that made a landmark; an error δ of that pose moves the robot by G δ
    pose, moved, delta = np.array(pose), np.array(moved), 1e-6 * np.array(error)
    robot = compose(pose, moved)
    shifted = compose(pose + delta, moved)
    change = shifted - robot
    change[2] = wrap_angle(change[2])
    d_cov = np.outer(delta, delta)
    predicted = lever_mean(d_cov[None], (robot[:2] - pose[:2])[None])
    assert np.allclose(predicted, np.outer(change, change), atol=1e-15, rtol=1e-4)


@settings(max_examples=60, deadline=None)
@given(n=st.integers(1, 40), rho=st.floats(0.0, 0.95))
def test_correlated_mean_factor_is_the_variance_of_an_ar1_mean(n, rho):
    # var(mean of n) with corr(e_i, e_j) = ρ^|i−j|, against what n independent observations would claim
    lags = np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    exact = (rho ** lags).sum() / n
    factor = correlated_mean_factor(np.array([n]), rho)[0]
    assert np.isclose(factor, exact, rtol=1e-9)
    assert 1.0 - 1e-12 <= factor <= min(n, (1 + rho) / (1 - rho)) + 1e-9


def test_exported_covariance_scales_with_the_correlation_and_the_estimates_do_not_change():
    def run(correlation):
        rng = np.random.default_rng(4)
        slam = FastSLAM(range_bearing_config(n_particles=5, association="id", observation_correlation=correlation),
                        np.random.default_rng(1))
        for _ in range(6):
            slam.update(_observe(rng, np.zeros(3), np.array([[3.0, 1.0], [4.0, -2.0]]), [1, 2]))
            slam.predict(OdometryIncrement(0.0, 0.0, 0.0))
        return slam.best_map(min_count=1, covariance="particle")
    plain, correlated = run(0.0), run(0.5)
    assert np.array_equal(plain.positions, correlated.positions)
    factor = correlated_mean_factor(plain.counts, 0.5)
    assert np.all(plain.counts == 6) and np.isclose(factor[0], 1 + 2 * sum((1 - k / 6) * 0.5 ** k for k in range(1, 6)))
    assert np.allclose(correlated.covariances, plain.covariances * factor[:, None, None])


@settings(max_examples=30, deadline=None)
@given(q=st.floats(1e-6, 1e-3), step=st.floats(0.05, 3.0), generations=st.integers(1, 30))
def test_translation_walk_adds_up_over_generations_of_landmarks_to_the_path_driven(q, step, generations):
    # each generation's landmarks are made where the robot stands and matched one step further on (no heading
    # uncertainty, no local term): the position variance is q per metre of the whole path, as a random walk is
    from estimation.fastslam.lever_drift import LeverDriftTracker
    tracker = LeverDriftTracker(translation_per_m=q)
    zero = np.zeros((3, 3))
    tracker.update(np.zeros(0, np.int64), np.array([0]), np.array([[0.0, 1.0, 0.0]]), np.zeros(3), zero, 1)
    for i in range(1, generations + 1):
        pose = np.array([i * step, 0.0, 0.0])
        tracker.update(np.array([i - 1]), np.array([i]), np.array([[i * step, 1.0, 0.0]]), pose, zero, i + 1)
    assert np.allclose(tracker.robot[:2, :2], q * generations * step * np.eye(2), rtol=1e-9)
    assert np.allclose(tracker.robot[2], 0.0)


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(2, 60), sx=st.floats(0.005, 0.2), sy=st.floats(0.005, 0.2),
       corr=st.floats(-0.9, 0.9))
def test_empirical_local_position_is_the_variance_of_the_residuals_mean(seed, n, sx, sy, corr):
    # readings whose real spread is Σ (whatever the model claims): the sandwich estimate Σ_l r rᵀ / L² has mean
    # Σ / L over many frames, the variance of the mean of L independent readings
    from estimation.fastslam.lever_drift import empirical_local_position
    cov = np.array([[sx * sx, corr * sx * sy], [corr * sx * sy, sy * sy]])
    draws = np.random.default_rng(seed).multivariate_normal(np.zeros(2), cov, (3000, n))
    mean_estimate = np.mean([empirical_local_position(r) for r in draws], axis=0)
    assert np.allclose(mean_estimate, cov / n, rtol=0.15, atol=0.15 * np.sqrt(sx * sx * sy * sy) / n)


def test_empirical_position_replaces_the_claimed_one_only_where_larger():
    from estimation.fastslam.lever_drift import with_empirical_position
    claimed = np.diag([1e-4, 1e-4, 1e-5])
    small, large = np.full((10, 2), 0.001), np.array([[0.3, 0.0], [-0.3, 0.0]] * 5)
    assert np.array_equal(with_empirical_position(claimed, small), claimed)
    widened = with_empirical_position(claimed, large)
    assert np.isclose(widened[0, 0], 1e-4 + 0.09 / 10) and widened[2, 2] == 1e-5 and widened[1, 1] == 1e-4
    assert np.array_equal(with_empirical_position(claimed, large[:1]), claimed)   # one reading: no spread to see


def test_a_generation_hands_on_its_error_averaged_over_the_correlated_sightings_of_its_landmarks():
    from estimation.fastslam.lever_drift import empirical_local_position, with_empirical_position
    claimed = np.diag([1e-6, 1e-6, 1e-5])
    residuals = np.array([[0.1, 0.0], [-0.1, 0.0]] * 10)
    whole = empirical_local_position(residuals) + claimed[:2, :2]
    assert np.allclose(with_empirical_position(claimed, residuals)[:2, :2], whole)
    assert np.allclose(with_empirical_position(claimed, residuals, np.ones(20), 0.49)[:2, :2], whole)  # seen once
    counts = np.full(20, 6)
    averaged = with_empirical_position(claimed, residuals, counts, 0.0)[:2, :2]
    measured = empirical_local_position(residuals)
    assert np.allclose(averaged, claimed[:2, :2] + measured / 6)      # independent sightings: a sixth
    correlated = with_empirical_position(claimed, residuals, counts, 0.49)[:2, :2]
    assert np.allclose(correlated, claimed[:2, :2] + measured * correlated_mean_factor(counts, 0.49)[0] / 6)
    assert np.trace(averaged) < np.trace(correlated) < np.trace(whole)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(2, 30), corr=st.floats(-0.99, 0.99), scale=st.floats(1e-4, 1.0))
def test_the_local_covariance_with_the_measured_position_stays_positive_semidefinite(seed, n, corr, scale):
    # a proposal covariance with strong position-heading cross terms, and residuals along any direction
    from estimation.fastslam.lever_drift import with_empirical_position
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(3, 3)) * [[1e-3], [1e-3], [1e-2]]
    claimed = a @ a.T
    claimed[:2, 2] = claimed[2, :2] = corr * np.sqrt(claimed[[0, 1], [0, 1]] * claimed[2, 2])
    claimed = claimed + (1e-12 - min(0.0, np.linalg.eigvalsh(claimed).min())) * np.eye(3)   # a valid proposal
    residuals = rng.normal(size=(n, 2)) * scale * rng.uniform(0.01, 1.0, 2)
    out = with_empirical_position(claimed, residuals, rng.integers(1, 20, n), 0.49)
    assert np.allclose(out, out.T) and np.linalg.eigvalsh(out).min() >= -1e-15
