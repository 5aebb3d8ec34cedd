"""fusion/confirmation.py: a live fusion's found is a candidate until a later fusion, on changed maps, agrees."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from estimation import chi2
from estimation.landmark_map import LandmarkMap
from fusion import Alignment, AlignmentCache, align
from fusion.confirmation import CANDIDATE, ConfirmingCache, candidate_clause, transforms_agree

THRESHOLD = chi2.ppf(0.999, 3)


def _found(pose, sigmas=None) -> Alignment:
    cov = None if sigmas is None else np.diag(np.square(sigmas))
    return Alignment.from_pose(pose, cov)


@given(x=st.floats(-50, 50), y=st.floats(-50, 50), theta=st.floats(-np.pi, np.pi),
       sx=st.floats(0.01, 2.0), sy=st.floats(0.01, 2.0), st_=st.floats(1e-3, 0.2), k=st.floats(0.0, 10.0),
       axis=st.integers(0, 2))
def test_two_transforms_agree_exactly_when_their_difference_is_inside_chi2_of_the_summed_covariances(
        x, y, theta, sx, sy, st_, k, axis):
    sigmas = np.array([sx, sy, st_])
    shift = np.zeros(3)
    shift[axis] = k * sigmas[axis] * np.sqrt(2.0)   # the sum of two equal covariances: σ√2 (a turn stays < π)
    earlier, later = _found([x, y, theta], sigmas), _found(np.array([x, y, theta]) + shift, sigmas)
    agree, apart = transforms_agree(earlier, later)
    if abs(k * k - THRESHOLD) > 1e-6:
        assert agree == (k * k <= THRESHOLD)
    assert apart.endswith("rad apart")
    assert transforms_agree(later, earlier)[0] == agree      # symmetric


@given(eps=st.floats(1e-4, 0.01))
def test_the_heading_difference_is_wrapped(eps):
    sigmas = [0.1, 0.1, 0.05]
    assert transforms_agree(_found([1.0, 2.0, np.pi - eps], sigmas), _found([1.0, 2.0, -np.pi + eps], sigmas))[0]


def test_without_covariances_the_supports_must_land_within_the_support_distance():
    points = np.array([[5.0, 0.0, 1.0], [0.0, 5.0, 0.5], [-3.0, -3.0, 2.0]])
    earlier = _found([0.0, 0.0, 0.0])
    assert transforms_agree(earlier, _found([0.05, 0.0, 0.0]), points, support_distance=0.1)[0]
    assert not transforms_agree(earlier, _found([0.05, 0.0, 0.05]), points, support_distance=0.1)[0]  # 0.25 m at 5 m
    assert not transforms_agree(earlier, _found([0.0, 0.0, 0.0]), None, support_distance=0.1)[0]


def _pair(sim, pose=(6.0, -2.0, 0.8), seed=3):
    map1, map2 = sim.random_pair(40, 30, 30, pose, seed=seed)[:2]
    map2.robot, map2.robots = "robot2", ["robot2"]
    map1.robot, map1.robots = "robot1", ["robot1"]
    return map1, map2


def _grown(m: LandmarkMap, rng: np.random.Generator) -> LandmarkMap:
    """The same map a little later: every estimate moved by a millimetre (its content changed)."""
    grown = LandmarkMap(m.positions + rng.normal(0, 1e-3, m.positions.shape), m.covariances.copy(),
                        m.descriptors.copy(), robot=m.robot, robots=list(m.robots), metadata=dict(m.metadata))
    return grown


def test_a_found_is_a_candidate_first_keeps_its_evidence_and_is_confirmed_by_a_later_agreeing_fusion(sim):
    map1, map2 = _pair(sim)
    plain = align(map1, map2, "robust", np.random.default_rng(0))
    assert plain.found
    cache = ConfirmingCache(min_gap=10.0)
    cache.start_round(0.0)
    first = cache.align(map1, map2, "robust", np.random.default_rng(0))
    assert not first.found and first.pose is None and first.reason.startswith(CANDIDATE)
    assert len(first.supports) == len(plain.supports) and first.statistics.to_dict() == plain.statistics.to_dict()
    assert candidate_clause(first.reason).startswith(f"{len(plain.supports)} supports at (")
    cache.start_round(5.0)                                   # too soon, even on changed maps
    rng = np.random.default_rng(1)
    assert "less than 10 s before" in cache.align(_grown(map1, rng), map2).reason
    cache.start_round(20.0)
    confirmed = cache.align(_grown(map1, rng), _grown(map2, rng))
    assert confirmed.found and np.allclose(confirmed.pose, plain.pose, atol=0.05)


def test_a_fusion_that_disagrees_is_a_candidate_again_and_says_how_far_apart(sim):
    map1, map2 = _pair(sim)
    other1, other2 = _pair(sim, pose=(-4.0, 3.0, -1.2), seed=5)     # the same robots, another transform
    cache = ConfirmingCache(min_gap=10.0)
    for t, maps in ((0.0, (map1, map2)), (20.0, (other1, other2))):
        cache.start_round(t)
        result = cache.align(*maps)
    assert not result.found and "disagrees with the fusion at t=0s (" in result.reason and "rad apart)" in result.reason


def test_alignments_within_one_fusion_never_confirm_each_other(sim):
    """A flagged map's parts and the whole map are aligned in one fusion: the same data, no confirmation."""
    map1, map2 = _pair(sim)
    cache = ConfirmingCache(min_gap=0.0)
    cache.start_round(0.0)
    rng = np.random.default_rng(2)
    assert not cache.align(map1, map2).found
    assert not cache.align(_grown(map1, rng), _grown(map2, rng)).found


def test_what_is_not_found_passes_unchanged_and_the_inner_cache_decides_alone(sim):
    map1 = _pair(sim)[0]
    far = sim.non_overlapping_pair()[1].map
    inner = AlignmentCache()
    cache = ConfirmingCache(min_gap=10.0, inner=inner)
    cache.start_round(0.0)
    missing = cache.align(map1, far)
    assert not missing.found and not missing.reason.startswith(CANDIDATE)
    assert inner.align(*_pair(sim)).found                     # the final fusion's way: decided on the maps alone


@pytest.mark.parametrize("gap", [-1.0, float("nan"), float("inf")])
def test_a_wrong_gap_is_refused(gap):
    with pytest.raises(ValueError, match="min_gap"):
        ConfirmingCache(min_gap=gap)
