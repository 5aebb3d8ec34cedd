"""estimation/chained_names.py: a log's sightings named through overlapping windows, without barcodes.

Synthetic windows (no filter) check the chaining rule sighting by sighting: two windows' landmarks are linked only on
a mutual clear majority of their shared sightings, each sighting takes its core window's name, and a landmark seen
through every overlap keeps one name across the log. Synthetic logs check the windows' cut and a window map's naming
of its sightings. The real-data chain (run_windows' filter) is tested in tests/datasets/test_chained_names.py.
"""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.chained_names import (
    MIN_WINDOW_FRAMES,
    Window,
    chain_windows,
    name_sightings,
    overlapping_windows,
)
from estimation.datasets import RangeBearingLog
from estimation.landmark_map import LandmarkMap


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


@settings(max_examples=50, deadline=None)
@given(st.integers(1, 6), st.integers(1, 5), st.integers(1, 4), st.data())
def test_a_landmark_seen_through_every_overlap_keeps_one_name_and_two_landmarks_never_share_one(
        n_landmarks, n_windows, half, data):
    # every landmark is sighted once a second; windows of 2·half s every half s (each second lies in two), each
    # window's map numbering the landmarks in its own (random) order: the chain undoes the numberings
    seconds, frames = 2 * half, (n_windows + 1) * half
    sightings = np.arange(frames * n_landmarks)                 # sighting t·L + l: landmark l at t s
    times = (sightings // n_landmarks).astype(float)
    landmark = sightings % n_landmarks
    windows = []
    for k in range(n_windows):
        rows = np.flatnonzero((times >= k * half) & (times < k * half + seconds))
        order = np.asarray(data.draw(st.permutations(range(n_landmarks))))
        windows.append(_window(float(k * half), float(seconds), rows, times[rows], order[landmark[rows]].tolist()))
    chained = chain_windows(windows, len(sightings))
    assert chained.links == (n_windows - 1) * n_landmarks and chained.unlinked == 0
    assert np.all(chained.names >= 0)
    name_of = {int(l): set(chained.names[landmark == l].tolist()) for l in range(n_landmarks)}
    assert all(len(names) == 1 for names in name_of.values())
    assert len(set().union(*name_of.values())) == n_landmarks
    assert len(chained.windows) == n_windows


def test_a_landmark_re_seen_after_more_than_the_overlap_is_a_new_name():
    # windows of 8 s every 4 s (0-8, 4-12, 8-16 s); landmark 1 is seen every second, landmark 0 at 0-3 s and again
    # at 12-15 s: no overlap holds it, so nothing carries its name across (the chain's limit the loop-closing meets)
    times = np.concatenate([np.arange(16.0), [0.0, 1.0, 2.0, 3.0, 12.0, 13.0, 14.0, 15.0]])
    landmark = np.concatenate([np.ones(16, int), np.zeros(8, int)])
    order = np.lexsort((landmark, times))
    times, landmark = times[order], landmark[order]
    windows = []
    for start in (0.0, 4.0, 8.0):
        rows = np.flatnonzero((times >= start) & (times < start + 8))
        labels = landmark[rows] if np.any(landmark[rows] == 0) else np.zeros(len(rows), int)
        windows.append(_window(start, 8.0, rows, times[rows], labels.tolist()))
    chained = chain_windows(windows, len(times))
    names = chained.names
    assert np.all(names >= 0)
    assert len(set(names[landmark == 1].tolist())) == 1
    before, after = set(names[(landmark == 0) & (times < 8)].tolist()), set(names[(landmark == 0) & (times > 8)])
    assert len(before) == 1 and len(after) == 1 and before != after
    assert not (before | after) & set(names[landmark == 1].tolist())


def _log(times):
    times = np.sort(np.asarray(times, float))
    odometry_t = np.arange(np.floor(times.min()) - 1, np.ceil(times.max()) + 2, 0.5)
    odometry = np.column_stack([odometry_t, odometry_t, np.zeros((len(odometry_t), 2))])
    n = len(times)
    return RangeBearingLog("synthetic", odometry, times, np.ones(n), np.zeros(n), np.arange(n, dtype=np.int64),
                           ground_truth=odometry.copy())


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 1000).map(lambda t: t / 10), min_size=1, max_size=60), st.floats(1.0, 30.0),
       st.floats(0.2, 1.0))
