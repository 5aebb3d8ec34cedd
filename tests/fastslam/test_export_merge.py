"""Coincident landmarks merged in the exported map (``export_merge_coincident``, export_merge.py)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.fastslam import FastSLAM, FastSLAMConfig
from estimation.fastslam.export_merge import CHI2_3_95, coincident_pairs, merge_coincident
from estimation.landmark_map import LandmarkMap
from estimation.observations import StereoObservations


def _d2(a, b, covariance) -> float:
    d = np.asarray(a, float) - b
    return float(d @ np.linalg.solve(covariance, d))


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2 ** 32 - 1), st.integers(2, 30), st.floats(0.01, 0.5))
def test_coincident_pairs_are_disjoint_passing_and_leave_no_passing_pair_behind(seed, n, spread):
    rng = np.random.default_rng(seed)
    positions = rng.uniform(-1, 1, (n, 3)) * spread * 5
    roots = rng.normal(0, spread, (n, 3, 3))
    covariances = roots @ roots.transpose(0, 2, 1) + np.eye(3) * 1e-6
    pairs = coincident_pairs(positions, covariances)
    assert len(np.unique(pairs)) == pairs.size and np.all(pairs[:, 0] < pairs[:, 1])
    for i, j in pairs:
        assert _d2(positions[i], positions[j], covariances[i] + covariances[j]) < CHI2_3_95
    alone = np.setdiff1d(np.arange(n), pairs)
    for a in alone:                      # greedy, but maximal: two unpaired landmarks never pass
        for b in alone[alone > a]:
            assert _d2(positions[a], positions[b], covariances[a] + covariances[b]) >= CHI2_3_95


def _map(positions, covariances, counts) -> LandmarkMap:
    n = len(positions)
    return LandmarkMap(np.array(positions, float), np.array(covariances, float), np.eye(n, 64, dtype=np.float32),
                       ids=np.array([7, 3, 9, 20][:n]), counts=np.array(counts), robot="robot1", frame="start")


def test_a_point_made_three_times_becomes_one_landmark_that_covers_all_three():
    cov = np.eye(3) * 0.05 ** 2
    estimates = [[1.00, 0.0, 0.5], [1.03, 0.01, 0.5], [0.98, -0.02, 0.52], [3.0, 1.0, 0.5]]
    landmark_map = _map(estimates, [cov] * 4, [4, 10, 2, 6])
    merged = merge_coincident(landmark_map, landmark_map.covariances)
    assert merged.ids.tolist() == [3, 20]                  # the oldest of the three keeps its id
    assert merged.counts.tolist() == [16, 6]
    np.testing.assert_allclose(merged.positions[0], np.average(estimates[:3], axis=0, weights=[4, 10, 2]))
    np.testing.assert_array_equal(merged.positions[1], estimates[3])          # the distinct point untouched
    assert np.all(np.linalg.eigvalsh(merged.covariances[0] - cov) >= -1e-15)  # never narrower than one estimate
    assert sorted(merged.metadata["merged_at_export"]) == sorted([[3, 7], [3, 9]])
    np.testing.assert_array_equal(merged.descriptors[0], landmark_map.descriptors[1])


@settings(max_examples=60, deadline=None)
@given(st.floats(0.0, 0.3), st.floats(0.05, 0.3), st.integers(1, 50), st.integers(1, 50))
def test_a_merge_of_two_close_points_covers_both_estimates(separation, sigma, count_a, count_b):
    """If the two were two points, the mixture still covers each estimate: d² ≤ w_other / w_own."""
    cov = np.eye(3) * sigma ** 2
    landmark_map = _map([[0, 0, 0], [separation, 0, 0]], [cov, cov], [count_a, count_b])
    merged = merge_coincident(landmark_map, landmark_map.covariances)
    if len(merged) == 2:
        assert _d2(landmark_map.positions[0], landmark_map.positions[1], 2 * cov) >= CHI2_3_95
        return
    wa = count_a / (count_a + count_b)
    for position, own in ((landmark_map.positions[0], wa), (landmark_map.positions[1], 1 - wa)):
        assert _d2(position, merged.positions[0], merged.covariances[0]) <= (1 - own) / own + 1e-9


def test_landmarks_apart_under_their_own_covariances_are_left_as_they_are():
    tight = np.eye(3) * 0.01 ** 2
    landmark_map = _map([[0, 0, 0], [0.1, 0, 0]], [tight, tight], [3, 3])
    assert merge_coincident(landmark_map, landmark_map.covariances) is landmark_map
    # the exported covariances may be wide (the frame's drift): the test is on the conditional ones
    wide = _map([[0, 0, 0], [0.1, 0, 0]], [np.eye(3)] * 2, [3, 3])
    assert len(merge_coincident(wide, np.array([tight, tight]))) == 2


def _frame(points, looks, t: float) -> StereoObservations:
    n = len(points)
    return StereoObservations(np.array(points, float), np.tile(np.eye(3) * 0.03 ** 2, (n, 1, 1)),
                              np.array(looks, np.float32), timestamp=t)


@pytest.mark.parametrize("merge", [False, True])
def test_the_export_merges_a_corner_the_filter_made_twice(merge):
    """One corner whose look changes beyond the association's and the merge's thresholds (as U-SURF does with the
    range): the filter makes it twice and keeps both; the exported map holds it once with the option."""
    rng = np.random.default_rng(2)
    first, second, other = (v / np.linalg.norm(v) for v in rng.standard_normal((3, 64)))
    slam = FastSLAM(FastSLAMConfig(n_particles=3, max_observations=0, export_merge_coincident=merge),
                    np.random.default_rng(0))
    corner, far = [2.0, 0.3, 0.4], [3.0, -1.0, 0.2]
    for k in range(4):
        slam.update(_frame([corner, far], [first, other], 0.1 * k))
    for k in range(4, 8):
        slam.update(_frame([corner, far], [second, other], 0.1 * k))
    exported = slam.best_map()
    near_corner = np.linalg.norm(exported.positions - corner, axis=1) < 0.1
    assert near_corner.sum() == (1 if merge else 2)
    assert np.sum(np.linalg.norm(exported.positions - far, axis=1) < 0.1) == 1
    assert ("merged_at_export" in exported.metadata) == merge
