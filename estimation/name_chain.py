"""The unknown-association chain's rounds as one function: chained names merged, screened, left out and named again
until the map holds one name per landmark it can tell apart.

:func:`run_chain` runs the whole chain on a range-bearing log from its chained names
(:func:`estimation.chained_names.chain_log`) and the known-ID filter's guess on them
(:func:`estimation.fresh_start.names_guess`), or from a state saved part way (:class:`Resume`), with the options of
:class:`ChainSettings` (defaults: session 30's recipe). Every step that decides is one of the modules it orders:

1. the first smoothing and, with ``split_bends``, names split at odometry bends (:mod:`estimation.name_merging`);
2. rounds: the log's passes judged against each other (:mod:`estimation.pass_matching`), their pairings screened by
   the honest-names screen (:func:`flagged_names`, :func:`without_flagged`), clustered (all or only mutual ones), the
   guard's leave-one-out shares (:func:`guard_groups`), the batch merged, cost-checked, bisected or guarded, each kept
   batch audited part by part (:func:`audit_parts`); the sighting offsets enter once a round keeps nothing;
3. flagged runs taken out, pairwise rounds (:func:`estimation.constellation.pairwise_groups`, each group merged alone
   first with ``pairwise_alone``), the ambiguous and unconfirmed names left out (:mod:`estimation.name_leave_out`),
   the unnamed sightings named (:mod:`estimation.unnamed_sightings`), the runs out and the last merges again.

The ground truth and the barcodes take no part: a caller scores the run through a :class:`ChainObserver`, whose hooks
are given every decision as it is made (``benchmarks/mrclam_constellation.py`` records and scores them all; its
docstring has the method step by step and what each option measured). Moved here from that benchmark in session 36
(A), unchanged (the same JSON row and kept states bit for bit on three runs): the benchmark's module-level run state
(``_OFFSET``, ``_LOSS``, ``_AUDIT``) became the :class:`NamedSmoother` a run carries from step to step and the
observer's records.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from estimation import name_leave_out, unnamed_sightings
from estimation.chained_names import chain_log
from estimation.constellation import guard_batches, pairwise_groups, spanning_pairs
from estimation.datasets import RangeBearingLog
from estimation.fastslam import FastSLAMConfig
from estimation.fresh_start import names_guess
from estimation.landmark_smoother import (
    HeadingDrift,
    HeadingLoss,
    SightingOffset,
    Smoothed,
    joint_landmark_covariance,
)
from estimation.map_honesty import Run, flagged_landmarks, self_covisible_frames, sighting_runs, split_scores
from estimation.merge_audit import covisible_spacing, held_parts, merged_parts, part_splits
from estimation.name_merging import NamedSmoother, merge_guarded, merge_once, split_at_bends
from estimation.named_smoothing import MergeRound, covisible_names
from estimation.noise_model import NoiseModel
from estimation.pairwise_audit import refused_alone
from estimation.pass_matching import (
    PassVerdict,
    judge_passes,
    merges_from,
    mutual_merges,
    name_pairs,
    pairwise_inputs,
    passes_of,
    without_pairings,
)

__all__ = ["ChainObserver", "ChainResult", "ChainSettings", "Guard", "PartAudit", "Resume", "alone_checked",
           "audit_parts", "first_state", "flagged_names", "guard_groups", "run_chain", "with_offsets",
           "without_flagged"]


@dataclass(frozen=True)
class ChainSettings:
    """Every option of the chain. Defaults: session 30's recipe (``benchmarks/mrclam_constellation.py``'s
    ``--max-rounds 9 --guard --sighting-offset 0.03 --offsets-once-tight --pairwise 6 --kept-covisible
    --split-ambiguous --honest-names 0.01 --honest-rounds --leave-out-ambiguous --leave-out-unconfirmed --slip 0.3
    --name-unnamed --fewer-rival --distinct-points --hold-two-points --runs-out``); the options sessions 25-35 measured
    and did not adopt (``split_bends``, ``mutual_rounds``, ``fresh_start``, ``audit_parts``, ``pairwise_alone``,
    ``heading_loss``, ``reguess``, ...) are off. Each field is the benchmark's option of the same name (its help
    says what it does and which session measured it)."""

    # the chained names (estimation.chained_names.chain_log) and the guess's filter (its random generator's seed)
    window_s: float = 40.0
    step_s: float | None = None           # None: half the window
    seed: int = 0
    # the smoother
    drift: tuple[float, float] = (0.16, 10.0)  # heading drift σ_b (rad/m), τ (s); σ_b 0 and slip 0: none
    slip: float = 0.3                     # heading slip σ per radian turned on the spot
    path_step_s: float = 0.25             # 0: the random walk's variance of the chord between sighting frames
    heading_loss: str = "gaussian"        # or "student-t"
    heading_dof: float = 3.0
    split_bends: bool = False
    # the rounds
    pass_seconds: float = 20.0
    min_sightings: int = 2
    min_pairs: int = 3
    ratio: float | None = None            # None: no rival allowed
    fewer_rival: bool = True
    distinct_points: bool = True
    rival_rounds: int | None = None       # None: the rival options in every round
    max_rounds: int = 9
    bisect: int = 2
    guard: bool = True
    honest_names: float | None = 0.01
    honest_rounds: bool = True
    hold_two_points: bool = True
    mutual_rounds: bool = False
    fresh_start: bool = False
    audit_parts: float | None = None      # the part audit's floor (m); None: off
    reguess: bool = False
    sighting_offset: float = 0.03         # σ (m) of an offset per chained name; 0: off
    offsets_once_tight: bool = True
    # after the rounds
    pairwise: int = 6
    kept_covisible: bool = True
    name_floor: float = 0.0
    split_ambiguous: bool = True
    pairwise_alone: bool = False
    leave_out_ambiguous: bool = True
    leave_out_unconfirmed: bool = True
    name_unnamed: bool = True
    runs_out: bool = True

    def __post_init__(self):
        if self.honest_names is not None and not 0 < self.honest_names < 1:
            raise ValueError(f"honest_names: α must be in (0, 1), not {self.honest_names}")
        needs = [(self.honest_rounds and self.honest_names is None, "honest_rounds needs honest_names"),
                 (self.hold_two_points and self.honest_names is None, "hold_two_points needs honest_names"),
                 (self.runs_out and (self.honest_names is None or not self.name_unnamed),
                  "runs_out needs honest_names and name_unnamed"),
                 (self.offsets_once_tight and not self.sighting_offset > 0, "offsets_once_tight needs sighting_offset"),
                 (self.rival_rounds is not None and not (self.fewer_rival or self.distinct_points),
                  "rival_rounds needs fewer_rival or distinct_points"),
                 (self.heading_loss not in ("gaussian", "student-t"), f"heading_loss {self.heading_loss!r}")]
        for wrong, why in needs:
            if wrong:
                raise ValueError(why)

    @property
    def heading_drift(self) -> HeadingDrift | None:
        """The smoother's heading drift (with the slip), or None when both are 0."""
        if self.drift[0] > 0 or self.slip > 0:
            return HeadingDrift(*self.drift, sigma_per_rad=self.slip)
        return None

    @property
    def path_step(self) -> float | None:
        """The increments' path step (s), or None for the chord's variance."""
        return self.path_step_s if self.path_step_s > 0 else None

    @property
    def loss(self) -> HeadingLoss | None:
        """The heading loss of every smoothing and cost, or None (Gaussian)."""
        return HeadingLoss("student-t", self.heading_dof) if self.heading_loss == "student-t" else None

    @property
    def offsets_from_start(self) -> bool:
        """Whether the sighting offsets are on from the chain's smoothing (else from when the map is tight)."""
        return self.sighting_offset > 0 and not self.offsets_once_tight

    def rival_options(self, round_number: int) -> dict:
        """``fewer_rival`` and ``distinct_points`` for round ``round_number``: off after ``rival_rounds``."""
        on = self.rival_rounds is None or round_number <= self.rival_rounds
        return {"fewer_rival": self.fewer_rival and on, "distinct_points": self.distinct_points and on}


