"""A map that flagged itself is two frames: split it at the alarm and align each part (session 8).

FastSLAM's self-check (``estimation.fastslam.self_check``) flags a map whose old landmarks, predicted in view after
a stretch in which the map did not hold the pose, stopped being re-detected. If it is right, the landmarks made
from that stretch on are in another frame than those made before it; if it is wrong (it flags some healthy maps),
they are in the same frame. The maps' own landmark ids tell the two apart: FastSLAM numbers landmarks in the order
it makes them, and the exported map keeps those numbers (``LandmarkMap.ids``), so the alarm's
``first_id_after_gap`` splits the map into the landmarks made before the gap and those made from it on.

Each part is then aligned on its own to the other robots' maps, with the ordinary alignment and its evidence. Two
parts that both align answer the alarm: if the map is one frame, both alignments estimate the same transform, and
their difference d (tx, ty, θ; θ wrapped) is explained by the two alignments' uncertainties. The test is
d^T (C1 + C2)^-1 d against χ²₃, with C the alignments' covariance against the true start frames
(``Alignment.start_covariance``: a part's landmarks share the drift of the poses that mapped them, so the whole
part can be off by about one landmark's σ; the alignment's own precision ``covariance`` treats them as independent
and would call a healthy map's two parts different by its drift alone). The two parts' alignments are taken as
independent; they share the other map's error, which only makes the test more lenient where both parts overlap the
same region, and their difference is what it tests.

A test that does not reject is not evidence of agreement when it could not have seen a difference that matters
(session 45): the start-frame covariances hold the map's drift, and a small part's are wide, so on rendered demo
seeds 11 and 16 a part after the gap turned by 0.17-0.18 rad and moved 2.3-2.5 m (``benchmarks/split_eval.py
--kick``) gave χ² 9.2 (p 0.027) and 5.8 (p 0.12), and the map was used whole with 54 % and 14 % of robot 2's landmarks
more than 0.5 m from their places. The healthy maps' parts there have start-frame σ of 0.5-1.2 m at their landmarks
yet agree to ≤ 0.25 m, so no covariance of this test is tight enough to establish agreement; their difference's size
is. So the parts also have to be close in absolute terms: the two alignments must place every landmark of the map
within the alignment's smallest support gate of each other (``split_tolerance``: the preset's ``min_gate``, 0.3 m in
"robust", the scale below which a landmark's start-frame position is not known; its ``support_threshold`` where the
preset has no floor). A part moved farther than that, used whole under one transform, would put its landmarks
outside the gate that recognises them as the same place.

- The parts agree (p ≥ ``SPLIT_SIGNIFICANCE`` and no landmark of the map placed more than ``split_tolerance`` apart
  by the two alignments): the map is used whole, as without the check.
- They disagree (significantly, or by more than the tolerance): each part is merged under its own alignment, as if
  two robots had made them.
- No landmark made after the gap (a smoothed known-ID map whose posts were all seen before the alarm: MRCLAM robots
  2 and 3): there is nothing to split, and the map is used whole, as without the check. (Nothing made *before* the
  gap is not the same: every landmark is then in the frame the map was in after it lost its place.)
- A part that does not align (or holds fewer landmarks than any alignment needs: "too small") cannot be checked;
  it is left out, with the reason, and the part that aligns is merged alone. A map neither part of which aligns is
  left out ("not found, and why" over a merge that may be wrong), except the reference map, whose part made
  before the gap keeps the fused map in its robot's start frame.

The parts are merged under the very alignments the decision rested on (each part's alignment in its check, inverted
where the merge places the other map in the part's frame; two maps used whole under their given alignment), never
under alignments drawn again: ``align`` is not symmetric (its ratio test runs from map 1's landmarks), and a part
aligned the other way round, or with another generator, can come out otherwise than its check (session 43: rendered
demo seed 4's check took a wrong half turn for found, and its sentence said the part was merged, while the merge,
aligned the other way, found nothing; session 44).

The significance leans towards "disagree" on purpose: a healthy map wrongly split is still merged, each part under
a correct alignment (only the constraint between the parts is lost), while a lost map wrongly kept whole puts a
misplaced part into the fused map, the worst output.

Only the first alarm splits the map; later alarms measured against another gap are reported as not checked.

One decision from the maps (session 51): every draw of a check (a part's alignment to another map, a part tested at
the other part's transform) is seeded by the contents of the two maps it aligns (:func:`draw`), and ``p3at fuse``,
a mission's fusion and the fleet's node all check through :func:`split_checks`, so the same maps get the same
decision from each, whatever the order they are given in, the fusions before or the cache. Before, the mission drew
from ``default_rng(k)`` of the flagged map's index and ``p3at fuse`` from a child of ``default_rng(0)``: on rendered
demo seed 0's re-checked smoothed maps the mission kept only robot 1's part before its gap (1,120 landmarks merged)
and ``p3at fuse`` used the map whole (1,718). The draws decide only where a test is marginal; there they still
decide (one draw of the maps' content instead of one of the caller's): on seed 0's maps the part after the gap,
tested at the other part's transform, gathers 7 supports where chance gives 0.1672 beyond 2 (200,000 decoys), and
the significance 10⁻⁶ needs below 0.1691; the 95 % bound of 1,000 decoys is below it on 11 % of draws. The option
``agreeing_draws`` (default 1) takes such a part as aligned at the other part's transform only when that many
independent draws all find it: a marginal test then leans towards "disagree", as the significance does (above). On
the demo's flagged maps (seeds 2 and 8; smoothed seeds 0, 4 and 8) 2 or 3 draws decide as one does.

A part made after the gap does not share its map's start: it is in the frame the map was in after it lost its place,
so its alignment places that frame, and its difference from the true start poses (simulated maps) is the map's loss,
not the alignment's error. A report scores only a whole map or the part made before the gap against the start poses
and says why not for the other (:meth:`SplitCheck.apart_from_start`, :func:`holds_start`).
"""
from __future__ import annotations

