"""benchmarks.mrclam_pass_support: the support of a merge group counted from synthetic pass verdicts (no data set)."""
from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from benchmarks.mrclam_pass_support import (
    held_passes,
    hold_back,
    split_by_visits,
    support_of,
    visit_labels,
    without_groups,
)
from estimation.pass_matching import PassVerdict, merges_from


def matched(index: int, pairs, best: int | None = None, earlier: int = 1) -> PassVerdict:
    pairs = [tuple(p) for p in pairs]
    return PassVerdict(index, "matched", pairs, (len(pairs) if best is None else best, float("inf")), earlier, True)


def test_adjacent_passes_are_one_visit_and_other_groups_passes_do_not_count():
    group = [(0, 1), (0, 2)]
    verdicts = [matched(3, [(1, 0), (7, 8)]), matched(4, [(2, 0)]), matched(9, [(0, 1)]),
                matched(5, [(7, 8)]),                               # another group's pass
                PassVerdict(6, "ambiguous")]
    [support] = support_of(verdicts, [group])
    assert support.passes == (3, 4, 9)
    assert support.visits == 2                                       # 3 and 4 are one passage cut by the grid
    assert support.span_passes == 6
    assert support.pass_pairings == (2, 1, 1)
    [apart] = support_of(verdicts, [group], visit_gap=1)
    assert apart.visits == 3


def test_visit_labels_start_a_new_visit_at_the_gap():
    assert visit_labels([1, 2, 4, 5, 9], 2) == {1: 0, 2: 0, 4: 1, 5: 1, 9: 2}
    assert visit_labels([1, 2, 4], 3) == {1: 0, 2: 0, 4: 0}


def test_a_group_joined_by_one_visit_alone_is_cut_there():
    # {1, 2} and {3, 4} each joined by two visits (passes 0 and 10); the bridge 2-3 only by pass 20
    verdicts = [matched(0, [(1, 2), (3, 4)]), matched(10, [(2, 1), (4, 3)]), matched(20, [(2, 3)])]
    group = [(1, 2), (1, 3), (1, 4)]
    parts, held = split_by_visits(verdicts, group)
    assert sorted(map(sorted, parts)) == [[1, 2], [3, 4]]
    assert held == {(2, 3, 20)}
    # a second visit (pass 30, not adjacent to 20) joining the two halves keeps the group whole
    parts, held = split_by_visits(verdicts + [matched(30, [(1, 4)])], group)
    assert [sorted(p) for p in parts] == [[1, 2, 3, 4]] and held == set()
    # but pass 21 is the same visit as 20: still cut
    parts, held = split_by_visits(verdicts + [matched(21, [(1, 4)])], group)
    assert sorted(map(sorted, parts)) == [[1, 2], [3, 4]]


def _connected(nodes: set[int], edges) -> bool:
    if len(nodes) < 2:
        return True
    reach, todo = set(), [min(nodes)]
    while todo:
        x = todo.pop()
        if x in reach:
            continue
        reach.add(x)
        todo += [b if a == x else a for a, b in edges if x in (a, b)]
    return reach == nodes


@given(st.lists(st.tuples(st.integers(0, 5), st.integers(0, 5), st.integers(0, 12)), min_size=1, max_size=14))
def test_every_part_left_stays_joined_without_any_one_visit(raw):
    edges = [(a, b, p) for a, b, p in raw if a != b]
    if not edges:
        return
    verdicts = [matched(p, [(a, b) for a, b, q in edges if q == p]) for p in sorted({p for _, _, p in edges})]
    members = sorted({x for a, b, _ in edges for x in (a, b)})
    group = [(members[0], m) for m in members[1:]]
    parts, held = split_by_visits(verdicts, group)
    seen = [x for p in parts for x in p]
    assert len(seen) == len(set(seen)) and set(seen) <= set(members)
    visit = visit_labels(sorted({p for _, _, p in edges}), 2)
    for part in parts:
        inside = [(a, b, p) for a, b, p in edges if a in part and b in part]
        for v in set(visit.values()):
            assert _connected(part, [(a, b) for a, b, p in inside if visit[p] != v])
    where = {x: k for k, p in enumerate(parts) for x in p}
    for a, b, _ in held:        # a held pairing never lies inside one part
        assert a not in where or b not in where or where[a] != where[b]


def test_a_pass_of_three_pairings_is_held_out_of_the_merges():
    verdicts = [matched(2, [(10, 0), (11, 1), (12, 2)]), matched(5, [(13, 3), (14, 4), (15, 5), (16, 6)]),
                PassVerdict(7, "too_few")]
    out = held_passes(verdicts, "< 4 pairings in all")
    assert [v.status for v in out] == ["held", "matched", "too_few"]
    clusters, used = merges_from(out, np.zeros((20, 20), bool))
    assert [v.index for v in used] == [5]
    assert set(clusters) == {13, 14, 15, 16}          # the absorbed names: none of the held pass's
    assert held_passes(verdicts, "one earlier pass matched")[1].status == "held"
    assert held_passes([matched(5, [(13, 3)], best=1, earlier=2)], "one earlier pass matched")[0].status == "matched"


def test_hold_back_names_the_groups_one_visit_proposes_and_without_groups_drops_their_pairings():
    groups = [[(0, 1)], [(2, 3)]]
    verdicts = [matched(1, [(1, 0), (3, 2)]), matched(8, [(3, 2)])]
    assert hold_back(verdicts, groups, rule="one visit") == [0]
    assert hold_back(verdicts, groups, rule="one pass") == [0]
    left = without_groups(verdicts, [groups[0]])
    assert [(v.index, v.pairs) for v in left] == [(1, [(3, 2)]), (8, [(3, 2)])]
    assert without_groups([matched(1, [(1, 0)])], [groups[0]]) == []


def test_deferred_weak_passes_wait_only_behind_a_stronger_one():
    weak = matched(2, [(10, 0), (11, 1), (12, 2)])
    strong = matched(5, [(13, 3), (14, 4), (15, 5), (16, 6)])
    alone = held_passes([weak], "< 4 pairings in all", defer=True)
    assert [v.status for v in alone] == ["matched"]                  # nothing stronger: it is taken
    assert [v.status for v in held_passes([weak], "< 4 pairings in all")] == ["held"]
    behind = held_passes([weak, strong, PassVerdict(7, "ambiguous")], "< 4 pairings in all", defer=True)
    assert [v.status for v in behind] == ["held", "matched", "ambiguous"]
