"""benchmarks/mrclam_constellation's session-31 and 32 options, through the benchmark's own functions with the
smoother and its cost stood in for: ``--fresh-start`` (helper A: a refused whole batch judged again from the filter's
guess), ``--audit-parts`` (helper C: a batch whose every merge the audit holds back keeps nothing) and
``--pairwise-alone``. ``--mutual-rounds``' clusters and the audit's regrouping are
:mod:`estimation.pass_matching`'s (tests/estimation/test_pass_matching.py)."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import benchmarks.mrclam_constellation as mc


def _matched(i, pairs):
    return mc.PassVerdict(i, "matched", pairs, (len(pairs), 1.0), 1, True)


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
