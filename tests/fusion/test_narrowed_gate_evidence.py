"""The evidence re-measured in the gate the winner's converged fit calls for (fusion.evidence.evidence, session 43).

Polishing sets the gate scale freely in its first round and only widens it afterwards (``settled_scale``).  A
hypothesis whose first fit was crude keeps the wide gate that fit called for after its pose has converged, and
gathers loose supports in it which the rival, scored in the same gate, cannot match.  Rendered demo seed 4 (robot 2
against robot 1's part before its gap): the building's half turn, polished from a hypothesis 0.2 rad off, kept the
1 m cap where its converged fit called for 0.3-0.4 m: 32 supports against the truth's 20, found 9.5 m / 3.1 rad off
on 28 of 40 RANSAC seeds; in the narrower gate it has 19 against 15, ambiguous.

The pair here is built to hold that state: honest start-frame covariances (σ 0.3 m, so the claimed gate is the 1 m
cap), a true overlap of tight pairs, and a half-turned look-alike with more tight pairs plus loose ones 0.5-0.9 m off.
"""
from __future__ import annotations

import numpy as np

from estimation.geometry import inverse, transform_points
from estimation.landmark_map import LandmarkMap
from fusion import ROBUST
from fusion.evidence import evidence
from fusion.ransac import correspondence_problem, ransac

TRUTH = np.array([3.0, 1.0, 0.2])         # map 2's frame in map 1's
HALF_TURN = np.array([24.0, 9.0, np.pi - 0.1])
CLAIMED_SIGMA = 0.3                       # honest start-frame std (m): drift the transform removes
LOCAL_SIGMA = 0.03                        # what a transform leaves


def _pair(seed: int, true_pairs: int, tight_twins: int, loose_twins: int):
    """map1, map2 (no descriptors needed: the correspondences are given) and the correspondences (K, 2): the true
    overlap's pairs, then the half turn's tight and loose look-alike pairs."""
    rng = np.random.default_rng(seed)
    n = true_pairs + tight_twins + loose_twins
    p1 = np.column_stack([rng.uniform(0, 30, n), rng.uniform(0, 10, n), rng.uniform(0, 2.5, n)])
    local = np.empty_like(p1)
    t = slice(0, true_pairs)
    local[t] = transform_points(inverse(TRUTH), p1[t])
    off = rng.normal(0, LOCAL_SIGMA, (n, 3)) * np.array([1.0, 1.0, 0.0])
    angle = rng.uniform(-np.pi, np.pi, loose_twins)
    off[true_pairs + tight_twins:, :2] = rng.uniform(0.5, 0.9, loose_twins)[:, None] * np.column_stack(
        [np.cos(angle), np.sin(angle)])
    local[t] += off[t]
    w = slice(true_pairs, n)
    local[w] = transform_points(inverse(HALF_TURN), p1[w] + off[w])
    cov = np.eye(3)[None].repeat(n, 0) * CLAIMED_SIGMA ** 2
    cov[:, 2, 2] = 1e-4
    desc = np.zeros((n, 0))
    m1 = LandmarkMap(p1, cov.copy(), desc, robot="robot1")
    m2 = LandmarkMap(local, cov.copy(), desc, robot="robot2")
    pairs = np.column_stack([np.arange(n), np.arange(n)]).astype(np.int64)
    return m1, m2, pairs


def _state(seed: int, winner: np.ndarray, true_pairs: int, tight_twins: int, loose_twins: int):
    """What align hands the evidence when polishing left the gate wide: the problem at the 1 m cap (inflation 1.8,
    as on seed 4), RANSAC's search over it, and the winner's pose and supports in that gate."""
    m1, m2, pairs = _pair(seed, true_pairs, tight_twins, loose_twins)
    problem = correspondence_problem(m1, m2, pairs, ROBUST, distinct_scoring=True).inflated(1.8)
    search = ransac(problem, ROBUST, np.random.default_rng(seed))
    mask = problem.one_to_one(problem.masks(winner[None])[0], winner)
    return problem, search, mask, m1, m2


def _log10_level() -> float:
    return float(np.log10(ROBUST.significance))


def test_a_half_turn_found_only_in_the_gate_its_crude_start_left_is_not_found():
    for seed in range(3):
        problem, search, mask, m1, m2 = _state(seed, HALF_TURN, true_pairs=16, tight_twins=19, loose_twins=13)
        assert problem.gate_radius == ROBUST.support_threshold            # the wide gate of the bug
        assert mask.sum() >= 30                                          # tight and loose look-alikes
        # the wide gate alone (the re-test turned off: "distinct" given): the half turn beats the truth clearly
        wide = evidence(problem, search, HALF_TURN, mask, m1, m2, ROBUST, np.random.default_rng(seed),
                        distinct_gate=problem.gate_radius)
        assert wide.log10_p <= _log10_level() and not wide.narrowed
        # in the gate its own converged fit calls for the loose look-alikes drop out, and the truth is its rival
        ev = evidence(problem, search, HALF_TURN, mask, m1, m2, ROBUST, np.random.default_rng(seed))
        assert ev.narrowed and ev.narrowed_gate < problem.gate_radius
        assert ev.supports < wide.supports and ev.second_best >= 14
        assert ev.log10_p > _log10_level()                               # not found: ambiguous
        assert ev.ambiguous


def test_the_true_overlap_stays_found_when_the_gate_narrows():
    """The same kind of pair with the truth the strong one: narrowing keeps its tight supports and drops the look-alike
    rival's loose ones, so it can only help; the re-test draws nothing from the generator."""
    for seed in range(3):
        problem, search, mask, m1, m2 = _state(seed, TRUTH, true_pairs=35, tight_twins=8, loose_twins=8)
        rng = np.random.default_rng(seed)
        ev = evidence(problem, search, TRUTH, mask, m1, m2, ROBUST, rng)
        assert ev.log10_p <= _log10_level()
        assert ev.supports >= 33
        after = rng.random()
        rng_wide = np.random.default_rng(seed)
        evidence(problem, search, TRUTH, mask, m1, m2, ROBUST, rng_wide, distinct_gate=problem.gate_radius)
        assert rng_wide.random() == after
