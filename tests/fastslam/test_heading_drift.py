"""The drifting heading bias per metre (FastSLAMConfig.odom_heading_drift_*): each particle carries b (rad/m), a
first-order Gauss–Markov process, and its increments turn by b × distance. Off (σ_b = 0) the filter is bit for bit
what it was; on, the cloud's heading spread after a straight run is the closed form's."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.fastslam import FastSLAM, FastSLAMConfig
from estimation.fastslam.motion import increment_variance, propagate_with_heading_drift, sample_motion
from estimation.geometry import compose
from estimation.observations import OdometryIncrement
from mocks.synthetic_stereo import SyntheticStereo

increments = st.lists(st.tuples(st.floats(-0.3, 0.3), st.floats(-0.05, 0.05), st.floats(-0.5, 0.5),
                                st.floats(0.0, 2.0)), min_size=1, max_size=25)


@settings(max_examples=60, deadline=None)
@given(steps=increments, seed=st.integers(0, 2 ** 31), version=st.sampled_from((1, 2)),
       tau=st.sampled_from((0.0, 0.5, 30.0)))
def test_without_a_drift_predictions_are_bit_identical_to_the_random_walk(steps, seed, version, tau):
    """σ_b = 0 (with or without a τ): every prediction is the plain random walk's, drawn from the same generator:
    FastSLAM 1.0 samples each particle's increment, 2.0 composes the noise-free one."""
    config = FastSLAMConfig(n_particles=7, version=version, odom_heading_drift_tau_s=tau)
    slam = FastSLAM(config, np.random.default_rng(seed), initial_pose=(0.5, -1.0, 0.3))
    rng = np.random.default_rng(seed)
    poses = np.tile([0.5, -1.0, 0.3], (7, 1))
    t = 0.0
    for dx, dy, dth, dt in steps:
        slam.predict(OdometryIncrement(dx, dy, dth, t, t + dt))
        t += dt
        delta = np.array([dx, dy, dth])
        poses = (sample_motion(poses, delta, increment_variance(delta, config), rng) if version == 1
                 else compose(poses, delta))
        assert np.array_equal(slam.poses, poses)
    assert np.array_equal(slam.heading_bias, np.zeros(7))
    assert np.array_equal(slam.rng.bit_generator.state["state"]["state"], rng.bit_generator.state["state"]["state"])


def test_without_a_drift_a_whole_run_is_unchanged(drive):
    """Predict and update over the corridor: a τ without a σ_b changes no particle, weight or landmark."""
    runs = []
    for config in (FastSLAMConfig(n_particles=10), FastSLAMConfig(n_particles=10, odom_heading_drift_tau_s=20.0)):
        slam = FastSLAM(config, np.random.default_rng(3))
        drive(slam, seed=4, frames=25)
        runs.append(slam)
    a, b = runs
    assert np.array_equal(a.poses, b.poses) and np.array_equal(a.log_weights, b.log_weights)
    assert np.array_equal(a.drift.robot, b.drift.robot)
    for m in range(10):
        ma, mb = a.particle_map(m, 1), b.particle_map(m, 1)
        assert np.array_equal(ma.ids, mb.ids) and np.array_equal(ma.positions, mb.positions)


def _closed_form_heading_variance(n: int, distance: float, sigma: float, decay: float) -> float:
    """Var(Σ_{k<n} b_k d) for a stationary AR(1) b (variance σ², lag-1 coefficient a): σ² d² Σ_i Σ_j a^|i−j|."""
    k = np.arange(1, n)
    return sigma ** 2 * distance ** 2 * (n + 2.0 * np.sum((n - k) * decay ** k))


@pytest.mark.parametrize("version", [1, 2])
def test_the_heading_spread_of_a_straight_run_is_the_gauss_markov_closed_form(version):
    """20,000 particles driven straight (0.02 m every 0.25 s, σ_b 0.15 rad/m, τ 10 s): the sample variance of the
    heading after 10, 40 and 200 increments is the closed form's (the AR(1) sum, plus FastSLAM 1.0's random walk),
    within 8 %: the sample variance of 20,000 normal draws is off by more than that with probability < 1e-15 (its
    relative standard error is √(2/N) = 1 %). The growth is ∝ n² over less than τ and ∝ n beyond, unlike a white
    random walk's ∝ n. The biases themselves keep their stationary σ_b."""
    n_particles, distance, dt, sigma, tau = 20_000, 0.02, 0.25, 0.15, 10.0
    q_theta = 0.01 ** 2
    config = FastSLAMConfig(n_particles=n_particles, version=version, odom_theta_var_per_m=q_theta,
                            odom_heading_drift_sigma_per_m=sigma, odom_heading_drift_tau_s=tau)
    slam = FastSLAM(config, np.random.default_rng(2026))
    decay = np.exp(-dt / tau)
    white = q_theta * distance + config.odom_var_floor if version == 1 else 0.0   # per increment (1.0 samples it)
    observed = {}
    for k in range(200):
        slam.predict(OdometryIncrement(distance, 0.0, 0.0, k * dt, (k + 1) * dt))
        if k + 1 in (10, 40, 200):
            n = k + 1
            expected = _closed_form_heading_variance(n, distance, sigma, decay) + n * white
            observed[n] = float(np.var(slam.poses[:, 2]))
            assert observed[n] == pytest.approx(expected, rel=0.08), n
    assert float(np.std(slam.heading_bias)) == pytest.approx(sigma, rel=0.05)
    assert observed[40] / observed[10] > 10.0          # ∝ n² within τ (40 increments: 10 s): a white walk gives 4
    assert np.max(np.abs(slam.poses[:, 2])) < 3.0      # no heading wrapped (the variance is of the unwrapped sum)


