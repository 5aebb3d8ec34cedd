"""The unknown-association chain's final state (:func:`estimation.name_chain.run_chain`) as a map and its scores.

:func:`chain_landmark_map` is the map ``p3at fuse`` reads: each name's smoothed position and covariance (z pinned at
0, as the data set maps are), the sightings each name kept, the smoothed trajectory in the map's frame (the robot's
pose at its first named sighting) and, only when the log has its true path, the true start pose for scoring. No
descriptors and no identities: the names are the chain's own, so fusion aligns such maps by geometry alone, and the
barcodes never enter the file. Moved out of ``benchmarks/mrclam_constellation.py`` (``chain_map``) in session 36 (A)
so that ``p3at slam dataset --association unknown --chain`` writes the benchmark's map.

:func:`chain_run` scores that state the way ``p3at slam dataset`` scores its other runs, with the project's scoring
helpers (:mod:`estimation.landmark_scores`): the trajectory's ATE (the benchmark's figure: the smoothed poses put in
the world by the true start pose) and dead reckoning's, the pose NEES where the smoother has pose covariances, and the
landmark figures of :func:`~estimation.landmark_scores.map_scores` with each name attributed to the barcode most of its
sightings carry (the barcodes only score). A log without ground truth, or without its landmarks' truth, is scored
on what it has, ``unscored`` saying why the rest is not there (:func:`estimation.dataset_slam.unscored_metrics`).
With or without a truth, ``frame_reliability_*`` say which sightings the map's frame rests on, from the final
smoothing's design (:func:`estimation.frame_reliability.reliability_metrics`, as the known-ID smoother's; its
sightings named by time and the chain's name, and by barcode only when the landmarks' truth scores the map); ``p3at
slam dataset`` warns when one is unchecked. ``untestable_namings`` and the other ``naming_reliability`` figures say
the same of the chain's namings (:func:`estimation.naming_reliability.naming_metrics`): a run of a name's sightings the
map cannot tell from a neighbouring post's that the frame or a stretch of the path rests on (session 43 (A)).
"""
from __future__ import annotations

import numpy as np

from estimation.dataset_slam import (
    UNSCORED_LANDMARKS,
    DatasetRun,
    log_body_metadata,
    sighted_true_ids,
    unscored_metrics,
)
from estimation.dataset_smoothing import planar_landmarks, smoothed_pose_nees
from estimation.datasets import RangeBearingLog
from estimation.frame_reliability import design_figures, reliability_metrics
from estimation.geometry import compose, dead_reckoning
from estimation.landmark_map import LandmarkMap
from estimation.landmark_scores import ate, map_scores, pose_nees_figures
from estimation.named_smoothing import MergeRound
from estimation.naming_reliability import naming_metrics

__all__ = ["chain_landmark_map", "chain_run", "name_barcodes"]


def chain_landmark_map(log: RangeBearingLog, state: MergeRound, robot: str) -> LandmarkMap:
    """The chain's final ``state`` on ``log`` as a landmark map of ``robot`` (module docstring)."""
    sol, named = state.solution, state.named
    seen, positions, covariances = planar_landmarks(sol)
    counts = np.bincount(named.problem.landmark_index[sol.inliers], minlength=len(seen))[seen]
    times = named.frame_times
    truth = ({"true_start_pose": [float(v) for v in log.true_pose(times[:1])[0]], "truth_heading": log.truth_heading}
             if log.has_ground_truth else {})
    metadata = {**truth, "dataset": log.name, "association": "unknown-chain", "simulated": False, "smoothed": True,
                "smoother_chi2_per_dof": float(sol.chi2_per_dof), **log_body_metadata(log)}
    return LandmarkMap(positions, covariances, np.zeros((len(positions), 0), np.float32),
                       counts=counts.astype(np.int64), robot=robot,
                       trajectory=np.column_stack([times, sol.poses[1:]]), metadata=metadata)


def name_barcodes(names: np.ndarray, barcodes: np.ndarray) -> dict[int, int]:
    """Each name's barcode (scoring only): the one most of its sightings carry (ties: the smaller barcode)."""
    out = {}
    for name in np.unique(names[names >= 0]):
        codes, counts = np.unique(barcodes[names == name], return_counts=True)
        out[int(name)] = int(codes[np.argmax(counts)])
    return out


def chain_run(log: RangeBearingLog, state: MergeRound, robot: str) -> DatasetRun:
    """The final ``state`` as ``p3at slam dataset``'s other runs are: its map (:func:`chain_landmark_map`), the
    trajectories (world frame; the map's for a log without ground truth), the pose NEES per frame (NaN where the
    smoother has no pose covariance) and the figures with the command's keys (module docstring)."""
    sol, named = state.solution, state.named
    times = named.frame_times
    t0 = float(times[0])
    landmark_map = chain_landmark_map(log, state, robot)
    nees = np.full(len(times), np.nan)
    dead_in_map = dead_reckoning(named.problem.increments)[1:]
    # which sightings the frame rests on (estimation.frame_reliability), from the design: each named by its time and
    # the chain's name, and by its barcode only where the barcodes score the map (the landmarks' truth)
    barcodes = log.landmark_ids[named.sightings] if log.has_ground_truth and len(log.truth_ids) else None
    # and which namings the frame or the path rests on that nothing checks (estimation.naming_reliability)
    reliability = design_figures(
        lambda: reliability_metrics(named.problem, sol, times, named.names, label="name", barcodes=barcodes),
        lambda: naming_metrics(named.problem, sol, times, named.names, barcodes=barcodes))
    if not log.has_ground_truth:
        return DatasetRun(landmark_map, np.zeros((0, 4)), np.column_stack([times, sol.poses[1:]]),
                          np.column_stack([times, dead_in_map]), nees,
                          unscored_metrics(landmark_map, times, t0) | reliability)
    true_start = log.true_pose(times[:1])[0]
    truth = log.true_pose(times)
    estimated = compose(true_start, sol.poses[1:])
    dead = compose(true_start, dead_in_map)
    metrics = {"ate_m": ate(estimated, truth), "dead_reckoning_ate_m": ate(dead, truth),
               "final_position_error_m": float(np.hypot(*(estimated[-1, :2] - truth[-1, :2]))),
               "seconds": float(times[-1] - t0), "start_time": t0,
               "true_start_pose": [float(v) for v in true_start]}
    nees = smoothed_pose_nees(sol, true_start, truth)
    if np.isfinite(nees).any():
        metrics.update(pose_nees_figures(nees))
    if not len(log.truth_ids):
        metrics.update(unscored_metrics(landmark_map, times, t0, UNSCORED_LANDMARKS))
    else:
        seen = planar_landmarks(sol)[0]
        owner = name_barcodes(state.names, log.landmark_ids)
        attributed = np.array([owner.get(int(x), -1) for x in named.names], np.int64)[seen]
        metrics.update(map_scores(landmark_map.positions, landmark_map.covariances, attributed, true_start,
                                  log.truth_ids, log.truth_positions, sighted_true_ids(log, t0, None)))
    metrics.update(reliability)
    return DatasetRun(landmark_map, np.column_stack([times, truth]), np.column_stack([times, estimated]),
                      np.column_stack([times, dead]), nees, metrics)
