"""Names merged (or split) on a smoothed map, each batch kept only when the smoother's cost says the map can hold it.

A loop closing proposes names that are one post (:mod:`estimation.pass_matching`); this module joins them, smooths the
log again under the new naming and keeps the batch when the truncated cost (:func:`estimation.named_smoothing.
truncated_cost`) rises by no more than χ² 99 % for 2 per absorbed name (:func:`apply_merges`). A refused batch is cut
in halves (:func:`merge_bisecting`) or, when a guard set some groups aside, retried without them
(:func:`merge_guarded`). :func:`split_at_bends` is the converse: a name split where the odometry bends, kept when the
cost falls by more than χ²₂.

Every smoothing and every cost of one run goes through one :class:`NamedSmoother` (the log, the noise model, the
smoother's heading drift, path variances, sighting offsets and heading loss), so that all judge one model.

Measured in ``benchmarks/mrclam_constellation.py`` (its docstring, steps 1b and 4; docs/fastslam-history.md,
"Session 24: joint (constellation) tests of a pass's co-visible names (A)", "Session 25: why partly merged maps are
overconfident ... (A)" for bisection and the bends, "Session 26 ... (A)" for the guard, "Session 31 ..." for
``fresh_start`` (A) and the part audit (C)). Moved here from the benchmark in session 36 (lead), unchanged: the
benchmark's run state (its sighting offset and heading loss) became the :class:`NamedSmoother` it passes.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from estimation import chi2
from estimation.datasets import RangeBearingLog
from estimation.fastslam import FastSLAMConfig
from estimation.fresh_start import judge_at_starts
from estimation.geometry import between, compose
from estimation.landmark_smoother import HeadingDrift, HeadingLoss, SightingOffset, Smoothed, normalised_residuals
from estimation.named_smoothing import MergeRound, NamedProblem, smooth_named, truncated_cost
from estimation.noise_model import NoiseModel
from estimation.pass_matching import clusters_of, without_members

# a fresh start for a merged naming: (names) -> (initial poses, {name: initial position})
Guess = Callable[[np.ndarray], tuple[np.ndarray, dict[int, np.ndarray]]]
# a part audit of a kept batch: (state before, state after) -> the landmark indices (of the state before) held back
Audit = Callable[[MergeRound, MergeRound], set[int]]

AUDIT_ROUNDS = 3          # a kept batch audited and merged again without what the audit holds back, at most this often


@dataclass(frozen=True)
class NamedSmoother:
    """How one run smooths a naming of ``log`` and scores the solution: the noise model and filter configuration,
    the smoother's heading-bias states (``heading_drift``), the increments' path variances (``path_step_s``), an
    offset per group of sightings (``sighting_offset``, the groups given by ``offset_names``: each sighting's name
    before any merge) and a heavy-tailed heading loss (``heading_loss``; None: Gaussian). A run that changes one of
    them (the offsets entering once the map is tight) makes a new one with :func:`dataclasses.replace`."""

    log: RangeBearingLog
    noise: NoiseModel
    config: FastSLAMConfig
    heading_drift: HeadingDrift | None = None
    path_step_s: float | None = None
    sighting_offset: SightingOffset | None = None
    offset_names: np.ndarray | None = None
    heading_loss: HeadingLoss | None = None

    def smooth(self, names: np.ndarray, *, initial_poses: np.ndarray | None = None,
               initial: dict[int, np.ndarray] | None = None) -> tuple[NamedProblem, Smoothed]:
        """:func:`estimation.named_smoothing.smooth_named` on this run's log and model."""
        return smooth_named(self.log, names, self.noise, self.config, initial_poses=initial_poses, initial=initial,
                            heading_drift=self.heading_drift, path_step_s=self.path_step_s,
                            sighting_offset=self.sighting_offset, offset_names=self.offset_names,
                            heading_loss=self.heading_loss)

    def cost(self, problem, solution: Smoothed) -> float:
        """The truncated cost the smoothings minimise (with the run's heading loss, if any)."""
        if self.heading_loss is None:
            return truncated_cost(problem, solution)
        return truncated_cost(problem, solution, heading_loss=self.heading_loss)


