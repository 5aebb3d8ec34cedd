"""estimation.fresh_start.judge_at_starts: the cost check of a batch of merges at the least cost over its starts."""
from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from estimation.fresh_start import judge_at_starts

costs = st.floats(min_value=0.0, max_value=1e6, allow_nan=False)


def test_a_batch_refused_from_the_current_solution_is_kept_when_a_fresh_start_finds_a_lower_minimum():
    # robot 5 seed 2's round 2 (session 31): 202.3 over the bound 195.5 from the current solution, 166.1 from the guess
    before = 9000.0
    verdict = judge_at_starts(before, [before + 202.3, before + 166.1], 195.5)
    assert verdict.best == 1 and verdict.accepted and verdict.rise == pytest.approx(166.1)
    alone = judge_at_starts(before, [before + 202.3], 195.5)
    assert not alone.accepted and alone.rise == pytest.approx(202.3)


def test_a_failed_start_never_wins():
    verdict = judge_at_starts(10.0, [30.0, math.nan, math.inf], 25.0)
    assert verdict.best == 0 and verdict.rise == pytest.approx(20.0) and verdict.accepted


def test_no_start_is_refused():
    with pytest.raises(ValueError):
        judge_at_starts(0.0, [], 1.0)


@given(before=costs, first=costs, more=st.lists(costs, max_size=4), bound=st.floats(min_value=0.0, max_value=1e3))
def test_the_rise_is_the_least_cost_over_the_starts_and_another_start_never_raises_it(before, first, more, bound):
    alone = judge_at_starts(before, [first], bound)
    verdict = judge_at_starts(before, [first, *more], bound)
    assert verdict.rise == pytest.approx(min([first, *more]) - before)
    assert verdict.rise <= alone.rise
    assert verdict.accepted == (verdict.rise <= bound)
    assert alone.accepted <= verdict.accepted            # a start can only keep a batch the current one refused
    assert verdict.costs[verdict.best] == min(verdict.costs)
