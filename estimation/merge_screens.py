"""The checks a round's proposed merges go through in the unknown-association chain
(:func:`estimation.name_chain.run_chain`), each a decision on its own, without the barcodes:

- the honest-names screen (:func:`flagged_names`, :func:`without_flagged`): a name holding a run of sightings the
  rest of the map bends to fit keeps its pairings out of the merges;
- the guard (:func:`guard_groups`, :class:`Guard`): the merge groups' leave-one-out shares, a group that cannot be
  one point set aside;
- the part audit (:func:`audit_parts`, :class:`PartAudit`): a kept batch audited part by part on its merged map.

Split out of :mod:`estimation.name_chain` in session 37 (B), unchanged (each session that measured one is in its
docstring).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimation.constellation import guard_batches
from estimation.landmark_smoother import Smoothed
from estimation.map_honesty import Run, flagged_landmarks, self_covisible_frames, sighting_runs, split_scores
from estimation.merge_audit import covisible_spacing, held_parts, merged_parts, part_splits
from estimation.named_smoothing import MergeRound
from estimation.pass_matching import PassVerdict, merges_from, without_pairings

__all__ = ["Guard", "PartAudit", "audit_parts", "flagged_names", "guard_groups", "without_flagged"]


@dataclass(frozen=True)
class Guard:
    """The guard's verdict on a round's merge groups (:func:`guard_groups`): the groups (pairings (root, member),
    in root order), the indices kept and the set-aside ones as (index, d², dof), and the kept groups as verdicts,
    largest first."""

    groups: list[list[tuple[int, int]]]
    keep: list[int]
    dropped: list[tuple[int, float, int]]
    kept: list[PassVerdict]



@dataclass(frozen=True)
class PartAudit:
    """A kept batch audited part by part (:func:`audit_parts`): the parts (runs of the merged map), each part's
    name before the merge, the verdict (:func:`estimation.merge_audit.held_parts`), which parts are held back, the
    map's co-visible spacing and the held names as landmark indices of the state before."""

    parts: list[Run]
    earlier: list[int]
    verdict: dict
    hold: np.ndarray
    spacing_m: float
    held: set[int]


def flagged_names(problem, solution: Smoothed, alpha: float, gap_s: float = 5.0, two_points: bool = False
                  ) -> np.ndarray:
    """(L,) the names holding a run of sightings (cut at gaps over ``gap_s``) whose split score
    (:func:`estimation.map_honesty.split_scores`: the first-order cost drop if the run were a name of its own) is
    beyond χ²₂ at 1 − α/k, k the name's runs (helper B, session 27: the screen that refused session 26's two wrong
    pairwise merges on robots 3 and 2, seed 0). ``two_points`` (session 30, C): also every name sighted twice in one
    frame (:func:`estimation.map_honesty.self_covisible_frames`: a camera reports a post once a frame, so such a name
    holds two posts, whatever its split scores say), so that its pairings are held back from the merges rather than
    cut (session 29, D: cutting changed which passes the loose first round matched)."""
    runs = sighting_runs(problem, solution, gap_s)
    flagged = flagged_landmarks(runs, split_scores(problem, solution, runs), len(solution.landmarks), alpha)
    if two_points:
        flagged |= self_covisible_frames(problem) > 0
    return flagged


def without_flagged(current: MergeRound, verdicts: list[PassVerdict], alpha: float, two_points: bool = False
                    ) -> tuple[list[PassVerdict], np.ndarray]:
    """``honest_rounds``: the matched passes without their pairings of a name the split-score screen flags
    (:func:`flagged_names`: a run of its sightings the rest of the map bends to fit); a pass left without pairings
    merges nothing. Session 27 (B) measured it refusing robot 2 seed 0's round-2 and robot 3 seed 2's round-1 wrong
    merges. Returns the verdicts kept and the flags."""
    flagged = flagged_names(current.named.problem, current.solution, alpha, two_points=two_points)
    return without_pairings(verdicts, lambda a, b: flagged[a] or flagged[b]), flagged


def guard_groups(current: MergeRound, covariance: np.ndarray, used: list[PassVerdict], covisible: np.ndarray
                 ) -> Guard:
    """:func:`estimation.constellation.guard_batches` on the groups of names a round would merge (the clusters
    :func:`estimation.pass_matching.merges_from` makes of the passes' pairings: disjoint, so each group's share is its
    own; a pairing that several passes hold, as a wrong one did on robot 2, leaves each pass a share of 0 degrees of
    freedom). The kept groups are verdicts of pairings (root, member) for
    :func:`estimation.name_merging.merge_bisecting`, largest first."""
    clusters = merges_from(used, covisible)[0]
    members: dict[int, list[int]] = {}
    for k, r in clusters.items():
        if k != r:
            members.setdefault(r, []).append(k)
    groups = [[(r, k) for k in sorted(members[r])] for r in sorted(members)]
    keep, dropped = guard_batches(current.solution.landmarks, covariance, groups)
    kept = sorted((groups[i] for i in keep), key=len, reverse=True)
    return Guard(groups, keep, dropped,
                 [PassVerdict(-1 - i, "matched", g, (len(g), 0.0), 0, True) for i, g in enumerate(kept)])


def audit_parts(current: MergeRound, attempt: MergeRound, *, floor_m: float, untestable: bool = True
                ) -> PartAudit | None:
    """A kept batch ``attempt`` (from ``current``) audited part by part on its merged map
    (:func:`estimation.merge_audit.held_parts` at ``floor_m``: a part is refused when its floored split score is
    beyond χ²₂ Bonferroni over the batch's parts; with ``untestable`` (the rounds), also held when its offset is as
    wide as the nearest two posts stand). None when the batch merged no parts."""
    named, solution = attempt.named, attempt.solution
    before = current.names[named.sightings]
    parts = merged_parts(named.problem, solution, before)
    if not parts:
        return None
    splits = part_splits(named.problem, solution, parts)
    spacing = covisible_spacing(named.problem, solution)
    verdict = held_parts(splits, floor_m=floor_m, spacing_m=spacing)
    hold = verdict["refused"] | (verdict["untestable"] & untestable)
    earlier = [int(before[p.sightings[0]]) for p in parts]
    index = {int(x): k for k, x in enumerate(current.named.names)}
    return PartAudit(parts, earlier, verdict, hold, spacing, {index[e] for e, h in zip(earlier, hold, strict=True)
                                                               if h})
