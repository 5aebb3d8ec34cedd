"""Issue 13, the rendered demo's ambiguous seeds: an ambiguous pair says what its rival is and what would settle it.

On the demo the rival of the true alignment is a half turn whose supports match as closely in appearance as the
true ones (docs/fusion-history.md, "Rendered demo: is the half-turn symmetry real in appearance?"); the decision keeps
"ambiguous", and the report must let a user see why.
"""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.geometry import compose, transform_points
from fusion import align
from fusion.evidence import rival_offset

HALF_TURN_CENTRE = np.array([10.0, 0.0])        # fusion_sim.half_turn_pair turns its pattern about (10, 0)


def test_an_ambiguous_pair_names_its_half_turned_rival(sim):
    for seed in range(3):
        # 14 landmarks truly shared, 12 of map 2 that look like (and lie a half turn from) 12 of map 1
        m1, m2 = sim.half_turn_pair(seed, repeated_in_map1=0, shared=14, seen_by_map2=12)
        a = align(m1, m2, "robust", np.random.default_rng(seed))
        st_ = a.statistics
        assert not a.found
        assert a.reason.startswith(f"ambiguous: a distinct transform gathers {st_.second_best_supports} supports "
                                   f"against the best one's {st_.supports}")
        assert st_.second_best_supports >= 10
        # the rival turns by π: a half turn about (10, 0) moves each support p by 2 |p - centre|
        assert st_.second_best_turn > 3.0 and "(a half turn)" in a.reason
        p1 = m1.positions[a.supports[:, 0], :2]
        expected = np.sqrt(np.mean(np.sum((2.0 * (p1 - HALF_TURN_CENTRE)) ** 2, axis=1)))
        assert abs(st_.second_best_shift - expected) < 0.5, (st_.second_best_shift, expected)
        # both sets of supports are descriptor matches with the same noise: alike in appearance, both reported
        d_best, d_rival = st_.support_descriptor_distance, st_.second_best_descriptor_distance
        assert 0.0 < d_best < 0.8 and 0.0 < d_rival < 0.8 and abs(d_best - d_rival) < 0.1
        assert f"{d_rival:.3f}" in a.reason and f"{d_best:.3f}" in a.reason
        assert "to tell them apart" in a.reason
        d = st_.to_dict()
        assert d["second_best_turn"] == st_.second_best_turn and d["second_best_descriptor_distance"] == d_rival


def test_maps_matched_by_geometry_report_no_descriptor_distances(sim):
    # a corridor of identical doors without descriptors: ambiguous, and there is no appearance to compare
    m1, m2 = sim.corridor_pair(range(0, 8), range(2, 10), (3.0, 0.5, 0.3), seed=1, descriptors="none")
    a = align(m1, m2, "robust", np.random.default_rng(0))
    assert not a.found and a.reason.startswith("ambiguous")
    assert np.isnan(a.statistics.support_descriptor_distance)
    assert np.isnan(a.statistics.second_best_descriptor_distance)
    assert "descriptor distance" not in a.reason
    assert a.statistics.to_dict()["second_best_descriptor_distance"] is None
    assert np.isfinite(a.statistics.second_best_turn) and a.statistics.second_best_shift > 0.0


poses = st.tuples(st.floats(-20, 20), st.floats(-20, 20), st.floats(-np.pi, np.pi))


@settings(max_examples=60, deadline=None)
@given(poses, poses, poses, st.integers(1, 30), st.integers(0, 2**31 - 1))
def test_rival_offset_is_symmetric_and_does_not_depend_on_the_reference_frame(a, b, g, n, seed):
    pts = np.random.default_rng(seed).uniform(-10, 10, (n, 3))
    a, b, g = np.array(a), np.array(b), np.array(g)
    shift, turn = rival_offset(a, b, pts)
    moved = transform_points(a, pts)[:, :2] - transform_points(b, pts)[:, :2]
    assert np.isclose(shift, np.sqrt(np.mean(np.sum(moved ** 2, axis=1))), atol=1e-9)
    assert 0.0 <= turn <= np.pi + 1e-12
    back = rival_offset(b, a, pts)
    assert np.allclose(back, (shift, turn), atol=1e-9)
    # the same two hypotheses seen from another map-1 frame (both composed with g): same figures
    assert np.allclose(rival_offset(compose(g, a), compose(g, b), pts), (shift, turn), atol=1e-7)
    assert np.allclose(rival_offset(a, a, pts), (0.0, 0.0), atol=1e-9)
