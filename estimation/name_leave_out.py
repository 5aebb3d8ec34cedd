"""Names and runs of sightings left out of a merged map: those that cannot stand as landmarks of their own.

After the merges, a name can still be a second name of some post: a glimpse whose gate holds two posts
(:func:`ambiguous_names`), a few sightings placed off their post that the sensor's own record explains as another
landmark's (:func:`unconfirmed_names`), or a run of sightings the rest of the map bends to fit
(:func:`flagged_runs_of`). Leaving it out (its sightings unnamed, the rest re-smoothed: :func:`leave_out`) is the
honest answer: a later naming step may give the sightings their right name (:mod:`estimation.unnamed_sightings`),
and a map without a name is better than a map with a confidently wrong one.

Measured in ``benchmarks/mrclam_constellation.py`` (its docstring, steps 7, 8 and 10; docs/fastslam-history.md,
"Session 28: the whole chain as one command ... (lead)" and "Session 30: the remedies in one command ... (B)").
Moved here from the benchmark in session 36 (lead), unchanged; the benchmark scores what is left out by the
barcodes, these functions never see them.
"""
from __future__ import annotations

import numpy as np

from estimation.constellation import pairwise_groups
from estimation.fastslam import FastSLAMConfig
from estimation.fastslam.existence import exclusive_log_odds, hit_log_odds, miss_log_odds
from estimation.geometry import wrap_angle
from estimation.map_honesty import Run, flagged_runs, sighting_runs, split_scores, split_threshold
from estimation.name_merging import NamedSmoother, resmoothed
from estimation.named_smoothing import MergeRound
from estimation.noise_model import NoiseModel, with_fastslam
from estimation.pass_matching import pairwise_inputs

RUN_GAP_S = 5.0        # a run: one name's kept sightings less than this apart (estimation.map_honesty.sighting_runs)


def ambiguous_names(current: MergeRound, *, name_floor_m: float = 0.0, kept_covisible: bool = False) -> list[int]:
    """The names to leave out so that no name is ambiguous under the pairwise judgement
    (:func:`estimation.constellation.pairwise_groups` with ``split_ambiguous``: a name whose χ²₂ 99 % gate holds two
    names that cannot be one post), the least certain first: while any name is ambiguous, the ambiguous name of
    largest position covariance (determinant) goes and the rest are judged again. A well-seen name is ambiguous only
    through the glimpses around it (a difference's covariance is the sum of both names'); once the glimpses go, it
    is not (session 28, robot 1 seed 0: a 519-sighting name, ambiguous beside a 10-sighting glimpse)."""
    solution = current.solution
    n = len(current.named.names)
    covariance, covisible, seen = pairwise_inputs(current, name_floor_m=name_floor_m, kept_covisible=kept_covisible)
    points = seen.tolist()
    blocks = covariance.reshape(n, 2, n, 2)[np.arange(n), :, np.arange(n), :]
    spread = blocks[:, 0, 0] * blocks[:, 1, 1] - blocks[:, 0, 1] * blocks[:, 1, 0]
    left = []
    while True:
        groups = pairwise_groups(solution.landmarks, covariance, points, allowed=~covisible, split_ambiguous=True)
        ambiguous = [g.members[0] for g in groups if g.status == "ambiguous"]
        if not ambiguous:
            return sorted(int(current.named.names[i]) for i in left)
        worst = max(ambiguous, key=lambda i: spread[i])
        left.append(worst)
        points.remove(worst)


def detected_in_frames(current: MergeRound) -> np.ndarray:
    """(frames, names) bool: which names a kept sighting reports in each of the smoother's frames."""
    problem, kept = current.named.problem, current.solution.inliers
    detected = np.zeros((len(current.named.frame_times), len(current.named.names)), bool)
    detected[problem.pose_index[kept] - 1, problem.landmark_index[kept]] = True
    return detected


