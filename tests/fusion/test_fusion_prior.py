"""A rough prior on the robots' relative start (fusion/prior.py; issue 13, the rendered demo's half-turn symmetry).

The prior only removes hypotheses: a rival outside it is no rival, and a best alignment outside it is "not found:
... contradicts the prior", never the best hypothesis inside it.
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.geometry import between, compose, inverse, transform_points
from estimation.landmark_map import LandmarkMap
from fusion import align
from fusion.alignment import alignment_error_xy_theta
from fusion.errors import IncompatibleMapsError
from fusion.prior import StartPrior, pair_priors, parse_start

SIGMA = 0.03
TRUE_POSE = np.array([2.0, -1.0, 0.6])      # map 2's start in map 1's frame
HALF_TURN = np.array([0.0, 0.0, np.pi])     # the building's symmetry, about map 1's origin


def _unit(rng, n, d=32):
    v = rng.normal(size=(n, d))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def twin_pair(seed: int, common: int, twins: int, pose=None):
    """Map 1 holds ``common`` landmarks both robots saw and ``twins`` more; map 2 holds the common ones and, for each
    twin, a look-alike (same descriptor) at its half-turned place.  Under the truth (``pose``, map 2's start in map
    1's frame; default TRUE_POSE) the common ones support; under the half turn the twins do, as on the rendered
    building.  Returns map1, map2."""
    true_pose = TRUE_POSE if pose is None else np.asarray(pose, float)
    rng = np.random.default_rng(seed)
    world_common = rng.uniform([-9, -2, 0.2], [9, 2, 2.5], (common, 3))
    world_twin = rng.uniform([-9, -2, 0.2], [9, 2, 2.5], (twins, 3))
    mirrored = transform_points(HALF_TURN, world_twin)
    d_common, d_twin = _unit(rng, common), _unit(rng, twins)
    p1 = np.vstack([world_common, world_twin]) + rng.normal(0, SIGMA, (common + twins, 3))
    p2 = transform_points(inverse(true_pose), np.vstack([world_common, mirrored])) + rng.normal(0, SIGMA,
                                                                                                  (common + twins, 3))
    cov = np.tile(np.eye(3) * SIGMA ** 2, (common + twins, 1, 1))
    desc2 = np.vstack([d_common, d_twin]) + rng.normal(0, 0.03, (common + twins, 32))
    perm = rng.permutation(common + twins)
    return (LandmarkMap(p1, cov, np.vstack([d_common, d_twin]), robot="robot1"),
            LandmarkMap(p2[perm], cov, desc2[perm], robot="robot2"))


def _prior(mean, sigma_xy=1.0, sigma_theta=0.3):
    return StartPrior.from_sigmas(mean, sigma_xy, sigma_theta)


WRONG_HALF_TURN = compose(HALF_TURN, TRUE_POSE)


# -- decisions ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", [0, 1])
def test_a_prior_at_the_truth_resolves_a_half_turned_rival(seed):
    m1, m2 = twin_pair(seed, common=30, twins=24)
    plain = align(m1, m2, "robust", np.random.default_rng(seed))
    assert not plain.found and plain.reason.startswith("ambiguous")
    a = align(m1, m2, "robust", np.random.default_rng(seed), prior=_prior(TRUE_POSE + [0.5, -0.5, 0.1]))
    assert a.found, a.reason
    assert alignment_error_xy_theta(a.pose, TRUE_POSE)[0] < 0.05
    assert a.statistics.outside_prior_supports >= 20          # the half turn, not counted as a rival
    assert a.statistics.second_best_supports < 10
    assert a.prior is not None and a.to_dict()["prior"]["source"] == "given"


@pytest.mark.parametrize("seed", [0, 1])
def test_a_half_turned_prior_is_contradicted_not_found(seed):
    m1, m2 = twin_pair(seed, common=30, twins=24)
    a = align(m1, m2, "robust", np.random.default_rng(seed), prior=_prior(WRONG_HALF_TURN))
    assert not a.found
    assert "contradicts the prior" in a.reason


def test_a_wrong_winner_outside_a_right_prior_is_not_replaced_by_the_best_loser():
    """The twins outnumber the common landmarks: the evidence's best is the half turn.  The true transform is inside
    the prior and would be the best consistent hypothesis, but the answer is 'not found', never that loser."""
    m1, m2 = twin_pair(2, common=20, twins=30)
    a = align(m1, m2, "robust", np.random.default_rng(2), prior=_prior(TRUE_POSE))
    assert not a.found
    assert "contradicts the prior" in a.reason


def test_a_prior_far_from_the_truth_is_contradicted():
    m1, m2 = twin_pair(3, common=40, twins=0)
    assert align(m1, m2, "robust", np.random.default_rng(3)).found
    a = align(m1, m2, "robust", np.random.default_rng(3), prior=_prior(TRUE_POSE + [5.0, 0.0, 0.0]))
    assert not a.found and "contradicts the prior" in a.reason
    assert "5.0" in a.reason or "4.9" in a.reason or "5.1" in a.reason      # says how far


def test_a_tight_prior_on_maps_that_share_nothing_finds_nothing(sim):
    """An adversarial prior, centred on the best hypothesis the maps give without one, does not make chance
    agreement found."""
    for seed in range(3):
        m1, m2 = sim.non_overlapping_pair(1.0, seed)
        m1, m2 = getattr(m1, "map", m1), getattr(m2, "map", m2)
        plain = align(m1, m2, "robust", np.random.default_rng(seed))
        assert not plain.found
        centre = np.zeros(3) if len(plain.supports) < 2 else _fit(m1, m2, plain.supports)
        a = align(m1, m2, "robust", np.random.default_rng(seed), prior=_prior(centre, 0.5, 0.1))
        assert not a.found


def _fit(m1, m2, supports):
    p1, p2 = m1.positions[supports[:, 0], :2], m2.positions[supports[:, 1], :2]
    c1, c2 = p1.mean(0), p2.mean(0)
    h = (p2 - c2).T @ (p1 - c1)
    theta = np.arctan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    r = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    return np.array([*(c1 - r @ c2), theta])


def test_without_a_prior_nothing_changes():
    m1, m2 = twin_pair(4, common=40, twins=10)
    a = align(m1, m2, "robust", np.random.default_rng(4))
    b = align(m1, m2, "robust", np.random.default_rng(4), prior=None)
    assert a.found and b.found and np.array_equal(a.pose, b.pose) and a.prior is None
    assert a.statistics.prior_hypotheses == 0 and np.isnan(a.statistics.prior_chi2)


def test_the_inverse_alignment_carries_the_inverse_prior():
    m1, m2 = twin_pair(5, common=40, twins=0)
    a = align(m1, m2, "robust", np.random.default_rng(5), prior=_prior(TRUE_POSE))
    assert a.found
    back = a.inverse()
    assert np.allclose(back.prior.mean, inverse(a.prior.mean))
    assert back.prior.chi2(back.pose) == pytest.approx(a.prior.chi2(a.pose), rel=0.05, abs=1e-3)


# -- the prior's geometry ---------------------------------------------------------------------------------------
coord = st.floats(-20, 20)
angle = st.floats(-np.pi, np.pi)
sig_xy = st.floats(0.05, 5.0)
sig_th = st.floats(0.01, 1.0)


@settings(max_examples=60, deadline=None)
@given(coord, coord, angle, coord, coord, angle, sig_xy, sig_th)
def test_the_mean_has_chi2_zero_and_a_full_turn_changes_nothing(x, y, th, dx, dy, dth, sxy, sth):
    p = _prior([x, y, th], sxy, sth)
    assert p.chi2(p.mean) == pytest.approx(0.0, abs=1e-9)
    pose = np.array([x + dx, y + dy, th + dth])
    turned = pose + [0.0, 0.0, 2 * np.pi]
    assert p.chi2(turned) == pytest.approx(p.chi2(pose), rel=1e-6, abs=1e-6)
    # χ² is quadratic in the deviation (while the angle does not wrap)
    small = np.array([dx, dy, dth / 8.0]) / 4.0
    assert p.chi2(p.mean + 2 * small) == pytest.approx(4 * p.chi2(p.mean + small), rel=1e-6, abs=1e-9)


@settings(max_examples=60, deadline=None)
@given(coord, coord, angle, coord, coord, angle, coord, coord, angle, sig_xy, sig_th)
def test_a_prior_from_start_poses_does_not_depend_on_the_common_frame(x1, y1, t1, x2, y2, t2, gx, gy, gt, sxy, sth):
    s1, s2, g = np.array([x1, y1, t1]), np.array([x2, y2, t2]), np.array([gx, gy, gt])
    a = StartPrior.between_starts(s1, s2, sxy, sth)
    b = StartPrior.between_starts(compose(g, s1), compose(g, s2), sxy, sth)
    assert np.allclose(a.mean[:2], between(s1, s2)[:2], atol=1e-9)
    assert alignment_error_xy_theta(a.mean, b.mean)[0] < 1e-8 and alignment_error_xy_theta(a.mean, b.mean)[1] < 1e-9
    assert np.allclose(a.covariance, b.covariance, atol=1e-8 * (1 + np.abs(a.covariance).max()))
    # the relative start is less certain than either start: at least the sum of the two in θ, 2σ² in the plane
    assert a.covariance[2, 2] == pytest.approx(2 * sth ** 2)
    assert np.linalg.eigvalsh(a.covariance[:2, :2]).min() >= 2 * sxy ** 2 * (1 - 1e-9)


@settings(max_examples=60, deadline=None)
@given(coord, coord, angle, sig_xy, sig_th, st.floats(-0.005, 0.005), st.floats(-0.005, 0.005),
       st.floats(-0.001, 0.001))
def test_inverting_a_prior_keeps_a_nearby_pose_s_chi2(x, y, th, sxy, sth, dx, dy, dth):
    p = _prior([x, y, th], sxy, sth)
    pose = p.mean + [dx, dy, dth]
    assert np.allclose(p.inverse().inverse().mean, p.mean, atol=1e-9)
    assert np.allclose(p.inverse().inverse().covariance, p.covariance, atol=1e-9 * (1 + np.abs(p.covariance).max()))
    # first order: the inverse pose against the inverse prior (linearised at the mean)
    assert p.inverse().chi2(inverse(pose)) == pytest.approx(p.chi2(pose), rel=0.05, abs=1e-3)


def test_pair_priors_compose_start_poses():
    starts = {0: (np.array([3.0, 5.0, 0.0]), (1.0, 0.3)), 2: (np.array([8.0, 5.0, np.pi]), (1.0, 0.3))}
    priors = pair_priors(starts, 3)
    assert list(priors) == [(0, 2)]
    assert max(alignment_error_xy_theta(priors[(0, 2)].mean, [5.0, 0.0, np.pi])) < 1e-9


# -- bad input: one clear line --------------------------------------------------------------------------------------
@pytest.mark.parametrize("text", ["1,2", "1,2,x", "1,2,3,4", "1,2,3,-1,0.3", "1,2,3,1,0", "nan,0,0"])
def test_a_malformed_start_is_refused(text):
    with pytest.raises(IncompatibleMapsError, match="start"):
        parse_start(text)


def test_a_prior_needs_a_positive_definite_covariance():
    with pytest.raises(IncompatibleMapsError, match="positive definite"):
        StartPrior(np.zeros(3), np.zeros((3, 3)))
    with pytest.raises(IncompatibleMapsError, match="standard deviations"):
        StartPrior.from_sigmas(np.zeros(3), -1.0, 0.3)
    with pytest.raises(IncompatibleMapsError, match="there are 2 maps"):
        pair_priors({0: (np.zeros(3), (1.0, 0.3)), 5: (np.zeros(3), (1.0, 0.3))}, 2)


# -- a flagged map's split check and the fusion of its parts use the prior (fusion/split.py) --------------------------
def test_a_split_map_s_parts_are_checked_and_fused_under_the_prior(sim):
    from fusion import true_relative_pose
    from fusion.split import fuse_checked
    from tests.fusion.test_fusion_split import KICK, _pair

    m1, m2, _, _ = _pair(sim, KICK)
    truth = true_relative_pose(m1, m2)
    right = fuse_checked([m1, m2], rng=np.random.default_rng(0), priors={(0, 1): _prior(truth)})
    (check,) = right.checks
    assert check.decision == "parts"                       # as without a prior (test_fusion_split)
    assert all(a.prior is not None for p in check.parts for a in p.alignments.values())
    # the pieces of two maps share their maps' prior; the two pieces of one map have none between them
    assert right.fusion is not None and right.sources == [(0, None), (1, "before"), (1, "after")]
    assert right.fusion.alignments[(0, 1)].prior is not None and right.fusion.alignments[(0, 2)].prior is not None
    assert right.fusion.alignments[(1, 2)].prior is None
    wrong = fuse_checked([m1, m2], rng=np.random.default_rng(0), priors={(0, 1): _prior(truth + [6.0, 0.0, 0.0])})
    (check,) = wrong.checks
    assert check.decision == "none"                        # neither part is placed against the prior
    assert all("contradicts the prior" in a.reason for p in check.parts for a in p.alignments.values())
    assert wrong.fusion is None or all(pose is None for pose in wrong.fusion.poses[1:])


def test_the_mission_s_fusion_report_says_when_a_prior_was_used(sim):
    from fusion import true_relative_pose
    from runtime.fusion_report import fuse_maps
    from tests.fusion.test_fusion_split import KICK, _pair

    m1, m2 = twin_pair(0, common=30, twins=24)
    report = fuse_maps({"robot1": m1, "robot2": m2}, priors={("robot1", "robot2"): _prior(TRUE_POSE)})
    (pair,) = report.pairs
    assert pair.aligned and pair.prior.startswith("prior (given)")
    assert fuse_maps({"robot1": m1, "robot2": m2}).pairs[0].prior == ""
    # a flagged map fused in parts (fusion_report's split path) says it too
    s1, s2, _, _ = _pair(sim, KICK)
    names = (s1.robot, s2.robot)
    split = fuse_maps(dict(zip(names, (s1, s2), strict=True)),
                      priors={names: _prior(true_relative_pose(s1, s2))})
    assert split.pairs[0].split_decision == "parts" and split.pairs[0].prior.startswith("prior (given)")
