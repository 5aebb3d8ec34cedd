"""Loop closing of named landmarks by passes: the log cut into passes, each pass's names matched jointly against every
earlier pass's, and the merges the matched passes propose.

A pass is a span of the log (e.g. 20 s) and the names it holds. Over hundreds of seconds two names of one post
differ by metres (the open chain's loops), but within one pass the names' relative geometry is known to
centimetres, so a pass's names are tested against an earlier pass's *together*
(:func:`estimation.constellation.match_constellation`): matched when enough pairings are jointly compatible and no
rival is (:func:`judge_passes`). The matched passes' pairings become merge clusters, strongest pass first, never
joining two names sighted in one frame (:func:`merges_from`; :func:`mutual_merges` also sets aside a cluster whose
members are not all within each other's gate). Whether a batch of merges is kept is the caller's cost check on the
re-smoothed map (:mod:`estimation.named_smoothing`).

Measured in ``benchmarks/mrclam_constellation.py`` (its docstring, steps 2-4; docs/fastslam-history.md, "Session 24:
joint (constellation) tests of a pass's co-visible names (A)", with ``fewer_rival``/``distinct_points`` from
"Session 29 ... (A)" and :func:`mutual_merges` from "Session 31 ... (B)"). Moved here from the benchmark in session
36 (lead), unchanged. Decisions use the map alone: positions, their joint covariance, co-visibility; never the
data set's landmark identities.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from estimation import chi2
from estimation.constellation import joint_d2, match_constellation, pairwise_d2
from estimation.landmark_smoother import Smoothed, joint_landmark_covariance
from estimation.named_smoothing import MergeRound, NamedProblem, covisible_names

# a pass's outcome against the earlier passes (PassVerdict.status)
STATUSES = ("matched", "ambiguous", "too_few", "incompatible", "no_earlier")


@dataclass
class Pass:
    """One span of the log: [start, end) s, the landmark indices (of the named problem) it holds."""

    start: float
    end: float
    landmarks: np.ndarray


@dataclass
class PassVerdict:
    """A pass's outcome against every earlier pass: status, its pairings (landmark indices) when matched, the
    number of pairings and the smallest log likelihood ratio over a rival among the matched earlier passes."""

    index: int
    status: str
    pairs: list[tuple[int, int]] = field(default_factory=list)
    strength: tuple[int, float] = (0, 0.0)
    matched_earlier: int = 0
    unique: bool | None = None


def passes_of(named: NamedProblem, solution: Smoothed, seconds: float, min_sightings: int) -> list[Pass]:
    """The log cut into spans of ``seconds`` from its first frame; each span's landmarks with ≥ ``min_sightings``
    kept sightings in it."""
    problem = named.problem
    times = named.frame_times[problem.pose_index - 1]
    kept = solution.inliers
    out = []
    t = float(named.frame_times[0])
    end = float(named.frame_times[-1])
    while t <= end:
        rows = kept & (times >= t) & (times < t + seconds)
        marks, counts = np.unique(problem.landmark_index[rows], return_counts=True)
        out.append(Pass(t, t + seconds, marks[counts >= min_sightings]))
        t += seconds
    return out


def judge_passes(positions: np.ndarray, covariance: np.ndarray, covisible: np.ndarray, passes: list[Pass], *,
                 min_pairs: int, ratio: float, probability: float = 0.99, fewer_rival: bool = False,
                 distinct_points: bool = False) -> list[PassVerdict]:
    """Every pass against every earlier pass: positions (n, 2) and their joint covariance (2n, 2n), covisible
    (n, n) names sighted in one frame (never paired). Names both passes hold are pairings already made, counted
    towards ``min_pairs``; the others are tested (:func:`~estimation.constellation.match_constellation` at
    ``probability``, with ``ratio``, ``fewer_rival`` and ``distinct_points``). A pass matched against some earlier
    passes is refused as ambiguous when all their compatible hypotheses cannot hold together (two places in the map
    for one constellation)."""
    n = len(positions)
    allowed = ~covisible
    seen = np.isfinite(np.diagonal(covariance)).reshape(n, 2).all(axis=1)
    out = []
    for i, p in enumerate(passes):
        mine = [int(k) for k in p.landmarks if seen[k]]
        matched, statuses, hypotheses = [], [], []
        for q in passes[:i]:
            theirs = [int(k) for k in q.landmarks if seen[k]]
            # a name both passes hold is already one post: a pairing the constellation counts, with nothing to
            # test (its difference is zero by construction; the others' joint covariance carries it)
            shared = set(mine) & set(theirs)
            rest_p = [k for k in mine if k not in shared]
            rest_q = [k for k in theirs if k not in shared]
            if not rest_p or not rest_q:
                continue
            result = match_constellation(positions, covariance, rest_p, rest_q, allowed=allowed,
                                         min_pairs=max(min_pairs - len(shared), 1), probability=probability,
                                         ratio=ratio, fewer_rival=fewer_rival, distinct_points=distinct_points)
            statuses.append(result.status)
            if result.status == "matched":
                matched.append(result)
            if result.status in ("matched", "ambiguous"):
                hypotheses += [h for h in (result.best, result.rival) if h is not None]
        if matched:
            # every compatible hypothesis of enough pairings, against any earlier pass, must be able to hold
            # together with the matches: else the constellation has two places in the map
            pairs = sorted({pair for h in hypotheses for pair in h.pairs})
            d2, _ = joint_d2(positions, covariance, pairs)
            if d2 < chi2.ppf(probability, 2 * len(pairs)):
                strength = (max(len(m.best.pairs) for m in matched), min(m.log_ratio for m in matched))
                out.append(PassVerdict(i, "matched", pairs, strength, len(matched), True))
            else:
                out.append(PassVerdict(i, "ambiguous", [], (0, 0.0), len(matched), False))
            continue
        for status in ("ambiguous", "too_few", "incompatible"):
            if status in statuses:
                out.append(PassVerdict(i, status, unique=False if status == "ambiguous" else None))
                break
        else:
            out.append(PassVerdict(i, "no_earlier"))
    return out


def merges_from(verdicts: list[PassVerdict], covisible: np.ndarray) -> tuple[dict[int, int], list[PassVerdict]]:
    """{landmark: its cluster's root} from the matched passes' pairings, strongest pass first; a pass whose pairings
    would put two co-visible landmarks in one cluster is skipped whole. Returns the map and the passes used."""
    parent: dict[int, int] = {}
    members: dict[int, set[int]] = {}
    used = []
    for v in sorted((v for v in verdicts if v.status == "matched"), key=lambda v: (-v.strength[0], -v.strength[1])):
        trial_parent = dict(parent)
        trial_members = {k: set(s) for k, s in members.items()}
        ok = True
        for a, b in v.pairs:
            ra, rb = _root(trial_parent, a), _root(trial_parent, b)
            if ra == rb:
                continue
            ga, gb = trial_members.get(ra, {ra}), trial_members.get(rb, {rb})
            if covisible[np.ix_(sorted(ga), sorted(gb))].any():
                ok = False
                break
            keep, drop = min(ra, rb), max(ra, rb)
            trial_parent[drop] = keep
            trial_members[keep] = ga | gb
            trial_members.pop(drop, None)
        if ok:
            parent, members = trial_parent, trial_members
            used.append(v)
    return {x: _root(parent, x) for x in parent}, used


def mutual_merges(verdicts: list[PassVerdict], covisible: np.ndarray, positions: np.ndarray, covariance: np.ndarray,
                  probability: float = 0.99) -> tuple[dict[int, int], list[PassVerdict], list[list[int]]]:
    """:func:`merges_from`, with each cluster whose members are not all within each other's χ²₂ gate at
    ``probability`` (:func:`estimation.constellation.pairwise_d2`: the pairwise rounds' own link) set aside for the
    round: its names' pairings dropped from the matched passes and the clusters formed again, until none fails. A
    pass links each name to its partner only, so a loose name can join two tight names that no pass pairs and that
    cannot be one point (session 31, B: robot 1 seed 2's wrong merge, a 3-sighting glimpse of post 8 joined to post
    9's names through a post-9 name of σ 0.52 m, 1.16 m between the glimpse and post 9's names, d² 11.7–14.2).
    Returns the clusters, the passes used and the clusters set aside (landmark indices)."""
    gate = float(chi2.ppf(probability, 2))
    aside: list[list[int]] = []
    while True:
        clusters, used = merges_from(verdicts, covisible)
        members: dict[int, set[int]] = {}
        for k, r in clusters.items():
            members.setdefault(r, {r}).add(k)
        apart = [m for m in (sorted(x) for x in members.values())
                 if np.any(pairwise_d2(positions, covariance, m)[np.triu_indices(len(m), 1)] >= gate)]
        if not apart:
            return clusters, used, aside
        aside += apart
        out = {x for m in apart for x in m}
        verdicts = without_pairings(verdicts, lambda a, b, out=out: a in out or b in out)


def _root(parent: dict[int, int], x: int) -> int:
    while parent.get(x, x) != x:
        x = parent[x]
    return x


def without_pairings(verdicts: list[PassVerdict], drop) -> list[PassVerdict]:
    """``verdicts`` with the matched passes' pairings (a, b) for which ``drop(a, b)`` holds removed; a matched pass
    left without pairings goes (it would merge nothing), the other verdicts stay as they are."""
    kept = [dataclasses.replace(v, pairs=[(a, b) for a, b in v.pairs if not drop(a, b)]) if v.status == "matched"
            else v for v in verdicts]
    return [v for v in kept if v.status != "matched" or v.pairs]


def without_members(clusters: dict[int, int], out: set[int]) -> dict[int, int]:
    """``clusters`` (landmark index → root) without the indices ``out``: a group that loses its root takes its
    smallest member left as root, a group left with one name goes."""
    groups: dict[int, set[int]] = {}
    for k, r in clusters.items():
        groups.setdefault(r, {r}).add(k)
    kept = {}
    for r, members in groups.items():
        left = members - out
        if len(left) >= 2:
            root = r if r in left else min(left)
            kept.update({m: root for m in left if m != root})
    return kept


def name_pairs(verdicts: list[PassVerdict], named: NamedProblem) -> list[list[tuple[int, int]]]:
    """Each pass's pairings as names (they outlive the landmark indices of one smoothing)."""
    return [[(int(named.names[a]), int(named.names[b])) for a, b in v.pairs] for v in verdicts]


def clusters_of(current: MergeRound, passes: list[list[tuple[int, int]]], alias: dict[int, int], *,
                kept_covisible: bool = False) -> dict[int, int]:
    """:func:`merges_from` on ``current``'s landmark indices for passes given as name pairs; ``alias`` maps a name
    absorbed by an earlier merge to the name that absorbed it."""
    index = {int(x): k for k, x in enumerate(current.named.names)}

    def now(x: int) -> int:
        while x in alias:
            x = alias[x]
        return x

    verdicts = []
    for pairs in passes:
        at = [(index[now(a)], index[now(b)]) for a, b in pairs if now(a) in index and now(b) in index]
        at = [(a, b) for a, b in at if a != b]
        if at:
            verdicts.append(PassVerdict(0, "matched", at))
    covisible = covisible_names(current.named.problem, current.solution.inliers, len(current.named.names),
                                kept_only=kept_covisible)
    return merges_from(verdicts, covisible)[0]


def pairwise_inputs(current: MergeRound, *, name_floor_m: float = 0.0, kept_covisible: bool = False
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What a pairwise judgement of ``current``'s names (:func:`estimation.constellation.pairwise_groups`) works on:
    the names' joint covariance (with an own offset of σ ``name_floor_m`` per name, independent of the others'),
    which names were sighted in one frame (``kept_covisible``: by kept sightings only), and the indices of the names
    with a finite covariance."""
    problem, solution = current.named.problem, current.solution
    n = len(current.named.names)
    covariance = joint_landmark_covariance(problem, solution)
    if name_floor_m > 0:
        covariance = covariance + np.eye(2 * n) * name_floor_m ** 2
    covisible = covisible_names(problem, solution.inliers, n, kept_only=kept_covisible)
    seen = np.flatnonzero(np.isfinite(np.diagonal(covariance)).reshape(n, 2).all(axis=1))
    return covariance, covisible, seen