import dataclasses
import hashlib
from dataclasses import dataclass, field

import numpy as np

from estimation import chi2
from estimation.fastslam.self_check import KEY as SELF_CHECK_KEY
from estimation.geometry import transform_points, wrap_angle
from estimation.landmark_map import LandmarkMap

from .alignment import Alignment, align, align_at
from .alignment_config import AlignmentConfig, resolve_preset
from .cache import AlignmentCache
from .errors import NoOverlapError
from .fingerprint import map_fingerprint
from .multi import MultiFusion, fuse_all, pairwise_alignments
from .provenance import source_metadata

SPLIT_SIGNIFICANCE = 0.01   # the parts disagree when their difference is this unlikely under one frame (see above)
PARTS = ("before", "after")


def split_id(landmark_map: LandmarkMap) -> int | None:
    """The first alarm's ``first_id_after_gap`` of a one-robot map that flagged itself, else None (no verdict, a map
    that holds, a merged map). ValueError (one line, naming the field) when the verdict is there but malformed."""
    if len(landmark_map.robots) > 1:
        return None
    verdict = landmark_map.metadata.get(SELF_CHECK_KEY)
    if verdict is None:
        return None
    if not isinstance(verdict, dict) or not isinstance(verdict.get("lost"), bool):
        raise ValueError(f"metadata {SELF_CHECK_KEY} must be a mapping with lost true or false")
    if not verdict["lost"]:
        return None
    alarms = verdict.get("alarms")
    if not isinstance(alarms, list) or not alarms or not isinstance(alarms[0], dict):
        raise ValueError(f"metadata {SELF_CHECK_KEY} says the map lost its place but lists no alarm")
    value = alarms[0].get("first_id_after_gap")
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"metadata {SELF_CHECK_KEY}.alarms[0].first_id_after_gap must be an integer >= 0, "
                         f"not {value!r:.40}")
    return value


def split_map(landmark_map: LandmarkMap, first_id: int) -> tuple[LandmarkMap, LandmarkMap]:
    """(landmarks with an id below ``first_id``, those from it on): made before the gap and after it."""
    before = landmark_map.ids < int(first_id)
    return landmark_map.subset(before), landmark_map.subset(~before)