def test_windows_hold_exactly_their_span_s_sightings_and_every_sighting_lies_in_one_that_has_frames(
        times, seconds, step_fraction):
    log = _log(times)
    t = log.sighting_times
    step = seconds * step_fraction
    windows = overlapping_windows(log, seconds, step)
    covered = np.zeros(len(log), bool)
    for start, rows, sub in windows:
        k = (start - t[0]) / step
        assert abs(k - round(k)) < 1e-6                     # windows start every step from the first sighting
        assert rows.tolist() == np.flatnonzero((t >= start) & (t < start + seconds)).tolist()
        assert len(np.unique(sub.sighting_times)) >= MIN_WINDOW_FRAMES
        assert np.array_equal(sub.sighting_times, t[rows]) and np.array_equal(sub.landmark_ids, log.landmark_ids[rows])
        # the odometry reaches one row either side of the window's sightings
        assert sub.odometry[0, 0] <= sub.sighting_times[0] and sub.odometry[-1, 0] >= sub.sighting_times[-1]
        covered[rows] = True
    # a sighting in no window: every window that would hold it has fewer than MIN_WINDOW_FRAMES frames
    for i in np.flatnonzero(~covered):
        for start in t[0] + step * np.arange(int((t[i] - t[0]) / step) + 2):
            if start <= t[i] < start + seconds and start <= t[-1]:
                frames = np.unique(t[(t >= start) & (t < start + seconds)])
                assert len(frames) < MIN_WINDOW_FRAMES, (start, t[i])


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 6), st.floats(-np.pi, np.pi), st.floats(-3.0, 3.0), st.floats(-3.0, 3.0), st.data())
def test_sightings_placed_on_their_landmarks_are_named_by_them_one_a_frame(n, heading, x, y, data):
    # landmarks 2 m apart on a line, their sightings exact from one pose: each falls on its own landmark; a second
    # sighting of one landmark in the same frame is left unnamed (one sighting per landmark a frame)
    positions = np.column_stack([2.0 * np.arange(n) + 5.0, np.zeros(n), np.zeros(n)])
    landmarks = LandmarkMap(positions, np.tile(np.eye(3) * 1e-4, (n, 1, 1)), np.zeros((n, 1), np.float32))
    pose = np.array([x, y, heading])
    order = np.asarray(data.draw(st.permutations(range(n))))
    rel = positions[order, :2] - pose[:2]
    ranges = np.hypot(rel[:, 0], rel[:, 1])
    bearings = np.arctan2(rel[:, 1], rel[:, 0]) - heading
    poses = np.tile(pose, (n, 1))
    sigma = np.full(n, 0.01)
    labels = name_sightings(landmarks, poses, np.zeros(n, int), ranges, bearings, sigma, sigma)
    assert labels.tolist() == order.tolist()
    twice = name_sightings(landmarks, np.tile(pose, (2, 1)), np.zeros(2, int), np.repeat(ranges[:1], 2),
                           np.repeat(bearings[:1], 2), sigma[:2], sigma[:2])
    assert sorted(twice.tolist()) == [-1, int(order[0])]
    apart = name_sightings(landmarks, np.tile(pose, (2, 1)), np.arange(2), np.repeat(ranges[:1], 2),
                           np.repeat(bearings[:1], 2), sigma[:2], sigma[:2])
    assert apart.tolist() == [int(order[0])] * 2
    far = name_sightings(landmarks, poses[:1], np.zeros(1, int), ranges[:1] + 1.0, bearings[:1], sigma[:1],
                         sigma[:1])
    assert far.tolist() == [-1]
