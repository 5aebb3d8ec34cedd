"""The alignment's cheaper forms of session 24 compute what the forms before them computed, bit for bit (signs of zero
included): the rotation matrices filled in place, one pose's point transform, the Gauss-Newton refinement with its
invariants hoisted and its χ² computed once, the start-frame covariance's clip, the one-to-one supports of
correspondences that share no landmark, the descriptor test of a map, and a map's self-repeat count with its
generator made only when it draws -- each against the form before it, written out here."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.geometry import rot_z, transform_points, wrap_angle
from estimation.landmark_map import LandmarkMap
from fusion.alignment import align
from fusion.alignment_config import ROBUST
from fusion.evidence import self_structure
from fusion.fingerprint import content_rng
from fusion.frame_covariance import _DIRECTIONS, _correlation_scale, start_frame_covariance
from fusion.matching import distinctive_correspondences, self_correspondences
from fusion.prior import StartPrior
from fusion.ransac import CorrespondenceProblem, has_descriptors, refine_pose, rotations_2d

SETTINGS = settings(max_examples=80, deadline=None)


def same_bits(a, b) -> bool:
    """Equal arrays of equal dtype and shape, NaN where NaN, and the same sign of every zero."""
    a, b = np.asarray(a), np.asarray(b)
    return (a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b, equal_nan=True)
            and np.array_equal(np.signbit(a), np.signbit(b)))


def reference_rotations_2d(theta):
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def reference_refine_pose(p1, P1, p2, P2, pose, floor=0.02, iterations=10):
    """Gauss-Newton as written before session 24 (every array made in every iteration, χ² in every iteration)."""
    pose = np.asarray(pose, float).copy()
    xy1, xy2 = p1[:, :2], p2[:, :2]
    H = np.eye(3)
    chi2 = 0.0
    for _ in range(iterations):
        R = reference_rotations_2d(pose[2])
        q = xy2 @ R.T
        r = xy1 - (q + pose[:2])
        S = P1[:, :2, :2] + R @ P2[:, :2, :2] @ R.T + floor ** 2 * np.eye(2)
        det = S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] * S[:, 1, 0]
        W = np.empty_like(S)
        W[:, 0, 0], W[:, 1, 1] = S[:, 1, 1] / det, S[:, 0, 0] / det
        W[:, 0, 1], W[:, 1, 0] = -S[:, 0, 1] / det, -S[:, 1, 0] / det
        J = np.zeros((len(q), 2, 3))
        J[:, 0, 0] = J[:, 1, 1] = 1.0
        J[:, 0, 2], J[:, 1, 2] = -q[:, 1], q[:, 0]
        JtW = np.einsum("kji,kjl->kil", J, W)
        H = np.einsum("kil,klm->im", JtW, J)
        g = np.einsum("kil,kl->i", JtW, r)
        chi2 = float(np.einsum("ki,kij,kj->", r, W, r))
        step = np.linalg.solve(H, g)
        pose += step
        pose[2] = wrap_angle(pose[2])
        if np.max(np.abs(step)) < 1e-10:
            break
    cov = np.linalg.inv(H)
    dof = 2 * len(p1) - 3
    if dof > 0:
        cov *= max(1.0, chi2 / dof)
    return pose, 0.5 * (cov + cov.T), chi2


def reference_correlation_scale(terms, total):
    """frame_covariance._correlation_scale before session 24 (np.clip on the one number)."""
    try:
        L = np.linalg.cholesky(total)
    except np.linalg.LinAlgError:
        return float(len(terms))
    u = np.linalg.solve(L.T, _DIRECTIONS.T).T
    _, vecs = np.linalg.eigh(total)
    u = np.vstack([u, vecs.T / np.sqrt(np.einsum("di,ij,dj->d", vecs.T, total, vecs.T))[:, None]])
    sigma = np.sqrt(np.maximum(np.einsum("di,kij,dj->dk", u, terms, u), 0.0))
    return float(np.clip(np.max(np.sum(sigma, axis=1) ** 2), 1.0, len(terms)))


angles = st.one_of(st.floats(-10.0, 10.0), st.sampled_from([0.0, -0.0, np.pi, -np.pi, np.pi / 2, 1e-300, -1e-300]))


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), shape=st.sampled_from([(), (1,), (7,), (300,), (3, 5)]), theta0=angles,
       single=st.booleans())
def test_rotations_filled_in_place_equal_the_stacked_form(seed, shape, theta0, single):
    theta = np.random.default_rng(seed).uniform(-7.0, 7.0, shape)
    theta = np.float64(theta0) if shape == () else theta
    if single:
        theta = np.asarray(theta, np.float32)
    assert same_bits(rotations_2d(theta), reference_rotations_2d(theta))


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 300), theta=angles,
       scale=st.sampled_from([0.0, 1e-3, 5.0, 1e4]))
def test_one_pose_placed_equals_transform_points(seed, n, theta, scale):
    """transform_points of one pose (rot_z's one-angle matrix, filled in) against the stacked matrices' form that the
    alignment used before session 24 (rot_z of a 1-element array): the same bits."""
    rng = np.random.default_rng(seed)
    pose = np.array([rng.uniform(-scale, scale), rng.uniform(-scale, scale), theta])
    points = rng.normal(0.0, scale + 1e-12, (n, 3))
    points[: n // 4] = 0.0                                 # zeros: the signs of the sums' zeros

    def stacked(pose, points):
        points = np.asarray(points, dtype=float)
        return points @ rot_z(np.asarray([pose[2]], float))[0].T + np.array([pose[0], pose[1], 0.0])

    assert same_bits(transform_points(pose, points), stacked(pose, points))
    if n:                                                  # lists, as transform_points takes them
        assert same_bits(transform_points(list(pose), points.tolist()), stacked(list(pose), points.tolist()))


def _supports(rng, k, diagonal, scale):
    truth = np.array([rng.uniform(-scale, scale), rng.uniform(-scale, scale), rng.uniform(-np.pi, np.pi)])
    p2 = np.column_stack([rng.uniform(-scale, scale, (k, 2)), rng.normal(0.0, 0.3, k)])
    p1 = transform_points(truth, p2) + rng.normal(0.0, 0.05, (k, 3))
    A1, A2 = rng.normal(0.0, 0.1, (k, 3, 3)), rng.normal(0.0, 0.1, (k, 3, 3))
    P1, P2 = A1 @ np.swapaxes(A1, 1, 2), A2 @ np.swapaxes(A2, 1, 2)
    if diagonal:                                          # zero off-diagonals: -0.0 weights
        P1, P2 = P1 * np.eye(3), P2 * np.eye(3)
    start = truth + rng.normal(0.0, [0.3, 0.3, 0.1])
    return p1, P1, p2, P2, start


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(0, 200), diagonal=st.booleans(),
       scale=st.sampled_from([0.5, 20.0, 3000.0]), floor=st.sampled_from([0.0, 0.02, 0.3]),
       iterations=st.sampled_from([0, 1, 3, 10]))
def test_gauss_newton_equals_the_form_before_session_24(seed, k, diagonal, scale, floor, iterations):
    p1, P1, p2, P2, start = _supports(np.random.default_rng(seed), k, diagonal, scale)
    with np.errstate(all="ignore"):
        try:
            expected = reference_refine_pose(p1, P1, p2, P2, start, floor, iterations)
        except np.linalg.LinAlgError:
            with pytest.raises(np.linalg.LinAlgError):
                refine_pose(p1, P1, p2, P2, start, floor, iterations)
            return
        got = refine_pose(p1, P1, p2, P2, start, floor, iterations)
    assert same_bits(got[0], expected[0]) and same_bits(got[1], expected[1])
    assert same_bits(np.float64(got[2]), np.float64(expected[2]))


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(1, 120), spread=st.sampled_from([1e-6, 1.0, 1e6]),
       bad=st.sampled_from([None, np.nan, np.inf]))
def test_correlation_scale_clips_as_np_clip(seed, k, spread, bad):
    rng = np.random.default_rng(seed)
    A = rng.normal(0.0, spread, (k, 3, 3))
    terms = A @ np.swapaxes(A, 1, 2)
    if rng.random() < 0.5:                                # errors moving together: a scale near k
        terms = np.repeat(terms[:1], k, axis=0)
    if bad is not None:
        terms[0, 0, 0] = bad
    total = terms.sum(axis=0)
    with np.errstate(all="ignore"):
        outcomes = []
        for scale in (_correlation_scale, reference_correlation_scale):
            try:
                outcomes.append(np.float64(scale(terms, total)))
            except np.linalg.LinAlgError as e:           # a NaN the eigen-solver refuses: refused by both
                outcomes.append(type(e))
    if isinstance(outcomes[1], type):
        assert outcomes[0] is outcomes[1]
    else:
        assert same_bits(outcomes[0], outcomes[1])


def reference_one_to_one(problem: CorrespondenceProblem, mask, pose):
    idx = np.flatnonzero(mask)
    if len(idx) == 0:
        return mask
    r = problem.p1[idx] - transform_points(pose, problem.p2[idx])
    order = idx[np.argsort(np.einsum("ki,ki->k", r, r), kind="stable")]
    _, first_i = np.unique(problem.i[order], return_index=True)
    order = order[np.sort(first_i)]
    _, first_j = np.unique(problem.j[order], return_index=True)
    keep = np.zeros_like(mask)
    keep[order[first_j]] = True
    return keep


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(0, 200), shared=st.booleans(), density=st.floats(0.0, 1.0))
def test_one_to_one_supports_equal_the_plain_form(seed, k, shared, density):
    rng = np.random.default_rng(seed)
    i = rng.integers(max(1, k // 2), size=k) if shared else rng.permutation(k)
    j = rng.integers(max(1, k // 2), size=k) if shared else rng.permutation(k) + 5
    p1, p2 = rng.normal(0.0, 3.0, (k, 3)), rng.normal(0.0, 3.0, (k, 3))
    problem = CorrespondenceProblem(p1, p2, np.zeros((k, 3, 3)), np.zeros((k, 3, 3)), i, j, np.ones(k), np.ones(k),
                                    ROBUST, distinct_scoring=True)
    mask = rng.random(k) < density
    pose = rng.normal(0.0, 1.0, 3)
    got = problem.one_to_one(mask, pose)
    assert same_bits(got, reference_one_to_one(problem, mask, pose))
    assert got is not mask or not mask.any()             # a new array whenever it holds supports, as before


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 6), size=st.sampled_from([0, 1, 8]),
       kind=st.sampled_from(["random", "equal", "last differs", "nan"]))
def test_descriptor_test_equals_the_plain_form(seed, n, size, kind):
    rng = np.random.default_rng(seed)
    d = np.tile(rng.normal(size=(1, size)).astype(np.float32), (n, 1))
    if kind == "random":
        d = rng.normal(size=(n, size)).astype(np.float32)
    elif kind == "last differs" and n and size:
        d[-1, -1] += 1.0
    elif kind == "nan" and n and size:
        d[rng.integers(n), rng.integers(size)] = np.nan
    m = LandmarkMap(np.zeros((n, 3)), np.tile(np.eye(3), (n, 1, 1)), d)
    plain = False if d.shape[1] == 0 else (len(d) < 2 or bool(np.any(d != d[0])))
    assert has_descriptors(m) == plain


def _repeating_map(seed: int, repeats: int) -> LandmarkMap:
    """A corridor of identical doors: ``repeats`` copies of a group of landmarks along x, each copy's descriptors
    the same up to noise (a self-repeat under every shift by the group's spacing)."""
    rng = np.random.default_rng(seed)
    group = rng.uniform(0.0, 4.0, (6, 3))
    desc = rng.normal(size=(6, 32))
    points = np.concatenate([group + [5.0 * c, 0.0, 0.0] for c in range(repeats)])
    d = np.concatenate([desc + rng.normal(0.0, 0.05, desc.shape) for _ in range(repeats)])
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    points = points + rng.normal(0.0, 0.02, points.shape)
    return LandmarkMap(points, np.tile(np.diag([0.01, 0.01, 0.01]), (len(points), 1, 1)), d)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("repeats", [1, 2, 4])
def test_self_repeat_without_a_generator_draws_from_the_map_s_content(seed, repeats):
    m = _repeating_map(seed, repeats)
    for config in (ROBUST, replace(ROBUST, self_repeat_gate="own")):
        for inflation in (None, 0.5, 3.0):
            assert self_structure(m, config, None, inflation) == self_structure(m, config, content_rng(m), inflation)
    if repeats == 2:        # one look-alike per landmark: enough self-matches that the generator was needed and drew
        assert len(self_correspondences(m.descriptors, ROBUST.descriptor_threshold, ROBUST.ratio)) >= 4
        assert self_structure(m, ROBUST, None) > 0


def test_rot_z_of_one_angle_is_the_matrix_filled_in():
    # rot_z fills one angle's matrix itself (no np.stack); if that changes, this says so before the exactness tests do
    theta = 0.7
    R = np.zeros((3, 3))
    R[0, 0], R[0, 1], R[1, 0], R[1, 1], R[2, 2] = np.cos(theta), -np.sin(theta), np.sin(theta), np.cos(theta), 1.0
    assert same_bits(rot_z(theta), R)


@pytest.mark.parametrize("seed", range(3))
def test_with_a_prior_the_start_covariance_is_the_supports_own(sim, seed):
    """With a start prior the winner's start-frame covariance is computed before the evidence (the prior is about the
    true starts); the alignment reports that one instead of computing it again: the same function of the same
    supports and pose, so the same bits."""
    pose = np.array([12.0, -3.0, 2.2])
    map1, map2, _ = sim.random_pair(60, 40, 50, pose, seed=seed, extent=(35.0, 10.0))
    a = align(map1, map2, "robust", np.random.default_rng(seed), prior=StartPrior.from_sigmas(pose, 1.0, 0.3))
    assert a.found and a.prior is not None
    i, j = a.supports[:, 0], a.supports[:, 1]
    expected = start_frame_covariance(map1.positions[i], map1.covariances[i], map2.positions[j],
                                      map2.covariances[j], a.pose, ROBUST.position_floor)
    assert same_bits(a.start_covariance, expected)


def test_searches_in_one_workspace_equal_searches_apart():
    """Inside search_workspace() the searches reuse one pair of distance buffers (grown when a search needs more,
    kept by a nested workspace, freed on leaving); every value read is written first, so the results are the same."""
    from fusion import matching

    rng = np.random.default_rng(3)

    def unit(n):
        d = rng.normal(size=(n, 64)).astype(np.float32)
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    a, b, c = unit(700), unit(600), unit(900)
    a[:50] = b[:50]                                       # mutual matches and exact ties
    c[:30] = c[30:60]                                     # repeats inside one map
    calls = [lambda: distinctive_correspondences(a, b, 0.9, 0.8), lambda: self_correspondences(a, 0.9, 0.8),
             lambda: self_correspondences(c, 0.9, 0.8), lambda: distinctive_correspondences(b, a, 0.9, 0.8),
             lambda: self_correspondences(unit(40), 0.9, 0.8)]       # below the workspace's size: fresh buffers
    apart = [call() for call in calls]
    with matching.search_workspace():
        together = [call() for call in calls[:2]]
        with matching.search_workspace():
            together += [call() for call in calls[2:4]]
        assert matching._WORKSPACE.buffers and matching._WORKSPACE.buffers[0].size >= 900 * 900
        together.append(calls[4]())
    assert matching._WORKSPACE.buffers is None
    for x, y in zip(apart[:4], together[:4], strict=True):
        assert same_bits(x[0] if isinstance(x, tuple) else x, y[0] if isinstance(y, tuple) else y)
    assert len(apart[0][0]) >= 50 and len(apart[2]) >= 30


@pytest.mark.parametrize("seed", range(3))
def test_both_clips_at_zero_give_the_same_neighbours(monkeypatch, seed):
    """Blocks above 2^20 distances are clipped by np.maximum, smaller ones by a mask: the same values (negatives ->
    +0.0, NaN kept), so the same neighbours, distances and mutual matches."""
    from fusion import matching

    rng = np.random.default_rng(seed)
    d = rng.normal(size=(300, 16)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    e = np.concatenate([d[:100], rng.normal(size=(150, 16)).astype(np.float32)])   # exact duplicates: d2 below 0
    e[100:] /= np.linalg.norm(e[100:], axis=1, keepdims=True)
    e[-1, 3] = np.nan
    with np.errstate(invalid="ignore"):
        by_mask = [matching._two_nearest_exact(d, e), matching._two_nearest_exact(e, e, exclude=np.arange(len(e)))]
        monkeypatch.setattr(matching, "_CLIP_BY_MASK", 0)
        by_maximum = [matching._two_nearest_exact(d, e), matching._two_nearest_exact(e, e, exclude=np.arange(len(e)))]
    for x, y in zip(by_mask, by_maximum, strict=True):
        assert all(same_bits(u, v) for u, v in zip(x, y, strict=True))
