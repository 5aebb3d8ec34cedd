"""Fusing the maps a fleet has published, and scoring each alignment against the truth where maps carry it.

One place for what the mission's fusion stage, ``p3at fuse`` and a live fusion node report about a fusion:
each pair's alignment (tx, ty, θ of the other map's frame in the reference's), its supports, its common
landmarks, and, for simulated maps whose metadata holds ``true_start_pose``, its error against the truth.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from estimation.geometry import wrap_angle
from estimation.landmark_map import LandmarkMap

# An alignment whose false-alarm probability exceeds this is reported with a warning (the robust preset
# never reports one as found; the paper preset, which decides by its support count alone, may).
LOW_CONFIDENCE_PROBABILITY = 1e-6


@dataclass
class PairResult:
    """One alignment of ``other``'s map to ``reference``'s.

    tx, ty, theta: pose of other's frame in reference's; supports: one-to-one supports; common: landmarks both
    maps hold after merging; error_xy (m), error_theta (rad): against the truth where the maps carry it;
    false_alarm_probability: probability that maps which do not overlap give this much support (the
    alignment's confidence; for an alignment composed through other maps, the weakest link's);
    required_supports: fewest supports that would have been accepted on these maps (for a split map's part, of the
    part's own alignment); second_best_supports:
    the best hypothesis distinct from the winner (repeated structure); self_repeat_supports: the best repeat of
    either map onto itself; low_confidence: found but with a
    false-alarm probability above LOW_CONFIDENCE_PROBABILITY; note: why not found, or how it was reached.
    """

    reference: str
    other: str
    aligned: bool
    tx: float = float("nan")
    ty: float = float("nan")
    theta: float = float("nan")
    supports: int = 0
    common: int = 0
    error_xy: float | None = None
    error_theta: float | None = None
    note: str = ""
    false_alarm_probability: float | None = None
    required_supports: int = 0
    second_best_supports: int = 0
    self_repeat_supports: int = 0        # the best repeat of either map onto itself (fusion.evidence.self_structure)
    low_confidence: bool = False
    sigma_xy: float | None = None        # m, 1σ of the alignment's translation (major axis); None: no covariance
    sigma_theta: float | None = None     # rad, 1σ of its rotation
    # 1σ against the true relative pose of the start frames (each map's error at the overlap counted as a
    # whole, fusion.frame_covariance): what covers the truth when the maps' covariances are honest
    start_sigma_xy: float | None = None
    start_sigma_theta: float | None = None
    # a map of the pair that flagged itself (its self-check) was split at the alarm and each part aligned
    # (fusion/split.py): what was decided and why, in one sentence; "" when neither map flagged itself
    self_check: str = ""
    split_decision: str | None = None    # "whole", "parts", "before", "after" or "none" (left out)
    # the placement is of this part of other's map ("before" or "after" its gap), not of the whole map; None: whole
    aligned_part: str | None = None
    # why error_xy / error_theta are None although the maps carry their true starts, in words: the placement is of a
    # part made after its map's gap, which does not share the start they are measured from (fusion/split.py); ""
    # when the error is given or no truth is known
    error_not_comparable: str = ""
    # why start_sigma_xy / start_sigma_theta are None although the alignment was found, in words (truth known or
    # not): the placement is of a part made after its map's gap, and the start-frame 1σ is a claim about the map's
    # start, which the gap broke (session 26's demo: 0.563 m / 0.108 rad); sigma_xy / sigma_theta, the precision of
    # the part's own alignment, are what holds for it. "" when the start-frame 1σ is given or there is none
    start_sigma_not_comparable: str = ""
    # the rough relative start the alignment was given (fusion/prior.py), in words; "" when none was used
    prior: str = ""
    # a placement found only because of that prior (the maps alone are ambiguous or too weak:
    # fusion.Alignment.prior_backing), in words beginning "found with the prior: "; for a placement composed through
    # other maps, the first such alignment on its path, named. "" when the maps' own evidence carries it
    prior_backed: str = ""
    # with the co-location option (AlignmentConfig.colocation, fusion/colocation.py): what was tested, or why there was
    # no test (maps without a shared clock or a footprint), once per pair; "" when the option is off
    colocation: str = ""

    def as_dict(self) -> dict:
        return dict(self.__dict__)

    def score_against_truth(self, reference_map: LandmarkMap, other_map: LandmarkMap) -> None:
        """The error of (tx, ty, θ) against the maps' true start poses, where both carry one (simulated maps)."""
        from fusion import true_relative_pose

        truth = true_relative_pose(reference_map, other_map)
        if truth is not None:
            self.error_xy = float(np.hypot(self.tx - truth[0], self.ty - truth[1]))
            self.error_theta = float(abs(wrap_angle(self.theta - truth[2])))

    def count_common(self, merged: LandmarkMap) -> None:
        """Landmarks of the merged map seen by both robots of the pair (where it names both)."""
        column = {r: c for c, r in enumerate(merged.robots)}
        if self.reference in column and self.other in column:
            self.common = int(np.count_nonzero(merged.seen_by[:, [column[self.reference], column[self.other]]].all(1)))

    def take_evidence(self, alignment) -> None:
        """Copy the confidence figures of a :class:`fusion.Alignment` (its statistics)."""
        st = alignment.statistics
        p = st.false_alarm_probability
        self.false_alarm_probability = float(p) if np.isfinite(p) else None
        self.required_supports = int(st.required_supports)
        self.second_best_supports = int(st.second_best_supports)
        self.self_repeat_supports = int(st.self_repeat_supports)
        prior = getattr(alignment, "prior", None)
        self.prior = "" if prior is None else prior.text()
        self.prior_backed = str(getattr(alignment, "prior_backing", "") or "")
        self.colocation = str(getattr(st, "colocation", ""))
        removed = int(getattr(st, "colocation_removed_supports", 0))
        if removed:
            self.colocation += f"; a distinct hypothesis with {removed} supports contradicts it and is no rival"
        cov = alignment.covariance
        if alignment.found and cov is not None:
            self.sigma_xy, self.sigma_theta = sigmas(cov)
        start = getattr(alignment, "start_covariance", None)
        if alignment.found and start is not None:
            self.start_sigma_xy, self.start_sigma_theta = sigmas(start)
        self.low_confidence = bool(self.aligned and (self.false_alarm_probability is None
                                                     or self.false_alarm_probability > LOW_CONFIDENCE_PROBABILITY))


def sigmas(covariance) -> tuple[float, float]:
    """(1σ of the translation along its major axis (m), 1σ of the rotation (rad)) of a (3, 3) pose covariance."""
    cov = np.asarray(covariance, float)
    return float(np.sqrt(max(np.linalg.eigvalsh(cov[:2, :2])[-1], 0.0))), float(np.sqrt(max(cov[2, 2], 0.0)))


def confidence_text(false_alarm_probability: float | None) -> str:
    """'false-alarm probability 3e-12' (or 'not evaluated')."""
    if false_alarm_probability is None:
        return "false-alarm probability not evaluated"
    return f"false-alarm probability {false_alarm_probability:.1e}"


@dataclass
class FusionReport:
    t: float
    pairs: list[PairResult]
    merged: LandmarkMap | None
    seconds: float

    def as_dict(self) -> dict:
        return {"t": round(self.t, 2), "pairs": [p.as_dict() for p in self.pairs],
                "merged_landmarks": 0 if self.merged is None else len(self.merged),
                "seconds": self.seconds}


def keep_latest_map(history: list[FusionReport], report: FusionReport) -> None:
    """Append ``report`` to a mission's fusion history; earlier reports keep their figures but drop their merged
    map (a whole map per fusion grew a long mission's memory by ~5 MB per 10 min; only the latest is used)."""
    if history and history[-1].merged is not None:
        history[-1] = dataclasses.replace(history[-1], merged=None)
    history.append(report)


def alignment_cache(confirm_after: float | None = None):
    """A new ``fusion.AlignmentCache`` for a caller that fuses the same robots' maps again and again (the fleet's
    fusion node, the mission): pairs of unchanged maps are then not aligned twice.  With ``confirm_after`` (s): a
    ``fusion.confirmation.ConfirmingCache``, whose found alignments are candidates until a fusion at least that much
    later, on grown maps, agrees (call its ``start_round(t)`` before each fusion)."""
    from fusion import AlignmentCache

    if confirm_after is None:
        return AlignmentCache()
    from fusion.confirmation import ConfirmingCache

    return ConfirmingCache(confirm_after)


def fuse_maps(maps: dict[str, LandmarkMap], preset: str = "robust", method: int = 1, t: float = 0.0,
              rng: np.random.Generator | None = None, cache=None, priors: dict | None = None) -> FusionReport:
    """Align every map to the first robot's (in name order), merge them, score against the truth when known.
    ``cache`` (``fusion.AlignmentCache``, kept by the caller between fusions): pairs of unchanged maps are not
    aligned again.  ``priors`` {(robot a, robot b): fusion.prior.StartPrior of b's start in a's, a < b by name}: a
    rough relative start the alignments use, a flagged map's split check and the fusion of its parts included."""
    from fusion import align, merge
    from fusion.split import split_checks

    start = time.perf_counter()
    names = sorted(maps)
    pairs: list[PairResult] = []
    if len(names) < 2:
        return FusionReport(t, pairs, maps[names[0]] if names else None, 0.0)
    reference = names[0]
    merged = maps[reference]
    rng = rng if rng is not None else np.random.default_rng(0)
    priors = priors or {}
    indexed = {(i, j): priors[(a, b)] for i, a in enumerate(names) for j, b in enumerate(names) if (a, b) in priors}
    # every flagged map checked, each draw from the maps it aligns, as p3at fuse checks them (not from the fusion's
    # generator or its count: fusion.split, *One decision from the maps*)
    checks = split_checks([maps[n] for n in names], preset, cache, indexed)
    if any(c.decision != "whole" for c in checks):
        return _fuse_split(maps, names, preset, method, t, start, checks, cache, indexed)
    if len(names) > 2:
        return _with_checks(_fuse_many(maps, names, preset, method, t, rng, start, cache, indexed), names, checks)
    for other in names[1:]:
        result = PairResult(reference, other, False)
        run = align if cache is None else cache.align
        alignment = run(maps[reference], maps[other], preset, rng, prior=priors.get((reference, other)))
        result.supports = int(len(alignment.supports))
        result.take_evidence(alignment)
        if not alignment.found:
            result.note = alignment.reason
            pairs.append(result)
            continue
        result.aligned = True
        result.take_evidence(alignment)
        result.tx, result.ty, result.theta = (float(v) for v in alignment.pose)
        merged_pair = merge(merged, maps[other], alignment, method=method)
        result.common = int(merged_pair.metadata.get("fusion", {}).get("common_landmarks", 0))
        merged = merged_pair
        result.score_against_truth(maps[reference], maps[other])
        pairs.append(result)
    return _with_checks(FusionReport(t, pairs, merged, time.perf_counter() - start), names, checks)


def _with_checks(report: FusionReport, names: list[str], checks: list) -> FusionReport:
    """A fusion in which every flagged map's parts agreed (it is the fusion of the maps as given): each pair with
    a flagged map says so."""
    for c in checks:
        for p in report.pairs:
            if names[c.index] in (p.reference, p.other):
                p.self_check = f"{names[c.index]} {c.text}"
                p.split_decision = c.decision
    return report


def _fuse_split(maps: dict[str, LandmarkMap], names: list[str], preset: str, method: int, t: float, start: float,
                checks: list, cache=None, priors: dict | None = None) -> FusionReport:
    """A flagged map's parts disagreed or could not be compared (fusion.split.fuse_checked): each robot's pair
    reports the placement of its map as merged (whole, or the part made before the gap when it was kept, else the
    part after it) with the evidence of the alignment it rests on (supports, needed, P(chance), 1σ), the split's
    sentence, and the error against the truth where the maps carry it -- not for a part made after the gap, which
    does not share its map's start (``error_not_comparable`` says so), nor its 1σ against the start frames, only
    its own alignment's (``start_sigma_not_comparable`` says why)."""
    from fusion import true_relative_pose
    from fusion.split import fuse_checked, holds_start

    ordered = [maps[n] for n in names]
    checked = fuse_checked(ordered, preset=preset, method=method, cache=cache, checks=checks,   # checked once
                           priors=priors)
    by_map = {c.index: c for c in checked.checks}
    multi = checked.fusion
    pairs = []
    for k, other in enumerate(names[1:], 1):
        result = PairResult(names[0], other, False)
        prior = (priors or {}).get((0, k))
        result.prior = "" if prior is None else prior.text()
        for c in checked.checks:
            if c.index in (0, k):
                result.self_check = f"{names[c.index]} {c.text}"
                result.split_decision = c.decision
        pieces = [i for i, (src, _) in enumerate(checked.sources) if src == k]
        placed = [i for i in pieces if multi is not None and multi.poses[i] is not None]
        if not placed:
            result.note = (by_map[k].text if k in by_map and not pieces else
                           checked.message or "not connected to the reference map")
            pairs.append(result)
            continue
        i = placed[0]
        result.aligned = True
        result.aligned_part = checked.sources[i][1]
        result.tx, result.ty, result.theta = (float(v) for v in multi.poses[i])
        _take_tree_evidence(result, multi, i, [names[src] + ("" if part is None else f"'s part {part} its gap")
                                                 for src, part in checked.sources])
        result.prior = "" if prior is None else prior.text()
        result.count_common(multi.map)
        # the fused frame is the reference's start unless its kept part is the one after its gap (nothing before it)
        apart = [by_map[src].apart_from_start() for src, part in (checked.sources[multi.reference], checked.sources[i])
                 if not holds_start(part)]
        if not apart:
            result.score_against_truth(ordered[0], ordered[k])
        else:   # the start-frame 1σ claims the map's start, which the gap broke: the part's own precision holds
            result.start_sigma_xy = result.start_sigma_theta = None
            result.start_sigma_not_comparable = apart[0]
            if true_relative_pose(ordered[0], ordered[k]) is not None:
                result.error_not_comparable = apart[0]
        pairs.append(result)
    merged = multi.map if multi is not None else maps[names[0]]
    return FusionReport(t, pairs, merged, time.perf_counter() - start)


def _fuse_many(maps: dict[str, LandmarkMap], names: list[str], preset: str, method: int, t: float,
               rng: np.random.Generator, start: float, cache=None, indexed: dict | None = None) -> FusionReport:
    """More than two maps: fusion's maximum spanning tree of pairwise alignments, all in the first map's frame.
    ``indexed``: start priors by map index in name order."""
    from fusion import NoOverlapError, fuse_all
    from fusion.multi import pairwise_alignments

    ordered = [maps[n] for n in names]
    try:
        alignments = pairwise_alignments(ordered, preset, rng, cache, indexed) if indexed else None
        multi = fuse_all(ordered, preset=preset, method=method, rng=rng, cache=cache, alignments=alignments)
    except NoOverlapError as e:
        pairs = [PairResult(names[0], n, False, note=str(e)) for n in names[1:]]
        return FusionReport(t, pairs, maps[names[0]], time.perf_counter() - start)
    parent = {child: p for p, child in multi.tree}
    pairs = []
    for k, other in enumerate(names[1:], 1):
        pose = multi.poses[k]
        result = PairResult(names[0], other, pose is not None)
        if pose is None:
            result.note = "not connected to the reference map"
            pairs.append(result)
            continue
        result.tx, result.ty, result.theta = (float(v) for v in pose)
        _take_tree_evidence(result, multi, k, names)
        result.count_common(multi.map)
        result.score_against_truth(ordered[0], ordered[k])
        result.note = f"through {names[parent[k]]}" if parent[k] != 0 else ""
        pairs.append(result)
    return FusionReport(t, pairs, multi.map, time.perf_counter() - start)


def _take_tree_evidence(result: PairResult, multi, k: int, labels: list[str] | None = None) -> None:
    """The evidence of map ``k``'s placement in a ``fusion.MultiFusion``: the supports and figures of the tree edge
    that placed it, the weakest false-alarm probability along its path from the reference, whether an alignment on
    that path rests on its start prior (``labels``: the fused inputs' names, for saying which), and the 1σ composed
    along it."""
    parent = {child: p for p, child in multi.tree}
    edge = multi.alignments.get(tuple(sorted((parent[k], k)))) if k in parent else None
    result.supports = 0 if edge is None else int(len(edge.supports))
    if edge is None:
        return
    result.take_evidence(edge)
    # a pose composed along the tree is as trustworthy as its weakest alignment; it rests on a start prior if one of
    # them does (the direct edge's own sentence is taken above)
    path = [(e, multi.alignments[tuple(sorted(e))]) for e in _tree_path(parent, k)]
    probs = [a.statistics.false_alarm_probability for _, a in path]
    backed = [(e, a.prior_backing) for e, a in path if getattr(a, "prior_backing", "")]
    if backed and not result.prior_backed:
        (p, c), text = backed[-1]                   # the one nearest the reference
        label = [f"map {i}" for i in range(max(p, c) + 1)] if labels is None else labels
        result.prior_backed = f"{text} (through {label[c]} -> {label[p]})"
    if probs and all(np.isfinite(probs)):
        result.false_alarm_probability = float(max(probs))
        result.low_confidence = result.false_alarm_probability > LOW_CONFIDENCE_PROBABILITY
    cov = multi.covariances[k]                  # composed along the tree
    if cov is not None and edge.covariance is not None:
        result.sigma_xy, result.sigma_theta = sigmas(cov)
    start_cov = multi.start_covariances[k] if multi.start_covariances else None
    result.start_sigma_xy, result.start_sigma_theta = (None, None) if start_cov is None else sigmas(start_cov)


def _tree_path(parent: dict[int, int], k: int) -> list[tuple[int, int]]:
    """Edges (parent, child) from the reference (index 0) down to map ``k``."""
    edges = []
    while k in parent:
        edges.append((parent[k], k))
        k = parent[k]
    return edges