@dataclass
class PartCheck:
    """One part of a split map: its landmarks, its alignment to each other map (None: too small to align), and
    whether it is merged."""

    name: str                                   # "before" or "after" the gap
    landmarks: int
    alignments: dict[int, Alignment] = field(default_factory=dict)   # other map index -> alignment of this part
    at_other: dict[int, Alignment] = field(default_factory=dict)     # ... tested at the other part's (align_at)
    too_small: bool = False
    used: bool = False

    @property
    def aligned_to(self) -> list[int]:
        return [j for j, a in self.alignments.items() if a.found]

    def why_not(self, names: list[str], min_supports: int) -> str:
        """Why this part did not align: too small, or each alignment's reason."""
        if self.too_small:
            return (f"too small to align ({self.landmarks} landmark{'s' if self.landmarks != 1 else ''}; an "
                    f"alignment needs at least {min_supports})")
        why = [f"against {names[j]}: {a.reason}" for j, a in self.alignments.items()]
        why += [f"against {names[j]}, {a.reason}" for j, a in self.at_other.items() if not a.found]
        return "; ".join(why) or "no other map"

    def to_dict(self) -> dict:
        return {"part": self.name, "landmarks": self.landmarks, "too_small": self.too_small, "used": self.used,
                "aligned_to": self.aligned_to,
                "alignments": {str(j): _brief(a) for j, a in self.alignments.items()},
                "at_other_part": {str(j): _brief(a) for j, a in self.at_other.items()}}


def _brief(a: Alignment) -> dict:
    """An alignment's figures without its support list (a JSON report stays small)."""
    out = a.to_dict()
    out["supports"] = len(a.supports)
    return out


@dataclass
class SplitCheck:
    """The check of one flagged map: where it was split, its parts, the parts' comparison and the decision.

    comparisons: per other map aligned by both parts, (index, χ², p); apart: per such map (index, m), the farthest
    the two parts' alignments place one landmark of the map from itself (:func:`parts_apart`); tolerance: m, the
    most ``apart`` may be for the parts to agree (:func:`split_tolerance`); agree: True / False, None when no
    other map aligned both parts; decision: "whole" (parts agree: the map is used as it is), "parts" (each part
    under its own alignment), "before" / "after" (only that part), "none" (left out)."""

    index: int
    robot: str
    first_id: int
    later_gaps: int               # later alarms measured against other gaps (not checked)
    parts: list[PartCheck]
    t: float | None = None        # s, when the first alarm was raised (the map's own clock)
    comparisons: list[tuple[int, float, float]] = field(default_factory=list)
    apart: list[tuple[int, float]] = field(default_factory=list)
    tolerance: float = 0.0
    agree: bool | None = None
    decision: str = "whole"
    text: str = ""

    def apart_from_start(self) -> str:
        """Why the part made after the gap is not scored against its map's true start, in words: "the part after
        robot2's gap at t≈13.8 s does not share robot2's start" (module docstring)."""
        when = "" if self.t is None else f" at t≈{self.t:.1f} s"
        return f"the part after {self.robot}'s gap{when} does not share {self.robot}'s start"

    def to_dict(self) -> dict:
        return {"map": self.index, "robot": self.robot, "first_id_after_gap": self.first_id, "t": self.t,
                "later_gaps_not_checked": self.later_gaps,
                "agree": self.agree, "decision": self.decision, "text": self.text,
                "tolerance_m": self.tolerance,
                "comparisons": [{"against": j, "chi2": c, "p": p, "apart_m": m}
                                for (j, c, p), (_, m) in zip(self.comparisons, self.apart, strict=True)],
                "parts": [p.to_dict() for p in self.parts]}


def holds_start(part: str | None) -> bool:
    """Whether a piece of a checked fusion (``CheckedFusion.sources[i][1]``: None for a whole map, "before" or
    "after") holds its map's start frame: the whole map and the part made before the gap do, the part after it does
    not (module docstring)."""
    return part != "after"


def parts_difference(a: Alignment, b: Alignment) -> tuple[float, float]:
    """(χ², p) of the difference of two found alignments of one map's two parts to the same map: d = b − a (θ
    wrapped) under C_a + C_b (start-frame covariances where given, else the alignments' own), 3 degrees of freedom."""
    d = np.asarray(b.pose, float) - np.asarray(a.pose, float)
    d[2] = wrap_angle(d[2])
    cov = _covariance(a) + _covariance(b)
    value = float(d @ np.linalg.solve(cov, d))
    return value, float(chi2.sf(value, 3))


