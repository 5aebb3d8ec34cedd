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

Split along its seams in session 37 (B), unchanged; everything is still importable from here:
:mod:`estimation.chain_settings` (:class:`ChainSettings`), :mod:`estimation.chain_observer` (:class:`ChainObserver`),
:mod:`estimation.merge_screens` (the honest-names screen, the guard, the part audit), :mod:`estimation.chain_run`
(:class:`estimation.chain_run.ChainRun`: what a run's rounds share, its smoother as it stands, the guard's verdict and
the merges) and :mod:`estimation.pairwise_rounds` (the pairwise rounds and ``pairwise_alone``'s check). This module
keeps the run itself: its start (:func:`first_state`, :class:`Resume`), the rounds, the offsets entering, the
leave-outs, the naming and the runs out.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from estimation import name_leave_out, unnamed_sightings
from estimation.chain_observer import ChainObserver
from estimation.chain_run import ChainRun
from estimation.chain_settings import ChainSettings
from estimation.chained_names import chain_log
from estimation.datasets import RangeBearingLog
from estimation.fastslam import FastSLAMConfig
from estimation.fresh_start import names_guess
from estimation.landmark_smoother import SightingOffset, joint_landmark_covariance
from estimation.merge_screens import Guard, PartAudit, audit_parts, flagged_names, guard_groups, without_flagged
from estimation.name_merging import NamedSmoother, split_at_bends
from estimation.named_smoothing import MergeRound, covisible_names
from estimation.noise_model import NoiseModel
from estimation.pairwise_rounds import alone_checked, pairwise_rounds
from estimation.pass_matching import judge_passes, merges_from, mutual_merges, passes_of

__all__ = ["ChainObserver", "ChainResult", "ChainSettings", "Guard", "PartAudit", "Resume", "alone_checked",
           "audit_parts", "first_state", "flagged_names", "guard_groups", "run_chain", "with_offsets",
           "without_flagged"]

_SESSION_30 = ChainSettings()      # run_chain's default settings: session 30's recipe (frozen)


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
              settings: ChainSettings = _SESSION_30, *, names: np.ndarray | None = None, guess=None,
              resume: Resume | None = None, observer: ChainObserver | None = None) -> ChainResult:
    """The whole chain on ``log`` (module docstring): from the chained ``names`` and the smoother's ``guess`` (see
    :func:`first_state`; both computed when None), or from a saved state (``resume``: ``names`` and ``guess`` are
    not used), each decision told to ``observer``. Reads neither the barcodes nor the ground truth."""
    return _Chain(log, noise, config, settings, observer or ChainObserver()).run(names, guess, resume)


class _Chain(ChainRun):
    """One run of the chain (:class:`estimation.chain_run.ChainRun`: its settings, its smoother as it stands and its
    observer) from its start through the rounds and the steps after them."""

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
            current = pairwise_rounds(self, current)
        if s.leave_out_ambiguous:
            left = name_leave_out.ambiguous_names(current, name_floor_m=s.name_floor, kept_covisible=s.kept_covisible)
            current = self._leave_out(current, left, "ambiguous")
            if s.pairwise and left:      # names the glimpses kept apart may merge now
                current = pairwise_rounds(self, current)
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
                    current = pairwise_rounds(self, current)
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
            guarded = self.guard(f"round {number}", current, covariance, used, covisible)
        if not clusters:
            return None
        reguess = self.guess if s.reguess else None
        state = self.merge(current, used, guarded, f"round {number}", reguess=reguess)
        if state is current:
            return None
        self.observer.state_kept(f"round{number}", state, number, self.smoother, current)
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