@dataclass(frozen=True)
class Resume:
    """A state saved part way (after ``round_done`` rounds; 0: the chain's, after the splits) to run on from, and the
    sighting offsets' groups (each sighting's name after the chain, round 0; None: no offsets)."""

    state: MergeRound
    round_done: int
    offset_names: np.ndarray | None = None


@dataclass(frozen=True)
class ChainResult:
    """The chain's final state, the smoother it ends with (its offsets and their groups as they stand) and the rounds
    it ran up to (counted from the chain, as ``max_rounds``)."""

    state: MergeRound
    smoother: NamedSmoother
    rounds_done: int


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


class ChainObserver:
    """What a caller is told as the chain runs: every hook has a no-op default. ``number`` is a round's (counted from
    the chain) or a pairwise round's; ``before`` a step's state before it. The states are the chain's own: read
    them, do not change them."""

    def chain_smoothed(self, state: MergeRound, smoother: NamedSmoother) -> None:
        """The chained names' first smoothing (not called when resuming)."""

    def split_tried(self, split: dict) -> None:
        """A split at a bend measured (``split_bends``)."""

    def splits_done(self, before: MergeRound, after: MergeRound, tried: list[dict]) -> None:
        """The splits at bends applied (``split_bends``)."""

    def resumed(self, state: MergeRound, round_done: int, offsets: bool) -> None:
        """A run from a saved state starts (``offsets``: it was re-smoothed with the sighting offsets first)."""

    def state_kept(self, tag: str, state: MergeRound, round_done: int, smoother: NamedSmoother,
                   before: MergeRound | None) -> None:
        """A state to keep: ``round0`` (the chain's), ``round<k>``, ``pairwise<k>`` (``round_done`` −k),
        ``out-ambiguous``/``out-unconfirmed`` (``round_done`` −1)."""

    def round_begins(self, number: int, state: MergeRound, smoother: NamedSmoother) -> None:
        """A round starts."""

    def round_judged(self, number: int, state: MergeRound, verdicts: list[PassVerdict]) -> None:
        """The passes judged (before any screen)."""

    def honest_screened(self, number: int, state: MergeRound, verdicts: list[PassVerdict], flagged: np.ndarray
                        ) -> None:
        """``honest_rounds``: the names the screen flags (their pairings in ``verdicts`` are held back)."""

    def mutual_aside(self, number: int, state: MergeRound, aside: list) -> None:
        """``mutual_rounds``: the clusters set aside, not all within each other's gate."""

    def round_proposed(self, number: int, state: MergeRound, used: list[PassVerdict]) -> None:
        """The passes whose pairings the round would merge."""

    def guard_judged(self, label: str, state: MergeRound, covariance: np.ndarray, used: list[PassVerdict],
                     covisible: np.ndarray, guard: Guard) -> None:
        """The guard's verdict (``label``: "round k" or "pairwise k"; acted on only with ``guard``)."""

    def audited(self, before: MergeRound, attempt: MergeRound, audit: PartAudit) -> None:
        """``audit_parts``: a kept batch audited."""

    def merged(self, label: str, before: MergeRound, attempts: list[MergeRound], state: MergeRound) -> None:
        """A round's or pairwise round's merges: every attempt, and the state they end in."""

    def offsets_entered(self, after_round: int, state: MergeRound) -> None:
        """``offsets_once_tight``: the offsets entered after round ``after_round``, the state re-smoothed."""

    def pairwise_begins(self, number: int, state: MergeRound) -> None:
        """A pairwise round starts."""

    def pairwise_grouped(self, number: int, state: MergeRound, groups: list) -> None:
        """The pairwise groups (every status)."""

    def pairwise_honest(self, number: int, state: MergeRound, flagged: np.ndarray, held: list) -> None:
        """``honest_names``: the flagged names and the merge groups held back for them."""

    def alone_checked(self, number: int, state: MergeRound, used: list[PassVerdict], rises: list[float],
                      absorbed: list[int], refused: np.ndarray) -> None:
        """``pairwise_alone``: each group's own rise and whether it was refused."""

    def pairwise_proposed(self, number: int, state: MergeRound, used: list[PassVerdict]) -> None:
        """The groups the pairwise round would merge (empty: the pairwise rounds end)."""

    def runs_flagged(self, key: str, before: MergeRound, flagged: list[tuple[Run, float, float]]) -> None:
        """``runs_out``: the flagged runs taken out (``key``: "runs_out_before_pairwise" or "runs_out")."""

    def left_out(self, why: str, before: MergeRound, left: list[int], after: MergeRound) -> None:
        """Names left out (``why``: "ambiguous" or "unconfirmed")."""

    def named_again(self, key: str, before: MergeRound, after: MergeRound, proposed: dict[int, int]) -> None:
        """Unnamed sightings named (``key``: "named_again" or "named_after_runs_out")."""


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


