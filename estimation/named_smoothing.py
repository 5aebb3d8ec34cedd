"""A landmark log smoothed under a given naming of its sightings: the problem, its smoothing, its cost, co-visibility.

A naming (N,) gives each sighting of a :class:`~estimation.datasets.RangeBearingLog` a name (−1: left out), e.g. the
chained names of :mod:`estimation.chained_names` or those after some names were merged. This module builds the
smoother's factors for it (:func:`named_problem`: the factors ``run_landmark_log(association="id", smooth=True)``
builds with the names as identities), smooths it (:func:`smooth_named`), scores a solution by one cost that compares
solutions which dropped different sightings (:func:`truncated_cost`), says which names were sighted in one frame and
so cannot be one post (:func:`covisible_names`), and records one round of merging names (:class:`MergeRound`).

Measured in ``benchmarks/mrclam_chained_names.py`` (its docstring; docs/fastslam-history.md, "Session 21: names
chained through overlapping windows ... (U)"), with the heading-bias states in "Session 23: the smoother's
heading-bias states and the open chain's loops (E)" and the increments' path variances (:func:`path_variances`) in
"Session 25: why partly merged maps are overconfident ... (A)"; the loop-closing built on it is
``benchmarks/mrclam_constellation.py``. Moved here from the benchmark in session 36 (A), unchanged (the same smoothed
solution, bit for bit, on robots 2 and 5).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from estimation.datasets import RangeBearingLog
from estimation.fastslam import FastSLAMConfig
from estimation.fastslam.motion import propagate_covariance
from estimation.geometry import between, compose, dead_reckoning
from estimation.landmark_smoother import (
    OUTLIER_CHI2,
    HeadingDrift,
    HeadingLoss,
    LandmarkLogProblem,
    SightingOffset,
    Smoothed,
    landmarks_from_first_sightings,
    normalised_residuals,
    smooth,
)
from estimation.noise_model import NoiseModel, increment_variances, with_fastslam


@dataclass
class NamedProblem:
    """A log's smoothing problem with given names: ``problem`` (landmark index ``k`` is name ``names[k]``), the
    frames' log times (T,) (pose k + 1 is frame k), the sightings (S,) of the log each factor is (row indices)."""

    problem: LandmarkLogProblem
    names: np.ndarray
    frame_times: np.ndarray
    sightings: np.ndarray


def named_problem(log: RangeBearingLog, names: np.ndarray, noise: NoiseModel, config: FastSLAMConfig, *,
                  path_step_s: float | None = None) -> NamedProblem:
    """The factors ``run_landmark_log(association="id", smooth=True)`` builds for ``log`` with each sighting named
    ``names`` (−1: left out): frames at the named sightings' time stamps, from the first; the calibrated odometry
    increments between them, their variances with the noise model's stalls after the command's dips if it has that
    term (:func:`~estimation.noise_model.increment_variances`, as the data set's filter and smoother have them);
    each sighting's calibrated range and bearing with the inflated σ.

    ``path_step_s``: the increments' variances propagated along the odometry's path in steps of about this many
    seconds (:func:`path_variances`) instead of the random walk's variance of the chord (None, the default)."""
    sensor = noise.range_bearing
    inflate_r, inflate_b = (float(np.sqrt(f)) for f in sensor.variance_inflation())
    config = with_fastslam(noise, config)
    rows = np.flatnonzero(np.asarray(names) >= 0)
    times, frame = np.unique(log.sighting_times[rows], return_inverse=True)
    frame_times = np.concatenate([times[:1], times])
    odometry = log.odometry_pose(noise.odometry_times(frame_times))
    increments = noise.calibrate_increments(between(odometry[:-1], odometry[1:]))
    variances = increment_variances(log, noise, config, frame_times, increments)
    if path_step_s is not None:
        variances = np.maximum(variances, path_variances(log, noise, config, frame_times, path_step_s))
    ranges, bearings = sensor.corrected(log.ranges[rows], log.bearings[rows])
    unique_names, landmark_index = np.unique(np.asarray(names)[rows], return_inverse=True)
    problem = LandmarkLogProblem(np.asarray(increments, float), variances,
                                 frame.astype(int) + 1, landmark_index.astype(int), ranges, bearings,
                                 sensor.range_sigma(ranges) * inflate_r,
                                 np.full(len(rows), sensor.bearing_sigma_rad * inflate_b), np.diff(frame_times))
    return NamedProblem(problem, unique_names, times, rows)


def path_variances(log: RangeBearingLog, noise: NoiseModel, config: FastSLAMConfig, frame_times: np.ndarray,
                   step_s: float) -> np.ndarray:
    """(T, 3) the variances of the increments between consecutive ``frame_times`` (T + 1,) as the random walk gives
    them along the odometry's path: each increment cut into steps of at most ``step_s`` s, each step's calibrated
    increment and variance (``config``: with the noise model's fastslam keys) composed from the increment's start
    (``propagate_covariance``), the diagonal of the result in the start pose's frame (the frame of the smoother's
    odometry residual). An increment of one step has its chord's variance; one across a gap of sightings in which the
    robot turned back and forth or drove a curve gets what the path it drove gives (the chord's variance of a spin
    out and back is the variance of no turn). The noise model's stalls after the command's dips, if it has that term,
    are on the steps that hold a dip, propagated with the rest."""
    frame_times = np.asarray(frame_times, float)
    t = len(frame_times) - 1
    steps = np.maximum(np.ceil(np.diff(frame_times) / step_s).astype(int), 1)
    owner = np.repeat(np.arange(t), steps)
    first = np.concatenate([[0], np.cumsum(steps)[:-1]])
    within = np.arange(len(owner)) - first[owner]
    start = frame_times[:-1][owner] + within * (np.diff(frame_times) / steps)[owner]
    grid = np.append(start, frame_times[-1])
    odometry = log.odometry_pose(noise.odometry_times(grid))
    fine = noise.calibrate_increments(between(odometry[:-1], odometry[1:]))
    fine_var = increment_variances(log, noise, config, grid, fine)     # a dip's stall on the step that holds it
    pose = np.zeros((t, 3))
    cov = np.zeros((t, 3, 3))
    for k in range(int(steps.max()) if t else 0):
        on = np.flatnonzero(steps > k)
        j = first[on] + k
        for i, row in zip(on, j, strict=True):      # a few long increments: a loop over them is cheap
            cov[i] = propagate_covariance(pose[i:i + 1], cov[i:i + 1], fine[row], fine_var[row])[0]
        pose[on] = compose(pose[on], fine[j])
    return np.diagonal(cov, axis1=1, axis2=2).copy()


