"""A data set run's map and trajectory smoothed over the whole log (``run_landmark_log(..., smooth=True)``).

The filter's best particle is the initial guess; :func:`estimation.landmark_smoother.smooth` finds the MAP poses
and landmarks of every odometry increment and every sighting (by its landmark's identity). The map it writes is
the smoother's: positions (z = 0, the sensor is planar), the marginal covariances of the landmarks in the map's
frame (the inverse information, so no drift export is added: the frame's uncertainty is in them already), the
identities in ``metadata["external_ids"]``, the smoothed trajectory. The filter's own figures stay in the metrics
under ``filter_``; ``smoother_*`` report the fit (χ² per degree of freedom, sightings dropped as outliers,
convergence). Scored against a truth with landmarks, ``landmark_frame_error`` / ``_sd`` / ``_nees`` give the map's
start-frame error as one rigid motion (dx, dy, dθ about the frame's origin) against the joint covariance of its
landmarks (:func:`~estimation.landmark_scores.frame_error`): whether a start-frame miss is the frame, pinned by the
log's first few factors, or the map's shape. With or without a truth, ``frame_reliability_*`` say how far an error
of one sighting that the data cannot find would move that frame, against its σ
(:func:`~estimation.frame_reliability.reliability_metrics`): whether the frame rests on sightings nothing checks.
With a heading drift (:class:`~estimation.landmark_smoother.HeadingDrift`: given, or the filter config's
``odom_heading_drift_sigma_per_m`` / ``odom_heading_drift_tau_s`` when σ > 0, i.e. the noise model's) the smoother
carries a heading-bias state per frame; ``smoother_heading_drift_*`` then say which (absent when off).
With ``image_timing`` (off by default) the bearings of each frame, one image, share one error of σ |ω| σ_t
(:mod:`estimation.image_timing`: the odometry's turn rate, the stamp period's timing uncertainty), held as their
joint covariance (:func:`~estimation.landmark_smoother.image_whitening`); ``smoother_image_timing_sigma_s`` says σ_t.
"""
from __future__ import annotations

import numpy as np

from .dataset_slam import UNSCORED_LANDMARKS, sighted_true_ids, unscored_metrics
from .frame_reliability import design_figures, reliability_metrics
from .geometry import between, compose
from .image_timing import image_bearing_sigmas
from .landmark_map import LandmarkMap
from .landmark_scores import ate, frame_error, map_scores, pose_nees, pose_nees_figures
from .landmark_smoother import (
    HeadingDrift,
    LandmarkLogProblem,
    joint_landmark_covariance,
    landmarks_from_first_sightings,
    smooth,
)
from .map_frame import CHECKED, FIRST_SIGHTING, FRAMES, Reframed, checked_frame, reframe
from .noise_model import increment_variances

_Z_VARIANCE = 1e-6      # m²: the planar sensor says nothing of the height; the map pins it at 0, as the filter does
_FILTER_KEYS = ("ate_m", "final_position_error_m", "pose_nees_mean", "pose_nees_median", "pose_nees_within_chi2_95",
                "pose_nees_frames", "landmarks", "duplicate_fraction", "landmark_error_median_m",
                "landmark_error_rigid_median_m", "landmark_nees_within_bound", "landmark_nees_rigid_within_bound",
                "landmark_nees_median")


