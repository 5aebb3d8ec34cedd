"""Play a range-bearing landmark log (:mod:`estimation.datasets`) through FastSLAM and score it.

The loop of one robot: sightings that share a time stamp form one observation frame; before it, the odometry
increment since the previous frame goes to ``predict``; the frame goes to ``update``. Association:

- ``"id"``: each observation carries the landmark id the data set gives (MRCLAM: the barcode's subject) in
  ``StereoObservations.ids``; the filter associates by it (its ID mode).
- ``"unknown"``: no ids and no descriptors: association by position alone. MRCLAM's landmarks are alike
  cylinders to the camera except for their barcodes, and any descriptor derived from a barcode would identify
  the landmark, so the only honest descriptor is none. The ids are used for scoring only.

The map is in the robot's start frame; its metadata carries the true start pose in the world
(``true_start_pose``, as simulated maps do, so ``p3at fuse`` scores alignments). Scores: see
:mod:`estimation.landmark_scores`; the trajectory and pose NEES are taken at every frame.

A log without ground truth (a lab's own, no motion capture) runs the same filter and smoother, which never read the
truth: the map, its names and trajectory are what they would be with it. Only the scores need it, so such a run has
none: its trajectories are in the map's frame (no world frame is known), ``true_trajectory`` is empty, the pose NEES
NaN, the map has no ``true_start_pose`` and the metrics hold no truth figure (no ATE, landmark error, NEES, true start
pose) but ``unscored``, a sentence saying why (:data:`UNSCORED`). A log with the robot's true path but not the
landmarks' is scored on its path only (:data:`UNSCORED_LANDMARKS`).
"""
from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass, field

import numpy as np

from .datasets import RangeBearingLog
from .fastslam import FastSLAM, FastSLAMConfig, range_bearing_observations
from .geometry import between, compose, dead_reckoning
from .landmark_map import LandmarkMap
from .landmark_scores import (
    ate,
    attribute_landmarks,
    count_sightings,
    map_scores,
    pose_nees,
    pose_nees_figures,
)
from .noise_model import NoiseModel, with_fastslam
from .observations import OdometryIncrement, StereoObservations
from .odometry_stall import command_stall_variance
from .sighting_spread import SightingRecorder

ASSOCIATIONS = ("id", "unknown")
# MRCLAM's robots are iRobot Creates: a disc, base cylinder radius 0.16495 m (turtlebot/turtlebot_create,
# create_description/urdf/create.urdf.xacro), written into the maps for fusion's co-location test (fusion/colocation.py)
MRCLAM_FOOTPRINT_RADIUS_M = 0.16495
_MRCLAM_LOG = re.compile(r"(MRCLAM_Dataset\d+)/Robot\d+")
_KNOWN_LANDMARK_VARIANCE = 1e-6   # m²: Vicon's landmark positions, taken as exact (known_map)
# a run of a log without ground truth: its metrics leave out every figure that needs the truth and say so here
UNSCORED = "the log has no ground truth: no trajectory (ATE), landmark or NEES scores and no true start pose"
UNSCORED_LANDMARKS = "the log has no landmark ground truth: no landmark scores"   # its path is scored


@dataclass
class DatasetRun:
    """Outcome of :func:`run_landmark_log`. Trajectories are (T, 4) rows (t, x, y, θ) in the world frame (in the map's
    frame for a log without ground truth, whose ``true_trajectory`` is then (0, 4) and ``pose_nees`` NaN)."""

    map: LandmarkMap
    true_trajectory: np.ndarray
    estimated_trajectory: np.ndarray
    dead_reckoning: np.ndarray
    pose_nees: np.ndarray                      # (T,) per frame (NaN where the cloud's covariance is singular)
    metrics: dict = field(default_factory=dict)


