"""Alignment: recovers known transforms, refuses non-overlapping maps, follows the paper where it should."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from estimation.chi2 import isf as chi2_isf
from estimation.geometry import transform_points, wrap_angle
from estimation.landmark_map import LandmarkMap
from fusion import (
    PAPER,
    ROBUST,
    Alignment,
    IncompatibleMapsError,
    NoOverlapError,
    align,
    alignment_error,
    true_relative_pose,
)
from fusion.matching import nearest_correspondences
from fusion.ransac import pair_hypotheses, refine_pose

poses = st.tuples(st.floats(-30, 30), st.floats(-30, 30), st.floats(-np.pi + 1e-6, np.pi - 1e-6))
# robot 2 starting inside the mapped area (35 × 10 m), as robots do
near_poses = st.tuples(st.floats(0, 35), st.floats(0, 10), st.floats(-np.pi + 1e-6, np.pi - 1e-6))
# The truth's Mahalanobis distance under the alignment's covariance is a random draw (χ²₃ if the covariance is
# honest): asserting it below a quantile on every Hypothesis example fails by chance at that quantile's tail. At
# χ²₃ 99.99 % (21.1) it failed 1 of 20,000 draws of the best-fit test's (seed, pose) (the map noise's own draw:
# 21.6 at seed 2390; session 38 (G), /tmp/G38/align_emu.py). A per-example bound is held at RARE = 1e-6 (30.7);
# the covariance's rate is asserted on fixed seeds by test_alignment_covariance_is_consistent.
RARE = 1e-6


@settings(max_examples=25, deadline=None)
@given(pose=near_poses, seed=st.integers(0, 10_000))
def test_robust_recovers_a_known_transform_from_noisy_maps(sim, pose, seed):
    map1, map2, common = sim.random_pair(50, 120, 150, pose, seed=seed, sigma=0.03)
    a = align(map1, map2, "robust", np.random.default_rng(seed))
    assert a.found, a.reason
    err = alignment_error(a.pose, pose)
    assert err[0] < 0.05 and err[1] < 0.05 and err[2] < 0.01, err
    # the supports are true common landmarks
    true_pairs = {tuple(p) for p in common.tolist()}
    assert sum(tuple(p) in true_pairs for p in a.supports.tolist()) >= 0.95 * len(a.supports)
    assert len(a.supports) >= 0.9 * len(common)
    assert np.allclose(a.covariance, a.covariance.T)
    assert np.all(np.linalg.eigvalsh(a.covariance) > 0)


@settings(max_examples=25, deadline=None)
@given(pose=poses, seed=st.integers(0, 10_000))
@example(pose=(28.49, -9.78, 1.333), seed=2390)      # the truth at 21.6: beyond χ²₃ 99.99 %, within 1 − RARE
def test_robust_alignment_is_the_best_rigid_fit_anywhere(sim, pose, seed):
    # far from the landmarks the translation error grows with the lever arm; what must hold anywhere is
    # that the result is the weighted least-squares fit on the true common landmarks, and within its covariance
    map1, map2, common = sim.random_pair(50, 120, 150, pose, seed=seed, sigma=0.03)
    a = align(map1, map2, "robust", np.random.default_rng(seed))
    assert a.found, a.reason
    i, j = common[:, 0], common[:, 1]
    best, _, _ = refine_pose(map1.positions[i], map1.covariances[i], map2.positions[j], map2.covariances[j], pose)
    def mahalanobis_sq(other):
        e = a.pose - np.asarray(other)
        e[2] = wrap_angle(e[2])
        return e @ np.linalg.solve(a.covariance, e)

    assert mahalanobis_sq(best) < 1.0                             # within 1σ of the best fit
    assert mahalanobis_sq(pose) < chi2_isf(RARE, 3)              # the truth within χ²₃ 1 − 1e-6 (30.7)


@settings(max_examples=15, deadline=None)
@given(pose=near_poses, seed=st.integers(0, 10_000))
def test_paper_preset_recovers_a_known_transform(sim, pose, seed):
    # robot 2 starts inside the mapped area, as in the paper (the unrefined translation of eqs. 2-3 is
    # anchored at one landmark, so its error grows with the distance of map 2's origin from the landmarks)
    map1, map2, _ = sim.random_pair(60, 100, 100, pose, seed=seed, sigma=0.03)
    a = align(map1, map2, "paper", np.random.default_rng(seed))
    assert a.found, a.reason
    err = alignment_error(a.pose, pose)
    # a minimal-sample estimate, unrefined: good to about the support gate th2 (the paper reports < 0.2)
    assert err[0] < 0.35 and err[1] < 0.35 and err[2] < 0.05, err
    assert a.covariance is None


def test_transform_matrix_is_column_vector_eq5(sim):
    pose = (4.0, -2.0, 2.5)
    map1, map2, common = sim.random_pair(40, 30, 30, pose, seed=3, sigma=0.01)
    a = align(map1, map2, "robust", np.random.default_rng(0))
    p2 = np.column_stack([map2.positions[common[:, 1]], np.ones(len(common))])
    mapped = (a.matrix @ p2.T).T[:, :3]
    assert np.allclose(a.matrix[3], [0, 0, 0, 1])
    assert np.sqrt(np.mean(np.sum((mapped - map1.positions[common[:, 0]]) ** 2, axis=1))) < 0.05
    assert a.matrix[0, 1] == pytest.approx(-np.sin(a.theta))


@given(theta=st.floats(-np.pi + 1e-3, np.pi - 1e-3), tx=st.floats(-10, 10), ty=st.floats(-10, 10))
def test_eq4_is_quadrant_safe_and_eqs_2_3_give_the_translation(theta, tx, ty):
    rng = np.random.default_rng(1)
    p2 = rng.uniform(-5, 5, (2, 3))
    p1 = transform_points((tx, ty, theta), p2)
    for config in (PAPER, ROBUST):
        est, valid = pair_hypotheses(p1, p2, np.array([0]), np.array([1]), config)
        if np.linalg.norm(p2[0, :2] - p2[1, :2]) > config.min_pair_separation:
            assert valid[0]
            assert alignment_error(est[0], (tx, ty, theta)) == pytest.approx(np.zeros(3), abs=1e-9)


def test_no_alignment_without_overlap_over_many_seeds(sim):
    for seed in range(20):
        map1, map2, _ = sim.random_pair(0, 250, 300, (3, 1, 0.4), seed=seed)
        for preset in ("paper", "robust"):
            a = align(map1, map2, preset, np.random.default_rng(seed))
            assert not a.found, (seed, preset, a.statistics)
            assert a.pose is None and a.reason
            with pytest.raises(NoOverlapError):
                a.require()
            with pytest.raises(NoOverlapError):
                _ = a.matrix


def test_no_alignment_between_building_maps_that_share_nothing(sim):
    for seed in range(6):
        s1, s2 = sim.non_overlapping_pair(1.0, seed=seed, noise=sim.MapNoise(descriptor_noise=0.45))
        assert len(sim.true_common(s1, s2)) == 0
        a = align(s1.map, s2.map, "robust", np.random.default_rng(seed))
        assert not a.found, (seed, a.statistics)


def test_too_few_common_landmarks_decide_no_overlap(sim):
    # 3 common landmarks: two define a hypothesis, one check cannot rule out chance
    for seed in range(5):
        map1, map2, _ = sim.random_pair(3, 200, 200, (1, 2, 0.3), seed=seed)
        a = align(map1, map2, "robust", np.random.default_rng(0))
        assert not a.found
        assert "supports" in a.reason or "correspondences" in a.reason


def test_the_supports_needed_adapt_to_the_evidence(sim):
    # distinctive descriptors (noise 0.2) leave almost no wrong correspondence, so a handful of supports is
    # already very unlikely by chance: 6 common landmarks among 400 align, and correctly
    for seed in range(5):
        map1, map2, _ = sim.random_pair(6, 200, 200, (1, 2, 0.3), seed=seed)
        a = align(map1, map2, "robust", np.random.default_rng(0))
        assert a.found, a.reason
        err = alignment_error(a.pose, (1, 2, 0.3))
        assert err[0] < 0.1 and err[1] < 0.1 and err[2] < 0.02
        st = a.statistics
        assert st.required_supports <= st.supports and st.log10_chance_probability < -6
        assert 0 < st.false_alarm_probability < 1e-6


def test_robust_beats_paper_on_building_maps(sim):
    s1, s2 = sim.building_pair(1.0, seed=2, noise=sim.MapNoise(descriptor_noise=0.45))
    truth = true_relative_pose(s1.map, s2.map)
    errors = {}
    for preset in ("paper", "robust"):
        a = align(s1.map, s2.map, preset, np.random.default_rng(0))
        assert a.found, a.reason
        errors[preset] = alignment_error(a.pose, truth)
    assert np.all(errors["paper"] < 0.2)
    assert errors["robust"][0] < 0.05 and errors["robust"][1] < 0.05 and errors["robust"][2] < 0.01
    assert np.linalg.norm(errors["robust"][:2]) <= np.linalg.norm(errors["paper"][:2]) + 0.01


def test_paper_th0_of_2_accepts_every_nearest_neighbour(sim):
    map1, map2, _ = sim.random_pair(10, 50, 60, (0, 0, 0), seed=1)
    pairs, dist = nearest_correspondences(map1.descriptors, map2.descriptors, PAPER.descriptor_threshold)
    assert len(pairs) == len(map1)          # unit descriptors: every distance is < 2
    assert np.all(dist <= 2.0)


def test_paper_min_supports_of_20(sim):
    # 15 common landmarks are recovered by the robust preset but fall short of the paper's min = 20
    map1, map2, _ = sim.random_pair(15, 100, 100, (2, 3, 1.0), seed=7, sigma=0.02)
    assert not align(map1, map2, "paper", np.random.default_rng(0)).found
    assert align(map1, map2, "robust", np.random.default_rng(0)).found


def test_deterministic_given_seed(sim):
    map1, map2, _ = sim.random_pair(30, 150, 150, (1, -2, -2.0), seed=5, descriptor_noise=0.5)
    for preset in ("paper", "robust"):
        a = align(map1, map2, preset, np.random.default_rng(42))
        b = align(map1, map2, preset, np.random.default_rng(42))
        assert np.array_equal(a.pose, b.pose) and np.array_equal(a.supports, b.supports)


def test_inverse_alignment_matches_aligning_the_other_way(sim):
    map1, map2, _ = sim.random_pair(60, 80, 80, (5, 1, 1.2), seed=8)
    ab = align(map1, map2, "robust", np.random.default_rng(0))
    ba = align(map2, map1, "robust", np.random.default_rng(0))
    assert alignment_error(ab.inverse().pose, ba.pose) == pytest.approx(np.zeros(3), abs=0.02)
    assert {tuple(p) for p in ab.inverse().supports.tolist()} == {tuple(p) for p in ba.supports.tolist()}


def test_refinement_is_weighted_least_squares():
    # exact data: converges to the truth from a poor start; weights make a noisy point matter less
    rng = np.random.default_rng(0)
    truth = np.array([1.0, -2.0, 0.7])
    p2 = rng.uniform(-5, 5, (20, 3))
    p1 = transform_points(truth, p2)
    P = np.repeat(np.eye(3)[None] * 0.01, 20, axis=0)
    pose, cov, chi2 = refine_pose(p1, P, p2, P, truth + [0.3, -0.2, 0.1])
    assert pose == pytest.approx(truth, abs=1e-9) and chi2 == pytest.approx(0, abs=1e-12)
    p1_bad = p1.copy()
    p1_bad[0, :2] += 1.0
    P_bad = P.copy()
    P_bad[0] *= 1e6
    pose_w, _, _ = refine_pose(p1_bad, P_bad, p2, P, truth)
    pose_u, _, _ = refine_pose(p1_bad, P, p2, P, truth)
    assert np.linalg.norm(pose_w - truth) < 1e-3 < np.linalg.norm(pose_u - truth)


def test_alignment_covariance_is_consistent(sim):
    # the normalised squared error averaged over seeds is about 3 (χ² with 3 dof), not wildly off
    nees = []
    for seed in range(20):
        map1, map2, _ = sim.random_pair(30, 50, 50, (3, 2, 0.5), seed=seed, sigma=0.05)
        a = align(map1, map2, "robust", np.random.default_rng(seed))
        e = a.pose - np.array([3, 2, 0.5])
        nees.append(e @ np.linalg.solve(a.covariance, e))
    assert 1.0 < np.mean(nees) < 6.0


def test_incompatible_descriptors_raise():
    a = LandmarkMap(np.zeros((3, 3)), np.repeat(np.eye(3)[None], 3, 0), np.ones((3, 64)))
    b = LandmarkMap(np.zeros((3, 3)), np.repeat(np.eye(3)[None], 3, 0), np.ones((3, 32)))
    with pytest.raises(IncompatibleMapsError):
        align(a, b)
    with pytest.raises(IncompatibleMapsError):
        align(a, a, preset="nonsense")


def test_empty_maps_do_not_overlap():
    empty = LandmarkMap(np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 64)))
    assert not align(empty, empty).found


def test_given_alignment_round_trips():
    a = Alignment.from_pose((1.0, 2.0, 0.5), np.diag([0.01, 0.02, 0.001]))
    back = a.inverse().inverse()
    assert back.pose == pytest.approx(a.pose) and back.covariance == pytest.approx(a.covariance)
    assert a.to_dict()["pose"] == pytest.approx([1.0, 2.0, 0.5])


def test_large_maps_search_a_subset_then_gather_every_support(sim, monkeypatch):
    import fusion.matching
    monkeypatch.setattr(fusion.matching, "SEARCH_BUDGET_PAIRS", 40_000)   # 300 x 320 maps count as large
    map1, map2, common = sim.random_pair(150, 150, 170, (7.0, -4.0, -2.5), seed=11, sigma=0.02)
    a = align(map1, map2, "robust", np.random.default_rng(0))
    assert a.found, a.reason
    assert a.statistics.correspondences < len(common)           # only the subset searched descriptors...
    assert len(a.supports) >= 0.95 * len(common)               # ...guided matching found the rest
    assert {tuple(p) for p in a.supports.tolist()} <= {tuple(p) for p in common.tolist()}
    err = alignment_error(a.pose, (7.0, -4.0, -2.5))
    assert err[0] < 0.02 and err[1] < 0.02 and err[2] < 0.005


def test_supports_in_one_spot_are_rejected_not_crashed():
    # every landmark of both maps at the same place: any transform "fits", none can be fixed
    rng = np.random.default_rng(0)
    desc = rng.standard_normal((30, 64))
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    cov = np.repeat(np.eye(3)[None] * 1e-4, 30, 0)
    m = LandmarkMap(np.zeros((30, 3)), cov, desc)
    for preset in ("paper", "robust"):
        a = align(m, m, preset, np.random.default_rng(0))
        assert not a.found
