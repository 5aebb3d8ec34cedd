"""estimation/name_merging: batches of merged names kept or refused by the smoother's cost, with the smoother stood in
for (a naming's cost chosen by the test): bisection keeps exactly the passes the cost check takes, the guard's groups
replace a refused batch, a second start can rescue a batch the current solution refuses, and an audit that holds back
every merge keeps nothing."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import estimation.name_merging as nm
from estimation.named_smoothing import MergeRound


def _stand_ins(patch, bad: set[int]):
    """Pass k joins name 10k + 1 to 10k; any batch holding a bad pass is refused (the cost check stood in for)."""
    def clusters_of(current, some, alias, **_):
        return {a: b for pairs in some for a, b in pairs if a not in alias}

    def apply_merges(smoother, current, clusters, **_):
        merged = [(b, a) for a, b in clusters.items()]
        ok = not any(a // 10 in bad for a in clusters)
        return MergeRound(current.merged + merged if ok else merged, 0.0, 1.0, ok, None, None, None)

    patch.setattr(nm, "clusters_of", clusters_of)
    patch.setattr(nm, "apply_merges", apply_merges)


@settings(max_examples=30, deadline=None)
@given(st.integers(2, 12), st.data())
def test_a_refused_batch_is_cut_in_halves_and_keeps_every_pass_the_cost_check_takes(n_passes, data):
    # bisecting deep enough keeps every good pass, never a bad one, and a good batch is kept in one attempt
    bad = set(data.draw(st.sets(st.integers(0, n_passes - 1), max_size=2)))
    passes = [[(10 * k + 1, 10 * k)] for k in range(n_passes)]
    start = MergeRound([], 0.0, 0.0, True, None, None, None)
    with pytest.MonkeyPatch.context() as patch:
        _stand_ins(patch, bad)
        depth = int(np.ceil(np.log2(n_passes)))
        state, attempts = nm.merge_bisecting(None, start, passes, depth=depth, alias={})
        alone, _ = nm.merge_bisecting(None, start, passes, depth=0, alias={})
    assert {a // 10 for _, a in state.merged} == set(range(n_passes)) - bad
    if not bad:
        assert len(attempts) == 1
    assert len(attempts) <= 2 * n_passes - 1
    # depth 0: the refused batch retried as its strongest (first) pass alone
    assert {a // 10 for _, a in alone.merged} == (set(range(n_passes)) if not bad else ({0} - bad))


@settings(max_examples=20, deadline=None)
@given(st.integers(2, 10), st.data())
def test_a_refused_batch_is_retried_without_the_groups_the_guard_set_aside(n_passes, data):
    bad = set(data.draw(st.sets(st.integers(0, n_passes - 1), min_size=1, max_size=2)))
    passes = [[(10 * k + 1, 10 * k)] for k in range(n_passes)]
    guarded = [p for k, p in enumerate(passes) if k not in bad]      # the guard saw the bad ones
    start = MergeRound([], 0.0, 0.0, True, None, None, None)
    with pytest.MonkeyPatch.context() as patch:
        _stand_ins(patch, bad)
        state, attempts = nm.merge_guarded(None, start, passes, guarded, depth=2)
        unguarded, _ = nm.merge_guarded(None, start, passes, None, depth=0)
    assert {a // 10 for _, a in state.merged} == set(range(n_passes)) - bad
    assert len(attempts) == (2 if guarded else 1)      # the whole batch, then the guard's groups at once
    assert not attempts[0].accepted
    assert not ({a // 10 for _, a in unguarded.merged} & bad)


class _StartSmoother:
    """A smoother stood in for: a solution remembers the start it was smoothed from, and its cost is the test's cost
    for that start ("current": from the current solution, "fresh": from the second start)."""

    def __init__(self, costs: dict[str, float]):
        self.costs = costs

    def smooth(self, names, *, initial_poses, **_):
        return SimpleNamespace(problem=None), SimpleNamespace(start=initial_poses)

    def cost(self, problem, solution):
        return self.costs[solution.start]


def _two_names():
    """Names 0 and 1 (two sightings each), to be merged; the state before costs ``costs["before"]``."""
    current = SimpleNamespace(names=np.array([0, 0, 1, 1]), named=SimpleNamespace(names=np.array([0, 1]), problem=None),
                              solution=SimpleNamespace(landmarks=np.zeros((2, 2)), poses="current", start="before"))
    return current, {1: 0}


@pytest.mark.parametrize("fresh_cost, kept", [(104.0, True), (130.0, False)])
def test_a_refused_batch_is_kept_when_the_fresh_start_s_rise_is_within_the_bound(fresh_cost, kept):
    smoother = _StartSmoother({"before": 100.0, "current": 130.0, "fresh": fresh_cost})   # bound: χ²₂ 99 % = 9.21
    current, clusters = _two_names()
    starts = []

    def fresh_start(names):
        starts.append(names.copy())
        return "fresh", {}

    refused = nm.apply_merges(smoother, current, clusters)
    assert not refused.accepted and refused.rise == pytest.approx(30.0)
    assert refused.names is current.names and refused.merged == [(0, 1)]
    attempt = nm.apply_merges(smoother, current, clusters, fresh_start=fresh_start)
    assert len(starts) == 1 and np.array_equal(starts[0], [0, 0, 0, 0])   # the guess gets the merged names
    assert attempt.accepted is kept
    assert attempt.rise == pytest.approx(min(fresh_cost, 130.0) - 100.0)
    assert (attempt.solution.start == "fresh") is kept


def test_a_kept_batch_never_calls_the_fresh_start():
    current, clusters = _two_names()

    def fresh_start(names):
        raise AssertionError("a kept batch needs no other start")

    kept = nm.apply_merges(_StartSmoother({"before": 100.0, "current": 105.0}), current, clusters,
                           fresh_start=fresh_start)
    assert kept.accepted and np.array_equal(kept.names, [0, 0, 0, 0])


def test_a_batch_whose_every_merge_the_audit_holds_back_keeps_nothing_and_is_not_refused():
    smoother = _StartSmoother({"before": 100.0, "current": 102.0})
    current, clusters = _two_names()
    held = nm.apply_merges(smoother, current, clusters, audit=lambda before, attempt: {0, 1})
    assert held.accepted and held.merged == [] and held.names is current.names   # not bisected: nothing to cut
    assert nm.apply_merges(smoother, current, clusters, audit=lambda before, attempt: set()).merged == [(0, 1)]