def parts_apart(a: Alignment, b: Alignment, positions: np.ndarray) -> float:
    """The farthest two alignments of one map's parts (poses of its frame in the same other map's) place one of its
    landmarks (``positions`` (N, 2+), in its own frame) from itself, in metres in the plane: how far a part would be
    misplaced if the map were used whole under the other part's transform."""
    points = np.asarray(positions, float)
    if len(points) == 0:
        return 0.0
    points = np.column_stack([points[:, :2], np.zeros(len(points))])
    moved = transform_points(b.pose, points) - transform_points(a.pose, points)
    return float(np.max(np.linalg.norm(moved[:, :2], axis=1)))


def split_tolerance(config: AlignmentConfig) -> float:
    """Metres: the most two parts' alignments may place a landmark apart for the parts to agree: the preset's
    smallest support gate (``min_gate``), or its ``support_threshold`` where it has none (module docstring)."""
    return float(config.min_gate if config.min_gate > 0 else config.support_threshold)


def _covariance(a: Alignment) -> np.ndarray:
    cov = a.start_covariance if a.start_covariance is not None else a.covariance
    if cov is None:   # the paper preset gives none: only an exact match would agree
        cov = np.zeros((3, 3))
    return np.asarray(cov, float) + 1e-12 * np.eye(3)


def draw(first: LandmarkMap, second: LandmarkMap, test: str) -> np.random.Generator:
    """The generator of one random draw of a split check (module docstring, *One decision from the maps*): seeded by
    ``test`` ("align": a part aligned to another map; "at": a part tested at the other part's transform) and the
    contents of the two maps it aligns (:func:`fusion.fingerprint.map_fingerprint`), so the draw depends on those maps
    only, not on who asks, in which order, or after how many fusions."""
    h = hashlib.blake2b(test.encode(), digest_size=8)
    h.update(map_fingerprint(first))
    h.update(map_fingerprint(second))
    return np.random.default_rng(int.from_bytes(h.digest(), "little"))