def smooth_run(run, log, noise, frames, increments, sensor, config, filter_poses, true_start, t0, until, *,
               heading_drift: HeadingDrift | None = None, frame: str = FIRST_SIGHTING, image_timing: bool = False):
    """The :class:`~estimation.dataset_slam.DatasetRun` ``run`` with its map, trajectory and pose NEES smoothed.

    noise: the run's noise model; frames: per filter frame k, (ids, ranges, bearings) as the filter was given them
    (calibrated); increments (T, 3) the calibrated odometry increments before each frame; sensor the (inflated)
    range-bearing noise; config the filter's (the model's motion noise); filter_poses (T, 3) the best particle's poses
    in the start frame. The increments' variances are :func:`~estimation.noise_model.increment_variances`' (the
    random walk, plus the model's stalls after the command's dips if it has that term, as the filter had them).
    heading_drift: the smoother's heading-bias states (None: the config's drift if it has one, else none).
    true_start None (a log without ground truth): the trajectory stays in the map's frame and nothing is scored.
    frame: the map's frame, ``"first-sighting"`` (the default: pose 0, the robot at its first sighting) or
    ``"checked"`` (:mod:`estimation.map_frame`: the first pose whose frame no single sighting can move unseen; the
    map, trajectory, covariances, ``true_start_pose`` and every score are then in that pose's frame, the reliability
    figures of that frame, ``map_frame_*`` say which; the ``filter_`` figures stay the filter's, in the first
    sighting's frame).
    image_timing: one bearing error shared by each frame's sightings, of σ |ω| σ_t (:mod:`estimation.image_timing`;
    False, the default: none, each bearing's error its own).
    """
    if frame not in FRAMES:
        raise ValueError(f"the map's frame must be one of {', '.join(FRAMES)}, not {frame!r}")
    if not any(len(ids) for ids, _, _ in frames):
        before = "" if until is None else f" before {until:g} s"
        raise ValueError(f"{log.name}: nothing to smooth: no sightings{before}")
    times = run.estimated_trajectory[:, 0]
    frame_times = np.concatenate([[t0], times])
    variances = increment_variances(log, noise, config, frame_times, increments)
    shared, sigma_t = image_bearing_sigmas(log, noise, times) if image_timing else (None, None)
    problem, landmark_ids = _problem(frames, increments, variances, sensor, np.diff(frame_times), shared)
    drift = heading_drift if heading_drift is not None else config_drift(config)
    initial = np.vstack([np.zeros(3), filter_poses])
    solution = smooth(problem, initial, _initial_landmarks(run.map, landmark_ids, problem, initial),
                      heading_drift=drift)
    # the map's frame: pose 0's, or the first pose no single sighting can move unseen (estimation.map_frame)
    framed, chosen, frame_metrics = None, None, {}
    if frame == CHECKED:
        chosen, framed, true_start, frame_metrics = _checked_frame(problem, solution, frame_times, true_start, log)
    landmark_map = _smoothed_map(run.map, solution if framed is None else framed.solution, landmark_ids,
                                 problem.landmark_index, times)
    metrics = {f"filter_{key}": run.metrics[key] for key in _FILTER_KEYS if key in run.metrics}
    metrics.update(run.metrics)
    metrics.update(
        smoothed=True, smoother_chi2_per_dof=solution.chi2_per_dof, smoother_dof=solution.dof,
        smoother_outliers=int((~solution.inliers).sum()), smoother_sightings=int(len(solution.inliers)),
        smoother_iterations=solution.iterations, smoother_converged=bool(solution.converged))
    metrics.update(frame_metrics)
    if image_timing:
        metrics.update(smoother_image_timing_sigma_s=sigma_t,
                       smoother_image_bearing_sd_max_rad=float(np.max(shared, initial=0.0)))
    if chosen is not None:
        landmark_map.metadata.update(map_frame=CHECKED, map_frame_time_s=metrics["map_frame_time_s"])
        if true_start is not None:
            landmark_map.metadata["true_start_pose"] = metrics["true_start_pose"] = [float(v) for v in true_start]
    # which sightings the frame rests on, from the problem's design alone (estimation.frame_reliability)
    pose = 0 if chosen is None else chosen.pose
    metrics.update(design_figures(lambda: reliability_metrics(problem, solution, times, landmark_ids, pose=pose)))
    if solution.heading_drift is not None:
        metrics.update(smoother_heading_drift_sigma_per_m=solution.heading_drift.sigma_per_m,
                       smoother_heading_drift_tau_s=solution.heading_drift.tau_s)
    solution = solution if framed is None else framed.solution
    if true_start is None:   # nothing to score against: the smoothed map's own figures
        metrics.update(unscored_metrics(landmark_map, times, t0))
        return type(run)(landmark_map, run.true_trajectory, np.column_stack([times, solution.poses[1:]]),
                         run.dead_reckoning, np.full(len(times), np.nan), metrics)
    estimated_world = np.column_stack([times, compose(true_start, solution.poses[1:])])
    nees = smoothed_pose_nees(solution, true_start, run.true_trajectory[:, 1:])
    metrics.update(
        ate_m=ate(estimated_world[:, 1:], run.true_trajectory[:, 1:]),
        final_position_error_m=float(np.hypot(*(estimated_world[-1, 1:3] - run.true_trajectory[-1, 1:3]))),
        **pose_nees_figures(nees))
    if not len(log.truth_ids):
        metrics.update(unscored_metrics(landmark_map, times, t0, UNSCORED_LANDMARKS))
    else:
        metrics.update(map_scores(landmark_map.positions, landmark_map.covariances,
                                  np.asarray(landmark_map.metadata["external_ids"], np.int64), true_start,
                                  log.truth_ids, log.truth_positions, sighted_true_ids(log, t0, until)))
        joint = joint_landmark_covariance(problem, solution) if framed is None else framed.joint_covariance
        metrics.update(_frame_error(solution, joint, landmark_ids, true_start, log))
    return type(run)(landmark_map, run.true_trajectory, estimated_world, run.dead_reckoning, nees, metrics)


