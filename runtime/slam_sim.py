"""Offline evaluation of onboard FastSLAM: one virtual robot drives a route of the simulated building.

Simulated time only (no driver, no threads): a pure-pursuit follower drives the true pose along the route
(unicycle kinematics at ``control_rate``); at ``frame_rate`` the odometry since the last frame goes to
``predict`` and the observer's frame of the true pose to ``update``. The observer is pluggable (anything with
``observe(pose, timestamp) -> (StereoObservations, feature_index)``); the default is
:class:`mocks.synthetic_stereo.SyntheticStereo`.

Scores, all in the world frame (the estimate is mapped through the true start pose, which is known here):
ATE = RMS position error of the best particle's trajectory; the same for dead reckoning; landmark error =
RMS distance of each map landmark to the true feature that created it; pose NEES = eᵀ P⁻¹ e per frame, e the
cloud mean's error in the start frame, against the weighted cloud's covariance before resampling and against the
drift tracker's D_r (3 on average for a consistent filter; the cloud keeps only the local spread, D_r is what
the map's export claims);
duplicates = map landmarks minus distinct true features they stand for (a map that doubles a corridor on a
loop has many).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from estimation.fastslam import FastSLAM, FastSLAMConfig
from estimation.geometry import between, compose, transform_points, wrap_angle
from estimation.landmark_map import LandmarkMap
from mocks.synthetic_stereo import OdometryErrorModel, SyntheticOdometry, SyntheticStereo
from runtime.motion import PurePursuit


@dataclass
class SimulationResult:
    """Outcome of :func:`simulate`. Trajectories are (T, 4) rows (t, x, y, θ) in the world frame."""

    map: LandmarkMap
    true_trajectory: np.ndarray
    estimated_trajectory: np.ndarray
    dead_reckoning: np.ndarray
    metrics: dict = field(default_factory=dict)
    pose_nees: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (F, 2) rows (t, NEES)


def simulate(world, *, start_pose, route, seconds: float, seed: int, config: FastSLAMConfig,
             robot: str = "robot1", frame_rate: float = 5.0, control_rate: float = 20.0, speed: float = 0.35,
             odometry_errors: OdometryErrorModel | None = None, observer=None) -> SimulationResult:
    """Drive ``route`` (K, 2) world waypoints from ``start_pose`` (3,) for at most ``seconds``; see the module."""
    rng = np.random.default_rng(seed)
    sensor_rng, odometry_rng, filter_rng = rng.spawn(3)
    observer = observer or SyntheticStereo.from_world(world, sensor_rng)
    odometry = SyntheticOdometry(odometry_rng, odometry_errors or OdometryErrorModel())
    slam = FastSLAM(config, filter_rng)
    follower = PurePursuit(np.asarray(route, float), speed=speed)
    start = np.asarray(start_pose, float)
    to_world = lambda poses: compose(start, poses)  # noqa: E731  start frame -> world

    pose, dead_reckoning = start.copy(), np.zeros(3)
    frame_pose, t = start.copy(), 0.0
    dt = 1.0 / control_rate
    steps_per_frame = max(1, round(control_rate / frame_rate))
    truth, dead, nees, drift_nees, feature_of_id = [(0.0, *start)], [(0.0, *start)], [], [], {}
    step = 0
    while t < seconds:
        command = follower.command(pose)
        if command.done:
            break
        # unicycle kinematics over one control period (exact arc)
        v, w = command.v, command.w
        if abs(w) > 1e-9:
            arc = np.array([v / w * np.sin(w * dt), v / w * (1 - np.cos(w * dt)), w * dt])
        else:
            arc = np.array([v * dt, 0.0, 0.0])
        pose = compose(pose, arc)
        t += dt
        step += 1
        if step % steps_per_frame:
            continue
        increment = odometry.increment(frame_pose, pose, t - steps_per_frame * dt, t)
        frame_pose = pose.copy()
        dead_reckoning = compose(dead_reckoning, increment.delta)
        slam.predict(increment)
        observations, feature_index = observer.observe(pose, t)
        report = slam.update(observations)
        for j in np.flatnonzero(report.new_landmark_ids >= 0):
            feature_of_id[int(report.new_landmark_ids[j])] = int(feature_index[j])
        truth.append((t, *pose))
        dead.append((t, *to_world(dead_reckoning)))
        # The pose error in the start frame, where both covariances are: the weighted cloud's (before resampling;
        # particle depletion keeps only the local spread) and the drift tracker's D_r (the pose's uncertainty
        # relative to the start frame, what the map's export claims: estimation/fastslam/lever_drift.py).
        mean, cov = report.pose_mean, report.pose_covariance
        error = between(start, pose) - mean
        error[2] = wrap_angle(error[2])
        for series, covariance in ((nees, cov), (drift_nees, slam.drift.robot)):
            if np.all(np.isfinite(covariance)) and np.linalg.cond(covariance) < 1e12:
                series.append((t, float(error @ np.linalg.solve(covariance, error))))

    landmark_map = slam.best_map(robot=robot, metadata={
        "true_start_pose": [float(v) for v in start], "seed": int(seed), "simulated": True,
        "world": getattr(world, "name", "world")})
    estimated = slam.trajectory()
    estimated_world = np.column_stack([estimated[:, 0], to_world(estimated[:, 1:])])
    true_trajectory = np.array(truth)
    dead_trajectory = np.array(dead)
    nees_series = np.array(nees, float).reshape(-1, 2)
    metrics = _score(landmark_map, world, start, true_trajectory, estimated_world, dead_trajectory,
                     feature_of_id, nees_series[:, 1], np.array([v for _, v in drift_nees], float))
    metrics.update(seconds=float(t), frames=len(truth) - 1, particles=config.n_particles, version=config.version)
    return SimulationResult(landmark_map, true_trajectory, estimated_world, dead_trajectory, metrics, nees_series)


def _ate(estimate: np.ndarray, truth: np.ndarray) -> float:
    n = min(len(estimate), len(truth))
    return float(np.sqrt(np.mean(np.sum((estimate[:n, 1:3] - truth[:n, 1:3]) ** 2, axis=1))))


def _score(landmark_map: LandmarkMap, world, start, truth, estimate, dead, feature_of_id, nees, drift_nees) -> dict:
    in_world = transform_points(start, landmark_map.positions)
    features = np.array([feature_of_id.get(int(i), -1) for i in landmark_map.ids], np.int64)
    known = features >= 0
    errors = np.linalg.norm(in_world[known] - world.features[features[known]], axis=1)
    final_error = between(estimate[-1, 1:], truth[-1, 1:]) if len(truth) > 1 else np.zeros(3)
    dead_final = between(dead[-1, 1:], truth[-1, 1:]) if len(truth) > 1 else np.zeros(3)
    return {
        "ate_m": _ate(estimate, truth),
        "dead_reckoning_ate_m": _ate(dead, truth),
        "final_position_error_m": float(np.hypot(*final_error[:2])),
        "dead_reckoning_final_position_error_m": float(np.hypot(*dead_final[:2])),
        "final_heading_error_rad": float(abs(wrap_angle(final_error[2]))),
        "landmarks": len(landmark_map),
        "landmark_rms_error_m": float(np.sqrt(np.mean(errors ** 2))) if len(errors) else float("nan"),
        "landmark_median_error_m": float(np.median(errors)) if len(errors) else float("nan"),
        "distinct_features": int(len(np.unique(features[known]))),
        "duplicate_landmarks": int(known.sum() - len(np.unique(features[known]))),
        "pose_nees_mean": float(np.mean(nees)) if len(nees) else float("nan"),
        "pose_nees_median": float(np.median(nees)) if len(nees) else float("nan"),
        "pose_nees_within_chi2_95": float(np.mean(nees < 7.815)) if len(nees) else float("nan"),
        "pose_nees_frames": len(nees),
        "pose_nees_drift_median": float(np.median(drift_nees)) if len(drift_nees) else float("nan"),
        "pose_nees_drift_within_chi2_95": float(np.mean(drift_nees < 7.815)) if len(drift_nees) else float("nan"),
    }
