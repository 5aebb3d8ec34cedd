"""The alignment's cheaper forms (session 23) compute what the plain forms before them computed, bit for bit: the
support masks (in place, screened by a matrix product), the one-to-one counts, the descriptors' nearest neighbours
and the rival's shift -- against those plain forms, written out here, on random maps and poses."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from fusion.alignment_config import PAPER, ROBUST
from fusion.evidence import rms_shift
from fusion.matching import distinctive_correspondences, self_correspondences, two_nearest
from fusion.ransac import CorrespondenceProblem, rotations_2d

SETTINGS = settings(max_examples=60, deadline=None)


def reference_masks(problem: CorrespondenceProblem, poses: np.ndarray) -> np.ndarray:
    """The support masks as the broadcast form computed them before session 23."""
    c, s = np.cos(poses[:, 2:3]), np.sin(poses[:, 2:3])
    x, y = problem.p2[None, :, 0], problem.p2[None, :, 1]
    rx = problem.p1[None, :, 0] - (c * x - s * y + poses[:, 0:1])
    ry = problem.p1[None, :, 1] - (s * x + c * y + poses[:, 1:2])
    r_xy_sq = rx * rx + ry * ry
    dz_sq = (problem.p1[:, 2] - problem.p2[:, 2]) ** 2
    if problem.config.covariance_gating:
        return (r_xy_sq < problem.gate_xy_sq) & (dz_sq < problem.gate_z_sq)[None, :]
    return r_xy_sq + dz_sq[None, :] < problem.config.support_threshold ** 2


def reference_counts(problem: CorrespondenceProblem, masks: np.ndarray) -> np.ndarray:
    """One-to-one counts: the fewer distinct landmarks of either map among each row's supports."""
    return np.array([min(len(set(problem.i[m].tolist())), len(set(problem.j[m].tolist()))) for m in masks], np.int64)


def random_problem(seed: int, k: int, scale: float, shared: bool, paper: bool, inflation: float):
    """Correspondences of which about half agree with one transform (so its neighbourhood gives dense masks) and a
    quarter of those lie on their gate's edge under it (|r|² equal to the gate to a few units in the last place:
    any other order of the operations moves some across), landmarks shared between correspondences or not,
    heights inside and outside their gate; the true pose is returned too."""
    rng = np.random.default_rng(seed)
    truth = np.array([rng.uniform(-scale, scale), rng.uniform(-scale, scale), rng.uniform(-np.pi, np.pi)])
    p2 = np.column_stack([rng.uniform(-scale, scale, (k, 2)), rng.normal(0.0, 0.3, k)])
    R = rotations_2d(truth[2])
    p1 = np.column_stack([p2[:, :2] @ R.T + truth[:2], p2[:, 2]])
    p1[:, :2] += rng.normal(0.0, rng.uniform(0.01, 0.6), (k, 2))
    p1[:, 2] += rng.normal(0.0, 0.4, k)
    wrong = rng.random(k) < 0.5
    p1[wrong, :2] = rng.uniform(-2 * scale, 2 * scale, (int(wrong.sum()), 2))
    n = max(1, k // 3) if shared else k
    i = rng.integers(n, size=k) if shared else rng.permutation(k)
    j = rng.integers(n, size=k) if shared else rng.permutation(k)
    var_xy, var_z = rng.uniform(0.0004, 0.2, k), rng.uniform(0.0004, 0.2, k)
    zeros = np.zeros((k, 3, 3))
    config = PAPER if paper else ROBUST

    def build() -> CorrespondenceProblem:
        return CorrespondenceProblem(p1, p2, zeros, zeros, i, j, var_xy, var_z, config, distinct_scoring=True,
                                     inflation=inflation)

    edge = ~wrong & (rng.random(k) < 0.25)
    gate = build().gate_xy_sq if config.covariance_gating else np.full(k, config.support_threshold ** 2)
    angle = rng.uniform(-np.pi, np.pi, int(edge.sum()))
    offset = np.sqrt(gate[edge])[:, None] * np.column_stack([np.cos(angle), np.sin(angle)])
    p1[edge, :2] = p2[edge, :2] @ R.T + truth[:2] + offset
    p1[edge, 2] = p2[edge, 2]
    return build(), truth, rng


def hypotheses(rng: np.random.Generator, problem: CorrespondenceProblem, truth: np.ndarray, near: int, decoys: int):
    """Poses around the truth (most supports, residuals at the gate) and decoys anchored on a landmark pair."""
    around = truth + rng.normal(0.0, [0.05, 0.05, 0.005], (near, 3))
    theta = rng.uniform(-np.pi, np.pi, decoys)
    a, b = rng.integers(len(problem.i), size=decoys), rng.integers(len(problem.i), size=decoys)
    t = problem.p1[a, :2] - np.einsum("hij,hj->hi", rotations_2d(theta), problem.p2[b, :2])
    return np.concatenate([truth[None], around, np.column_stack([t, theta])])


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(1, 300), scale=st.sampled_from([0.5, 5.0, 40.0, 400.0, 5000.0]),
       shared=st.booleans(), paper=st.booleans(), inflation=st.floats(0.01, 30.0),
       near=st.sampled_from([0, 1, 15, 16, 17, 300]), decoys=st.sampled_from([0, 1, 16, 200, 1500]))
def test_masks_and_counts_equal_the_plain_forms(seed, k, scale, shared, paper, inflation, near, decoys):
    problem, truth, rng = random_problem(seed, k, scale, shared, paper, inflation)
    poses = hypotheses(rng, problem, truth, near, decoys)
    masks = problem.masks(poses)
    expected = reference_masks(problem, poses)
    assert masks.shape == expected.shape and np.array_equal(masks, expected)
    assert np.array_equal(problem.distinct_counts(masks), reference_counts(problem, expected))
    wider = problem.inflated(inflation * 3.0)          # the gates change with the scale; the cached parts do not
    assert np.array_equal(wider.masks(poses), reference_masks(wider, poses))


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), h=st.integers(1, 400), k=st.integers(1, 200), density=st.sampled_from(
    [0.0, 0.001, 0.02, 0.06, 0.5, 1.0]), shared=st.integers(1, 200))