def check_split(maps: list[LandmarkMap], index: int, first_id: int, preset: str | AlignmentConfig = "robust",
                rng: np.random.Generator | None = None, cache: AlignmentCache | None = None,
                later_gaps: int = 0, priors: dict | None = None, agreeing_draws: int = 1) -> SplitCheck:
    """Split ``maps[index]`` at ``first_id``, align each part to every other map (each part as map 2: the pose of
    the flagged map's frame in the other's) and decide (module docstring). Where only one part aligns to a map, the
    other is tested at that part's transform (:func:`align_at`) before the two are compared.  ``priors`` {(i, j),
    i < j: fusion.prior.StartPrior}: both parts are in the flagged map's start frame, so its pair's prior applies to
    each. ``rng``: None (the default), each alignment drawn from the two maps it aligns (:func:`draw`), so the check
    is a function of the maps alone; a generator, its children in the order of the other maps. ``agreeing_draws``
    (an option, default 1: one draw): a part tested at the other part's transform counts as aligned only when that
    many independent draws of its chance supports all find it (module docstring, *One decision from the maps*)."""
    if isinstance(agreeing_draws, bool) or not isinstance(agreeing_draws, int) or agreeing_draws < 1:
        raise ValueError(f"agreeing_draws must be a whole number >= 1, not {agreeing_draws!r:.40}")
    config = resolve_preset(preset)
    halves = split_map(maps[index], first_id)
    if len(halves[0]) and not len(halves[1]):   # every landmark made before the gap: nothing to split (docstring)
        parts = [PartCheck(name, len(h), used=True) for name, h in zip(PARTS, halves, strict=True)]
        result = SplitCheck(index, maps[index].robot, int(first_id), int(later_gaps), parts,
                            _alarm_time(maps[index]), tolerance=split_tolerance(config), decision="whole")
        result.text = _text(result, [m.robot for m in maps], config.min_supports)
        return result
    others = [j for j in range(len(maps)) if j != index]
    parts = []
    for name, part in zip(PARTS, halves, strict=True):
        check = PartCheck(name, len(part), too_small=len(part) < max(config.min_supports, 2))
        if not check.too_small:
            children = rng.spawn(len(others)) if rng is not None else [draw(maps[j], part, "align") for j in others]
            for j, child in zip(others, children, strict=True):
                prior = _pair_prior(priors, j, index)
                check.alignments[j] = (cache.align(maps[j], part, config, child, prior=prior) if cache is not None
                                       else align(maps[j], part, config, child, prior=prior))
        parts.append(check)
    result = SplitCheck(index, maps[index].robot, int(first_id), int(later_gaps), parts, _alarm_time(maps[index]),
                        tolerance=split_tolerance(config))
    for j, child in zip(others, rng.spawn(len(others)) if rng is not None else [None] * len(others), strict=True):
        found = [p for p in parts if j in p.aligned_to]
        if len(found) == 1 and not (other := parts[1 - parts.index(found[0])]).too_small:
            tested = halves[parts.index(other)]
            first = draw(maps[j], tested, "at") if child is None else child
            generators = [first, *(draw(maps[j], tested, f"at {r}") for r in range(1, agreeing_draws))]
            other.at_other[j] = _agreed([align_at(maps[j], tested, found[0].alignments[j].pose, config, g)
                                         for g in generators])
        pair = [p.alignments[j] if j in p.aligned_to else p.at_other.get(j) for p in parts]
        pair = [a if a is not None and a.found else None for a in pair]
        if all(a is not None for a in pair):
            value, p = parts_difference(*pair)
            result.comparisons.append((j, value, p))
            result.apart.append((j, parts_apart(*pair, maps[index].positions)))
    if result.comparisons:   # Bonferroni over the maps against which both parts were placed; and close in metres
        result.agree = (all(p >= SPLIT_SIGNIFICANCE / len(result.comparisons) for _, _, p in result.comparisons)
                        and all(m <= result.tolerance for _, m in result.apart))
    if result.agree:
        result.decision = "whole"
        parts[0].used = parts[1].used = True
    else:
        for part in parts:
            part.used = bool(part.aligned_to)
        used = [p.name for p in parts if p.used]
        result.decision = "parts" if len(used) == 2 else (used[0] if used else "none")
    result.text = _text(result, [m.robot for m in maps], config.min_supports)
    return result


def _agreed(tests: list[Alignment]) -> Alignment:
    """One part's tests at the other part's transform on independent draws: the first when all agree, else the first
    that did not find it, its reason saying on how many draws it was found (the decision does not hang on one)."""
    missed = [a for a in tests if not a.found]
    if not missed:
        return tests[0]
    if len(missed) == len(tests):
        return missed[0]
    return dataclasses.replace(missed[0], reason=f"{missed[0].reason}; found on {len(tests) - len(missed)} of "
                                                 f"{len(tests)} draws of the chance supports, not on all")


def _text(check: SplitCheck, names: list[str], min_supports: int) -> str:
    before, after = check.parts
    when = "" if check.t is None else f" at t≈{check.t:.1f} s"
    head = (f"flagged itself{when}: split at landmark id {check.first_id} ({before.landmarks} landmarks made before "
            f"the gap, {after.landmarks} from it on)")
    if check.later_gaps:
        head += (f"; {check.later_gaps} later alarm{'s' if check.later_gaps > 1 else ''} measured against "
                 f"another gap not checked")
    figures = ", ".join(f"against {names[j]}: χ² {c:.1f}, p {p:.2g}, landmarks up to {m:.2f} m apart"
                        for (j, c, p), (_, m) in zip(check.comparisons, check.apart, strict=True))
    tested = "; ".join(f"the part {p.name} the gap does not align on its own and was tested at the other part's "
                       f"transform against {names[j]} ({a.statistics.supports} supports, "
                       f"{a.statistics.expected_chance_supports - 2:.1f} by chance beyond 2)"
                       for p in check.parts for j, a in p.at_other.items() if a.found)
    figures += f"; {tested}" if tested else ""
    if before.landmarks and not after.landmarks:
        return f"{head}: no landmark was made after the gap, so there is nothing to split: the map is used whole"
    kept = [p for p in check.parts if p.used]
    lost = [p for p in check.parts if not p.used]
    why = "; ".join(f"the part {p.name} the gap {p.why_not(names, min_supports)}" for p in lost)
    if check.agree:
        return f"{head}: the parts agree ({figures}): the map is used whole"
    if check.agree is False:
        figures += f"; {_disagreement(check)}"
    if check.agree is False and not lost:
        return f"{head}: the parts disagree ({figures}): each part is merged under its own alignment"
    if check.agree is False:
        return (f"{head}: the parts disagree ({figures}): the part {kept[0].name} the gap is merged under its own "
                f"alignment and the other left out ({why})")
    if kept:
        return (f"{head}: only the part {kept[0].name} the gap aligns, so the parts cannot be compared; it is merged "
                f"under its own alignment and the other left out ({why})")
    return f"{head}: neither part aligns on its own, so the alarm cannot be checked and the map is left out ({why})"


