"""fusion/confirmation.py when fusions come faster than ``min_gap`` (a live node fuses about once a second).

Session 48: each found was judged against the latest round's found only, so with a fusion every second the
earlier found was always "less than 10 s before" and a live fleet confirmed nothing until its final fusion.  A
found is now judged against the first found of its agreeing run: confirmed ``min_gap`` s after the run began; a
found that disagrees starts a new run (the clock restarts)."""
from __future__ import annotations

import numpy as np

from fusion.confirmation import CANDIDATE, ConfirmingCache
from tests.fusion.test_fusion_confirmation import _grown, _pair


def _rounds(cache: ConfirmingCache, maps_at: dict) -> dict:
    """One fusion per second: {t: alignment} of each round's (map1, map2) grown by a millimetre (changed maps)."""
    noise, results = np.random.default_rng(7), {}
    for t, (map1, map2) in maps_at.items():
        cache.start_round(float(t))
        results[t] = cache.align(_grown(map1, noise), _grown(map2, noise), "robust", np.random.default_rng(t))
    return results


def test_fusions_every_second_that_agree_confirm_from_min_gap_after_the_first_found(sim):
    map1, map2 = _pair(sim)
    results = _rounds(ConfirmingCache(min_gap=10.0), {t: (map1, map2) for t in range(16)})
    assert [t for t, r in results.items() if r.found] == list(range(10, 16))
    assert "no earlier fusion of these maps found it" in results[0].reason
    for t in range(1, 10):
        assert results[t].reason.startswith(CANDIDATE)
        assert "agrees with the fusion at t=0s, which is less than 10 s before" in results[t].reason
    assert all(np.allclose(results[t].pose, results[10].pose, atol=0.05) for t in range(10, 16))


def test_a_found_that_disagrees_restarts_the_clock(sim):
    map1, map2 = _pair(sim)
    other = _pair(sim, pose=(-4.0, 3.0, -1.2), seed=5)        # the same robots, another transform
    maps_at = {t: (other if t == 6 else (map1, map2)) for t in range(26)}
    results = _rounds(ConfirmingCache(min_gap=10.0), maps_at)
    assert "disagrees with the fusion at t=0s (" in results[6].reason
    assert "disagrees with the fusion at t=6s (" in results[7].reason      # back to the first: a new run from t=7
    assert "agrees with the fusion at t=7s, which is less than 10 s before" in results[16].reason
    assert [t for t, r in results.items() if r.found] == list(range(17, 26))


def test_a_fusion_that_finds_nothing_neither_continues_nor_ends_a_run(sim):
    map1, map2 = _pair(sim)
    far = sim.random_pair(0, 40, 30, (6.0, -2.0, 0.8), seed=9)[1]   # no landmark in common with map1
    far.robot, far.robots = "robot2", ["robot2"]
    maps_at = {t: ((map1, far) if t in (4, 5, 10) else (map1, map2)) for t in range(13)}
    results = _rounds(ConfirmingCache(min_gap=10.0), maps_at)
    assert not any(results[t].found or results[t].reason.startswith(CANDIDATE) for t in (4, 5, 10))
    assert [t for t, r in results.items() if r.found] == [11, 12]


def test_unchanged_maps_move_the_run_s_start_to_the_later_fusion(sim):
    """The clock counts the maps' growth: a found on the anchor's maps seen again later starts the run there."""
    map1, map2 = _pair(sim)
    cache, noise = ConfirmingCache(min_gap=10.0), np.random.default_rng(3)
    same1, same2 = _grown(map1, noise), _grown(map2, noise)
    for t in (0.0, 8.0):
        cache.start_round(t)
        assert "candidate" in cache.align(same1, same2).reason
    cache.start_round(12.0)
    assert "agrees with the fusion at t=8s, which is less than 10 s before" in cache.align(
        _grown(map1, noise), _grown(map2, noise)).reason
    cache.start_round(18.0)
    assert cache.align(_grown(map1, noise), _grown(map2, noise)).found
