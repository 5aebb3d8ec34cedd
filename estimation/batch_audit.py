"""Each merge group of a batch tested given the others, with what the test rests on (issue 13, MRCLAM without
barcodes; session 32, helper B).

The unknown-association rounds merge a batch of disjoint groups of names at once; the guard
(:func:`estimation.constellation.leave_one_out`) gives each group's share of the batch, d² of the group's pairings
given every other group's, as one number. Here the same share comes with the conditional offsets it is made of and
their covariance, so that one can ask not only "is the group beyond its bound" but "could the map have told this
group's post from a neighbour's at all" — :mod:`estimation.merge_audit`'s power question, asked before the merge on
the map the batch is judged on rather than on the merged map.

Measured (session 32, robot 3 seed 1 round 2, the wrong pairing of post 19's name 48 with post 20's name 11 inside
an accepted batch of 30): the share is 7.36 on 2 (the guard's own number), the offset 0.17 m with σ 0.038 × 0.126 m,
so the map *could* test it (widest σ × √χ²₂(99 %) = 0.38 m, within the 0.66 m at which two of its posts are seen in
one frame) and found it one point. Against the truth the difference's error has NEES 25.5: the map before the round
was confidently wrong there, which no test on it can see.

Why it was wrong: name 48 held, besides its 35 sightings of post 19 (488–503 s), one sighting of post 20 at 453.0 s,
35 s and an on-the-spot turn earlier (the odometry under-reports that turn by 0.22 rad). Kept as an inlier, that one
sighting pins the stretch after the turn so that post 19's sightings land on post 20's place (heading 0.23 rad off
at σ 0.078). Its split score is 1.8: the stretch bends to fit it almost for free, so the honest-names screen cannot
flag it. But it cannot be *tested* either: the offset of that one-sighting run from the rest of its name has a
widest σ of 0.36 m, so a neighbouring post 0.66 m away would score within χ²₂ 99 %. :func:`untestable_runs` finds
such runs (merge_audit's power rule on a name's runs instead of a merged name's parts). With that sighting unnamed,
the round's two passes holding name 48 are ambiguous and the wrong pairing is not made.

Measured end to end, negative: every untestable run of the round-0 map unnamed before the rounds (scratch driver,
the session-30 command) gives robot 3 seed 1 0 wrong merges and 15 names (fitted: the rule was found on it), but robot
2 seed 1 6 wrong merges (2 without) and robot 1 seed 0, which had none, 4: the changed loose maps send other
batches to the guard. Dropping instead each round's pairings of names that hold an untestable run leaves robot 1 seed
0 with 1 wrong merge (round 7). Not wired; the functions are the diagnosis's tools.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .landmark_smoother import LandmarkLogProblem, Smoothed
from .map_honesty import Run, minor_runs
from .merge_audit import covisible_spacing, held_parts, indistinguishable, part_splits

__all__ = ["GroupOffsets", "group_offsets", "untestable_groups", "untestable_runs"]


@dataclass(frozen=True)
class GroupOffsets:
    """For G groups: ``d2`` (G,) each group's share (its pairings' stacked differences given every other group's
    pairings hold, χ² with ``dof`` (G,) = 2 per absorbed member; NaN where a covariance is not finite), ``offsets``
    (per group (m, 2): member − root for each of its m pairings, conditioned on the others) and ``covariances``
    (per group (2m, 2m): those offsets' covariance given the others). d2 = offsetᵀ covariance⁻¹ offset."""

    d2: np.ndarray
    dof: np.ndarray
    offsets: list[np.ndarray]
    covariances: list[np.ndarray]

    def widest_sigma(self) -> np.ndarray:
        """(G,) the largest σ (m) along any axis of any one member's offset (its own 2 × 2 block; NaN without a
        finite share)."""
        out = np.full(len(self.d2), np.nan)
        for g, cov in enumerate(self.covariances):
            if np.isfinite(self.d2[g]):
                blocks = [cov[2 * i:2 * i + 2, 2 * i:2 * i + 2] for i in range(len(cov) // 2)]
                out[g] = float(np.sqrt(max(np.linalg.eigvalsh(b)[-1] for b in blocks)))
        return out


def group_offsets(positions: np.ndarray, covariance: np.ndarray, groups) -> GroupOffsets:
    """Each group's pairings (root, member) tested given all the other groups' (module docstring).

    positions (n, 2), covariance (2n, 2n) their joint covariance (rows of point i: 2i, 2i + 1); ``groups``: lists
    of pairings (root, member), disjoint (no point in two groups, none twice in one: a spanning set each). With S the
    covariance of all the batch's stacked differences δ and Λ = S⁻¹, a group's offsets given the others are
    Λ_gg⁻¹ (Λδ)_g with covariance Λ_gg⁻¹, and its d² is d²(all) − d²(all but g), leave_one_out's share."""
    positions = np.asarray(positions, float)
    groups = [[(int(a), int(b)) for a, b in g] for g in groups]
    seen: set[int] = set()
    for g in groups:
        points = {x for pair in g for x in pair}
        if len(points) != len(g) + 1 or points & seen:
            raise ValueError("the groups must be disjoint spanning sets of pairings (root, member)")
        seen |= points
    pairs = [pair for g in groups for pair in g]
    empty = GroupOffsets(np.full(len(groups), np.nan), np.array([2 * len(g) for g in groups], int),
                         [np.full((len(g), 2), np.nan) for g in groups],
                         [np.full((2 * len(g), 2 * len(g)), np.nan) for g in groups])
    if not pairs:
        return empty
    p = np.array([a for a, _ in pairs])
    q = np.array([b for _, b in pairs])
    ip = np.stack([2 * p, 2 * p + 1], 1).reshape(-1)
    iq = np.stack([2 * q, 2 * q + 1], 1).reshape(-1)
    c = np.asarray(covariance, float)
    s = c[np.ix_(iq, iq)] + c[np.ix_(ip, ip)] - c[np.ix_(iq, ip)] - c[np.ix_(ip, iq)]
    if not np.all(np.isfinite(s)):
        return empty
    delta = (positions[q] - positions[p]).reshape(-1)
    precision = np.linalg.inv(0.5 * (s + s.T))
    weighted = precision @ delta
    d2, offsets, covariances = [], [], []
    start = 0
    for g in groups:
        rows = np.arange(2 * start, 2 * (start + len(g)))
        start += len(g)
        conditional = np.linalg.inv(precision[np.ix_(rows, rows)])
        offset = conditional @ weighted[rows]
        d2.append(float(offset @ weighted[rows]))
        offsets.append(offset.reshape(-1, 2))
        covariances.append(0.5 * (conditional + conditional.T))
    return GroupOffsets(np.array(d2), np.array([2 * len(g) for g in groups], int), offsets, covariances)


def untestable_groups(shares: GroupOffsets, spacing_m: float, alpha: float = 0.01) -> np.ndarray:
    """(G,) bool: a group some member of which could be ``spacing_m`` (the nearest two posts are known to stand,
    :func:`estimation.merge_audit.covisible_spacing`) off along its widest axis and still test within χ²₂ at
    1 − α: the map cannot tell that member's post from a neighbour's (merge_audit's "untestable", before the merge)."""
    if not 0 < alpha < 1 or not spacing_m > 0:
        raise ValueError(f"need 0 < α < 1 and a spacing > 0 m, not {alpha} and {spacing_m}")
    wide = shares.widest_sigma()
    return np.isfinite(wide) & indistinguishable(np.nan_to_num(wide), spacing_m, alpha)


def untestable_runs(problem: LandmarkLogProblem, solution: Smoothed, *, gap_s: float = 5.0, alpha: float = 0.01
                    ) -> list[Run]:
    """The runs of a name's kept sightings (cut at gaps over ``gap_s``, :func:`estimation.map_honesty.sighting_runs`)
    that the map cannot test against the rest of their name: the run's offset from the rest could be the nearest
    distance at which two of the map's landmarks are seen in one frame
    (:func:`estimation.merge_audit.covisible_spacing`) along its widest axis and still score within χ²₂ at 1 − α
    (merge_audit's "untestable", on runs). A name's largest
    run is never returned (ties: the earliest): it is what the name is. Such a run holds the stretch it was seen from
    to wherever its name is, whether or not it is that name's post, and nothing can say which."""
    candidates = minor_runs(problem, solution, gap_s)
    if not candidates:
        return []
    splits = part_splits(problem, solution, candidates)
    verdict = held_parts(splits, floor_m=0.0, spacing_m=covisible_spacing(problem, solution), alpha=alpha)
    return [run for run, untestable in zip(candidates, verdict["untestable"], strict=True) if untestable]
