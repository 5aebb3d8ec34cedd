"""benchmarks/mrclam_constellation's ``--pairwise-alone`` (session 32, A): :func:`estimation.name_chain.alone_checked`
with the run's smoother stood in for, and the benchmark's record of it. The merges it checks, ``--fresh-start``'s
second start and ``--audit-parts``' held-back batches are :mod:`estimation.name_merging`'s
(tests/estimation/test_name_merging.py); ``--mutual-rounds``' clusters and the audit's regrouping
:mod:`estimation.pass_matching`'s (tests/estimation/test_pass_matching.py)."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import benchmarks.mrclam_constellation as mc
from estimation.name_chain import ChainObserver, alone_checked
from estimation.name_merging import merge_once
from estimation.pass_matching import PassVerdict, merges_from


class _PenaltySmoother:
    """A smoother stood in for: a naming's cost is 100 plus the penalty of each name it no longer holds."""

    def __init__(self, penalty: dict[int, float]):
        self.penalty = penalty

    def smooth(self, names, **_):
        cost = 100.0 + sum(p for x, p in self.penalty.items() if x not in names)
        return SimpleNamespace(problem=None), SimpleNamespace(cost=cost)

    def cost(self, problem, solution):
        return solution.cost


def test_pairwise_alone_leaves_out_the_group_whose_own_rise_its_batch_would_hide():
    # names 0..3, two groups: {0, 1} costs 2.0 merged, {2, 3} 9.6 (beyond χ²₂ 99 % = 9.21 for one absorbed name);
    # together 11.6, within χ²₄ 99 % = 13.28: the batch alone would keep the wrong group (session 32, A)
    smoother = _PenaltySmoother({1: 2.0, 3: 9.6})
    current = SimpleNamespace(names=np.array([0, 0, 1, 1, 2, 2, 3, 3]),
                              named=SimpleNamespace(names=np.arange(4), problem=None),
                              solution=SimpleNamespace(landmarks=np.zeros((4, 2)), poses=None, cost=100.0))
    groups = [PassVerdict(-1, "matched", [(0, 1)], (1, 1.0), 1, True),
              PassVerdict(-2, "matched", [(2, 3)], (1, 1.0), 1, True)]
    covisible = np.zeros((4, 4), bool)
    assert merge_once(smoother, current, merges_from(groups, covisible)[0]).accepted
    told = []

    class Told(ChainObserver):
        def alone_checked(self, number, state, used, rises, absorbed, refused):
            told.append((number, used, rises, absorbed, refused))

    kept = alone_checked(smoother, current, groups, covisible, observer=Told(), number=3)
    assert kept == groups[:1]
    [(number, used, rises, absorbed, refused)] = told
    assert number == 3 and used == groups and absorbed == [1, 1] and list(refused) == [False, True]
    # the benchmark's record of it, scored by the barcodes (names 2 and 3 are of two posts)
    record = mc._alone_record(current, used, rises, absorbed, refused, np.array([6, 6, 8, 9]))
    assert [(g["group"], g["refused"], g["wrong"]) for g in record] == [([0, 1], False, False), ([2, 3], True, True)]
    assert [g["rise"] for g in record] == pytest.approx([2.0, 9.6])