def truncated_cost(problem: LandmarkLogProblem, solution: Smoothed, heading_loss: HeadingLoss | None = None
                   ) -> float:
    """Σ r² of the odometry (and of the heading drift's factors) plus Σ min(r², χ²₂ 99 %) of every sighting: one
    cost for solutions that dropped different sightings as outliers (a dropped sighting counts at the bound).
    ``heading_loss``: the smoother's heavy-tailed heading loss, if the solution was smoothed with one: the odometry's
    heading residuals then count by its ρ(r), the cost the smoother minimised (None: r², today's cost exactly)."""
    odometry, sightings, drift = normalised_residuals(problem, solution)
    per = np.sum(sightings ** 2, axis=1)
    if heading_loss is None:
        odometry_cost = np.sum(odometry ** 2)
    else:
        odometry_cost = np.sum(odometry[:, :2] ** 2) + np.sum(heading_loss.rho(odometry[:, 2],
                                                                               problem.increment_sigmas[:, 2]))
    return float(odometry_cost + np.sum(drift ** 2) + np.sum(np.minimum(per, OUTLIER_CHI2)))


def covisible_names(problem: LandmarkLogProblem, inliers: np.ndarray, n: int, *, kept_only: bool = False
                    ) -> np.ndarray:
    """(L, L) True where two landmarks were sighted in one frame (every sighting counts, kept or dropped; with
    ``kept_only`` only the sightings the smoother kept: a dropped one is not the landmark's by its own verdict)."""
    rows = np.asarray(inliers, bool) if kept_only else np.ones(len(problem.pose_index), bool)
    incidence = sp.csr_matrix((np.ones(int(rows.sum())), (problem.pose_index[rows], problem.landmark_index[rows])),
                              shape=(problem.n_poses + 1, n))
    return (incidence.T @ incidence).toarray() > 0


@dataclass
class MergeCandidate:
    """Names ``a`` < ``b`` proposed as one post: d² under their difference's covariance, and the log likelihood
    ratio of the pair over the second most likely partner of either (the smaller of the two)."""

    a: int
    b: int
    d2: float
    log_ratio: float


@dataclass
class MergeRound:
    """One round of merging names (a loop-closing step): the pairs merged (name kept, name absorbed), the truncated
    cost's rise and its χ² 99 % bound for the merges' 2·m degrees of freedom, whether it was kept; the names (N,) and
    the solution after it (those before it when it was undone); the candidates that proposed the merges, if any."""

    merged: list[tuple[int, int]]
    rise: float
    bound: float
    accepted: bool
    names: np.ndarray
    named: NamedProblem
    solution: Smoothed
    candidates: list[MergeCandidate] = field(default_factory=list)


def smooth_named(log: RangeBearingLog, names: np.ndarray, noise: NoiseModel, config: FastSLAMConfig, *,
                 initial_poses: np.ndarray | None = None, initial: dict[int, np.ndarray] | None = None,
                 heading_drift: HeadingDrift | None = None, path_step_s: float | None = None,
                 sighting_offset: SightingOffset | None = None, offset_names: np.ndarray | None = None,
                 heading_loss: HeadingLoss | None = None) -> tuple[NamedProblem, Smoothed]:
    """The smoother on ``log`` with ``names``; initial poses (T + 1, 3) (default: the calibrated dead reckoning),
    initial landmark positions by name (default: placed from their first sightings); ``heading_drift``: the
    smoother's heading-bias states (None: none); ``path_step_s``: :func:`named_problem`'s. ``sighting_offset``: an
    offset per group of sightings (:class:`~estimation.landmark_smoother.SightingOffset`), the groups given by
    ``offset_names`` (N,) (each sighting's name before any merge: a chained name's sightings share one offset; default
    ``names``: each landmark its own). ``heading_loss``: the smoother's heavy-tailed loss on the odometry's heading
    residuals (:class:`~estimation.landmark_smoother.HeadingLoss`; None: Gaussian)."""
    named = named_problem(log, names, noise, config, path_step_s=path_step_s)
    if sighting_offset is not None and sighting_offset.on and offset_names is not None:
        groups = np.unique(np.asarray(offset_names)[named.sightings], return_inverse=True)[1]
        named = dataclasses.replace(named, problem=dataclasses.replace(named.problem,
                                                                       offset_index=groups.astype(int)))
    problem = named.problem
    if initial_poses is None:
        initial_poses = dead_reckoning(problem.increments)
    landmarks = landmarks_from_first_sightings(problem, initial_poses)
    for k, name in enumerate(named.names):
        if initial is not None and int(name) in initial:
            landmarks[k] = initial[int(name)]
    return named, smooth(problem, initial_poses, landmarks, heading_drift=heading_drift,
                         sighting_offset=sighting_offset, heading_loss=heading_loss)