def _disagreement(check: SplitCheck) -> str:
    """Why parts that were compared do not agree: a significant difference, or one too large to call agreement
    though the χ² test (with covariances too wide to see it) did not reject it."""
    if any(p < SPLIT_SIGNIFICANCE / len(check.comparisons) for _, _, p in check.comparisons):
        return f"below {SPLIT_SIGNIFICANCE:g}"
    return (f"not significant, but farther apart than the {check.tolerance:.2g} m the parts may differ to be used "
            f"as one map: their covariances are too wide to establish that they agree")


def split_checks(maps: list[LandmarkMap], preset: str | AlignmentConfig = "robust", cache: AlignmentCache | None = None,
                 priors: dict | None = None, split_ids: list[int | None] | None = None,
                 agreeing_draws: int = 1, rng: np.random.Generator | None = None) -> list[SplitCheck]:
    """:func:`check_split` of every map that flagged itself (``split_ids``: per map, where to split it or None; default
    :func:`split_id` of each map, a malformed verdict read as none), each draw from the maps it aligns: the one call
    of ``p3at fuse``, a mission's fusion and the fleet's node, so the same maps get the same decisions from all three
    whatever their order, fusion history or cache (module docstring, *One decision from the maps*). With ``rng``,
    each flagged map's check draws from one of its children instead."""
    if split_ids is None:
        split_ids = [_split_id_or_none(m) for m in maps]
    flagged = [k for k, first in enumerate(split_ids) if first is not None]
    children = rng.spawn(len(flagged)) if rng is not None else [None] * len(flagged)
    return [check_split(maps, k, split_ids[k], preset, child, cache, later_gaps(maps[k]), priors, agreeing_draws)
            for k, child in zip(flagged, children, strict=True)]


@dataclass
class CheckedFusion:
    """:func:`fuse_checked`'s result. ``fusion`` is the fusion used (of ``inputs``, the maps as merged: a split
    map's kept parts in place of it), None when nothing overlaps the reference (``message`` says why);
    ``sources[i]`` = (index of the input map, None | "before" | "after"); ``checks``: one per flagged map;
    ``whole`` is the fusion of the maps as given (None if it found no overlap)."""

    fusion: MultiFusion | None
    inputs: list[LandmarkMap]
    sources: list[tuple[int, str | None]]
    checks: list[SplitCheck]
    whole: MultiFusion | None
    message: str = ""

    @property
    def split(self) -> bool:
        """True when some map was merged in parts or left out."""
        return any(c.decision != "whole" for c in self.checks)


def _pair_prior(priors: dict | None, i: int, j: int):
    """The start prior of map j's frame in map i's from {(a, b), a < b: prior}, or None."""
    if not priors:
        return None
    if (i, j) in priors:
        return priors[(i, j)]
    return priors[(j, i)].inverse() if (j, i) in priors else None