def run_landmark_log(log: RangeBearingLog, config: FastSLAMConfig, rng: np.random.Generator, *, noise: NoiseModel,
                     association: str = "id", robot: str = "robot", until: float | None = None,
                     inflate_correlated: bool = True, known_map: bool = False, smooth: bool = False,
                     frame: str = "first-sighting", image_timing: bool = False) -> DatasetRun:
    """Run FastSLAM over ``log`` and score it against its ground truth if it has some; see the module docstring.

    ``config``: the filter's settings; ``noise`` sets its motion noise, the sensor noise (σ_r growing with the
    range, σ_φ) and the calibration (odometry scales, bearing offset); ``until``: stop after this log time (s).
    ``inflate_correlated``: multiply the sensor variances by the model's :meth:`RangeBearingNoise.variance_inflation`
    (consecutive sightings of a landmark share most of their error; the filter takes them as independent).
    ``known_map``: localization only, the floor of what the filter and the noise model can reach when the map is
    not the problem: every particle starts with the log's true landmarks (in the start frame, σ 1 mm, named by
    their ids) and none is ever removed (needs ``association="id"``).
    ``smooth``: after the filter, the whole log's MAP poses and landmarks from the filter's best particle
    (:mod:`estimation.dataset_smoothing`; needs ``association="id"``): the map, trajectory and pose NEES are then
    the smoother's, the filter's figures stay in the metrics under ``filter_``.
    ``frame``: the smoothed map's frame, ``"first-sighting"`` (the default: the robot's pose at its first sighting)
    or ``"checked"`` (the first pose whose frame no single sighting can move unseen: :mod:`estimation.map_frame`;
    needs ``smooth``).
    ``image_timing``: the smoother holds one bearing error shared by each frame's sightings, of σ |ω| σ_t
    (:mod:`estimation.image_timing`; needs ``smooth``; the filter takes its bearings as it did: its landmarks are
    updated one at a time given the particle's pose, which a shared error would couple).
    """
    if association not in ASSOCIATIONS:
        raise ValueError(f"association must be one of {', '.join(ASSOCIATIONS)}, not {association!r}")
    if noise.range_bearing is None:
        raise ValueError(f"the noise model of {noise.robot!r} has no [range_bearing] section")
    sensor = noise.range_bearing
    if smooth and association != "id":
        raise ValueError("smoothing needs association='id' (the sightings must name their landmarks)")
    from .map_frame import FIRST_SIGHTING, FRAMES
    if frame not in FRAMES:
        raise ValueError(f"the map's frame must be one of {', '.join(FRAMES)}, not {frame!r}")
    if frame != FIRST_SIGHTING and not smooth:
        raise ValueError(f"the map's frame {frame!r} is chosen on the smoothed solution: it needs smoothing")
    if image_timing and not smooth:
        raise ValueError("one bearing error per image is the smoother's: it needs smoothing")
    if inflate_correlated:
        inflate_r, inflate_b = (float(np.sqrt(f)) for f in sensor.variance_inflation())
        sensor = dataclasses.replace(sensor, range_sigma_m=sensor.range_sigma_m * inflate_r,
                                     range_sigma_per_m=sensor.range_sigma_per_m * inflate_r,
                                     bearing_sigma_rad=sensor.bearing_sigma_rad * inflate_b)
    config = _association_config(with_fastslam(noise, config), association)
    if known_map:   # the true landmarks stay whatever the existence evidence says
        config = dataclasses.replace(config, existence_remove=-1e9)
    no_descriptors = np.zeros((0, 0), np.float32)
    slam = FastSLAM(config, rng)
    times, first = np.unique(log.sighting_times, return_index=True)
    # the map's frame is the robot's pose at its first sighting: odometry before it (MRCLAM's robots wait, then
    # turn on the spot) gives the map nothing, and its heading error would become a permanent offset of the frame
    t0 = float(times[0]) if len(times) else log.start_time
    true_start = log.true_pose([t0])[0] if log.has_ground_truth else None
    if known_map:
        _load_true_landmarks(slam, log, true_start, association)
    # each frame's sightings end where the next frame's begin, counted before ``until`` cuts the frames: after the
    # cut the last kept frame would otherwise run to the end of the log and take in every later sighting
    bounds = np.append(first, len(log))[1:]
    keep = (times >= t0) & (times <= (np.inf if until is None else until))
    times, first, bounds = times[keep], first[keep], bounds[keep]
    frame_times = np.concatenate([[t0], times])
    odometry = log.odometry_pose(noise.odometry_times(frame_times))   # the odometry's lag calibrated (noise_model)
    increments = noise.calibrate_increments(between(odometry[:-1], odometry[1:]))
    # the stalls after the command's dips (estimation.odometry_stall): the filter's predict adds them to its random
    # walk on the increments that hold one (the smoother takes both from noise_model.increment_variances)
    stalls = command_stall_variance(log.velocities, noise, frame_times)

    votes: dict[int, dict[int, int]] = {}
    means, covs, frames = [], [], []
    sightings = SightingRecorder()     # the map's own spread at each landmark (estimation.sighting_spread)
    for k, (start, stop) in enumerate(zip(first, bounds, strict=True)):
        slam.predict(OdometryIncrement(*increments[k], t0=float(frame_times[k]), t1=float(frame_times[k + 1])),
                     None if stalls is None else stalls[k])
        ids = log.landmark_ids[start:stop]
        ranges, bearings = sensor.corrected(log.ranges[start:stop], log.bearings[start:stop])
        obs = _observations(ranges, bearings, sensor, no_descriptors.reshape(len(ids), 0), float(times[k]))
        if association == "id":
            obs = dataclasses.replace(obs, ids=ids)
        report = slam.update(obs)
        frames.append((ids, ranges, bearings))
        count_sightings(votes, ids, report)
        sightings.add_report(float(times[k]), obs.points, report)
        means.append(report.pose_mean)
        covs.append(report.pose_covariance)

    truth_metadata = {} if true_start is None else {"true_start_pose": [float(v) for v in true_start],
                                                    "truth_heading": log.truth_heading}
    landmark_map = slam.best_map(robot=robot, metadata={
        **truth_metadata, "dataset": log.name, "association": association,
        "noise_model": noise.robot, "inflate_correlated": bool(inflate_correlated), "simulated": False})
    landmark_map.sighting_covariances = sightings.covariances(landmark_map)
    landmark_map.metadata.update(log_body_metadata(log))
    if len(landmark_map.trajectory) and landmark_map.trajectory[0, 0] < t0:
        landmark_map.trajectory[0, 0] = t0     # row 0 is the pose the map's frame is: the robot's at its first sighting
    estimated = slam.trajectory()[1:]                                    # row 0 is the initial pose
    dead_start_frame = dead_reckoning(increments)[1:]
    if true_start is None:   # no world frame known: the map's
        estimated_world, truth = estimated, np.zeros((0, 4))
        dead = np.column_stack([times, dead_start_frame])
        nees = np.full(len(times), np.nan)
        metrics = unscored_metrics(landmark_map, times, t0)
    else:
        estimated_world = np.column_stack([estimated[:, 0], compose(true_start, estimated[:, 1:])])
        truth = np.column_stack([times, log.true_pose(times)])
        dead = np.column_stack([times, compose(true_start, dead_start_frame)])
        true_in_start = between(true_start, truth[:, 1:])
        nees = pose_nees(between(true_in_start, np.array(means).reshape(-1, 3)) if len(means) else np.zeros((0, 3)),
                         np.array(covs).reshape(-1, 3, 3))
        metrics = _metrics(log, landmark_map, votes, true_start, truth, estimated_world, dead, nees, t0, until)
    metrics.update(frames=len(times), particles=config.n_particles, version=config.version,
                   association=association)
    run = DatasetRun(landmark_map, truth, estimated_world, dead, nees, metrics)
    if not smooth:
        return run
    from .dataset_smoothing import smooth_run
    return smooth_run(run, log, noise, frames, increments, sensor, config, estimated[:, 1:], true_start, t0, until,
                      frame=frame, image_timing=image_timing)


