"""benchmarks/rendered_duplicates.py's pieces that score the exported map: the scorer's clusters redone at any radius
(the same as eval_slam_rendered's at its own), the export's merge chains, and the scorer-independent count."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from benchmarks.eval_slam_rendered import SNAP, RenderedObserver
from benchmarks.rendered_duplicates import export_groups, same_point_duplicates, snap_clusters

coordinate = st.floats(-0.3, 0.3, allow_nan=False)
points_strategy = st.lists(st.tuples(coordinate, coordinate, coordinate), min_size=1, max_size=60)


def _eval_clusters(points: np.ndarray) -> np.ndarray:
    """eval_slam_rendered's own clustering of the true points, in order (its observer without a renderer)."""
    observer = RenderedObserver.__new__(RenderedObserver)
    observer._cell_index, observer._points = {}, []
    return np.array([observer._point_index(p) for p in points], np.int64)


@settings(max_examples=60, deadline=None)
@given(points_strategy)
def test_snap_clusters_are_the_scorers_at_its_radius(raw):
    points = np.array(raw, float)
    assert np.array_equal(snap_clusters(points, SNAP), _eval_clusters(points))


@settings(max_examples=60, deadline=None)
@given(points_strategy, st.sampled_from([0.02, 0.03, 0.05]))
def test_snap_clusters_hold_their_points_and_keep_their_firsts_apart(raw, snap):
    points = np.array(raw, float)
    clusters = snap_clusters(points, snap)
    first = {c: points[np.flatnonzero(clusters == c)[0]] for c in np.unique(clusters)}
    for p, c in zip(points, clusters, strict=True):
        assert np.linalg.norm(p - first[c]) < snap + 1e-12
    firsts = np.array(list(first.values()))
    gaps = np.linalg.norm(firsts[:, None] - firsts[None], axis=2)[np.triu_indices(len(firsts), 1)]
    assert np.all(gaps >= snap - 1e-12)


def test_snap_clusters_skip_points_without_truth():
    points = np.array([[0.0, 0.0, 0.0], [np.nan, np.nan, np.nan], [0.01, 0.0, 0.0], [0.2, 0.0, 0.0]])
    assert snap_clusters(points, 0.05).tolist() == [0, -1, 0, 1]


def test_export_groups_follow_merges_over_rounds():
    # round 1: 3 absorbs 7, 5 absorbs 9; round 2: 3 absorbs 5 (which holds 9 already)
    groups = export_groups([1, 3, 4], [(3, 7), (5, 9), (3, 5)])
    assert groups == {1: {1}, 3: {3, 5, 7, 9}, 4: {4}}


@settings(max_examples=40, deadline=None)
@given(points_strategy, st.floats(0.001, 0.1))
def test_same_point_duplicates_count_chains(raw, radius):
    points = np.array(raw, float)
    n = same_point_duplicates(points, radius)
    assert 0 <= n < len(points) or len(points) == 1 and n == 0
    assert same_point_duplicates(np.vstack([points, points]), radius) == n + len(points)   # every point twice
