"""benchmarks/mrclam_chained_names: names chained through overlapping windows by the sightings they share.

The chaining links two windows' landmarks only on a mutual clear majority of their shared sightings and names each
sighting by its core window; a merge of names is tested on the smoother's joint covariance. Synthetic windows (no
filter) check the chaining rule sighting by sighting; the real data (skipped without ../shared/data) check that a
stretch of robot 2's log is chained with few wrong sightings and that the loops it closes join names of one post.
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from benchmarks.mrclam_chained_names import (
    Window,
    chain_windows,
    close_loops,
    majority,
    naming_scores,
    path_variances,
    run_windows,
)
from estimation.datasets import read_mrclam
from estimation.fastslam import range_bearing_config
from estimation.fastslam.motion import increment_variance
from estimation.geometry import between
from estimation.noise_model import DATASET_CALIBRATIONS, estimate_noise

from .conftest import MRCLAM2


def _window(start, seconds, sightings, times, labels):
    return Window(start, seconds, np.asarray(sightings), np.asarray(times, float), np.asarray(labels),
                  map=_Rows(max(labels) + 1))


class _Rows(list):
    """A stand-in for a window map: chain_windows needs only its length."""

    def __init__(self, n):
        super().__init__(range(n))


def test_mutual_majority_links_and_a_minority_does_not():
    # window 0 covers sightings 0-7 (t 0-7 s), window 1 sightings 4-11 (t 4-11 s): the overlap is 4-7
    times = np.arange(12.0)
    w0 = _window(0.0, 8.0, range(0, 8), times[0:8], [0, 0, 1, 1, 0, 0, 1, 1])
    # in window 1, landmark 0 takes sightings 4, 5 (window 0's landmark 0: linked); landmark 1 takes one of
    # landmark 1's two overlap sightings (6) and landmark 2 the other (7): no clear majority, neither is linked
    w1 = _window(4.0, 8.0, range(4, 12), times[4:12], [0, 0, 1, 2, 0, 1, 2, 2])
    chained = chain_windows([w0, w1], 12)
    assert chained.links == 1
    assert chained.unlinked == 2
    assert chained.window_names[1][0] == chained.window_names[0][0]
    assert len({*chained.window_names[0].tolist(), *chained.window_names[1].tolist()}) == 4
    # the core window names each sighting: window 0's middle is 4 s, window 1's 8 s; sightings 0-5 are window 0's,
    # 6 is equidistant (window 0's, named first), 7-11 are window 1's
    names = chained.names
    n0, n1 = chained.window_names
    assert names[:7].tolist() == [n0[0], n0[0], n0[1], n0[1], n0[0], n0[0], n0[1]]
    assert names[7:].tolist() == [n1[2], n1[0], n1[1], n1[2], n1[2]]


def test_a_sighting_its_core_window_leaves_unnamed_takes_the_other_windows_name():
    times = np.arange(8.0)
    w0 = _window(0.0, 6.0, range(0, 6), times[0:6], [0, 0, 0, 0, 0, 0])
    w1 = _window(2.0, 6.0, range(2, 8), times[2:8], [0, 0, 0, -1, 0, 0])   # sighting 5 is unnamed in window 1
    chained = chain_windows([w0, w1], 8)
    assert chained.links == 1
    assert np.all(chained.names == chained.window_names[0][0])


def test_naming_scores_count_sightings_of_another_barcode():
    names = np.array([0, 0, 0, 1, 1, -1, 2, 2, 2, 2, 2])
    barcodes = np.array([6, 6, 7, 7, 7, 6, 6, 6, 6, 6, 6])
    assert majority(names, barcodes) == {0: 6, 1: 7, 2: 6}
    scores = naming_scores(names, barcodes)
    assert scores["wrong"] == 1 and scores["unnamed"] == 1 and scores["names"] == 3
    assert scores["names_min_sightings"] == 1 and scores["posts"] == 1      # names of fewer than 5 sightings: glimpses


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


@pytest.mark.slow
def test_mrclam_stretch_is_chained_nearly_right_and_its_loops_close_right():
    if not MRCLAM2.is_dir():
        pytest.skip("MRCLAM data set 2 is not in ../shared/data")
    log = read_mrclam(MRCLAM2, 2, until=400.0)
    noise = estimate_noise([read_mrclam(MRCLAM2, 2)], **DATASET_CALIBRATIONS).model
    config = range_bearing_config(n_particles=50)
    windows = run_windows(log, 40.0, config, noise, seed=0)
    chained = chain_windows(windows, len(log))
    scores = naming_scores(chained.names, log.landmark_ids)
    assert scores["wrong_fraction"] < 0.02
    assert chained.links > len(windows)
    owner = majority(chained.names, log.landmark_ids)
    closure = close_loops(log, chained.names, noise, config, max_rounds=5)
    merged = [pair for r in closure.rounds if r.accepted for pair in r.merged]
    assert merged                                       # 400 s: the drift is small enough for names to merge
    assert all(owner[a] == owner[b] for a, b in merged)