def sighted_true_ids(log: RangeBearingLog, t0: float, until: float | None) -> np.ndarray:
    """The true landmark ids the robot sighted between t0 and ``until`` (its map should hold each once)."""
    horizon = np.inf if until is None else until
    sighted = log.landmark_ids[(log.sighting_times >= t0) & (log.sighting_times <= horizon)]
    return sighted[np.isin(sighted, log.truth_ids)]


def log_body_metadata(log: RangeBearingLog) -> dict:
    """What fusion's co-location test needs, where the data set says it: an MRCLAM data set's five logs are on one
    clock (the distributed files start at 0 on the same 0.02 s ticks; the Vicon poses of two robots never come closer
    than 0.332 m, two Create radii being 0.330 m) and its robots are Creates.  {} for any other log."""
    match = _MRCLAM_LOG.fullmatch(log.name)
    if match is None:
        return {}
    return {"clock": f"{match.group(1)} log time", "footprint_radius_m": MRCLAM_FOOTPRINT_RADIUS_M}


def _load_true_landmarks(slam: FastSLAM, log: RangeBearingLog, true_start: np.ndarray, association: str) -> None:
    """Every particle's map := the log's true landmarks in the start frame, 1 mm σ (``known_map``)."""
    if association != "id":
        raise ValueError("known_map needs association='id' (the true landmarks are named by their ids)")
    if true_start is None or not len(log.truth_ids):
        raise ValueError(f"{log.name}: known_map needs the log's ground truth (its true landmarks and start pose)")
    planar = between(true_start, np.column_stack([log.truth_positions, np.zeros(len(log.truth_ids))]))[:, :2]
    n = len(planar)
    covariances = np.tile(np.eye(3) * _KNOWN_LANDMARK_VARIANCE, (n, 1, 1))
    slam.load_prior_map(LandmarkMap(np.column_stack([planar, np.zeros(n)]), covariances,
                                    np.zeros((n, 0), np.float32), counts=np.ones(n, np.int64)),
                        external_ids=log.truth_ids)


