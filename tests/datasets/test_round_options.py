"""benchmarks/mrclam_constellation's session-31 options, through the benchmark's own functions with the smoother and
its cost stood in for: ``--mutual-rounds`` (helper B: a round's cluster merges only when its members are all within
each other's gate), ``--fresh-start`` (helper A: a refused whole batch judged again from the filter's guess) and
``--audit-parts``' regrouping (helper C: the names an audit holds back leave their groups)."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import benchmarks.mrclam_constellation as mc
from estimation import chi2
from estimation.constellation import pairwise_d2

GATE = float(chi2.ppf(0.99, 2))


def _matched(i, pairs):
    return mc.PassVerdict(i, "matched", pairs, (len(pairs), 1.0), 1, True)


def test_a_loose_name_does_not_join_two_tight_names_that_cannot_be_one_point():
    # post 9's tight name 0 and a tight glimpse 1 of post 8, 1.16 m apart; name 2 of post 9 loose (σ 0.5 m) between
    positions = np.array([[0.0, 0.0], [1.16, 0.0], [0.3, 0.0]])
    covariance = np.diag(np.repeat([0.15, 0.3, 0.5], 2) ** 2)
    covisible = np.zeros((3, 3), bool)
    verdicts = [_matched(0, [(2, 0)]), _matched(1, [(2, 1)])]          # each pass: the loose name and one partner
    assert mc.merges_from(verdicts, covisible)[0] == {1: 0, 2: 0}       # one cluster through the loose name
    clusters, used, aside = mc.mutual_merges(verdicts, covisible, positions, covariance)
    assert aside == [[0, 1, 2]] and clusters == {} and used == []
    clusters, used, aside = mc.mutual_merges(verdicts[:1], covisible, positions, covariance)
    assert clusters == {2: 0} and aside == []                            # the loose name and one partner merge


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2 ** 16))
def test_every_cluster_merged_is_mutually_within_the_gate_and_every_one_set_aside_is_not(seed):
    rng = np.random.default_rng(seed)
    n = 10
    positions = rng.uniform(0, 3, (n, 2))
    covariance = np.diag(np.repeat(rng.uniform(0.05, 0.8, n), 2) ** 2)
    covisible = np.zeros((n, n), bool)
    verdicts = [_matched(i, [tuple(int(x) for x in rng.choice(n, 2, replace=False))]) for i in range(8)]
    clusters, used, aside = mc.mutual_merges(verdicts, covisible, positions, covariance)
    members = {}
    for k, r in clusters.items():
        members.setdefault(r, {r}).add(k)
    for m in members.values():
        m = sorted(m)
        assert np.all(pairwise_d2(positions, covariance, m)[np.triu_indices(len(m), 1)] < GATE)
    for m in aside:
        assert np.any(pairwise_d2(positions, covariance, m)[np.triu_indices(len(m), 1)] >= GATE)
        assert not set(m) & (set(clusters) | set(clusters.values()))


def _one_merge_batch(monkeypatch, costs: dict[str, float]):
    """Two names (0, 1) merged; the smoother stood in for: each smoothing's cost by its start ("current" or
    "fresh"), the state before at ``costs["before"]``."""
    current = SimpleNamespace(names=np.array([0, 0, 1, 1]), named=SimpleNamespace(names=np.array([0, 1]), problem=None),
                              solution=SimpleNamespace(landmarks=np.zeros((2, 2)), poses="current", start="before"))

    def smooth(log, names, noise, config, *, initial_poses, **_):
        return SimpleNamespace(problem=None), SimpleNamespace(start=initial_poses)

    monkeypatch.setattr(mc, "_smooth_named", smooth)
    monkeypatch.setattr(mc, "truncated_cost", lambda problem, solution: costs[solution.start])
    return current, {1: 0}


@pytest.mark.parametrize("fresh_cost, kept", [(104.0, True), (130.0, False)])
def test_a_refused_batch_is_kept_when_the_fresh_start_s_rise_is_within_the_bound(monkeypatch, fresh_cost, kept):
    costs = {"before": 100.0, "current": 130.0, "fresh": fresh_cost}   # bound for one merge: χ²₂ 99 % = 9.21
    current, clusters = _one_merge_batch(monkeypatch, costs)
    starts = []

    def fresh_start(names):
        starts.append(names.copy())
        return "fresh", {}

    refused = mc.apply_merges(None, current, clusters, None, None, None)
    assert not refused.accepted and refused.rise == pytest.approx(30.0)
    attempt = mc.apply_merges(None, current, clusters, None, None, None, fresh_start=fresh_start)
    assert len(starts) == 1 and np.array_equal(starts[0], [0, 0, 0, 0])   # the guess gets the merged names
    assert attempt.accepted is kept
    assert attempt.rise == pytest.approx(min(fresh_cost, 130.0) - 100.0)
    assert (attempt.solution.start == "fresh") is kept


def test_a_kept_batch_never_calls_the_fresh_start(monkeypatch):
    current, clusters = _one_merge_batch(monkeypatch, {"before": 100.0, "current": 105.0})

    def fresh_start(names):
        raise AssertionError("a kept batch needs no other start")

    assert mc.apply_merges(None, current, clusters, None, None, None, fresh_start=fresh_start).accepted


@given(st.lists(st.integers(0, 5), max_size=25), st.sets(st.integers(0, 24)))
def test_names_held_back_leave_their_groups_and_the_rest_stay_together(group_of, out):
    groups = {}
    for index, group in enumerate(group_of):
        groups.setdefault(group, set()).add(index)
    clusters = {k: min(m) for m in groups.values() for k in m if k != min(m)}     # index -> root, as merges_from
    kept = mc.without_members(clusters, out)
    assert not (set(kept) | set(kept.values())) & out
    regrouped = {}
    for k, r in kept.items():
        regrouped.setdefault(r, {r}).add(k)
    expected = [m - out for m in groups.values() if len(m - out) >= 2]
    assert sorted(map(sorted, regrouped.values())) == sorted(map(sorted, expected))


def test_a_batch_whose_every_merge_the_audit_holds_back_keeps_nothing_and_is_not_refused(monkeypatch):
    current, clusters = _one_merge_batch(monkeypatch, {"before": 100.0, "current": 102.0})
    monkeypatch.setitem(mc._AUDIT, "floor_m", 0.042)
    monkeypatch.setattr(mc, "audit_batch", lambda log, before, attempt: {0, 1})
    held = mc.apply_merges(None, current, clusters, None, None, None)
    assert held.accepted and held.merged == [] and held.names is current.names   # not bisected: nothing to cut
    monkeypatch.setattr(mc, "audit_batch", lambda log, before, attempt: set())
    assert mc.apply_merges(None, current, clusters, None, None, None).merged == [(0, 1)]


def test_pairwise_alone_leaves_out_the_group_whose_own_rise_its_batch_would_hide(monkeypatch):
    # names 0..3, two groups: {0, 1} costs 2.0 merged, {2, 3} 9.6 (beyond χ²₂ 99 % = 9.21 for one absorbed name);
    # together 11.6, within χ²₄ 99 % = 13.28: the batch alone would keep the wrong group (session 32, A)
    penalty = {1: 2.0, 3: 9.6}
    current = SimpleNamespace(names=np.array([0, 0, 1, 1, 2, 2, 3, 3]),
                              named=SimpleNamespace(names=np.arange(4), problem=None),
                              solution=SimpleNamespace(landmarks=np.zeros((4, 2)), poses=None, cost=100.0))

    def smooth(log, names, noise, config, **_):
        return SimpleNamespace(problem=None), SimpleNamespace(cost=100.0 + sum(p for x, p in penalty.items()
                                                                              if x not in names))

    monkeypatch.setattr(mc, "_smooth_named", smooth)
    monkeypatch.setattr(mc, "truncated_cost", lambda problem, solution: solution.cost)
    groups = [_matched(-1, [(0, 1)]), _matched(-2, [(2, 3)])]
    covisible = np.zeros((4, 4), bool)
    assert mc._merge_once(None, current, mc.merges_from(groups, covisible)[0], None, None, None).accepted
    record = {}
    kept = mc._alone_checked(None, current, groups, covisible, record, np.array([6, 6, 8, 9]), None, None, None,
                             SimpleNamespace(path_step=0.0, progress=False))
    assert kept == groups[:1]
    assert [(g["group"], g["refused"], g["wrong"]) for g in record["alone"]] == [([0, 1], False, False),
                                                                                 ([2, 3], True, True)]
    assert [g["rise"] for g in record["alone"]] == pytest.approx([2.0, 9.6])
