"""AlignmentCache: repeated fusions of unchanged maps reuse their alignments; a changed map is recomputed."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.landmark_map import LandmarkMap
from fusion import ROBUST, AlignmentCache, align, fuse_all, map_fingerprint


def _pair(sim):
    return sim.random_pair(40, 30, 30, (6.0, -2.0, 0.8), seed=3)[:2]


def _moved(m: LandmarkMap, row: int, dx: float) -> LandmarkMap:
    positions = m.positions.copy()
    positions[row, 0] += dx
    return LandmarkMap(positions, m.covariances.copy(), m.descriptors.copy(), robot=m.robot,
                       metadata=dict(m.metadata))


def test_a_cached_alignment_equals_a_fresh_one_and_is_not_recomputed_for_unchanged_maps(sim):
    map1, map2 = _pair(sim)
    cache = AlignmentCache()
    first = cache.align(map1, map2, "robust", np.random.default_rng(7))
    fresh = align(map1, map2, "robust", np.random.default_rng(7))
    assert first.found and first.to_dict() == fresh.to_dict()
    assert (cache.misses, cache.self_misses) == (1, 2)          # the pair, and each map's self-structure once
    # the same contents in new objects, another generator: the stored alignment, nothing recomputed
    again = cache.align(_moved(map1, 0, 0.0), _moved(map2, 0, 0.0), "robust", np.random.default_rng(99))
    assert again is first and cache.hits == 1 and cache.self_misses == 2


def test_a_changed_map_is_aligned_again_and_an_unchanged_one_keeps_its_self_structure(sim):
    """With the self-repeat counted in each map's own gate, an unchanged map's repeat is reused; counted in the pair's
    gate (the robust default since session 10) it is reused only while the pair's gate scale is the same."""
    map1, map2 = _pair(sim)
    own = replace(ROBUST, self_repeat_gate="own")
    cache = AlignmentCache()
    cache.align(map1, map2, own, np.random.default_rng(1))
    changed = _moved(map2, 5, 0.5)
    result = cache.align(map1, changed, own, np.random.default_rng(2))
    assert cache.misses == 2 and cache.hits == 0
    assert result.to_dict() == align(map1, changed, own, np.random.default_rng(2)).to_dict()
    assert (cache.self_hits, cache.self_misses) == (1, 3)       # map 1 from the store, the changed map anew
    assert cache.align(map1, map2, "paper", np.random.default_rng(1)).preset == "paper"   # preset in the key
    assert cache.misses == 3


def test_fuse_all_with_a_cache_gives_the_fresh_result_then_reuses_every_pair(sim):
    map1, map2 = _pair(sim)
    map3 = map2.subset(np.arange(len(map2)) % 3 != 0)
    map3.robot = "robot3"
    maps = [map1, map2, map3]
    cache = AlignmentCache()
    cached = fuse_all(maps, "robust", 1, np.random.default_rng(4), cache=cache)
    fresh = fuse_all(maps, "robust", 1, np.random.default_rng(4))
    as_dicts = [{k: a.to_dict() for k, a in r.alignments.items()} for r in (cached, fresh)]
    assert as_dicts[0] == as_dicts[1]
    np.testing.assert_array_equal(cached.map.positions, fresh.map.positions)
    misses = cache.misses
    again = fuse_all(maps, "robust", 1, np.random.default_rng(5), cache=cache)
    assert cache.misses == misses and cache.hits == 3
    np.testing.assert_array_equal(again.map.positions, cached.map.positions)


def test_the_cache_stays_within_its_bound(sim):
    map1, map2 = _pair(sim)
    cache = AlignmentCache(max_pairs=2, max_maps=3)
    for k in range(4):
        cache.align(map1, _moved(map2, 0, 0.1 * (k + 1)), "robust", np.random.default_rng(k))
    assert len(cache) == 2 and len(cache._self) == 3


@settings(max_examples=40, deadline=None)
@given(row=st.integers(0, 9), field=st.sampled_from(["position", "covariance", "descriptor", "identity"]),
       delta=st.floats(1e-6, 1.0))
def test_the_fingerprint_changes_with_any_landmark_and_not_with_a_copy(row, field, delta):
    rng = np.random.default_rng(0)
    cov = np.repeat(np.eye(3)[None] * 0.01, 10, 0)
    desc = rng.standard_normal((10, 8)).astype(np.float32)
    meta = {"external_ids": list(range(10))}
    m = LandmarkMap(rng.standard_normal((10, 3)), cov, desc, robot="r", metadata=meta)
    copy = LandmarkMap(m.positions.copy(), m.covariances.copy(), m.descriptors.copy(), robot="other",
                       metadata={"external_ids": list(range(10))})
    assert map_fingerprint(copy) == map_fingerprint(m)
    p, c, d, ids = m.positions.copy(), m.covariances.copy(), m.descriptors.copy(), list(range(10))
    if field == "position":
        p[row, 1] += delta
    elif field == "covariance":
        c[row, 0, 0] += delta
    elif field == "descriptor":
        d[row, 3] += np.float32(max(delta, 1e-3))
    else:
        ids[row] = 100 + row
    changed = LandmarkMap(p, c, d, robot="r", metadata={"external_ids": ids})
    assert map_fingerprint(changed) != map_fingerprint(m)


def test_fuse_maps_with_the_callers_cache_reports_as_without_it_and_reuses_the_alignment(sim):
    from runtime.fusion_report import alignment_cache, fuse_maps

    map1, map2 = _pair(sim)
    maps = {"robot1": map1, "robot2": map2}
    cache = alignment_cache()
    cached = fuse_maps(maps, "robust", 1, t=1.0, rng=np.random.default_rng(3), cache=cache)
    fresh = fuse_maps(maps, "robust", 1, t=1.0, rng=np.random.default_rng(3))
    assert [p.as_dict() for p in cached.pairs] == [p.as_dict() for p in fresh.pairs]
    assert cached.pairs[0].aligned
    again = fuse_maps(maps, "robust", 1, t=2.0, rng=np.random.default_rng(4), cache=cache)
    assert cache.hits == 1 and cache.misses == 1
    assert again.pairs[0].as_dict() == cached.pairs[0].as_dict()
    np.testing.assert_array_equal(again.merged.positions, cached.merged.positions)
