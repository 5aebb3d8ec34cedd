"""The warm starts that make an iteration cheap give exactly what a cold query gives.

WarmNearest re-queries the k-d tree only for points that moved past their margin, and Polyline.project with a
NearestVertexCache re-gathers only those points' candidate segments; both must agree with a fresh query at every
step of a random walk that mixes tiny moves (the converging iterations) with large ones (the first iterations).
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from estimation.scanmatch import Polyline, laser_scan, match_scans
from estimation.scanmatch.common import apply_pose
from estimation.scanmatch.nearest import NearestPoint, WarmNearest
from estimation.scanmatch.polyline import NearestVertexCache

POSE = np.array([0.2, -0.4, 0.3])


def random_walk(points: np.ndarray, rng: np.random.Generator, steps: int = 40):
    """Successive (N, 2) positions of the points under rigid moves of random size (1e-5 m to 0.3 m)."""
    pose = np.zeros(3)
    for _ in range(steps):
        size = 10.0 ** rng.uniform(-5.0, -0.5)
        pose = pose + rng.normal(0.0, size, 3) * np.array([1.0, 1.0, 0.3])
        yield apply_pose(pose, points) + rng.normal(0.0, 1e-3, points.shape) * (rng.random() < 0.2)


@pytest.mark.parametrize("k", [1, 2, 3])
def test_warm_nearest_agrees_with_a_fresh_tree_query(k):
    rng = np.random.default_rng(k)
    reference = rng.uniform(-5.0, 5.0, (150, 2))
    tree = cKDTree(reference)
    warm = WarmNearest(tree, k)
    queried = []
    for queries in random_walk(rng.uniform(-5.0, 5.0, (120, 2)), rng):
        queried.append(warm.update(np.ascontiguousarray(queries).view(np.complex128)[:, 0]).size)
        _, fresh = tree.query(queries, k=k)
        np.testing.assert_array_equal(np.sort(warm.nearest, axis=1), np.sort(fresh.reshape(-1, k), axis=1))
    assert queried[0] == 120 and min(queried) < 120   # it did skip queries, or this test tests nothing


def test_nearest_point_is_bit_identical_to_the_tree_query():
    """ICP and PL-ICP rely on it: the same index and the very same distance bits as cKDTree.query."""
    rng = np.random.default_rng(7)
    reference = rng.uniform(-5.0, 5.0, (180, 2))
    tree = cKDTree(reference)
    nearest = NearestPoint(reference)
    for queries in random_walk(rng.uniform(-5.0, 5.0, (150, 2)), rng):
        distance, index = nearest(queries)
        fresh_distance, fresh_index = tree.query(queries)
        np.testing.assert_array_equal(index, fresh_index)
        np.testing.assert_array_equal(distance, fresh_distance)


def test_projection_with_a_warm_cache_is_identical_to_a_cold_one(laser):
    rng = np.random.default_rng(3)
    scan = laser_scan(laser(POSE))
    curve = Polyline(scan, gap=0.5)
    cache = NearestVertexCache()
    for queries in random_walk(scan.points + rng.normal(0.0, 0.05, scan.points.shape), rng):
        warm, cold = curve.project(queries, cache), curve.project(queries)
        for field in ("point", "arc", "distance", "normal", "vertex"):
            np.testing.assert_array_equal(getattr(warm, field), getattr(cold, field), err_msg=field)
        _, nearest = cKDTree(scan.points).query(queries)
        np.testing.assert_array_equal(warm.vertex, nearest)


def test_a_tiny_reference_needs_no_margin():
    """With no more reference points than asked for, every point is always among the nearest."""
    tree = cKDTree(np.array([[0.0, 0.0], [1.0, 0.0]]))
    warm = WarmNearest(tree, 2)
    for x in (0.0, 5.0, -3.0):
        queries = np.array([x + 0.5j, x - 2.0j])
        warm.update(queries)
        np.testing.assert_array_equal(np.sort(warm.nearest, axis=1), [[0, 1], [0, 1]])
    assert warm.update(np.array([9.0 + 0j, 0j])).size == 0


def test_matching_twice_gives_the_same_result(laser):
    """No state leaks between matches (each match has its own warm start)."""
    a, b = laser_scan(laser(POSE)), laser_scan(laser(np.array([0.5, -0.2, 0.4])))
    for method in ("eicp", "icp", "plicp"):
        first, second = match_scans(a, b, method), match_scans(a, b, method)
        np.testing.assert_array_equal(first.pose, second.pose)
        np.testing.assert_array_equal(first.covariance, second.covariance)
