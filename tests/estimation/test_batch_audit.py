"""Each merge group of a batch tested given the others, with its conditional offsets (estimation/batch_audit.py)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from estimation.batch_audit import group_offsets, untestable_groups, untestable_runs
from estimation.constellation import leave_one_out
from estimation.geometry import between, dead_reckoning, wrap_angle
from estimation.landmark_smoother import LandmarkLogProblem, landmarks_from_first_sightings, smooth
from estimation.map_honesty import sighting_runs


def correlated_covariance(rng: np.random.Generator, n: int, frame_sigma: float = 1.0, own_sigma: float = 0.05
                          ) -> np.ndarray:
    """(2n, 2n): a shared frame error (translation and a rotation about the origin, as a map's points share their
    start frame's) plus each point's own error: strongly correlated points, as the smoother's map gives."""
    positions = rng.uniform(-4, 4, (n, 2))
    shared = np.zeros((2 * n, 3))
    shared[0::2, 0] = 1.0
    shared[1::2, 1] = 1.0
    shared[0::2, 2] = -positions[:, 1]
    shared[1::2, 2] = positions[:, 0]
    own = rng.standard_normal((2 * n, 2 * n)) * own_sigma / np.sqrt(2 * n)
    return frame_sigma ** 2 * shared @ np.diag([1.0, 1.0, 0.05]) @ shared.T + own @ own.T + 1e-4 * np.eye(2 * n)


@st.composite
def batches(draw):
    n = draw(st.integers(5, 9))
    seed = draw(st.integers(0, 2 ** 31 - 1))
    order = draw(st.permutations(list(range(n))))
    sizes, left = [], n
    while left >= 2 and len(sizes) < 4:
        k = draw(st.integers(2, min(left, 3)))
        sizes.append(k)
        left -= k
    groups, start = [], 0
    for k in sizes:
        members = order[start:start + k]
        groups.append([(members[0], m) for m in members[1:]])
        start += k
    return n, seed, groups


@settings(max_examples=60, deadline=None)
@given(batches())
def test_the_share_is_the_guards_leave_one_out_share(batch):
    n, seed, groups = batch
    rng = np.random.default_rng(seed)
    covariance = correlated_covariance(rng, n)
    positions = rng.uniform(-4, 4, (n, 2))
    shares = group_offsets(positions, covariance, groups)
    expected = leave_one_out(positions, covariance, groups)
    assert shares.d2 == pytest.approx([d2 for d2, _ in expected], rel=1e-6, abs=1e-6)
    assert shares.dof.tolist() == [dof for _, dof in expected]
    for g, offset in enumerate(shares.offsets):
        solved = np.linalg.solve(shares.covariances[g], offset.reshape(-1))
        assert float(offset.reshape(-1) @ solved) == pytest.approx(shares.d2[g], rel=1e-6, abs=1e-6)


@settings(max_examples=30, deadline=None)
@given(batches(), st.floats(-50, 50), st.floats(-50, 50))
def test_a_common_shift_of_every_point_changes_nothing(batch, dx, dy):
    n, seed, groups = batch
    rng = np.random.default_rng(seed)
    covariance = correlated_covariance(rng, n)
    positions = rng.uniform(-4, 4, (n, 2))
    here = group_offsets(positions, covariance, groups)
    there = group_offsets(positions + [dx, dy], covariance, groups)
    assert there.d2 == pytest.approx(here.d2, rel=1e-6, abs=1e-6)
    for a, b in zip(here.offsets, there.offsets, strict=True):
        assert b == pytest.approx(a, abs=1e-6)


def test_right_groups_drawn_from_the_covariance_score_as_chi2_and_their_offsets_as_stated():
    """Points that truly are one per group, their estimates drawn from the joint covariance: each group's
    conditional offsets scatter with the stated covariance, and its d² averages its degrees of freedom."""
    rng = np.random.default_rng(3)
    n = 7
    covariance = correlated_covariance(rng, n)
    truth = np.repeat(rng.uniform(-4, 4, (3, 2)), [3, 2, 2], axis=0)      # groups {0,1,2}, {3,4}, {5,6}
    groups = [[(0, 1), (0, 2)], [(3, 4)], [(5, 6)]]
    root = np.linalg.cholesky(covariance)
    draws = 4000
    d2 = np.zeros((draws, 3))
    first = np.zeros((draws, 4))
    for k in range(draws):
        positions = truth + (root @ rng.standard_normal(2 * n)).reshape(n, 2)
        shares = group_offsets(positions, covariance, groups)
        d2[k] = shares.d2
        first[k] = shares.offsets[0].reshape(-1)
    assert d2.mean(axis=0) == pytest.approx([4.0, 2.0, 2.0], abs=0.2)
    stated = shares.covariances[0]
    assert np.cov(first.T) == pytest.approx(stated, rel=0.1, abs=0.05 * float(np.max(np.diag(stated))))


def test_a_wrong_member_shows_its_offset_where_the_map_can_test_it_and_is_untestable_where_it_cannot():
    """Two names of posts 0.73 m apart paired as one, beside a right pair: on a tight map the wrong group's offset
    is the 0.73 m and its share far beyond χ²₂; on a map whose points are 0.5 m loose each (independently) the
    same offset scores little and the group is untestable at a 0.66 m spacing, the right tight pair is not."""
    truth = np.array([[0.0, 0.0], [0.73, 0.0], [3.0, 1.0], [3.0, 1.0]])
    groups = [[(0, 1)], [(2, 3)]]
    tight = np.eye(8) * 0.02 ** 2
    shares = group_offsets(truth, tight, groups)
    assert shares.offsets[0][0] == pytest.approx([0.73, 0.0], abs=1e-9)
    assert shares.d2[0] > 500 and shares.d2[1] == pytest.approx(0.0, abs=1e-9)
    assert not untestable_groups(shares, 0.66).any()
    loose = tight.copy()
    loose[:4, :4] = np.eye(4) * 0.5 ** 2
    shares = group_offsets(truth, loose, groups)
    assert shares.d2[0] < 2.0
    assert shares.widest_sigma()[0] == pytest.approx(0.5 * np.sqrt(2))
    assert untestable_groups(shares, 0.66).tolist() == [True, False]


def test_groups_must_be_disjoint_spanning_sets():
    covariance = np.eye(8)
    positions = np.zeros((4, 2))
    with pytest.raises(ValueError, match="disjoint"):
        group_offsets(positions, covariance, [[(0, 1)], [(1, 2)]])
    with pytest.raises(ValueError, match="disjoint"):
        group_offsets(positions, covariance, [[(0, 1), (1, 0)]])


def test_a_point_without_a_finite_covariance_gives_no_share_and_is_not_called_untestable():
    covariance = np.eye(8)
    covariance[6:, 6:] = np.inf
    shares = group_offsets(np.zeros((4, 2)), covariance, [[(0, 1)], [(2, 3)]])
    assert np.isnan(shares.d2).all()
    assert not untestable_groups(shares, 0.5).any()
    with pytest.raises(ValueError):
        untestable_groups(shares, 0.0)


def glimpse_log(seed: int, loose: bool):
    """A robot driving a 2 m circle twice (1 s a step) among 8 landmarks 3.2 m from its centre and a ninth 0.7 m
    beyond landmark 5 (as MRCLAM's posts 19 and 20: the map's co-visible spacing), odometry and sightings drawn
    from the model, each sighting named by its true landmark. Over steps 200-222 of the second lap
    the robot sees nothing but one sighting of landmark 5 (step 211); with ``loose`` the odometry over that stretch is
    loose (σ 0.5 m and rad in all), as an on-the-spot turn the odometry under-reports. Returns the problem and the
    glimpse's sighting index."""
    rng = np.random.default_rng(seed)
    steps, lap, marks = 240, 120, 8
    step = np.array([2 * np.pi * 2.0 / lap, 0.0, 2 * np.pi / lap])
    truth = dead_reckoning(np.tile(step, (steps, 1)))
    angles = np.linspace(0, 2 * np.pi, marks, endpoint=False)
    landmarks = np.column_stack([3.2 * np.cos(angles), 2.0 + 3.2 * np.sin(angles)])
    landmarks = np.vstack([landmarks, [3.9 * np.cos(angles[5]), 2.0 + 3.9 * np.sin(angles[5])]])
    variance = np.tile(2e-3 * np.hypot(step[0], step[1]), (steps, 3))
    if loose:
        variance[199:222] = 0.5 ** 2 / 23
    measured = between(truth[:-1], truth[1:]) + rng.standard_normal((steps, 3)) * np.sqrt(variance)
    pose_index, index, ranges, bearings, glimpse = [], [], [], [], -1
    for k in range(1, steps + 1):
        for m in range(marks + 1):
            if 200 <= k < 222 and not (k == 211 and m == 5):
                continue
            d = landmarks[m] - truth[k, :2]
            r, b = np.hypot(d[0], d[1]), wrap_angle(np.arctan2(d[1], d[0]) - truth[k, 2])
            if not (abs(b) < 0.8 and r < 5.0):
                continue
            if k == 211:
                glimpse = len(ranges)
            pose_index.append(k)
            index.append(m)
            ranges.append(r + 0.05 * rng.standard_normal())
            bearings.append(b + 0.02 * rng.standard_normal())
    s = len(ranges)
    problem = LandmarkLogProblem(measured, variance, np.array(pose_index), np.array(index), np.array(ranges),
                                 np.array(bearings), np.full(s, 0.05), np.full(s, 0.02),
                                 increment_seconds=np.ones(steps))
    return problem, glimpse


@settings(max_examples=3, deadline=None)
@given(seed=st.integers(0, 2 ** 16))
# the tight log's glimpse dropped as an outlier by the noise draw (see below)
@example(seed=39301)
def test_a_glimpse_from_a_loose_stretch_is_the_one_untestable_run_and_from_a_tight_one_none_is(seed):
    for loose in (True, False):
        problem, glimpse = glimpse_log(seed, loose)
        assert glimpse >= 0
        poses = dead_reckoning(problem.increments)
        solution = smooth(problem, poses, landmarks_from_first_sightings(problem, poses))
        # On the tight log the glimpse is an honest sighting like any other, and the smoother drops an honest
        # sighting beyond χ²₂ 99 % (OUTLIER_CHI2) by design: asserting this one kept on every draw failed about 1 draw
        # in 1000 (seeds 39301 and 64634 of 2000: its normalised residuals (4.5, −3.6) and (5.1, 1.9) after the robust
        # solve, where the residual's χ²₂ averages 0.83; 2-4 of the log's 493 sightings are dropped on these draws;
        # session 38 (G), /tmp/G38/glimpse_margin.py). Then there is no run of it to test, and no run may be
        # untestable all the same. On the loose log the pose absorbs the glimpse (χ²₂ at most 0.44 in those 2000).
        if loose or solution.inliers[glimpse]:
            assert solution.inliers[glimpse]
            runs = sighting_runs(problem, solution, 5.0)
            assert any(glimpse in r.sightings for r in runs)      # the glimpse is a run of its landmark's
        found = untestable_runs(problem, solution)
        if loose:
            assert [r.sightings.tolist() for r in found] == [[glimpse]]
        else:
            assert found == []

