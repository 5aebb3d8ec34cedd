"""The ratio test on both sides of a match (fusion.matching.symmetric_correspondences, AlignmentConfig.ratio_sides;
session 45).

The robust preset's ``distinctive_correspondences`` keeps a mutual best match i <-> j when i's nearest map-2
descriptor passes Lowe's ratio test among map 2: only map 1's landmark is tested, so the correspondences of
``align(A, B)`` are not those of ``align(B, A)`` swapped (session 44: demo seed 8's parts, 158 against 114).
``ratio_sides="both"`` also requires j's test among map 1, ``"either"`` one of the two. Here:

- the pairs of (B, A) are exactly those of (A, B) swapped, for any descriptors (ties, copies, look-alikes);
- they are what the definition says, checked against a plain float64 form on integer descriptors (exact in float32);
- on a hand-built pair (one map holds a look-alike of each landmark) the one-sided test decides by the direction:
  found one way, not the other; with either symmetric rule the two directions decide the same.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.geometry import inverse, transform_points, wrap_angle
from estimation.landmark_map import LandmarkMap
from fusion import ROBUST, align
from fusion.errors import IncompatibleMapsError
from fusion.matching import distinctive_correspondences, symmetric_correspondences

SETTINGS = settings(max_examples=150)


def _as_set(pairs: np.ndarray, swap: bool = False) -> set[tuple[int, int]]:
    return {(int(b), int(a)) if swap else (int(a), int(b)) for a, b in pairs}


def _descriptors(rng, n1, n2, dim, copies, lookalikes):
    """Unit descriptors with exact copies across the maps (ties, round-off) and near copies inside each map."""
    d1 = rng.normal(size=(n1, dim))
    d2 = rng.normal(size=(n2, dim))
    for _ in range(copies if n1 and n2 else 0):
        d1[rng.integers(n1)] = d2[rng.integers(n2)]
    for d in (d1, d2):
        for _ in range(lookalikes if len(d) >= 2 else 0):
            a, b = rng.choice(len(d), 2, replace=False)
            d[a] = d[b] + rng.normal(0, 0.01, dim)
    return (d1 / np.linalg.norm(d1, axis=1, keepdims=True)).astype(np.float32), \
        (d2 / np.linalg.norm(d2, axis=1, keepdims=True)).astype(np.float32)


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), n1=st.integers(0, 60), n2=st.integers(0, 60), dim=st.sampled_from([2, 3, 8, 64]),
       copies=st.integers(0, 20), lookalikes=st.integers(0, 20), sides=st.sampled_from(["both", "either"]),
       max_distance=st.sampled_from([0.2, 0.8, 3.0]), ratio=st.sampled_from([0.5, 0.8, 0.95, 1.0]))
def test_the_pairs_of_b_a_are_those_of_a_b_swapped(seed, n1, n2, dim, copies, lookalikes, sides, max_distance, ratio):
    d1, d2 = _descriptors(np.random.default_rng(seed), n1, n2, dim, copies, lookalikes)
    ab, dist_ab = symmetric_correspondences(d1, d2, max_distance, ratio, sides)
    ba, dist_ba = symmetric_correspondences(d2, d1, max_distance, ratio, sides)
    assert _as_set(ab) == _as_set(ba, swap=True)
    assert len(_as_set(ab)) == len(ab)
    # one-to-one, sorted by map 1's landmark, distances of the pairs (the same both ways up to float32 round-off)
    assert len(set(ab[:, 0])) == len(ab) and len(set(ab[:, 1])) == len(ab)
    assert np.all(np.diff(ab[:, 0]) > 0)
    assert np.allclose(dist_ab, np.linalg.norm(d1[ab[:, 0]].astype(float) - d2[ab[:, 1]], axis=1), atol=1e-3)
    other_way = {(int(i), int(j)): x for (j, i), x in zip(ba, dist_ba, strict=True)}
    assert np.allclose(dist_ab, [other_way[int(i), int(j)] for i, j in ab], atol=1e-3)
    # "both" is what each one-sided search keeps in common; "either" holds "both"
    one_ab = _as_set(distinctive_correspondences(d1, d2, max_distance, ratio)[0])
    one_ba = _as_set(distinctive_correspondences(d2, d1, max_distance, ratio)[0], swap=True)
    if sides == "both":
        assert _as_set(ab) == one_ab & one_ba
    else:
        assert _as_set(symmetric_correspondences(d1, d2, max_distance, ratio, "both")[0]) <= _as_set(ab)
        assert _as_set(ab) <= one_ab | one_ba


def _reference(d1: np.ndarray, d2: np.ndarray, max_distance: float, ratio: float, sides: str):
    """The definition, written out in float64: mutual best matches (the first of tied nearest), within the distance
    gate, passing the ratio test of both landmarks or of either."""
    d = np.sqrt(((d1[:, None, :].astype(float) - d2[None, :, :]) ** 2).sum(axis=2))

    def passes(dist):                       # each row's ratio test among the columns (second nearest inf if alone)
        s = np.sort(dist, axis=1)
        second = s[:, 1] if dist.shape[1] > 1 else np.full(len(dist), np.inf)
        return s[:, 0] < ratio * second

    row_ok, col_ok = passes(d), passes(d.T)
    out = set()
    for i in range(len(d1)):
        j = int(np.argmin(d[i]))
        if int(np.argmin(d[:, j])) != i or not d[i, j] < max_distance:
            continue
        if (row_ok[i] and col_ok[j]) if sides == "both" else (row_ok[i] or col_ok[j]):
            out.add((i, j))
    return out


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), n1=st.integers(1, 40), n2=st.integers(1, 40), dim=st.integers(1, 6),
       spread=st.integers(1, 4), sides=st.sampled_from(["both", "either"]))
def test_the_pairs_are_the_mutual_best_matches_passing_the_gate_and_the_ratio_tests(seed, n1, n2, dim, spread, sides):
    # integer descriptors: every squared distance is exact in float32, so the search and the float64 form agree;
    # a ratio of 0.77 and a gate of 4.3 sit between the square roots such small integers give
    rng = np.random.default_rng(seed)
    d1 = rng.integers(-spread, spread + 1, (n1, dim)).astype(np.float32)
    d2 = rng.integers(-spread, spread + 1, (n2, dim)).astype(np.float32)
    got, _ = symmetric_correspondences(d1, d2, 4.3, 0.77, sides)
    assert _as_set(got) == _reference(d1, d2, 4.3, 0.77, sides)


def test_an_unknown_rule_is_refused_by_name():
    d = np.eye(3, dtype=np.float32)
    with pytest.raises(ValueError, match="'both', 'either'.*'map2'"):
        symmetric_correspondences(d, d, 0.8, 0.8, "map2")


# -- the hand-built pair: one map holds a look-alike of each landmark ----------------------------------------------
TRUTH = np.array([4.0, -2.0, 0.7])      # the twin map's frame in the clean map's
N, DIM = 30, 64


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _pair(seed: int) -> tuple[LandmarkMap, LandmarkMap]:
    """(clean map, twin map): both see the same 30 landmarks (2 cm apart, descriptors slightly changed); the twin
    map also holds a look-alike of each (a near copy of its descriptor at a random place). Queried from the clean
    map, every landmark has two equally near matches and fails the ratio test; queried from the twin map, every
    landmark has one clear match."""
    rng = np.random.default_rng(seed)
    points = np.column_stack([rng.uniform(0, 20, N), rng.uniform(0, 10, N), rng.uniform(0.2, 2.5, N)])
    desc = _unit(rng.normal(size=(N, DIM)))

    def seen(pose, where):
        p = transform_points(inverse(pose), where) + rng.normal(0, 0.02, where.shape) * [1, 1, 0]
        return p, _unit(desc + rng.normal(0, 0.02, desc.shape))

    clean_p, clean_d = seen(np.zeros(3), points)
    twin_p, twin_d = seen(TRUTH, points)
    look_p, look_d = seen(TRUTH, np.column_stack([rng.uniform(0, 20, N), rng.uniform(0, 10, N),
                                                  rng.uniform(0.2, 2.5, N)]))

    def as_map(p, d, robot):
        return LandmarkMap(p, np.eye(3)[None].repeat(len(p), 0) * 0.05 ** 2, d, robot=robot)

    return as_map(clean_p, clean_d, "robot1"), as_map(np.vstack([twin_p, look_p]), np.vstack([twin_d, look_d]),
                                                      "robot2")


def _agree(ab, ba) -> bool:
    """B->A found within 5 cm / 0.01 rad of the inverse of A->B, and A->B of the truth."""
    d = np.asarray(ba.pose) - np.asarray(ab.inverse().pose)
    return bool(np.hypot(*np.asarray(ab.pose)[:2] - TRUTH[:2]) < 0.05 and abs(wrap_angle(ab.pose[2] - TRUTH[2])) < 0.01
                and np.hypot(d[0], d[1]) < 0.05 and abs(wrap_angle(d[2])) < 0.01)


@pytest.mark.parametrize("seed", range(3))
def test_on_a_map_with_look_alikes_the_one_sided_test_decides_by_the_direction_and_the_symmetric_ones_do_not(seed):
    clean, twins = _pair(seed)
    one = [align(clean, twins, ROBUST, np.random.default_rng(0)), align(twins, clean, ROBUST, np.random.default_rng(0))]
    assert not one[0].found and one[0].statistics.correspondences < 4
    assert one[1].found and one[1].statistics.correspondences >= 15
    assert np.allclose(one[1].inverse().pose, TRUTH, atol=0.05)
    both = replace(ROBUST, ratio_sides="both")
    ab, ba = align(clean, twins, both, np.random.default_rng(0)), align(twins, clean, both, np.random.default_rng(0))
    # every match has a look-alike on the twin map's side: refused both ways, from the same (too few) pairs
    assert not ab.found and not ba.found
    assert ab.statistics.correspondences == ba.statistics.correspondences < 4
    either = replace(ROBUST, ratio_sides="either")
    ab = align(clean, twins, either, np.random.default_rng(0))
    ba = align(twins, clean, either, np.random.default_rng(0))
    assert ab.found and ba.found and _agree(ab, ba)
    assert ab.statistics.correspondences == ba.statistics.correspondences == one[1].statistics.correspondences


def test_an_unknown_rule_in_the_configuration_is_refused_in_one_line():
    clean, twins = _pair(0)
    with pytest.raises(IncompatibleMapsError, match="ratio_sides 'map2' .choose from map1, both, either"):
        align(clean, twins, replace(ROBUST, ratio_sides="map2"), np.random.default_rng(0))


def test_the_presets_keep_the_one_sided_test():
    from fusion import PAPER
    assert ROBUST.ratio_sides == "map1" and PAPER.ratio_sides == "map1"
