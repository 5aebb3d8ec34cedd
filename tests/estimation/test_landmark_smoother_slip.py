"""The smoother's heading slip per radian turned (HeadingDrift.sigma_per_rad, session 29 C) on simulated logs of a
robot that wiggles on the spot: the per-metre bias adds nothing there, the slip does."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from estimation.geometry import dead_reckoning, wrap_angle
from estimation.landmark_scores import pose_nees
from estimation.landmark_smoother import (
    HeadingDrift,
    LandmarkLogProblem,
    SmoothingError,
    landmarks_from_first_sightings,
    normalised_residuals,
    smooth,
)
from tests.estimation.test_landmark_smoother import SIGMA_B, SIGMA_R, gauss_markov, simulated_log, simulated_sightings

SLIP_SIGMA, SLIP_TAU = 0.05, 20.0          # rad/rad, s
CHI2_3_95 = 7.815


def wiggling_log(seed: int, blocks: int = 10, sigma: float = SLIP_SIGMA, tau: float = SLIP_TAU):
    """A robot that drives 1.8 m straight (6 steps of 1 s), then turns back and forth on the spot (8 steps of ±0.5
    rad), ``blocks`` times, past landmarks strewn along its path (in view within 4 m and ±0.8 rad). Its odometry's
    heading loses c_k |Δθ_k| at step k, c a Gauss–Markov process (stationary σ rad/rad, correlation time τ s) the
    odometry's variances do not know: the wiggle's turns cancel, the slip does not. Returns (problem, true poses
    (T + 1, 3), true slips (T,))."""
    rng = np.random.default_rng(seed)
    block = [(0.3, 0.0, 0.0)] * 6 + [(0.0, 0.0, 0.5 * (-1) ** k) for k in range(8)]
    true_increments = np.array(block * blocks)
    steps = len(true_increments)
    truth = dead_reckoning(true_increments)
    distance, turn = np.hypot(true_increments[:, 0], true_increments[:, 1]), np.abs(true_increments[:, 2])
    variance = np.column_stack([1e-4 * distance + 1e-6, 1e-4 * distance + 1e-6, 2e-4 * turn + 1e-4 * distance + 1e-6])
    slip = gauss_markov(steps, sigma, tau, rng)
    measured = true_increments + rng.standard_normal((steps, 3)) * np.sqrt(variance)
    measured[:, 2] -= slip * turn
    landmarks = truth[::6, :2] + rng.normal(0, 1.5, (len(truth[::6]), 2))
    pose_index, landmark_index, ranges, bearings = simulated_sightings(truth, landmarks, rng)
    _, landmark_index = np.unique(landmark_index, return_inverse=True)
    s = len(ranges)
    problem = LandmarkLogProblem(measured, variance, np.array(pose_index), landmark_index, np.array(ranges),
                                 np.array(bearings), np.full(s, SIGMA_R), np.full(s, SIGMA_B),
                                 increment_seconds=np.ones(steps))
    return problem, truth, slip


def initial_guess(problem: LandmarkLogProblem):
    poses = dead_reckoning(problem.increments)
    return poses, landmarks_from_first_sightings(problem, poses)


def end_nees(problem, truth, drift) -> float:
    solution = smooth(problem, *initial_guess(problem), pose_covariance_stride=problem.n_poses, heading_drift=drift)
    assert solution.converged
    error = solution.poses[-1] - truth[-1]
    error[2] = wrap_angle(error[2])
    return float(pose_nees(error[None], solution.pose_covariances[-1:])[0])


def test_with_the_slip_states_a_wiggles_heading_is_covered_and_with_the_per_metre_drift_alone_it_is_not():
    """The end pose's NEES over 30 logs: with the slip's states (the data's own model) it follows χ²₃ (measured 30
    of 30 within, mean 3.0); with a per-metre drift instead (σ 0.05 rad/m, generous: the straight legs carry it) the
    wiggles' heading is not covered (measured 16 of 30 within, mean 9.6), and with the white model alone worse (9 of
    30, mean 32)."""
    nees = {"slip": [], "metre": [], "white": []}
    drifts = {"slip": HeadingDrift(0.0, SLIP_TAU, sigma_per_rad=SLIP_SIGMA), "metre": HeadingDrift(0.05, SLIP_TAU),
              "white": None}
    for seed in range(30):
        problem, truth, _ = wiggling_log(seed)
        for name, drift in drifts.items():
            nees[name].append(end_nees(problem, truth, drift))
    within = {name: np.mean(np.array(v) < CHI2_3_95) for name, v in nees.items()}
    assert within["slip"] >= 0.85 and np.mean(nees["slip"]) < 4.5       # χ²₃: 95 %, mean 3
    assert within["metre"] <= 0.7 and np.mean(nees["metre"]) > 6.0
    assert within["white"] <= 0.5


def test_both_processes_together_cover_the_wiggle_and_recover_the_slip():
    """Per metre and per radian together (the MRCLAM drift with the slip): the slips found follow the true ones and
    the per-metre biases stay near 0 (the data have none)."""
    problem, truth, slip = wiggling_log(seed=5)
    solution = smooth(problem, *initial_guess(problem), heading_drift=HeadingDrift(0.01, SLIP_TAU, SLIP_SIGMA))
    assert solution.converged
    assert solution.turn_biases.shape == solution.heading_biases.shape == (problem.n_poses,)
    assert np.corrcoef(solution.turn_biases, slip)[0, 1] > 0.5
    assert np.std(solution.heading_biases) < 0.5 * 0.01


def test_the_slip_solution_is_a_minimum_of_its_own_cost():
    """At the solution, Σ r² of every factor (odometry less b_k d_k + c_k |Δθ_k|, sightings, both processes' priors
    and Gauss–Markov factors) equals its χ² and rises when the poses, the biases or the slips move."""
    problem, _, _ = wiggling_log(seed=2)
    solution = smooth(problem, *initial_guess(problem), heading_drift=HeadingDrift(0.02, SLIP_TAU, SLIP_SIGMA))

    def cost(s):
        odometry, sightings, extra = normalised_residuals(problem, s)
        assert extra.shape == (2 * problem.n_poses,)
        return np.sum(odometry ** 2) + np.sum(sightings[s.inliers] ** 2) + np.sum(extra ** 2)

    best = cost(solution)
    assert best == pytest.approx(solution.chi2, rel=1e-9)
    rng = np.random.default_rng(0)
    t = problem.n_poses
    for _ in range(5):
        moved = [dataclasses.replace(solution, poses=solution.poses + np.vstack([np.zeros(3),
                                                                                  rng.normal(0, 1e-3, (t, 3))])),
                 dataclasses.replace(solution, heading_biases=solution.heading_biases + rng.normal(0, 1e-3, t)),
                 dataclasses.replace(solution, turn_biases=solution.turn_biases + rng.normal(0, 1e-3, t))]
        assert all(cost(m) > best for m in moved)


def test_a_slip_on_a_log_that_never_turns_on_the_spot_leaves_the_solution_as_it_was():
    """The slip multiplies only the turns on the spot: on the wiggling log with its wiggles made arcs (each turning
    step also moves 0.1 m: 0.2 m per radian) and on a log of circles, its states keep their priors and the poses,
    landmarks and covariances are those without it (to rounding: the factorisation has more variables)."""
    problem, _, _ = wiggling_log(seed=1)
    arcs = problem.increments.copy()
    arcs[np.abs(arcs[:, 2]) > 0, 0] = 0.1
    circles, _, _ = simulated_log(seed=1, steps=120)
    circles = dataclasses.replace(circles, increment_seconds=np.ones(circles.n_poses))
    for log in (dataclasses.replace(problem, increments=arcs), circles):
        assert not np.any(log.in_place_turns)
        plain = smooth(log, *initial_guess(log), heading_drift=HeadingDrift(0.05, SLIP_TAU))
        slipping = smooth(log, *initial_guess(log), heading_drift=HeadingDrift(0.05, SLIP_TAU, SLIP_SIGMA))
        for name in ("poses", "landmarks", "landmark_covariances", "pose_covariances", "heading_biases"):
            np.testing.assert_allclose(getattr(slipping, name), getattr(plain, name), rtol=1e-6, atol=1e-9,
                                       err_msg=name)
        np.testing.assert_allclose(slipping.turn_biases, 0.0, atol=1e-12)
        assert slipping.chi2 == pytest.approx(plain.chi2, rel=1e-6)


def test_a_slip_of_sigma_zero_is_off_and_a_malformed_one_is_refused():
    assert not HeadingDrift(0.0, 10.0, sigma_per_rad=0.0).on
    assert HeadingDrift(0.0, 10.0, sigma_per_rad=0.1).on
    problem, _, _ = wiggling_log(seed=0, blocks=3)
    solution = smooth(problem, *initial_guess(problem), heading_drift=HeadingDrift(0.0, 10.0, sigma_per_rad=0.0))
    assert solution.heading_drift is None and solution.turn_biases is None
    only_slip = smooth(problem, *initial_guess(problem), heading_drift=HeadingDrift(0.0, 10.0, sigma_per_rad=0.1))
    assert only_slip.heading_biases is None and only_slip.turn_biases.shape == (problem.n_poses,)
    for bad in (-0.1, np.nan, np.inf):
        with pytest.raises(SmoothingError, match="slip"):
            HeadingDrift(0.1, 10.0, sigma_per_rad=bad)