def _observations(ranges: np.ndarray, bearings: np.ndarray, sensor, descriptors: np.ndarray,
                  timestamp: float) -> StereoObservations:
    """range_bearing_observations with each sighting's own σ_r (σ_r grows with the range)."""
    return range_bearing_observations(ranges, bearings, sensor.range_sigma(ranges), sensor.bearing_sigma_rad,
                                      descriptors, timestamp=timestamp)


def _association_config(config: FastSLAMConfig, association: str) -> FastSLAMConfig:
    """The filter settings of an association mode: no descriptors in either (see the module docstring)."""
    return dataclasses.replace(config, association=association, descriptor_size=0)


def unscored_metrics(landmark_map, times, t0, reason: str = UNSCORED) -> dict:
    """A log without ground truth: the figures that do not need it, and ``unscored`` saying why the others are not
    there (left out, not null: a figure never computed is not in the output, as a smoothed run's ``filter_`` keys)."""
    positions, covariances = landmark_map.positions, landmark_map.covariances
    return {"seconds": float(times[-1] - t0) if len(times) else 0.0, "start_time": float(t0),
            "landmarks": int(len(positions)),
            "landmark_sd_median_m": float(np.median(np.sqrt(0.5 * (covariances[:, 0, 0] + covariances[:, 1, 1]))))
            if len(positions) else float("nan"),
            "unscored": reason}


def _metrics(log, landmark_map, votes, true_start, truth, estimated, dead, nees, t0, until) -> dict:
    attributed = attribute_landmarks(votes, landmark_map.ids)
    sighted = sighted_true_ids(log, t0, until)
    metrics = {
        "ate_m": ate(estimated[:, 1:], truth[:, 1:]),
        "dead_reckoning_ate_m": ate(dead[:, 1:], truth[:, 1:]),
        "final_position_error_m": float(np.hypot(*(estimated[-1, 1:3] - truth[-1, 1:3]))) if len(truth) else 0.0,
        **pose_nees_figures(nees),
        "seconds": float(truth[-1, 0] - t0) if len(truth) else 0.0,
        "start_time": float(t0),
        "true_start_pose": [float(v) for v in true_start],
    }
    if not len(log.truth_ids):
        metrics.update(unscored_metrics(landmark_map, truth[:, 0], t0, UNSCORED_LANDMARKS))
        return metrics
    metrics.update(map_scores(landmark_map.positions, landmark_map.covariances, attributed, true_start,
                              log.truth_ids, log.truth_positions, sighted))
    return metrics
