"""A map file as a foreign or hostile writer leaves it: ``LandmarkMap.save`` refuses whatever its reader would refuse
(names, typed metadata, arrays), so a test of the reader writes such a file member by member."""
from __future__ import annotations

import json

import numpy as np

from estimation.landmark_map import LandmarkMap
from estimation.map_validation import FORMAT_NAME, FORMAT_VERSION


def _json_member(obj) -> np.ndarray:
    return np.frombuffer(json.dumps(obj).encode(), np.uint8)


def save_unchecked(landmark_map: LandmarkMap, path) -> None:
    """Write ``landmark_map`` in the map format, every member as the format lays it out (the optional drift and
    sighting covariances where the map has them), without the writer's checks."""
    meta = {"robot": landmark_map.robot, "frame": landmark_map.frame, "robots": landmark_map.robots,
            "metadata": landmark_map.metadata}
    optional = {} if landmark_map.drift_covariances is None else {
        "drift_covariances": landmark_map.drift_covariances, "drift_origins": landmark_map.drift_origins}
    if landmark_map.sighting_covariances is not None:
        optional["sighting_covariances"] = landmark_map.sighting_covariances
    np.savez_compressed(path, format=_json_member({"format": FORMAT_NAME, "version": FORMAT_VERSION}),
                        positions=landmark_map.positions, covariances=landmark_map.covariances,
                        descriptors=landmark_map.descriptors, ids=landmark_map.ids, counts=landmark_map.counts,
                        seen_by=landmark_map.seen_by, trajectory=landmark_map.trajectory, meta=_json_member(meta),
                        **optional)