def apply_merges(smoother: NamedSmoother, current: MergeRound, clusters: dict[int, int], *,
                 reguess: Guess | None = None, fresh_start: Guess | None = None, audit: Audit | None = None
                 ) -> MergeRound:
    """Names joined by ``clusters`` (landmark index → root), re-smoothed from the current solution (or, with
    ``reguess``, from that guess); kept when the truncated cost rises by no more than χ² 99 % for 2 per absorbed
    name. ``fresh_start`` (session 31, A): a batch refused from the current solution is smoothed again from that
    guess and judged at the lower cost (:func:`estimation.fresh_start.judge_at_starts`: the current solution can be a
    local minimum that refuses right loop closures). ``audit`` (session 31, C): a kept batch is audited part by part
    on its merged map and merged again without the names it holds back, up to :data:`AUDIT_ROUNDS` times; a batch it
    holds back whole keeps nothing (accepted, no merge: nothing to bisect)."""
    attempt = _merge_once(smoother, current, clusters, reguess, fresh_start)
    for _ in range(AUDIT_ROUNDS):
        if not (attempt.accepted and audit is not None):
            break
        held = audit(current, attempt)
        if not held:
            break
        clusters = without_members(clusters, held)
        if not clusters:
            return MergeRound([], 0.0, 0.0, True, current.names, current.named, current.solution)
        attempt = _merge_once(smoother, current, clusters, reguess, fresh_start)
    return attempt


def merge_once(smoother: NamedSmoother, current: MergeRound, clusters: dict[int, int]) -> MergeRound:
    """:func:`apply_merges` without a guess or an audit: the batch merged, re-smoothed and cost-checked once."""
    return _merge_once(smoother, current, clusters, None, None)


def _merge_once(smoother: NamedSmoother, current: MergeRound, clusters: dict[int, int], reguess: Guess | None,
                fresh_start: Guess | None) -> MergeRound:
    names = current.names.copy()
    index_name = current.named.names
    position = dict(zip(index_name.tolist(), current.solution.landmarks, strict=True))
    groups: dict[int, list[int]] = {}
    for k, r in clusters.items():
        groups.setdefault(r, []).append(k)
    merged = []
    for r, ks in groups.items():
        keep = int(index_name[r])
        all_names = {int(index_name[k]) for k in ks} | {keep}
        position[keep] = np.mean([position[x] for x in all_names], axis=0)
        for x in all_names - {keep}:
            names[names == x] = keep
            merged.append((keep, x))
    initial_poses = current.solution.poses
    if reguess is not None:         # a fresh start: the known-ID filter and smoother on the merged names
        initial_poses, position = reguess(names)
    named, solution = smoother.smooth(names, initial_poses=initial_poses, initial=position)
    before = smoother.cost(current.named.problem, current.solution)
    rise = smoother.cost(named.problem, solution) - before
    bound = float(chi2.ppf(0.99, 2 * len(merged)))
    if rise > bound and fresh_start is not None and reguess is None:
        poses, guessed = fresh_start(names)
        fresh = smoother.smooth(names, initial_poses=poses, initial=guessed)
        verdict = judge_at_starts(before, [before + rise, smoother.cost(fresh[0].problem, fresh[1])], bound)
        if verdict.best == 1:
            (named, solution), rise = fresh, verdict.rise
    if rise <= bound:
        return MergeRound(merged, rise, bound, True, names, named, solution)
    return MergeRound(merged, rise, bound, False, current.names, current.named, current.solution)