def _checked_frame(problem, solution, frame_times, true_start, log):
    """:func:`~estimation.map_frame.checked_frame` of ``solution``, and what follows from it: the choice, the solution
    reframed (:class:`~estimation.map_frame.Reframed`; ``solution`` itself with the joint covariance if the frame
    stays pose 0's), the true pose of the chosen frame (None without a truth) and the ``map_frame_*`` figures."""
    choice = checked_frame(problem, solution)
    if choice.pose:
        framed = reframe(problem, solution, choice.pose)
    else:
        framed = Reframed(0, solution, joint_landmark_covariance(problem, solution))
    at = float(frame_times[choice.pose])
    metrics = {"map_frame": CHECKED, "map_frame_pose": choice.pose, "map_frame_time_s": at,
               "map_frame_found": choice.found, "map_frame_poses_tried": choice.poses_tried,
               "map_frame_effect_sd": [float(v) for v in choice.effect_sd],
               "map_frame_first_sighting_effect_sd": [float(v) for v in choice.first_effect_sd]}
    if true_start is not None and choice.pose:
        true_start = log.true_pose([at])[0]
    return choice, framed, true_start, metrics


def smoothed_pose_nees(solution, true_start: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """The NEES (T,) of a smoothed ``solution``'s poses at its T frames against the true poses ``truth`` (T, 3) (world
    frame; ``true_start`` the true pose of the map's origin), NaN at the frames without a pose covariance. The
    covariances are of (x, y, θ) in the map's frame: the error is the difference there (θ wrapped)."""
    nees = np.full(len(truth), np.nan)
    rows = solution.covariance_poses - 1
    nees[rows] = pose_nees(solution.poses[solution.covariance_poses] - between(true_start, truth[rows]),
                           solution.pose_covariances)
    return nees


def _frame_error(solution, joint, landmark_ids, true_start, log) -> dict:
    """The smoothed map's start-frame error as one rigid motion and its NEES by the landmarks' joint covariance
    ``joint`` (:func:`~estimation.landmark_scores.frame_error`), over the landmarks placed whose true position is
    known."""
    truth = {int(i): p for i, p in zip(log.truth_ids, log.truth_positions, strict=True)}
    rows = np.array([k for k, i in enumerate(landmark_ids) if int(i) in truth and np.isfinite(joint[2 * k, 2 * k])],
                    np.int64)
    world = np.array([truth[int(landmark_ids[k])] for k in rows]).reshape(-1, 2)
    local = between(true_start, np.column_stack([world, np.zeros(len(world))]))[:, :2]
    columns = np.column_stack([2 * rows, 2 * rows + 1]).ravel()
    return frame_error(solution.landmarks[rows], local, joint[np.ix_(columns, columns)])


def config_drift(config) -> HeadingDrift | None:
    """The filter config's heading drift (``odom_heading_drift_sigma_per_m``, ``odom_heading_drift_tau_s``: the
    noise model's, which the filter's particles carry), None if it has none or σ is 0."""
    sigma = float(config.odom_heading_drift_sigma_per_m)
    if sigma <= 0:
        return None
    return HeadingDrift(sigma, float(config.odom_heading_drift_tau_s))


def _problem(frames, increments, variances, sensor, seconds=None, image_sigmas=None
             ) -> tuple[LandmarkLogProblem, np.ndarray]:
    """The factors of the run (``variances`` (T, 3): the increments', ``seconds`` (T,): their durations,
    ``image_sigmas`` (T,): the σ of each frame's shared bearing error, None: none), and the identity (L,) of each
    landmark index."""
    pose_index = np.concatenate([np.full(len(ids), k + 1) for k, (ids, _, _) in enumerate(frames)]).astype(int)
    ids = np.concatenate([f[0] for f in frames]).astype(np.int64)
    ranges = np.concatenate([f[1] for f in frames]).astype(float)
    bearings = np.concatenate([f[2] for f in frames]).astype(float)
    named = ids >= 0
    landmark_ids, landmark_index = np.unique(ids[named], return_inverse=True)
    problem = LandmarkLogProblem(np.asarray(increments, float), np.asarray(variances, float),
                                 pose_index[named], landmark_index, ranges[named], bearings[named],
                                 sensor.range_sigma(ranges[named]),
                                 np.full(int(named.sum()), float(sensor.bearing_sigma_rad)),
                                 np.zeros(0) if seconds is None else np.asarray(seconds, float),
                                 image_bearing_sigmas=np.zeros(0) if image_sigmas is None
                                 else np.asarray(image_sigmas, float))
    return problem, landmark_ids


def _initial_landmarks(filter_map: LandmarkMap, landmark_ids, problem, poses) -> np.ndarray:
    """The filter's landmark of each identity; one it does not hold: placed from its first sighting."""
    out = landmarks_from_first_sightings(problem, poses)
    external = np.asarray(filter_map.metadata.get("external_ids", []), np.int64)
    for i, identity in enumerate(landmark_ids):
        rows = np.flatnonzero(external == identity)
        if len(rows):
            out[i] = filter_map.positions[rows[0], :2]
    return out


def planar_landmarks(solution) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A smoother solution's landmarks as map landmarks: which have a finite covariance (L,) bool, their positions
    (K, 3) with z pinned at 0 and covariances (K, 3, 3) with the planar sensor's height variance."""
    seen = np.all(np.isfinite(solution.landmark_covariances.reshape(len(solution.landmarks), -1)), axis=1)
    n = int(seen.sum())
    covariances = np.zeros((n, 3, 3))
    covariances[:, :2, :2] = solution.landmark_covariances[seen]
    covariances[:, 2, 2] = _Z_VARIANCE
    return seen, np.column_stack([solution.landmarks[seen], np.zeros(n)]), covariances


def _smoothed_map(filter_map: LandmarkMap, solution, landmark_ids, landmark_index, times) -> LandmarkMap:
    seen, positions, covariances = planar_landmarks(solution)
    counts = np.bincount(landmark_index[solution.inliers], minlength=len(landmark_ids))[seen]
    metadata = dict(filter_map.metadata, external_ids=[int(i) for i in landmark_ids[seen]], smoothed=True,
                    smoother_chi2_per_dof=solution.chi2_per_dof)
    return LandmarkMap(positions, covariances, np.zeros((len(positions), 0), np.float32),
                       ids=np.arange(len(positions)), counts=counts, robot=filter_map.robot, frame=filter_map.frame,
                       trajectory=np.column_stack([np.append(times[:1], times), solution.poses]), metadata=metadata)
