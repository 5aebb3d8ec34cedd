"""estimation/pass_matching: passes of named landmarks judged against earlier passes, and the merges they propose.

Synthetic maps (no data set): rows of posts for the joint test's options, random verdicts and co-visibility for the
merge clusters (properties: a cluster never holds two names sighted in one frame, every used pass's pairings end in one
cluster, a pass is left out only when it would join co-visible names), and random groups for the regrouping helpers.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation import chi2
from estimation.constellation import pairwise_d2
from estimation.pass_matching import (
    Pass,
    PassVerdict,
    judge_passes,
    merges_from,
    mutual_merges,
    passes_of,
    without_members,
    without_pairings,
)
from tests.datasets.test_constellation import _row_of_posts

GATE = float(chi2.ppf(0.99, 2))


def _matched(i, pairs, strength=None):
    return PassVerdict(i, "matched", pairs, strength or (len(pairs), 1.0), 1, True)


def _groups(clusters):
    members = {}
    for k, r in clusters.items():
        members.setdefault(r, {r}).add(k)
    return list(members.values())


def test_judge_passes_refuses_a_shifted_row_with_fewer_rival_and_matches_it_without():
    positions, covariance = _row_of_posts(1.35)
    covisible = np.zeros((6, 6), bool)
    covisible[:3, :3] = covisible[3:, 3:] = True          # each pass's posts were sighted together
    passes = [Pass(0.0, 20.0, np.arange(3)), Pass(20.0, 40.0, np.arange(3, 6))]
    plain = judge_passes(positions, covariance, covisible, passes, min_pairs=3, ratio=np.inf)
    assert [v.status for v in plain] == ["no_earlier", "matched"] and plain[1].pairs == [(3, 0), (4, 1), (5, 2)]
    for options in ({"fewer_rival": True}, {"fewer_rival": True, "distinct_points": True}):
        refused = judge_passes(positions, covariance, covisible, passes, min_pairs=3, ratio=np.inf, **options)
        assert [v.status for v in refused] == ["no_earlier", "ambiguous"] and refused[1].pairs == []


def test_a_pass_holding_only_names_an_earlier_pass_holds_has_nothing_to_test():
    positions, covariance = _row_of_posts(1.35)
    covisible = np.zeros((6, 6), bool)
    passes = [Pass(0.0, 20.0, np.arange(3)), Pass(20.0, 40.0, np.arange(3))]
    assert [v.status for v in judge_passes(positions, covariance, covisible, passes, min_pairs=3, ratio=np.inf)] == \
        ["no_earlier", "no_earlier"]


def test_passes_cut_the_log_into_spans_and_hold_names_with_enough_kept_sightings():
    # frames at 0..9 s (pose k + 1 is frame k, as in the smoother's problem); name 0 sighted every second, name 1
    # three times before 5 s (one sighting dropped), name 2 three times after 5 s
    pose_index = np.array([1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 1, 2, 3, 7, 8, 9])
    landmark_index = np.array([0] * 10 + [1, 1, 1, 2, 2, 2])
    inliers = np.ones(16, bool)
    inliers[12] = False
    problem = SimpleNamespace(pose_index=pose_index, landmark_index=landmark_index)
    named = SimpleNamespace(problem=problem, frame_times=np.arange(10.0))
    solution = SimpleNamespace(inliers=inliers)
    passes = passes_of(named, solution, 5.0, 2)
    assert [(p.start, p.end) for p in passes] == [(0.0, 5.0), (5.0, 10.0)]
    assert [p.landmarks.tolist() for p in passes] == [[0, 1], [0, 2]]
    assert [p.landmarks.tolist() for p in passes_of(named, solution, 5.0, 3)] == [[0], [0, 2]]


def test_merges_join_the_strongest_passes_first_and_never_two_names_seen_together():
    covisible = np.eye(8, dtype=bool)
    covisible[5, 7] = covisible[7, 5] = True             # names 5 and 7 were sighted in one frame
    strong = PassVerdict(0, "matched", [(4, 0), (5, 1), (6, 2)], (3, 9.0))
    clash = PassVerdict(1, "matched", [(7, 3), (1, 7)], (3, 2.0))   # after the strong one: 7 ~ 1 ~ 5
    refused = PassVerdict(2, "ambiguous")
    clusters, used = merges_from([clash, refused, strong], covisible)
    assert used == [strong]
    assert {k: clusters[k] for k in (4, 5, 6)} == {4: 0, 5: 1, 6: 2}
    assert 7 not in clusters and 3 not in clusters


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2 ** 32 - 1))
def test_clusters_hold_no_covisible_pair_and_every_used_pass_whole(seed):
    rng = np.random.default_rng(seed)
    n = 12
    covisible = rng.random((n, n)) < 0.15
    covisible = covisible | covisible.T
    verdicts = [_matched(i, [tuple(int(x) for x in rng.choice(n, 2, replace=False))
                             for _ in range(rng.integers(1, 4))], (int(rng.integers(1, 4)), float(rng.random())))
                for i in range(8)] + [PassVerdict(8, "ambiguous")]
    clusters, used = merges_from(verdicts, covisible)
    root = {k: clusters.get(k, k) for k in range(n)}
    for group in _groups(clusters):
        g = sorted(group)
        assert not covisible[np.ix_(g, g)][~np.eye(len(g), dtype=bool)].any()
    for v in used:
        assert all(root[a] == root[b] for a, b in v.pairs)
    assert all(v.status == "matched" for v in used)
    # a matched pass left out would have joined co-visible names: adding it back to the used ones shows the clash
    for v in verdicts:
        if v.status == "matched" and v not in used:
            both = merges_from(used + [_judged_last(v)], covisible)[1]
            assert v.index not in [u.index for u in both]


def _judged_last(v: PassVerdict) -> PassVerdict:
    """``v`` made the weakest of all (judged last), so that it is tried on top of the passes used."""
    return PassVerdict(v.index, v.status, v.pairs, (-1, -np.inf), v.matched_earlier, v.unique)


def test_a_loose_name_does_not_join_two_tight_names_that_cannot_be_one_point():
    # post 9's tight name 0 and a tight glimpse 1 of post 8, 1.16 m apart; name 2 of post 9 loose (σ 0.5 m) between
    positions = np.array([[0.0, 0.0], [1.16, 0.0], [0.3, 0.0]])
    covariance = np.diag(np.repeat([0.15, 0.3, 0.5], 2) ** 2)
    covisible = np.zeros((3, 3), bool)
    verdicts = [_matched(0, [(2, 0)]), _matched(1, [(2, 1)])]          # each pass: the loose name and one partner
    assert merges_from(verdicts, covisible)[0] == {1: 0, 2: 0}          # one cluster through the loose name
    clusters, used, aside = mutual_merges(verdicts, covisible, positions, covariance)
    assert aside == [[0, 1, 2]] and clusters == {} and used == []
    clusters, used, aside = mutual_merges(verdicts[:1], covisible, positions, covariance)
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
    clusters, used, aside = mutual_merges(verdicts, covisible, positions, covariance)
    for m in _groups(clusters):
        m = sorted(m)
        assert np.all(pairwise_d2(positions, covariance, m)[np.triu_indices(len(m), 1)] < GATE)
    for m in aside:
        assert np.any(pairwise_d2(positions, covariance, m)[np.triu_indices(len(m), 1)] >= GATE)
        assert not set(m) & (set(clusters) | set(clusters.values()))


@given(st.lists(st.integers(0, 5), max_size=25), st.sets(st.integers(0, 24)))
def test_names_held_back_leave_their_groups_and_the_rest_stay_together(group_of, out):
    groups = {}
    for index, group in enumerate(group_of):
        groups.setdefault(group, set()).add(index)
    clusters = {k: min(m) for m in groups.values() for k in m if k != min(m)}     # index -> root, as merges_from
    kept = without_members(clusters, out)
    assert not (set(kept) | set(kept.values())) & out
    expected = [m - out for m in groups.values() if len(m - out) >= 2]
    assert sorted(map(sorted, _groups(kept))) == sorted(map(sorted, expected))


def test_without_pairings_drops_pairings_and_the_matched_passes_left_without_any():
    verdicts = [_matched(0, [(1, 0), (2, 3)]), _matched(1, [(4, 5)]), PassVerdict(2, "ambiguous")]
    kept = without_pairings(verdicts, lambda a, b: 4 in (a, b) or 2 in (a, b))
    assert [(v.index, v.status, v.pairs) for v in kept] == [(0, "matched", [(1, 0)]), (2, "ambiguous", [])]
    assert verdicts[0].pairs == [(1, 0), (2, 3)]                         # the input is not changed