def fuse_checked(maps: list[LandmarkMap], preset: str | AlignmentConfig = "robust", method: int = 1,
                 rng: np.random.Generator | None = None, reference: int = 0,
                 alignments: dict[tuple[int, int], Alignment] | None = None, cache: AlignmentCache | None = None,
                 split_ids: list[int | None] | None = None, check_rng: np.random.Generator | None = None,
                 checks: list[SplitCheck] | None = None, priors: dict | None = None, agreeing_draws: int = 1,
                 **options) -> CheckedFusion:
    """:func:`fusion.fuse_all`, with every map that flagged itself checked by :func:`check_split` (``split_ids``:
    per map, where to split it or None; default :func:`split_id` of each map, a malformed verdict read as none).
    The maps as given are fused first with ``rng`` / ``alignments`` exactly as ``fuse_all`` would; the parts are
    aligned by :func:`split_checks` (each draw from the maps it aligns; with ``check_rng``, from its children), so a
    fusion whose flagged maps' parts agree is that fusion. A
    fusion of parts rests on the alignments the decisions rested on (:func:`_piece_alignments`): the checks' and
    those of the maps as given; only pairs no decision judged (a map's two parts, parts of two flagged maps) are
    aligned again.
    ``checks``: the flagged maps' :func:`check_split` results where the caller already has them (they are not
    made again); ``agreeing_draws``: :func:`check_split`'s option. ``priors`` {(i, j), i < j:
    fusion.prior.StartPrior}: start priors for the alignments (when not given), the split checks and the fusion of the
    parts (a part is in its map's start frame).
    Where no map overlaps the reference, ``fusion`` is None and ``message`` says why (``fuse_all``
    would raise :class:`NoOverlapError`); other errors of ``fuse_all`` are raised."""
    if split_ids is None:
        split_ids = [_split_id_or_none(m) for m in maps]
    cache = AlignmentCache() if cache is None else cache
    whole, message = None, ""
    if alignments is None:   # the draws fuse_all would make (with the priors where given): the parts' merge reuses them
        alignments = pairwise_alignments(maps, preset, rng, cache, priors)
    try:
        whole = fuse_all(maps, preset, method, rng, reference, alignments, cache, **options)
    except NoOverlapError as e:
        message = str(e)
    if checks is None:
        checks = split_checks(maps, preset, cache, priors, split_ids, agreeing_draws, check_rng)
    if not any(c.decision != "whole" for c in checks):
        return CheckedFusion(whole, list(maps), [(k, None) for k in range(len(maps))], checks, whole, message)
    by_map = {c.index: c for c in checks}
    inputs, sources = [], []
    new_reference = None
    for k, m in enumerate(maps):
        c = by_map.get(k)
        if c is None or c.decision == "whole":
            pieces = [(m, None)]
        else:
            halves = dict(zip(PARTS, split_map(m, c.first_id), strict=True))
            kept = [p.name for p in c.parts if p.used]
            if k == reference and "before" not in kept and len(halves["before"]):
                kept = ["before"] + kept     # the reference robot's start frame stays the fused frame
            pieces = [(halves[name], name) for name in kept]
        for piece, name in pieces:
            if k == reference and new_reference is None:
                new_reference = len(inputs)
            inputs.append(piece)
            sources.append((k, name))
    if new_reference is None:
        return CheckedFusion(None, inputs, sources, checks, whole,
                             f"the reference map {maps[reference].robot!r} was left out: nothing to fuse into")
    # each piece is in its map's start frame, so the pieces of two maps share their maps' start prior
    piece_priors = {(a, b): p for a in range(len(inputs)) for b in range(a + 1, len(inputs))
                    if sources[a][0] != sources[b][0]
                    and (p := _pair_prior(priors, sources[a][0], sources[b][0])) is not None}
    piece_alignments = _piece_alignments(inputs, sources, by_map, alignments, preset, cache, piece_priors)
    try:
        fused = fuse_all(inputs, preset, method, np.random.default_rng(0), new_reference, piece_alignments, cache,
                         **options)
    except NoOverlapError as e:
        return CheckedFusion(None, inputs, sources, checks, whole, str(e))
    # the fused map holds the maps as given, not their parts: a file given again beside it is known by its fingerprint
    # (a fusion that merged nothing, the reference's part alone, records no sources)
    if isinstance(fused.map.metadata.get("fusion"), dict):
        fused.map.metadata["fusion"].update(source_metadata([maps[k] for k, _ in sources],
                                                            [i for i, r in enumerate(fused.rows) if r is not None]))
    return CheckedFusion(fused, inputs, sources, checks, whole)