def test_one_to_one_counts_of_any_masks_equal_the_plain_count(seed, h, k, density, shared):
    rng = np.random.default_rng(seed)
    i, j = rng.integers(shared, size=k), rng.integers(max(1, shared // 2), size=k)
    zeros = np.zeros((k, 3))
    problem = CorrespondenceProblem(zeros, zeros, np.zeros((k, 3, 3)), np.zeros((k, 3, 3)), i, j, np.ones(k),
                                    np.ones(k), ROBUST, distinct_scoring=True)
    masks = rng.random((h, k)) < density
    assert np.array_equal(problem.distinct_counts(masks), reference_counts(problem, masks))
    unique = replace(problem, i=np.arange(k), j=rng.permutation(k))
    assert np.array_equal(unique.distinct_counts(masks), masks.sum(axis=1))


def reference_two_nearest(queries: np.ndarray, base: np.ndarray, exclude: np.ndarray | None = None):
    """The descriptors' two nearest neighbours and each base row's nearest query as computed before session 23."""
    q, b = queries.astype(np.float32), base.astype(np.float32)
    d2 = np.einsum("ij,ij->i", q, q)[:, None] + np.einsum("ij,ij->i", b, b)[None, :] - 2.0 * (q @ b.T)
    np.maximum(d2, 0.0, out=d2)
    r = np.arange(len(q))
    if exclude is not None:
        d2[r, exclude] = np.inf
    back = np.argmin(d2, axis=0)
    back[~(d2[back, np.arange(len(b))] < np.inf)] = 0
    first = np.argmin(d2, axis=1)
    dist = [np.sqrt(d2[r, first])]
    d2[r, first] = np.inf
    second = np.argmin(d2, axis=1)
    index = np.column_stack([first, second])
    dist = np.column_stack(dist + [np.sqrt(d2[r, second])]).astype(float)
    return index, dist, back


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), nq=st.integers(3, 120), nb=st.integers(2, 120), dim=st.sampled_from([2, 8, 64]),
       copies=st.integers(0, 40))
def test_descriptor_neighbours_equal_the_plain_form(seed, nq, nb, dim, copies):
    rng = np.random.default_rng(seed)
    desc1 = rng.normal(size=(nq, dim)).astype(np.float32)
    desc2 = rng.normal(size=(nb, dim)).astype(np.float32)
    desc2 /= np.linalg.norm(desc2, axis=1, keepdims=True)
    n = min(copies, nq)                                   # exact copies: ties, and round-off below zero
    desc1[:n] = desc2[rng.integers(nb, size=n)]
    desc1 /= np.linalg.norm(desc1, axis=1, keepdims=True)
    index, dist, back = reference_two_nearest(desc1, desc2)
    got_index, got_dist = two_nearest(desc1, desc2)
    assert np.array_equal(got_index, index) and np.array_equal(got_dist, dist)
    pairs, _ = distinctive_correspondences(desc1, desc2, 0.9, 0.8)
    keep = (dist[:, 0] < 0.9) & (dist[:, 0] < 0.8 * dist[:, 1])
    rows = np.flatnonzero(keep)
    mutual = back[index[rows, 0]] == rows
    assert np.array_equal(pairs, np.column_stack([rows[mutual], index[rows[mutual], 0]]))
    s_index, s_dist, _ = reference_two_nearest(desc1, desc1, np.arange(nq))
    s_keep = (s_dist[:, 0] < 0.9) & (s_dist[:, 0] < 0.8 * s_dist[:, 1])
    assert np.array_equal(self_correspondences(desc1, 0.9, 0.8),
                          np.column_stack([np.flatnonzero(s_keep), s_index[s_keep, 0]]))


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), h=st.integers(1, 300), k=st.integers(1, 300),
       scale=st.sampled_from([0.1, 10.0, 1000.0]))
def test_rival_shift_equals_the_plain_form(seed, h, k, scale):
    rng = np.random.default_rng(seed)
    poses = np.column_stack([rng.uniform(-scale, scale, (h, 2)), rng.uniform(-np.pi, np.pi, h)])
    points, reference = rng.uniform(-scale, scale, (k, 3)), rng.uniform(-scale, scale, (k, 2))
    moved = np.einsum("hij,kj->hki", rotations_2d(poses[:, 2]), points[:, :2]) + poses[:, None, :2]
    expected = np.sqrt(np.mean(np.sum((moved - reference[None]) ** 2, axis=2), axis=1))
    assert np.array_equal(rms_shift(poses, points, reference), expected)


def test_masks_with_a_coordinate_not_finite_equal_the_plain_form():
    problem, truth, rng = random_problem(7, 120, 40.0, False, False, 1.0)
    for bad in (np.nan, np.inf):
        p1 = problem.p1.copy()
        p1[3, 0] = bad
        broken = CorrespondenceProblem(p1, problem.p2, problem.P1, problem.P2, problem.i, problem.j, problem.var_xy,
                                       problem.var_z, problem.config, distinct_scoring=True)
        poses = hypotheses(rng, broken, truth, 20, 300)
        with np.errstate(invalid="ignore"):          # inf − inf, in both forms
            masks, expected = broken.masks(poses), reference_masks(broken, poses)
        assert np.array_equal(masks, expected)
        assert masks[:, 3].sum() == 0 and masks.sum() > 0
