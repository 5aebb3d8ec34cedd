"""How well a map agrees with itself at each landmark: the spread of the robot's own sightings of it.

Each sighting of landmark l, placed by the map's own trajectory (the robot's pose when it made the sighting, in
the map's frame), is a point p_i; the map's estimate x_l is (nearly) their weighted mean.  The file keeps

    S_l = (1/n_l) Σ_i (p_i − x_l)(p_i − x_l)ᵀ        (n_l sightings placed; 0 when none was)

(``LandmarkMap.sighting_covariances``).  What it holds that the map's other covariances do not: the EKF part of a
FastSLAM landmark is conditional on the particle's trajectory and shrinks with every sighting, the frame's drift is
mostly rigid (an alignment removes it), while S_l also holds how far the trajectory's passes disagree about where the
landmark is — the map's bend at the landmark, which is what a merge of maps must weigh.  S_l is a spread of single
sightings, not the error of their mean: its level is left to whoever weighs it (``fusion.multi`` fits one level for
all maps on the aligned pairs), its differences between landmarks and maps are what the map knows.

Needs no truth: the sightings, the landmark each was given to (the most probable particle's association at the time),
and the trajectory the map file already keeps.
"""
from __future__ import annotations

import numpy as np

from .landmark_map import LandmarkMap


class SightingRecorder:
    """Collects each frame's sightings: their time, points (N, 3) in the robot's frame (base_link), and the landmark
    id (the map's ``ids``) each was given to, −1 when none."""

    def __init__(self) -> None:
        self._times: list[np.ndarray] = []
        self._points: list[np.ndarray] = []
        self._landmarks: list[np.ndarray] = []

    def add(self, time: float, points: np.ndarray, landmarks: np.ndarray) -> None:
        points = np.asarray(points, float).reshape(-1, 3)
        landmarks = np.asarray(landmarks, np.int64).reshape(-1)
        if len(points) != len(landmarks):
            raise ValueError(f"{len(points)} points but {len(landmarks)} landmark ids")
        self._times.append(np.full(len(points), float(time)))
        self._points.append(points)
        self._landmarks.append(landmarks)

    def add_report(self, time: float, points: np.ndarray, report) -> None:
        """One FastSLAM update's sightings: each is given to the landmark the most probable particle matched it to
        (``UpdateReport.best_matches``) or, failing that, the one it made (``new_landmark_ids``)."""
        matched = np.asarray(report.best_matches, np.int64)
        self.add(time, points, np.where(matched >= 0, matched, np.asarray(report.new_landmark_ids, np.int64)))

    def covariances(self, landmark_map: LandmarkMap) -> np.ndarray:
        """(N, 3, 3) S_l for the map's landmarks (module docstring), the sightings placed by ``landmark_map``'s
        trajectory at their times (the nearest row; a sighting further than 1 ms from every row is left out)."""
        if not self._times:
            return np.zeros((len(landmark_map), 3, 3))
        return sighting_covariances(landmark_map, np.concatenate(self._times), np.concatenate(self._points),
                                    np.concatenate(self._landmarks))


def sighting_covariances(landmark_map: LandmarkMap, times: np.ndarray, points: np.ndarray,
                         landmarks: np.ndarray, tolerance: float = 1e-3) -> np.ndarray:
    """(N, 3, 3) S_l of ``landmark_map``'s landmarks from sightings at ``times`` (K,) of ``points`` (K, 3) in the
    robot's frame given to ``landmarks`` (K,) (the map's ids; others and −1 are left out), each placed by the map's
    trajectory row at its time (planar pose x, y, θ)."""
    n = len(landmark_map)
    out = np.zeros((n, 3, 3))
    traj = landmark_map.trajectory
    if not len(traj) or not len(times) or not n:
        return out
    order = np.argsort(landmark_map.ids, kind="stable")
    sorted_ids = landmark_map.ids[order]
    rank = np.searchsorted(sorted_ids, landmarks)
    rank = np.minimum(rank, n - 1)
    known = sorted_ids[rank] == landmarks
    row = np.clip(np.searchsorted(traj[:, 0], times), 0, len(traj) - 1)
    earlier = np.maximum(row - 1, 0)
    row = np.where(np.abs(traj[earlier, 0] - times) < np.abs(traj[row, 0] - times), earlier, row)
    keep = known & (np.abs(traj[row, 0] - times) <= tolerance)
    pose, p = traj[row[keep], 1:], np.asarray(points, float)[keep]
    c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    placed = np.column_stack([pose[:, 0] + c * p[:, 0] - s * p[:, 1], pose[:, 1] + s * p[:, 0] + c * p[:, 1],
                              p[:, 2]])
    r = order[rank[keep]]
    d = placed - landmark_map.positions[r]
    count = np.bincount(r, minlength=n).astype(float)
    for i in range(3):
        for j in range(i, 3):
            out[:, i, j] = out[:, j, i] = np.bincount(r, d[:, i] * d[:, j], minlength=n)
    return out / np.maximum(count, 1.0)[:, None, None]
