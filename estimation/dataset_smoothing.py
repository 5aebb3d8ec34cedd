"""A data set run's map and trajectory smoothed over the whole log (``run_landmark_log(..., smooth=True)``).

The filter's best particle is the initial guess; :func:`estimation.landmark_smoother.smooth` finds the MAP poses
and landmarks of every odometry increment and every sighting (by its landmark's identity). The map it writes is
the smoother's: positions (z = 0, the sensor is planar), the marginal covariances of the landmarks in the map's
frame (the inverse information, so no drift export is added: the frame's uncertainty is in them already), the
identities in ``metadata["external_ids"]``, the smoothed trajectory. The filter's own figures stay in the metrics
under ``filter_``; ``smoother_*`` report the fit (χ² per degree of freedom, sightings dropped as outliers,
convergence).
"""
from __future__ import annotations

import numpy as np

from .dataset_slam import sighted_true_ids
from .fastslam.motion import increment_variance
from .geometry import between, compose
from .landmark_correspondence import smooth_with_correspondences
from .landmark_map import LandmarkMap
from .landmark_scores import CHI2_95, ate, map_scores, pose_nees
from .landmark_smoother import LandmarkLogProblem, landmarks_from_first_sightings, smooth

_Z_VARIANCE = 1e-6      # m²: the planar sensor says nothing of the height; the map pins it at 0, as the filter does
_FILTER_KEYS = ("ate_m", "final_position_error_m", "pose_nees_mean", "pose_nees_median", "pose_nees_within_chi2_95",
                "pose_nees_frames", "landmarks", "duplicate_fraction", "landmark_error_median_m",
                "landmark_error_rigid_median_m", "landmark_nees_within_bound", "landmark_nees_rigid_within_bound",
                "landmark_nees_median")


def smooth_run(run, log, frames, named, increments, sensor, config, filter_poses, true_start, t0, until):
    """The :class:`~estimation.dataset_slam.DatasetRun` ``run`` with its map, trajectory and pose NEES smoothed.

    frames: per filter frame k, (true ids, ranges, bearings) as the filter was given them (calibrated); named: per
    frame, the landmark each sighting names (its id with ``association="id"``; the best particle's landmark id with
    ``"unknown"``, whose landmarks are then merged where the smoothed log shows them to be one); increments (T, 3)
    the calibrated odometry increments before each frame; sensor the (inflated) range-bearing noise; config the
    filter's (its motion noise); filter_poses (T, 3) the best particle's poses in the start frame.
    """
    if not any(len(ids) for ids, _, _ in frames):
        before = "" if until is None else f" before {until:g} s"
        raise ValueError(f"{log.name}: nothing to smooth: no sightings{before}")
    by_id = config.association == "id"
    initial = np.vstack([np.zeros(3), filter_poses])
    problem, landmark_keys = _problem(frames, named, increments, sensor, config)
    initial_landmarks = _initial_landmarks(run.map, landmark_keys, problem, initial, by_id)
    merge_metrics = {}
    if by_id:
        solution = smooth(problem, initial, initial_landmarks)
        landmark_ids, written = landmark_keys, np.ones(len(landmark_keys), bool)
    else:
        found = smooth_with_correspondences(problem, initial, initial_landmarks)
        solution, problem = found.solution, found.problem
        landmark_ids = _majority_true_ids(problem, solution.inliers, _true_ids(frames, named), len(solution.landmarks))
        written = _still_believed(found.merged_into, landmark_keys, run.map.ids, len(solution.landmarks))
        merge_metrics = dict(smoother_merges=len(found.merges), smoother_merges_undone=len(found.rejected),
                             smoother_merge_rounds=found.rounds, smoother_landmarks_dropped=int((~written).sum()))
    times = run.true_trajectory[:, 0]
    estimated_world = np.column_stack([times, compose(true_start, solution.poses[1:])])
    landmark_map = _smoothed_map(run.map, solution, landmark_ids, problem.landmark_index, times, written, by_id)
    covariance_rows = solution.covariance_poses - 1
    true_in_start = between(true_start, run.true_trajectory[covariance_rows, 1:])
    nees = np.full(len(times), np.nan)
    # the covariances are of (x, y, θ) in the map's frame: the error is the difference there (θ wrapped)
    nees[covariance_rows] = pose_nees(solution.poses[solution.covariance_poses] - true_in_start,
                                      solution.pose_covariances)
    finite = nees[np.isfinite(nees)]
    metrics = {f"filter_{key}": run.metrics[key] for key in _FILTER_KEYS if key in run.metrics}
    metrics.update(run.metrics)
    metrics.update(
        ate_m=ate(estimated_world[:, 1:], run.true_trajectory[:, 1:]),
        final_position_error_m=float(np.hypot(*(estimated_world[-1, 1:3] - run.true_trajectory[-1, 1:3]))),
        pose_nees_mean=float(np.mean(finite)), pose_nees_median=float(np.median(finite)),
        pose_nees_within_chi2_95=float(np.mean(finite < CHI2_95[3])), pose_nees_frames=int(len(finite)),
        smoothed=True, smoother_chi2_per_dof=solution.chi2_per_dof, smoother_dof=solution.dof,
        smoother_outliers=int((~solution.inliers).sum()), smoother_sightings=int(len(solution.inliers)),
        smoother_iterations=solution.iterations, smoother_converged=bool(solution.converged), **merge_metrics)
    attributed = (np.asarray(landmark_map.metadata["external_ids"], np.int64) if by_id
                  else landmark_ids[_written_rows(solution, written)])
    metrics.update(map_scores(landmark_map.positions, landmark_map.covariances, attributed, true_start,
                              log.truth_ids, log.truth_positions, sighted_true_ids(log, t0, until)))
    return type(run)(landmark_map, run.true_trajectory, estimated_world, run.dead_reckoning, nees, metrics)


