"""estimation/named_smoothing.py: a log smoothed under a given naming of its sightings.

The increments' variances along the odometry's path (path_variances) against stand-in logs whose odometry is a
formula; the co-visibility of names against frames of random landmark sets; the truncated cost on a problem with a
known exact solution (a dropped sighting counts at the bound, however far it is). The smoothing of real names
(smooth_named, named_problem) is tested with the real data in tests/datasets (test_constellation, test_seed_vote,
test_name_unnamed, test_fresh_start_guess).
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.fastslam import range_bearing_config
from estimation.fastslam.motion import increment_variance
from estimation.geometry import between, dead_reckoning
from estimation.landmark_smoother import OUTLIER_CHI2, LandmarkLogProblem, Smoothed
from estimation.named_smoothing import covisible_names, path_variances, truncated_cost
from estimation.noise_model import OdometryNoise


class _Odometry:
    """A log stand-in whose odometry pose at time t is ``pose(t)`` (path_variances reads only this and its command,
    here none)."""

    velocities = np.zeros((0, 3))

    def __init__(self, pose):
        self.pose = pose

    def odometry_pose(self, times):
        return np.array([self.pose(float(t)) for t in np.asarray(times, float)])


class _Uncalibrated:
    """A noise-model stand-in with no lag, no calibration (the increments as the odometry gives them), no stall term."""

    odometry = OdometryNoise(0.0, 0.0, 0.0)     # stall_sigma_s 0: no stall term

    @staticmethod
    def odometry_times(times):
        return np.asarray(times, float)

    @staticmethod
    def calibrate_increments(increments):
        return np.asarray(increments, float)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(0.01, 0.2), min_size=1, max_size=8), st.floats(-1.0, 1.0), st.floats(0.0, 0.5))
def test_path_variances_of_one_step_increments_are_the_chords(gaps, turn_rate, speed):
    # every increment shorter than the step: one step each, the random walk's variance of its chord exactly
    config = range_bearing_config()
    log = _Odometry(lambda t: np.array([speed * t, 0.1 * speed * t ** 2, turn_rate * t]))
    times = np.concatenate([[0.0], np.cumsum(gaps)])
    chord = increment_variance(between(log.odometry_pose(times)[:-1], log.odometry_pose(times)[1:]), config)
    np.testing.assert_allclose(path_variances(log, _Uncalibrated(), config, times, 0.25), chord, rtol=1e-12)


@settings(max_examples=25, deadline=None)
@given(st.floats(0.3, 3.0), st.floats(4.0, 40.0))
def test_a_spin_out_and_back_between_two_frames_carries_the_turn_it_made(amplitude, seconds):
    # the robot turns by `amplitude` and back on the spot between two sighting frames: the chord says no turn
    # (the variance floor), the path says 2·amplitude radians of turning
    config = range_bearing_config()
    log = _Odometry(lambda t: np.array([0.0, 0.0, amplitude * np.sin(np.pi * t / seconds)]))
    times = np.array([0.0, seconds])
    chord = increment_variance(between(log.odometry_pose(times)[:1], log.odometry_pose(times)[1:]), config)[0]
    path = path_variances(log, _Uncalibrated(), config, times, 0.25)[0]
    turned = config.odom_theta_var_per_rad * 2 * amplitude
    assert chord[2] < 0.01 * turned
    assert path[2] == pytest.approx(turned, rel=0.02, abs=1e-6)


@settings(max_examples=25, deadline=None)
@given(st.floats(0.05, 0.5), st.floats(2.0, 30.0))
def test_a_straight_drive_keeps_its_along_track_variance_and_gains_across_track(speed, seconds):
    # straight ahead: the along-track variance is the steps' sum (the chord's but for the floors); the heading's
    # random walk on the way swings the end sideways, which the chord's variance does not hold
    config = range_bearing_config()
    log = _Odometry(lambda t: np.array([speed * t, 0.0, 0.0]))
    times = np.array([0.0, seconds])
    chord = increment_variance(between(log.odometry_pose(times)[:1], log.odometry_pose(times)[1:]), config)[0]
    path = path_variances(log, _Uncalibrated(), config, times, 0.25)[0]
    steps = int(np.ceil(seconds / 0.25))
    assert path[0] == pytest.approx(chord[0] + (steps - 1) * config.odom_var_floor, rel=1e-9)
    assert path[1] > chord[1]
    assert path[2] == pytest.approx(chord[2] + (steps - 1) * config.odom_var_floor, rel=1e-9)


def _problem(frames: list[list[int]], n_landmarks: int, rng) -> tuple[LandmarkLogProblem, Smoothed]:
    """A robot driving 1 m a frame along x; frame k (pose k + 1) sights the landmarks ``frames[k]``, placed at random
    within 5 m; ranges and bearings exact: the true poses and landmarks are a solution of zero residuals."""
    t = len(frames)
    increments = np.tile([1.0, 0.0, 0.0], (t, 1))
    poses = dead_reckoning(increments)
    landmarks = rng.uniform(-5.0, 5.0, (n_landmarks, 2)) + [t / 2, 0.0]
    pose_index = np.array([k + 1 for k, seen in enumerate(frames) for _ in seen], int)
    landmark_index = np.array([m for seen in frames for m in seen], int)
    rel = landmarks[landmark_index] - poses[pose_index, :2]
    bearings = np.arctan2(rel[:, 1], rel[:, 0]) - poses[pose_index, 2]
    s = len(pose_index)
    problem = LandmarkLogProblem(increments, np.full((t, 3), 1e-3), pose_index, landmark_index,
                                 np.hypot(rel[:, 0], rel[:, 1]), bearings, np.full(s, 0.05), np.full(s, 0.02),
                                 np.ones(t))
    solution = Smoothed(poses, landmarks, np.tile(np.eye(2) * 1e-3, (n_landmarks, 1, 1)), np.zeros(0, int),
                        np.zeros((0, 3, 3)), np.ones(s, bool), 0.0, max(2 * s - 2 * n_landmarks, 1), 0, True)
    return problem, solution


_FRAMES = st.integers(2, 6).flatmap(lambda n: st.tuples(
    st.just(n), st.lists(st.lists(st.integers(0, n - 1), min_size=1, max_size=n, unique=True), min_size=1,
                         max_size=8)))


@settings(max_examples=50, deadline=None)
@given(_FRAMES, st.data())
def test_two_names_are_covisible_exactly_when_one_frame_sighted_both(frames_of, data):
    n, frames = frames_of
    problem, _ = _problem(frames, n, np.random.default_rng(0))
    inliers = np.asarray(data.draw(st.lists(st.booleans(), min_size=len(problem.ranges),
                                            max_size=len(problem.ranges))))
    every = covisible_names(problem, inliers, n)
    kept = covisible_names(problem, inliers, n, kept_only=True)
    kept_frames = [[m for m, keep in zip(seen, inliers[problem.pose_index == k + 1], strict=True) if keep]
                   for k, seen in enumerate(frames)]
    for i in range(n):
        for j in range(n):
            assert every[i, j] == any(i in seen and j in seen for seen in frames)
            assert kept[i, j] == any(i in seen and j in seen for seen in kept_frames)


@settings(max_examples=30, deadline=None)
@given(_FRAMES, st.integers(0, 2 ** 32 - 1), st.floats(0.005, 0.02), st.floats(50.0, 1e4))
def test_the_truncated_cost_counts_a_sighting_at_most_at_the_outlier_bound(frames_of, seed, nudge, far):
    n, frames = frames_of
    problem, exact = _problem(frames, n, np.random.default_rng(seed))
    assert truncated_cost(problem, exact) == pytest.approx(0.0, abs=1e-12)
    moved = int(problem.landmark_index[0])
    sightings_of_it = int(np.sum(problem.landmark_index == moved))
    # a landmark moved far: each of its sightings counts the bound, whether the smoother kept or dropped it
    away = exact.landmarks.copy()
    away[moved] += [far, 0.0]
    for inliers in (exact.inliers, ~exact.inliers):
        solution = dataclasses.replace(exact, landmarks=away, inliers=inliers)
        assert truncated_cost(problem, solution) == pytest.approx(sightings_of_it * OUTLIER_CHI2, rel=1e-12)
    # nudged by a centimetre or so: a cost of its own, no more than the bound for each sighting
    near = exact.landmarks.copy()
    near[moved] += [nudge, nudge]
    assert 0 < truncated_cost(problem, dataclasses.replace(exact, landmarks=near)) <= sightings_of_it * OUTLIER_CHI2
