"""Where a map's landmarks go in a merge (fusion.placement): the least-squares fit of its shape under the covariances
the merge uses."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.geometry import inverse, transform_points
from estimation.landmark_map import LandmarkMap
from fusion.placement import shape_placement

poses = st.tuples(st.floats(-20, 20), st.floats(-20, 20), st.floats(-3.1, 3.1)).map(np.array)


def _map(points: np.ndarray, sigma: float, robot: str) -> LandmarkMap:
    cov = np.repeat(np.diag([sigma ** 2, sigma ** 2, 1e-6])[None], len(points), 0)
    return LandmarkMap(points, cov, np.zeros((len(points), 0), np.float32), robot=robot)


@settings(max_examples=40, deadline=None)
@given(pose=poses, seed=st.integers(0, 10_000))
def test_shape_placement_recovers_the_pose_and_weighs_by_the_given_covariances(pose, seed):
    rng = np.random.default_rng(seed)
    world = np.column_stack([rng.uniform(0, 15, (20, 2)), np.zeros(20)])
    child = transform_points(inverse(pose), world)
    supports = np.column_stack([np.arange(20), np.arange(20)])
    start = pose + np.array([0.3, -0.2, 0.05])
    placed, cov = shape_placement(_map(world, 0.05, "a"), _map(child, 0.05, "b"), supports, start)
    np.testing.assert_allclose(placed[:2], pose[:2], atol=1e-6)
    assert abs(np.angle(np.exp(1j * (placed[2] - pose[2])))) < 1e-7
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    # ten landmarks of the child moved 0.5 m and claiming 10 m: the fit follows the other ten
    bent = child.copy()
    bent[:10, 0] += 0.5
    cov_child = np.repeat(np.diag([0.05 ** 2, 0.05 ** 2, 1e-6])[None], 20, 0)
    cov_child[:10, :2, :2] = np.eye(2) * 100.0
    loose = LandmarkMap(bent, cov_child, np.zeros((20, 0), np.float32), robot="b")
    placed, _ = shape_placement(_map(world, 0.05, "a"), loose, supports, pose)
    np.testing.assert_allclose(transform_points(placed, bent[10:])[:, :2], world[10:, :2], atol=0.01)


def test_one_support_fixes_no_placement():
    m = _map(np.zeros((1, 3)), 0.1, "a")
    placed, cov = shape_placement(m, m, np.array([[0, 0]]), np.array([1.0, 2.0, 0.3]))
    np.testing.assert_allclose(placed, [1.0, 2.0, 0.3])
    assert not np.any(cov)