def with_offsets(smoother: NamedSmoother, current: MergeRound) -> MergeRound:
    """``current``'s names re-smoothed by ``smoother`` (with its sighting offsets) from its solution (one name's
    offset alone moves nothing; merged names' offsets let them differ)."""
    initial = dict(zip(current.named.names.tolist(), current.solution.landmarks, strict=True))
    named, solution = smoother.smooth(current.names, initial_poses=current.solution.poses, initial=initial)
    return MergeRound([], 0.0, 0.0, True, current.names, named, solution)


def first_state(log: RangeBearingLog, noise: NoiseModel, config: FastSLAMConfig, settings: ChainSettings, *,
                names: np.ndarray | None = None, guess=None) -> tuple[MergeRound, NamedSmoother]:
    """The chain's first smoothing: ``names`` (None: :func:`estimation.chained_names.chain_log` with the settings'
    window, step and seed) smoothed from ``guess`` ((poses, {name: position}); None:
    :func:`estimation.fresh_start.names_guess` with the settings' seed), and the run's smoother (the sighting offsets
    only when ``offsets_from_start``, their groups not yet set: each sighting's own name)."""
    if names is None:
        names = chain_log(log, noise, config, seconds=settings.window_s, step=settings.step_s, seed=settings.seed).names
    if guess is None:
        guess = names_guess(log, names, noise, config, np.random.default_rng(settings.seed))
    smoother = NamedSmoother(log, noise, config, settings.heading_drift, settings.path_step,
                             SightingOffset(settings.sighting_offset) if settings.offsets_from_start else None, None,
                             settings.loss)
    initial_poses, initial = guess
    named, solution = smoother.smooth(names, initial_poses=initial_poses, initial=initial)
    return MergeRound([], 0.0, 0.0, True, names.copy(), named, solution), smoother