def test_the_bias_walks_with_its_correlation_time():
    """Between two predicts Δt apart, the biases' correlation is e^(−Δt/τ) (the process's only memory)."""
    config = FastSLAMConfig(n_particles=20_000, version=2, odom_heading_drift_sigma_per_m=0.1,
                            odom_heading_drift_tau_s=2.0)
    slam = FastSLAM(config, np.random.default_rng(7))
    before = slam.heading_bias.copy()
    slam.predict(OdometryIncrement(0.1, 0.0, 0.0, 0.0, 1.0))
    assert np.corrcoef(before, slam.heading_bias)[0, 1] == pytest.approx(np.exp(-0.5), abs=0.04)  # > 5 σ


def test_resampling_carries_each_particles_bias(corridor):
    """After every resampling update of a corridor run, particles that are copies of one parent (identical poses:
    the proposal's draws are continuous) share its bias, and distinct parents keep distinct biases."""
    config = FastSLAMConfig(n_particles=30, odom_heading_drift_sigma_per_m=0.1, odom_heading_drift_tau_s=5.0,
                            resample_threshold=1.0)   # resample every frame
    rng = np.random.default_rng(9)
    features, desc = corridor(rng)
    sensor = SyntheticStereo(features, desc, rng)
    slam = FastSLAM(config, np.random.default_rng(10))
    pose, checked = np.zeros(3), 0
    for i in range(8):
        pose = compose(pose, [0.1, 0.0, 0.0])
        slam.predict(OdometryIncrement(0.1, 0.0, 0.0, 0.2 * i, 0.2 * (i + 1)))
        report = slam.update(sensor.observe(pose, timestamp=0.2 * (i + 1))[0])
        if not report.resampled:
            continue
        _, first, group = np.unique(slam.poses, axis=0, return_index=True, return_inverse=True)
        assert np.array_equal(slam.heading_bias, slam.heading_bias[first][group.ravel()])
        assert len(np.unique(slam.heading_bias)) == len(first) < 30
        checked += 1
    assert checked >= 4


@settings(max_examples=200, deadline=None)
@given(pose=st.tuples(st.floats(-20, 20), st.floats(-20, 20), st.floats(-4, 4)),
       delta=st.tuples(st.floats(-0.5, 0.5), st.floats(-0.1, 0.1), st.floats(-0.6, 0.6)),
       spread=st.lists(st.floats(-1, 1), min_size=9, max_size=9), cross=st.tuples(*[st.floats(-0.05, 0.05)] * 3),
       sigma=st.floats(0.0, 0.3), decay=st.floats(0.0, 1.0))
def test_the_drift_trackers_propagation_is_the_dense_four_state_one(pose, delta, spread, cross, sigma, decay):
    """The filter's closed form (pose covariance P, its cross-covariance c with b, Var(b) held at σ_b²) is the dense
    [x, y, θ, b] propagation ``odometry_consistency.dead_reckoned_windows`` does, F Σ Fᵀ + G V Gᵀ + Q_b with
    F = [[J, d e_θ], [0, e^(−Δt/τ)]], to round-off: the two propagations of the drift agree."""
    pose, delta, cross = np.array(pose), np.array(delta), np.array(cross)
    a = np.array(spread).reshape(3, 3)
    cov = a @ a.T + 1e-6 * np.eye(3)
    variance = increment_variance(delta, FastSLAMConfig())
    out, out_cross = propagate_with_heading_drift(pose, cov, cross, delta, variance, sigma, decay)
    d, c, s = np.hypot(delta[0], delta[1]), np.cos(pose[2]), np.sin(pose[2])
    dense = np.zeros((4, 4))
    dense[:3, :3], dense[:3, 3], dense[3, :3], dense[3, 3] = cov, cross, cross, sigma ** 2
    f = np.eye(4)
    f[0, 2], f[1, 2], f[2, 3], f[3, 3] = -s * delta[0] - c * delta[1], c * delta[0] - s * delta[1], d, decay
    g = np.zeros((4, 3))
    g[:2, :2], g[2, 2] = [[c, -s], [s, c]], 1.0
    dense = f @ dense @ f.T + (g * variance) @ g.T
    dense[3, 3] += sigma ** 2 * (1.0 - decay ** 2)
    scale = 1.0 + np.abs(dense).max()
    np.testing.assert_allclose(out, dense[:3, :3], rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(out_cross, dense[:3, 3], rtol=0, atol=1e-12 * scale)
    assert dense[3, 3] == pytest.approx(sigma ** 2, rel=1e-12, abs=1e-15)   # Var(b) stays stationary: held, not lost
