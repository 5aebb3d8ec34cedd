"""Merging: the Kalman update is the information-form fusion; merged maps are order-independent and tighter."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from estimation.geometry import inverse, rot_z, transform_points
from estimation.landmark_map import LandmarkMap
from fusion import Alignment, NoOverlapError, align, common_landmarks, kalman_fuse, merge
from fusion.merging import transform_landmarks

finite = st.floats(-10, 10, allow_nan=False)


def _spd(raw: np.ndarray) -> np.ndarray:
    a = raw.reshape(-1, 3, 3)
    return a @ np.swapaxes(a, 1, 2) + 0.05 * np.eye(3)


@settings(max_examples=50, deadline=None)
@given(x1=arrays(float, (4, 3), elements=finite), x2=arrays(float, (4, 3), elements=finite),
       a1=arrays(float, (4, 9), elements=st.floats(-1, 1)), a2=arrays(float, (4, 9), elements=st.floats(-1, 1)))
def test_kalman_merge_equals_information_form(x1, x2, a1, a2):
    P1, P2 = _spd(a1), _spd(a2)
    x, P = kalman_fuse(x1, P1, x2, P2)
    info = np.linalg.inv(P1) + np.linalg.inv(P2)
    P_info = np.linalg.inv(info)
    x_info = np.einsum("nij,nj->ni", P_info,
                       np.einsum("nij,nj->ni", np.linalg.inv(P1), x1) + np.einsum("nij,nj->ni", np.linalg.inv(P2), x2))
    assert P == pytest.approx(P_info, abs=1e-8)
    assert x == pytest.approx(x_info, abs=1e-7)
    assert np.allclose(P, np.swapaxes(P, 1, 2))
    # the merged covariance shrinks: P1 − P and P2 − P are positive semi-definite
    assert np.all(np.linalg.eigvalsh(P1 - P) > -1e-9) and np.all(np.linalg.eigvalsh(P2 - P) > -1e-9)


def test_fused_mean_moves_toward_map_2():
    x1, x2 = np.zeros((1, 3)), np.ones((1, 3))
    P = np.eye(3)[None]
    x, _ = kalman_fuse(x1, P, x2, P)
    assert x == pytest.approx(0.5 * np.ones((1, 3)))
    x, _ = kalman_fuse(x1, 9 * P, x2, P)     # map 1 much less certain: the mean goes most of the way to map 2
    assert x == pytest.approx(0.9 * np.ones((1, 3)))


def test_map_2_covariances_are_rotated_into_map_1():
    P = np.diag([0.04, 0.0001, 0.01])[None]
    x, P_rot = transform_landmarks(np.array([[1.0, 0.0, 0.5]]), P, (2.0, 3.0, np.pi / 2))
    assert x == pytest.approx(np.array([[2.0, 4.0, 0.5]]))
    assert P_rot[0] == pytest.approx(np.diag([0.0001, 0.04, 0.01]))
    _, P_unc = transform_landmarks(np.array([[1.0, 0.0, 0.5]]), P, (2.0, 3.0, np.pi / 2), np.diag([0, 0, 0.01]))
    assert P_unc[0, 0, 0] == pytest.approx(0.0001 + 0.01)     # θ uncertainty moves a point 1 m out sideways


@pytest.fixture(scope="module")
def building(sim):
    s1, s2 = sim.building_pair(1.0, seed=4)
    return s1, s2, align(s1.map, s2.map, "robust", np.random.default_rng(0))


@pytest.mark.parametrize("method", [1, 2])
def test_merged_map_keeps_everything_once_and_records_who_saw_it(sim, building, method):
    s1, s2, a = building
    pairs = common_landmarks(s1.map, s2.map, a, method)
    assert len(np.unique(pairs[:, 0])) == len(pairs) == len(np.unique(pairs[:, 1]))
    truth = {tuple(p) for p in sim.true_common(s1, s2).tolist()}
    # Method 2 checks no descriptor, so some of its pairs are wrong (as the paper warns)
    precision = sum(tuple(p) in truth for p in pairs.tolist()) / len(pairs)
    assert precision >= (0.95 if method == 1 else 0.85)
    g = merge(s1.map, s2.map, a, method)
    assert len(g) == len(s1.map) + len(s2.map) - len(pairs)
    assert g.robots == ["robot1", "robot2"] and g.frame == s1.map.frame
    assert g.seen_by.all(axis=1).sum() == len(pairs)
    assert g.seen_by.any(axis=1).all()
    assert np.allclose(np.linalg.norm(g.descriptors, axis=1), 1.0, atol=1e-5)
    assert len(np.unique(g.ids)) == len(g)
    # common landmarks: covariance shrinks, merged position nearer the truth on average
    rows = pairs[:, 0]
    assert np.all(np.trace(g.covariances[rows], axis1=1, axis2=2) < np.trace(s1.map.covariances[rows], axis1=1,
                                                                               axis2=2))
    correct = np.array([tuple(p) in truth for p in pairs.tolist()])
    rows = pairs[correct, 0]
    start = np.asarray(s1.map.metadata["true_start_pose"])
    true_local = transform_points(inverse(start), sim.load_world().features[s1.feature_index[rows]])
    before = np.linalg.norm(s1.map.positions[rows] - true_local, axis=1).mean()
    after = np.linalg.norm(g.positions[rows] - true_local, axis=1).mean()
    assert after < before
    # map-1-only landmarks are untouched; the merged map round-trips through its file format
    only1 = np.setdiff1d(np.arange(len(s1.map)), pairs[:, 0])
    assert np.array_equal(g.positions[only1], s1.map.positions[only1])


def test_merged_map_saves_and_loads(tmp_path, building):
    s1, s2, a = building
    g = merge(s1.map, s2.map, a, 1)
    g.save(tmp_path / "g.npz")
    back = LandmarkMap.load(tmp_path / "g.npz")
    assert np.array_equal(back.seen_by, g.seen_by) and back.robots == g.robots


def test_method_2_finds_at_least_the_true_common_landmarks_it_can(sim, building):
    s1, s2, a = building
    n1 = len(common_landmarks(s1.map, s2.map, a, 1))
    n2 = len(common_landmarks(s1.map, s2.map, a, 2, gate=0.5))
    assert n2 >= 0.8 * n1 > 0


def test_merging_does_not_depend_on_which_map_comes_first(sim):
    map1, map2, _ = sim.random_pair(40, 60, 70, (3.0, -1.0, 2.0), seed=2)
    a12 = align(map1, map2, "robust", np.random.default_rng(0))
    a21 = a12.inverse()
    # without the alignment's uncertainty the two orders give the same map exactly (up to the frame)
    g12 = merge(map1, map2, a12, 1, use_alignment_covariance=False)
    g21 = merge(map2, map1, a21, 1, use_alignment_covariance=False)
    x, P = transform_landmarks(g21.positions, g21.covariances, a12.pose)
    order12 = np.lexsort(np.round(g12.positions, 6).T)
    order21 = np.lexsort(np.round(x, 6).T)
    assert len(g12) == len(g21)
    assert g12.positions[order12] == pytest.approx(x[order21], abs=1e-6)
    assert g12.covariances[order12] == pytest.approx(P[order21], abs=1e-9)
    # with it, each order trusts the other map a little less: nearly the same map
    g12 = merge(map1, map2, a12, 1)
    g21 = merge(map2, map1, a21, 1)
    x, _ = transform_landmarks(g21.positions, g21.covariances, a12.pose)
    d = np.linalg.norm(g12.positions[:, None, :] - x[None, :, :], axis=2).min(axis=1)
    assert np.all(d < 0.02)


def test_merge_refuses_a_missing_alignment(sim):
    map1, map2, _ = sim.random_pair(0, 50, 50, (0, 0, 0), seed=1)
    a = align(map1, map2, "robust", np.random.default_rng(0))
    assert not a.found
    with pytest.raises(NoOverlapError):
        merge(map1, map2, a)


def test_given_alignment_merges_by_position():
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 10, (30, 3))
    pose = np.array([1.0, 2.0, 0.3])
    desc = rng.standard_normal((30, 64)).astype(np.float32)
    cov = np.repeat(np.eye(3)[None] * 1e-4, 30, 0)
    m1 = LandmarkMap(pts, cov, desc, robot="a")
    m2 = LandmarkMap((pts - [pose[0], pose[1], 0]) @ rot_z(pose[2]), cov, desc, robot="b")
    g = merge(m1, m2, Alignment.from_pose(pose), method=2)
    assert len(g) == 30 and g.seen_by.all()
    assert g.positions == pytest.approx(pts, abs=1e-9)
    assert g.counts.tolist() == [2] * 30
