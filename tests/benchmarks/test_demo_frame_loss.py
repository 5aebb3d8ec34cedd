"""benchmarks/demo_frame_loss.py: the de-biased odometry increment, the wrong-match count and the truth's NEES in a
pose cloud (the pure functions of the frame-loss diagnosis)."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from benchmarks import demo_frame_loss as dfl
from estimation.geometry import between, compose, wrap_angle


def _firmware_increment(ds: float, dtheta: float, distance_scale: float, wheelbase_scale: float) -> np.ndarray:
    """What the virtual P3-AT's firmware integrates (mocks/p3at/model.py, no noise) for a true step of ``ds`` metres
    and ``dtheta`` radians: each wheel's travel × distance_scale, the turn over the track × wheelbase_scale, the
    chord at the midpoint heading."""
    track = 0.4
    half = dtheta * track / 2.0
    ml, mr = (ds - half) * distance_scale, (ds + half) * distance_scale
    ods, odth = (ml + mr) / 2.0, (mr - ml) / (track * wheelbase_scale)
    return np.array([ods * np.cos(odth / 2), ods * np.sin(odth / 2), odth])


@settings(max_examples=200)
@given(st.floats(-0.3, 0.3), st.floats(-0.8, 0.8), st.floats(0.9, 1.1), st.floats(0.9, 1.1))
def test_unbias_gives_back_the_true_step_of_the_firmwares_integration(ds, dtheta, distance_scale, wheelbase_scale):
    measured = _firmware_increment(ds, dtheta, distance_scale, wheelbase_scale)
    true = _firmware_increment(ds, dtheta, 1.0, 1.0)
    got = dfl.unbias_increment(measured, distance_scale, wheelbase_scale)
    assert np.allclose(got, true, atol=1e-9)


def test_a_spin_measured_short_by_the_realistic_errors_is_unbiased_to_the_full_turn():
    measured = _firmware_increment(0.0, np.pi / 2, 0.99, 1.03)
    assert abs(measured[2] - np.pi / 2 * 0.99 / 1.03) < 1e-12          # 3.9 % short
    assert np.allclose(dfl.unbias_increment(measured, 0.99, 1.03), [0.0, 0.0, np.pi / 2], atol=1e-12)


@settings(max_examples=50)
@given(st.lists(st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-3, 3)), min_size=1, max_size=20),
       st.tuples(st.floats(-5, 5), st.floats(-5, 5), st.floats(-3, 3)))
def test_compose_increments_is_undone_by_between(deltas, first):
    poses = dfl.compose_increments(np.array(first), np.array(deltas))
    assert len(poses) == len(deltas) + 1
    for k, d in enumerate(deltas):
        back = between(poses[k], poses[k + 1])
        assert np.allclose(back[:2], d[:2], atol=1e-9)
        assert abs(wrap_angle(back[2] - d[2])) < 1e-9


def test_wrong_matches_counts_only_readings_far_from_their_landmarks_first_reading():
    origin = {7: np.array([0.0, 0.0, 0.0]), 8: np.array([5.0, 0.0, 0.0]), 9: np.array([np.nan] * 3)}
    matches = np.array([7, 7, 8, -1, 9, 11])
    points = np.array([[0.05, 0.0, 0.0],     # 7, 5 cm: right
                       [1.0, 0.0, 0.0],      # 7, 1 m: wrong
                       [np.nan, 0, 0],       # 8, its own truth unknown: not judged
                       [0.0, 0.0, 0.0],      # no match
                       [0.0, 0.0, 0.0],      # 9, the landmark's truth unknown: not judged
                       [0.0, 0.0, 0.0]])     # 11, no first reading known: not judged
    assert dfl.wrong_matches(matches, points, origin) == (2, 1)
    assert dfl.wrong_matches(matches, points, origin, radius=2.0) == (2, 0)


def test_pose_nees_wraps_the_heading_and_is_chi2_of_the_error():
    cov = np.diag([0.01, 0.04, 0.0001])
    truth = np.array([1.0, 2.0, np.pi - 0.005])
    pose = compose(truth, np.zeros(3)) + np.array([0.1, -0.2, 0.0])
    pose[2] = -np.pi + 0.005                           # 0.01 rad from the truth across ±π
    assert np.isclose(dfl.pose_nees(pose, truth, cov), 1.0 + 1.0 + 1.0)
    assert dfl.pose_nees(pose, truth, np.zeros((3, 3))) == float("inf")


def test_near_frames_are_those_with_more_matches_beyond_the_range_than_the_share():
    beyond = np.array([0, 20, 3, 0, 5])
    kept = np.array([60, 10, 57, 0, 5])
    assert dfl.near_frames(beyond, kept, 0.3).tolist() == [False, True, False, False, True]
    assert dfl.near_frames(beyond, kept, 0.0).tolist() == [False, True, True, False, True]
    assert not dfl.near_frames(beyond, kept, 1.0).any()


def test_group_episodes_joins_runs_less_than_the_gap_apart():
    t = np.arange(10) * 0.5
    mask = np.array([0, 1, 1, 0, 1, 0, 0, 0, 1, 0], bool)
    assert dfl.group_episodes(t, mask, gap=1.1) == [(0.5, 2.0, 3), (4.0, 4.0, 1)]
    assert dfl.group_episodes(t, mask, gap=0.6) == [(0.5, 1.0, 2), (2.0, 2.0, 1), (4.0, 4.0, 1)]
    assert dfl.group_episodes(t, np.zeros(10, bool)) == []


@settings(max_examples=50)
@given(st.tuples(st.floats(-5, 5), st.floats(-5, 5), st.floats(-3, 3)),
       st.tuples(st.floats(-2, 2), st.floats(-2, 2), st.floats(-3, 3)), st.floats(0.05, 3.0), st.floats(-0.5, 0.5))
def test_near_readings_are_those_whose_true_point_is_nearer_than_the_depth_ahead_of_the_head(start, pose, ahead,
                                                                                               lateral):
    head_x, min_depth = 0.12, 0.4875
    world = compose(np.array(start), np.array(pose))
    local = np.array([[head_x + ahead, lateral, 0.5], [head_x + 4.0, lateral, 0.5], [np.nan] * 3])
    c, s = np.cos(world[2]), np.sin(world[2])
    points = local.copy()
    points[:, 0] = world[0] + c * local[:, 0] - s * local[:, 1]
    points[:, 1] = world[1] + s * local[:, 0] + c * local[:, 1]
    rec = {"t": np.array([0.0]), "counts": np.array([3]), "start": np.array(start), "truth": np.array([pose]),
           "true_points": points}
    near = dfl.near_readings(rec, min_depth, head_x)
    assert near.tolist() == [ahead < min_depth, False, False] or abs(ahead - min_depth) < 1e-9


def test_reading_errors_scores_readings_against_their_truth_in_their_own_covariance():
    truth = np.array([[2.0, 0.0, 0.5], [0.0, 3.0, 0.5], [4.0, 0.0, 0.0], [np.nan] * 3])
    points = truth.copy()
    points[0, 0] += 0.01                    # 1 σ off
    points[1, 1] += 0.5                     # 50 σ off
    points[3] = [1.0, 1.0, 1.0]             # no truth: not scored
    cov = np.tile(np.eye(3) * 1e-4, (4, 1, 1))
    r = dfl.reading_errors(points, cov, truth)
    assert r["scored"] == 3
    assert np.isclose(r["beyond"], 1 / 3)
    assert np.isclose(r["median_error"], 0.01)
    assert np.isclose(r["true_range"], 3.0) and np.isclose(r["range"], 3.5)
    assert dfl.reading_errors(points[3:], cov[3:], truth[3:])["scored"] == 0
