"""estimation/named_smoothing.py: a log smoothed under a given naming of its sightings.

The increments' variances along the odometry's path (path_variances) against stand-in logs whose odometry is a
formula. The smoothing of real names (smooth_named, named_problem) is tested with the real data in tests/datasets
(test_constellation, test_seed_vote, test_name_unnamed, test_fresh_start_guess).
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.fastslam import range_bearing_config
from estimation.fastslam.motion import increment_variance
from estimation.geometry import between
from estimation.named_smoothing import path_variances


class _Odometry:
    """A log stand-in whose odometry pose at time t is ``pose(t)`` (path_variances reads only this)."""

    def __init__(self, pose):
        self.pose = pose

    def odometry_pose(self, times):
        return np.array([self.pose(float(t)) for t in np.asarray(times, float)])


class _Uncalibrated:
    """A noise-model stand-in with no lag and no calibration (the increments as the odometry gives them)."""

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