def _problem(frames, named, increments, sensor, config) -> tuple[LandmarkLogProblem, np.ndarray]:
    """The factors of the run (the sightings that name a landmark, ≥ 0), and the name (L,) of each landmark index."""
    pose_index = np.concatenate([np.full(len(ids), k + 1) for k, (ids, _, _) in enumerate(frames)]).astype(int)
    keys = np.concatenate([np.asarray(k, np.int64) for k in named]).astype(np.int64)
    ranges = np.concatenate([f[1] for f in frames]).astype(float)
    bearings = np.concatenate([f[2] for f in frames]).astype(float)
    used = keys >= 0
    landmark_keys, landmark_index = np.unique(keys[used], return_inverse=True)
    problem = LandmarkLogProblem(np.asarray(increments, float), increment_variance(increments, config),
                                 pose_index[used], landmark_index, ranges[used], bearings[used],
                                 sensor.range_sigma(ranges[used]),
                                 np.full(int(used.sum()), float(sensor.bearing_sigma_rad)))
    return problem, landmark_keys


def _true_ids(frames, named) -> np.ndarray:
    """The true id of each sighting the problem holds (those that name a landmark), for scoring."""
    keys = np.concatenate([np.asarray(k, np.int64) for k in named])
    return np.concatenate([np.asarray(f[0], np.int64) for f in frames])[keys >= 0]


def _majority_true_ids(problem, inliers, true_ids, n_landmarks) -> np.ndarray:
    """The true id most of each landmark's kept sightings were of (scoring only; -1: none kept)."""
    out = np.full(n_landmarks, -1, np.int64)
    for landmark in range(n_landmarks):
        ids = true_ids[inliers & (problem.landmark_index == landmark)]
        if len(ids):
            values, counts = np.unique(ids, return_counts=True)
            out[landmark] = values[np.argmax(counts)]
    return out


def _still_believed(merged_into, landmark_keys, filter_map_ids, n_landmarks) -> np.ndarray:
    """(L,) bool: the landmark holds a landmark of the filter's final map. The filter's existence estimate removed
    the others (seen too seldom where they should have been); their sightings stay in the smoothing (they tie their
    poses together) but the map does not claim them."""
    out = np.zeros(n_landmarks, bool)
    alive = np.isin(landmark_keys, np.asarray(filter_map_ids, np.int64))
    out[merged_into[alive]] = True
    return out


def _initial_landmarks(filter_map: LandmarkMap, landmark_keys, problem, poses, by_id: bool) -> np.ndarray:
    """The filter's landmark of each name (its identity, or its id in the filter); one the filter's final map does
    not hold: placed from its first sighting."""
    out = landmarks_from_first_sightings(problem, poses)
    names = np.asarray(filter_map.metadata.get("external_ids", []) if by_id else filter_map.ids, np.int64)
    for i, key in enumerate(landmark_keys):
        rows = np.flatnonzero(names == key)
        if len(rows):
            out[i] = filter_map.positions[rows[0], :2]
    return out


def _written_rows(solution, written) -> np.ndarray:
    """(L,) bool: the landmarks the map holds: ``written`` and sighted (a finite covariance)."""
    return np.all(np.isfinite(solution.landmark_covariances.reshape(len(written), -1)), axis=1) & written


def _smoothed_map(filter_map: LandmarkMap, solution, landmark_ids, landmark_index, times, written,
                  by_id: bool) -> LandmarkMap:
    """The map of the landmarks ``written`` (L,) that were sighted; identities in the metadata in ID mode."""
    seen = _written_rows(solution, written)
    n = int(seen.sum())
    covariances = np.zeros((n, 3, 3))
    covariances[:, :2, :2] = solution.landmark_covariances[seen]
    covariances[:, 2, 2] = _Z_VARIANCE
    counts = np.bincount(landmark_index[solution.inliers], minlength=len(landmark_ids))[seen]
    metadata = dict(filter_map.metadata, smoothed=True, smoother_chi2_per_dof=solution.chi2_per_dof)
    if by_id:
        metadata["external_ids"] = [int(i) for i in landmark_ids[seen]]
    return LandmarkMap(np.column_stack([solution.landmarks[seen], np.zeros(n)]), covariances,
                       np.zeros((n, 0), np.float32), ids=np.arange(n), counts=counts, robot=filter_map.robot,
                       frame=filter_map.frame, trajectory=np.column_stack([np.append(times[:1], times),
                                                                           solution.poses]),
                       metadata=metadata)