def _piece_alignments(inputs: list[LandmarkMap], sources: list[tuple[int, str | None]], checks: dict[int, SplitCheck],
                      alignments: dict[tuple[int, int], Alignment], preset: str | AlignmentConfig,
                      cache: AlignmentCache, priors: dict) -> dict[tuple[int, int], Alignment]:
    """The alignment of every pair of pieces (keys (a, b), a < b: piece b's frame in piece a's), resting on the
    alignments the decisions rested on: two maps used whole keep the alignment of the maps as given (``alignments``);
    a flagged map's part and a map used whole keep the part's alignment in its :func:`check_split`, inverted where the
    direction differs (a part that the check found not to align stays not found: a draw in the other direction, or
    with another generator, can come out otherwise, session 43). Only pairs no decision judged are aligned here, each
    with the generator the merge has always given it (the pairs' children of ``default_rng(0)``): two parts of one map
    (aligned to each other as two robots' maps would be) and parts of two flagged maps."""
    keys = [(a, b) for a in range(len(inputs)) for b in range(a + 1, len(inputs))]
    children = dict(zip(keys, np.random.default_rng(0).spawn(len(keys)) if keys else [], strict=True))
    out = {}
    for a, b in keys:
        judged = _judged(sources[a], sources[b], checks, alignments)
        out[(a, b)] = judged if judged is not None else cache.align(inputs[a], inputs[b], preset, children[(a, b)],
                                                                    prior=priors.get((a, b)))
    return out


def _judged(first: tuple[int, str | None], second: tuple[int, str | None], checks: dict[int, SplitCheck],
            alignments: dict[tuple[int, int], Alignment]) -> Alignment | None:
    """The alignment of piece ``second``'s frame in piece ``first``'s that a decision rested on, or None."""
    (i, p), (j, q) = first, second
    if i == j:
        return None
    if p is None and q is None:
        if (i, j) in alignments:
            return alignments[(i, j)]
        return alignments[(j, i)].inverse() if (j, i) in alignments else None
    if (p is None) == (q is None):     # parts of two flagged maps: each was checked against the other whole
        return None
    if p is None:                      # the check aligned the part as map 2 onto map i: that is this direction
        return checks[j].parts[PARTS.index(q)].alignments.get(i)
    judged = checks[i].parts[PARTS.index(p)].alignments.get(j)
    return None if judged is None else judged.inverse()


def _split_id_or_none(landmark_map: LandmarkMap) -> int | None:
    try:
        return split_id(landmark_map)
    except ValueError:   # the caller reports a malformed verdict (p3at fuse: a one-line note); the map is fused
        return None


def _alarms(landmark_map: LandmarkMap) -> list:
    """The verdict's alarms as the file gives them; [] where the verdict or its list is malformed (split_id has
    said so already, or found the first alarm sound: the later ones are only counted)."""
    verdict = landmark_map.metadata.get(SELF_CHECK_KEY)
    alarms = verdict.get("alarms") if isinstance(verdict, dict) else None
    return alarms if isinstance(alarms, list) else []


def _alarm_time(landmark_map: LandmarkMap) -> float | None:
    alarms = _alarms(landmark_map) or [{}]
    t = alarms[0].get("t") if isinstance(alarms[0], dict) else None
    return float(t) if isinstance(t, int | float) and not isinstance(t, bool) and np.isfinite(t) else None


def _gap(alarm) -> int | None:
    value = alarm.get("first_id_after_gap") if isinstance(alarm, dict) else None
    return value if isinstance(value, int) and not isinstance(value, bool) else None


def later_gaps(landmark_map: LandmarkMap) -> int:
    """Later alarms of a flagged map measured against another gap than the first's (the alarms it lists): each would
    split the map elsewhere; only the first split is checked. Alarms at the same gap are the same split; an alarm
    whose gap is not a whole number (a corrupt file) names no gap and is not counted."""
    alarms = _alarms(landmark_map)
    first = {_gap(a) for a in alarms[:1]}
    return len({_gap(a) for a in alarms[1:]} - first - {None})