def run_chain(log: RangeBearingLog, noise: NoiseModel, config: FastSLAMConfig,
              settings: ChainSettings = ChainSettings(), *, names: np.ndarray | None = None, guess=None,
              resume: Resume | None = None, observer: ChainObserver | None = None) -> ChainResult:
    """The whole chain on ``log`` (module docstring): from the chained ``names`` and the smoother's ``guess`` (see
    :func:`first_state`; both computed when None), or from a saved state (``resume``: ``names`` and ``guess`` are
    not used), each decision told to ``observer``. Reads neither the barcodes nor the ground truth."""
    return _Chain(log, noise, config, settings, observer or ChainObserver()).run(names, guess, resume)


class _Chain:
    """One run of the chain: its settings, its smoother as it stands and its observer."""

    def __init__(self, log, noise, config, settings: ChainSettings, observer: ChainObserver):
        self.log, self.noise, self.config, self.settings, self.observer = log, noise, config, settings, observer
        self.smoother: NamedSmoother | None = None
        self.pairwise_done = 0

    def run(self, names, guess, resume: Resume | None) -> ChainResult:
        s = self.settings
        if resume is None:
            current, self.smoother = first_state(self.log, self.noise, self.config, s, names=names, guess=guess)
            self.observer.chain_smoothed(current, self.smoother)
            if s.split_bends:
                before = current
                current, tried = split_at_bends(self.smoother, current, on_try=self.observer.split_tried)
                self.observer.splits_done(before, current, tried)
            self.observer.state_kept("round0", current, 0, self.smoother, None)
            if s.sighting_offset > 0:       # the groups: the names after the chain (and the splits)
                self.smoother = dataclasses.replace(self.smoother, offset_names=current.names.copy())
            if s.offsets_from_start:
                current = with_offsets(self.smoother, current)
            start = 0
        else:
            self.smoother = NamedSmoother(self.log, self.noise, self.config, s.heading_drift, s.path_step,
                                          SightingOffset(s.sighting_offset) if s.offsets_from_start else None,
                                          resume.offset_names if s.sighting_offset > 0 else None, s.loss)
            current, start = resume.state, int(resume.round_done)
            if s.offsets_from_start:
                current = with_offsets(self.smoother, current)
            self.observer.resumed(current, start, s.offsets_from_start)
        k, current = self._rounds(current, start)
        return ChainResult(current, self.smoother, k)

    def _rounds(self, current: MergeRound, start: int) -> tuple[int, MergeRound]:
        s = self.settings
        pending = s.offsets_once_tight and self.smoother.sighting_offset is None and s.sighting_offset > 0
        k = start
        while k < s.max_rounds:
            state = self._one_round(current, k)
            if state is None:
                if not pending:
                    break
                current, pending = self._enter_offsets(current, k), False
                continue                # the round that kept nothing, judged again with the offsets
            current, k = state, k + 1
        if pending:
            current = self._enter_offsets(current, k)
        if s.runs_out:        # the last merges judge the tight map without the runs that bend it
            current = self._runs_out(current, "runs_out_before_pairwise")
        if s.pairwise:
            current = self._pairwise_rounds(current)
        if s.leave_out_ambiguous:
            left = name_leave_out.ambiguous_names(current, name_floor_m=s.name_floor, kept_covisible=s.kept_covisible)
            current = self._leave_out(current, left, "ambiguous")
            if s.pairwise and left:      # names the glimpses kept apart may merge now
                current = self._pairwise_rounds(current)
        if s.leave_out_unconfirmed:
            left = name_leave_out.unconfirmed_names(current, self.noise, self.config)
            current = self._leave_out(current, left, "unconfirmed")
        if s.name_unnamed:
            current = self._name_unnamed(current, "named_again")
        if s.runs_out:
            before = current
            current = self._runs_out(current, "runs_out")
            if current is not before:           # their names judged again without them, their sightings re-offered
                if s.pairwise:
                    current = self._pairwise_rounds(current)
                current = self._name_unnamed(current, "named_after_runs_out")
        return k, current

    def _one_round(self, current: MergeRound, k: int) -> MergeRound | None:
        s, number = self.settings, k + 1
        self.observer.round_begins(number, current, self.smoother)
        covariance = joint_landmark_covariance(current.named.problem, current.solution)
        passes = passes_of(current.named, current.solution, s.pass_seconds, s.min_sightings)
        covisible = covisible_names(current.named.problem, current.solution.inliers, len(current.named.names))
        verdicts = judge_passes(current.solution.landmarks, covariance, covisible, passes, min_pairs=s.min_pairs,
                                ratio=s.ratio if s.ratio is not None else np.inf, **s.rival_options(number))
        self.observer.round_judged(number, current, verdicts)
        if s.honest_rounds:
            screened, flagged = without_flagged(current, verdicts, s.honest_names, s.hold_two_points)
            self.observer.honest_screened(number, current, verdicts, flagged)
            verdicts = screened
        if s.mutual_rounds:
            clusters, used, aside = mutual_merges(verdicts, covisible, current.solution.landmarks, covariance)
            self.observer.mutual_aside(number, current, aside)
        else:
            clusters, used = merges_from(verdicts, covisible)
        self.observer.round_proposed(number, current, used)
        guarded = None
        if used:          # the guard's verdict is told on every round, and acted on with ``guard``
            guarded = self._guard(f"round {number}", current, covariance, used, covisible)
        if not clusters:
            return None
        reguess = self._guess if s.reguess else None
        state = self._merge(current, used, guarded, f"round {number}", reguess=reguess)
        if state is current:
            return None
        self.observer.state_kept(f"round{number}", state, number, self.smoother, current)
        return state

    def _guess(self, merged_names: np.ndarray):
        """The known-ID filter's guess on merged names (no barcodes): ``reguess``' and ``fresh_start``'s start."""
        return names_guess(self.log, merged_names, self.noise, self.config, np.random.default_rng(self.settings.seed))

    def _guard(self, label: str, current: MergeRound, covariance, used, covisible) -> list[PassVerdict] | None:
        guard = guard_groups(current, covariance, used, covisible)
        self.observer.guard_judged(label, current, covariance, used, covisible, guard)
        return guard.kept if self.settings.guard and guard.dropped else None

    def _merge(self, current: MergeRound, used: list[PassVerdict], guarded: list[PassVerdict] | None, label: str, *,
               reguess=None, kept_covisible: bool = False, untestable: bool = True) -> MergeRound:
        """A round's merges (:func:`estimation.name_merging.merge_guarded`); the state kept (``current`` when none
        was). ``untestable``: with ``audit_parts``, whether the audit holds back the parts the map cannot test (the
        rounds) or only those it refuses (the pairwise rounds)."""
        s = self.settings
        audit = None
        if s.audit_parts is not None:
            def audit(before: MergeRound, attempt: MergeRound) -> set[int]:
                result = audit_parts(before, attempt, floor_m=s.audit_parts, untestable=untestable)
                if result is None:
                    return set()
                self.observer.audited(before, attempt, result)
                return result.held
        state, attempts = merge_guarded(self.smoother, current, name_pairs(used, current.named),
                                        None if guarded is None else name_pairs(guarded, current.named),
                                        depth=s.bisect, reguess=reguess, kept_covisible=kept_covisible,
                                        fresh_start=self._guess if s.fresh_start else None, audit=audit)
        self.observer.merged(label, current, attempts, state)
        if np.array_equal(state.names, current.names):      # the audit held every merge back: nothing kept
            return current
        return state

    def _enter_offsets(self, current: MergeRound, k: int) -> MergeRound:
        """``offsets_once_tight``: the sighting offsets switched on after round k (the rounds without them stopped,
        or ran out) and ``current`` re-smoothed with them. Session 27 (A): from round 0, on a loose map, a 3 cm offset
        per name lets batches holding wrong pairings pass the cost check; it belongs to the tight map's last
        merges."""
        offset = SightingOffset(self.settings.sighting_offset)
        self.smoother = dataclasses.replace(self.smoother, sighting_offset=offset)
        current = with_offsets(self.smoother, current)
        self.observer.offsets_entered(k, current)
        return current

    def _runs_out(self, current: MergeRound, key: str) -> MergeRound:
        """The runs of sightings the honest-names screen flags taken out of their names (``current`` when none)."""
        flagged = name_leave_out.flagged_runs_of(current, self.settings.honest_names)
        self.observer.runs_flagged(key, current, flagged)
        return name_leave_out.leave_out_runs(self.smoother, current, [run for run, _, _ in flagged])

    def _leave_out(self, current: MergeRound, left: list[int], why: str) -> MergeRound:
        after = name_leave_out.leave_out(self.smoother, current, left)
        self.observer.left_out(why, current, left, after)
        if left:
            self.observer.state_kept(f"out-{why}", after, -1, self.smoother, current)
        return after

    def _name_unnamed(self, current: MergeRound, key: str) -> MergeRound:
        state, proposed, self.smoother = unnamed_sightings.name_unnamed(self.smoother, current)
        self.observer.named_again(key, current, state, proposed)
        return state

    def _pairwise_rounds(self, current: MergeRound) -> MergeRound:
        """The last merges on a tight map (:func:`estimation.constellation.pairwise_groups`): every group of names
        that can be one post and nothing else, merged (with ``guard``, the groups' leave-one-out shares tested
        first), checked by the cost rise and bisected as the passes are; repeated until nothing merges or
        ``pairwise`` rounds, numbered on from the pairwise rounds already run."""
        s = self.settings
        done = self.pairwise_done
        for k in range(done, done + s.pairwise):
            number = k + 1
            self.pairwise_done = number
            self.observer.pairwise_begins(number, current)
            problem, solution = current.named.problem, current.solution
            covariance, covisible, seen = pairwise_inputs(current, name_floor_m=s.name_floor,
                                                          kept_covisible=s.kept_covisible)
            groups = pairwise_groups(solution.landmarks, covariance, seen, allowed=~covisible,
                                     split_ambiguous=s.split_ambiguous)
            self.observer.pairwise_grouped(number, current, groups)
            if s.honest_names is not None:      # helper B's screen (session 27): a member holding a run that bends
                flagged = flagged_names(problem, solution, s.honest_names, two_points=s.hold_two_points)
                held = [g for g in groups if g.status == "merge" and flagged[list(g.members)].any()]
                self.observer.pairwise_honest(number, current, flagged, held)
                groups = [g for g in groups if not any(g is h for h in held)]
            merging = [PassVerdict(-1 - i, "matched", spanning_pairs([(g.members[0], m) for m in g.members[1:]]),
                                   (len(g.members), -g.d2 / g.dof), 0, True)
                       for i, g in enumerate(x for x in groups if x.status == "merge")]
            clusters, used = merges_from(merging, covisible)
            if used and s.pairwise_alone:       # each group's own cost check before the batch's (session 32, A)
                used = alone_checked(self.smoother, current, used, covisible, observer=self.observer, number=number)
            guarded = None
            if used:
                guarded = self._guard(f"pairwise {number}", current, covariance, used, covisible)
            self.observer.pairwise_proposed(number, current, used)
            if not used:
                break
            state = self._merge(current, used, guarded, f"pairwise {number}", kept_covisible=s.kept_covisible,
                                untestable=False)
            if state is current:
                break
            self.observer.state_kept(f"pairwise{number}", state, -number, self.smoother, current)
            current = state
        return current



def alone_checked(smoother: NamedSmoother, current: MergeRound, used: list[PassVerdict], covisible: np.ndarray, *,
                  observer: ChainObserver | None = None, number: int = 0) -> list[PassVerdict]:
    """``pairwise_alone`` (session 32, A): each pairwise group of ``used`` merged alone from ``current`` and kept for
    the batch only when its own rise is within χ² 99 % for 2 per absorbed name
    (:func:`estimation.pairwise_audit.refused_alone`): the batch's bound is the sum over its groups, and one wrong
    group hides in the others' slack (robot 2 seed 1's glimpse: 9.6 alone against 9.2, 14.2 against 23.2 in its
    batch of five). Each group's rise and verdict told to ``observer`` (as pairwise round ``number``)."""
    rises, absorbed = [], []
    for v in used:
        alone = merge_once(smoother, current, merges_from([v], covisible)[0])
        rises.append(alone.rise)
        absorbed.append(len(alone.merged))
    refused = refused_alone(rises, absorbed)
    if observer is not None:
        observer.alone_checked(number, current, used, rises, absorbed, refused)
    return [v for v, f in zip(used, refused, strict=True) if not f]