def merge_bisecting(smoother: NamedSmoother, current: MergeRound, passes: list[list[tuple[int, int]]], *,
                    depth: int, alias: dict[int, int], reguess: Guess | None = None, kept_covisible: bool = False,
                    fresh_start: Guess | None = None, audit: Audit | None = None
                    ) -> tuple[MergeRound, list[MergeRound]]:
    """The passes' merges (given as name pairs, strongest first) as one batch; a batch the cost check refuses is cut
    in two halves, each tried in turn (the second on top of the first if it was kept), down to ``depth`` cuts; a batch
    still refused at the last level is retried as its strongest pass alone (depth 0: session 21's rule, the strongest
    pass alone at once). Returns the last kept state and every attempt; ``alias`` gains the names each kept merge
    absorbed. ``fresh_start``: :func:`apply_merges`' for this whole batch only, not its halves."""
    clusters = clusters_of(current, passes, alias, kept_covisible=kept_covisible)
    if not clusters:
        return current, []
    attempt = apply_merges(smoother, current, clusters, reguess=reguess, fresh_start=fresh_start, audit=audit)
    attempts = [attempt]
    if attempt.accepted:
        alias.update({x: keep for keep, x in attempt.merged})
        return attempt, attempts
    if len(passes) == 1:
        return current, attempts
    halves = [passes[:1]] if depth <= 0 else [passes[:(len(passes) + 1) // 2], passes[(len(passes) + 1) // 2:]]
    state = current
    for half in halves:
        state, more = merge_bisecting(smoother, state, half, depth=max(depth - 1, 0), alias=alias, reguess=reguess,
                                      kept_covisible=kept_covisible, audit=audit)
        attempts += more
    return state, attempts


def merge_guarded(smoother: NamedSmoother, current: MergeRound, passes: list[list[tuple[int, int]]],
                  guarded: list[list[tuple[int, int]]] | None, *, depth: int, reguess: Guess | None = None,
                  kept_covisible: bool = False, fresh_start: Guess | None = None, audit: Audit | None = None
                  ) -> tuple[MergeRound, list[MergeRound]]:
    """The round's batch whole; if the cost check refuses it and the guard set groups aside (``guarded``: the groups
    it kept, as name pairs; None: it set none aside or is off), the guard's groups are tried and bisected instead of
    the whole batch (the cost check says something in the batch is wrong, the guard's shares say which); else
    :func:`merge_bisecting` as it is. Returns the last kept state and every attempt."""
    if guarded is None:
        return merge_bisecting(smoother, current, passes, depth=depth, alias={}, reguess=reguess,
                               kept_covisible=kept_covisible, fresh_start=fresh_start, audit=audit)
    clusters = clusters_of(current, passes, {}, kept_covisible=kept_covisible)
    if not clusters:
        return current, []
    whole = apply_merges(smoother, current, clusters, reguess=reguess, fresh_start=fresh_start, audit=audit)
    if whole.accepted:
        return whole, [whole]
    state, more = merge_bisecting(smoother, current, guarded, depth=depth, alias={}, reguess=reguess,
                                  kept_covisible=kept_covisible, audit=audit)
    return state, [whole] + more


def split_at_bends(smoother: NamedSmoother, current: MergeRound, *, window_s: float = 20.0,
                   bend_probability: float = 0.999, probability: float = 0.99, on_try=None
                   ) -> tuple[MergeRound, list[dict]]:
    """Names split where the odometry bends: each increment whose normalised odometry χ²₃ exceeds
    ``bend_probability``; each name with kept sightings within ``window_s`` s on both sides of it is split there (its
    sightings from the bend on get a new name) and re-smoothed alone; a split is kept when the truncated cost falls by
    more than χ²₂ at ``probability``. The kept splits are applied together and re-smoothed. Returns the new state
    (``current`` if none is kept) and each split tried (name, time, cost drop, kept), each also given to
    ``on_try(split)`` as it is measured (a benchmark's progress). Session 25 (A): a chained name holding a run of
    another post's sightings."""
    problem, solution = current.named.problem, current.solution
    sighting_times = smoother.log.sighting_times
    odometry = normalised_residuals(problem, solution)[0]
    times = current.named.frame_times
    sighted = times[problem.pose_index - 1]
    base = smoother.cost(problem, solution)
    position = dict(zip(current.named.names.tolist(), solution.landmarks, strict=True))
    next_name = int(current.names.max()) + 1
    tried, kept = [], []
    bend_bound = chi2.ppf(bend_probability, 3)
    for j in np.flatnonzero(np.sum(odometry ** 2, axis=1) > bend_bound):
        at = float(times[j])
        near = solution.inliers & (sighted >= at - window_s) & (sighted < at + window_s)
        for k in np.unique(problem.landmark_index[near]):
            mine = near & (problem.landmark_index == k)
            if not (np.any(mine & (sighted < at)) and np.any(mine & (sighted >= at))):
                continue
            name = int(current.named.names[k])
            names = current.names.copy()
            names[(names == name) & (sighting_times >= at)] = next_name
            named, trial = smoother.smooth(names, initial_poses=solution.poses,
                                           initial={**position, next_name: position[name]})
            drop = base - smoother.cost(named.problem, trial)
            keep = drop > chi2.ppf(probability, 2)
            tried.append({"name": name, "t": at, "cost_drop": float(drop), "kept": bool(keep)})
            if on_try is not None:
                on_try(tried[-1])
            if keep:
                kept.append((name, at))
    if not kept:
        return current, tried
    names = current.names.copy()
    initial = dict(position)
    for name, at in kept:
        names[(names == name) & (sighting_times >= at)] = next_name
        initial[next_name] = position[name]
        next_name += 1
    named, trial = smoother.smooth(names, initial_poses=solution.poses, initial=initial)
    rise = smoother.cost(named.problem, trial) - base
    return MergeRound([], rise, 0.0, True, names, named, trial), tried


def poses_at(log: RangeBearingLog, current: MergeRound, noise: NoiseModel, times: np.ndarray) -> np.ndarray:
    """The smoothed poses (len(times), 3) at any log ``times``: each from the solution's frame nearest in time, moved
    by the calibrated odometry between the two (what the smoother's own increments would give). Means only: the noise
    model's stalls after the command's dips (a zero-mean variance, :mod:`estimation.odometry_stall`) do not move
    them; the smoother that takes these poses as its start adds them (:func:`~estimation.named_smoothing.
    named_problem`)."""
    frames = current.named.frame_times
    k = np.clip(np.searchsorted(frames, times), 1, len(frames) - 1)
    k = np.where(np.abs(frames[k - 1] - times) <= np.abs(frames[k] - times), k - 1, k)
    odometry = log.odometry_pose(noise.odometry_times(np.concatenate([frames[k], times])))
    step = noise.calibrate_increments(between(odometry[:len(times)], odometry[len(times):]))
    return compose(current.solution.poses[1 + k], step)


def resmoothed(smoother: NamedSmoother, current: MergeRound, names: np.ndarray, same_labels: bool = True
               ) -> MergeRound:
    """``names`` smoothed from ``current``'s solution: the poses at the new frames (:func:`poses_at`: an old frame's
    own pose, a new one's nearest moved by the odometry) and the names kept, in the frame of the new first pose.
    ``same_labels`` False: ``names`` label the landmarks otherwise than ``current`` does (another run's), so they are
    placed from their first sightings instead."""
    log = smoother.log
    frames = np.unique(log.sighting_times[names >= 0])
    at = poses_at(log, current, smoother.noise, np.r_[frames[:1], frames])
    start = at[0]
    kept = set(np.unique(names[names >= 0]).tolist()) if same_labels else set()
    initial = {int(x): between(start, np.r_[p, 0.0])[:2]
               for x, p in zip(current.named.names, current.solution.landmarks, strict=True) if int(x) in kept}
    named, solution = smoother.smooth(names, initial_poses=between(start, at), initial=initial)
    return MergeRound([], 0.0, 0.0, True, names, named, solution)