def unconfirmed_names(current: MergeRound, noise: NoiseModel, config: FastSLAMConfig) -> list[int]:
    """The names the sensor's own record says are not landmarks of their own, by the filter's two rules on the
    smoothed map (the calibrated detection rates of ``noise``, :mod:`estimation.fastslam.existence`): a name's
    *existence* — log-odds from the detections under it and the frames in which it was in view (range, field of
    view) and not detected — is below ``existence_remove``, and a name within ``merge_radius`` never detected in one
    frame with it holds the *co-visibility* evidence "one point" (``exclusive_log_odds`` over the frames in which one
    of them was detected and the other in view, at least ``merge_log_odds``): its sightings are another landmark's,
    placed off. Taken greedily, least existence first, against the names still kept. A rarely detected post of its
    own (robot 1 seed 0's post 8: existence −18.8) has no such neighbour and stays. Only the smoother's frames count
    (frames without any sighting are not poses of it), so misses are undercounted: the test errs towards keeping."""
    config = with_fastslam(noise, config)
    solution = current.solution
    poses = solution.poses[1:]                                  # pose k + 1 is frame k
    offset = solution.landmarks[None, :, :] - poses[:, None, :2]
    ranges = np.hypot(offset[..., 0], offset[..., 1])
    bearings = wrap_angle(np.arctan2(offset[..., 1], offset[..., 0]) - poses[:, None, 2])
    in_view = (ranges >= config.min_range) & (ranges <= config.max_range) \
        & (np.abs(bearings) <= config.fov_horizontal / 2)
    detected = detected_in_frames(current)
    existence = config.existence_initial + np.where(
        detected, hit_log_odds(config, ranges), np.where(in_view, miss_log_odds(config, ranges), 0.0)).sum(axis=0)
    exclusive = exclusive_log_odds(config, ranges)
    apart = np.hypot(*(solution.landmarks[:, None] - solution.landmarks[None]).transpose(2, 0, 1))
    left: list[int] = []
    for i in np.argsort(existence, kind="stable"):
        if existence[i] >= config.existence_remove:
            break
        for j in np.flatnonzero(apart[i] <= config.merge_radius):
            if j == i or j in left or (detected[:, i] & detected[:, j]).any():
                continue
            one_point = (exclusive[:, i] * (detected[:, j] & ~detected[:, i] & in_view[:, i])).sum() \
                + (exclusive[:, j] * (detected[:, i] & ~detected[:, j] & in_view[:, j])).sum()
            if one_point >= config.merge_log_odds:
                left.append(int(i))
                break
    return sorted(int(current.named.names[i]) for i in left)


def leave_out(smoother: NamedSmoother, current: MergeRound, left: list[int]) -> MergeRound:
    """``current`` without the names ``left``: their sightings unnamed, the rest re-smoothed (``current`` itself
    when nothing is left out)."""
    if not left:
        return current
    names = current.names.copy()
    names[np.isin(names, left)] = -1
    return resmoothed(smoother, current, names)


def flagged_runs_of(current: MergeRound, alpha: float) -> list[tuple[Run, float, float]]:
    """The runs of sightings the honest-names screen flags on ``current``'s map
    (:func:`estimation.map_honesty.flagged_runs`: split score beyond χ²₂ at 1 − α/k, k the name's runs; a name's
    largest run never), each with its score and threshold. Session 30 (B): robot 4's right run of 9 sightings at 13.5
    against 13.1 kept its name from its twin 1.3 cm away; robot 2 seed 0's 17 sightings of post 8 under post 9's name
    bent the stretch around them."""
    named, solution = current.named, current.solution
    runs = sighting_runs(named.problem, solution, RUN_GAP_S)
    scores = split_scores(named.problem, solution, runs)
    out = flagged_runs(runs, scores, alpha)
    per_name = np.bincount([run.landmark for run in runs], minlength=len(named.names))
    return [(run, float(score), split_threshold(int(per_name[run.landmark]), alpha))
            for run, score, o in zip(runs, scores, out, strict=True) if o]


def leave_out_runs(smoother: NamedSmoother, current: MergeRound, runs: list[Run]) -> MergeRound:
    """``current`` with the sightings of ``runs`` unnamed and the rest re-smoothed (``current`` when there are none):
    a flagged run no longer keeps its name from every merge, nor bends the stretch that holds a post's other name."""
    if not runs:
        return current
    names = current.names.copy()
    for run in runs:
        names[current.named.sightings[run.sightings]] = -1
    return resmoothed(smoother, current, names)
