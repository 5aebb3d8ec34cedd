"""2-D scans as ordered point sets: a laser sweep, or a sonar ring gathered over a stretch of odometry.

A scan keeps its points in acquisition order together with a ``beam_index`` so that the curve through
it (see :mod:`estimation.scanmatch.polyline`) can be broken where a reading is missing.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimation.geometry import compose, inverse
from estimation.scanmatch.errors import ScanMatchError

#: Readings at or beyond this range are "no return" (SICK: 50 m in aces, 81.91 m in csail); metres.
DEFAULT_MAX_RANGE = 49.0
#: Readings at or below this range are sensor faults; metres.
DEFAULT_MIN_RANGE = 0.02


@dataclass(frozen=True)
class Scan2D:
    """An ordered 2-D point set in the sensor frame.

    points:     (N, 2) metres, REP-103 (x forward, y left)
    beam_index: (N,) int, strictly increasing; a jump larger than 1 marks a dropout between two points
    """

    points: np.ndarray
    beam_index: np.ndarray

    def __post_init__(self) -> None:
        points = np.asarray(self.points, dtype=float)
        beam_index = np.asarray(self.beam_index, dtype=np.int64)
        if points.ndim != 2 or points.shape[1] != 2:
            raise ScanMatchError(f"scan points must have shape (N, 2), got {points.shape}")
        if beam_index.shape != (points.shape[0],):
            raise ScanMatchError(f"beam_index must have shape ({points.shape[0]},), got {beam_index.shape}")
        if not np.all(np.isfinite(points)):
            raise ScanMatchError("scan points must be finite")
        if np.any(np.diff(beam_index) <= 0):
            raise ScanMatchError("beam_index must be strictly increasing")
        object.__setattr__(self, "points", points)
        object.__setattr__(self, "beam_index", beam_index)

    def __len__(self) -> int:
        return self.points.shape[0]

    @classmethod
    def from_points(cls, points) -> Scan2D:
        """An ordered point list with no dropouts.  points: (N, 2)."""
        points = np.asarray(points, dtype=float)
        return cls(points, np.arange(points.shape[0]))


def laser_angles(n_beams: int, fov: float = np.pi, start: float | None = None) -> np.ndarray:
    """Bearings (n_beams,) of a sweep over ``fov`` radians in equal steps, from ``start`` (default -fov/2)."""
    if n_beams < 2:
        raise ScanMatchError(f"a laser sweep needs at least 2 beams, got {n_beams}")
    first = -fov / 2.0 if start is None else start
    return first + fov * np.arange(n_beams) / (n_beams - 1)


def laser_scan(ranges, angles=None, *, min_range: float = DEFAULT_MIN_RANGE,
               max_range: float = DEFAULT_MAX_RANGE) -> Scan2D:
    """Points of one laser sweep; readings outside (min_range, max_range) are dropped as dropouts.

    ranges: (N,) metres; angles: (N,) radians (default: 180° from -90° to +90°, the CARMEN FLASER layout).
    """
    ranges = np.asarray(ranges, dtype=float)
    if ranges.ndim != 1:
        raise ScanMatchError(f"ranges must be one-dimensional, got shape {ranges.shape}")
    angles = laser_angles(ranges.shape[0]) if angles is None else np.asarray(angles, dtype=float)
    if angles.shape != ranges.shape:
        raise ScanMatchError(f"angles {angles.shape} and ranges {ranges.shape} differ in shape")
    valid = np.isfinite(ranges) & (ranges > min_range) & (ranges < max_range)
    r, a = ranges[valid], angles[valid]
    return Scan2D(np.column_stack([r * np.cos(a), r * np.sin(a)]), np.flatnonzero(valid))


def sonar_scan(odometry_poses, sonar_poses, ranges, *, anchor: int = -1, min_range: float = 0.1,
               max_range: float = 4.5) -> Scan2D:
    """One point set from sonar rings read at successive odometry poses, in the frame of one of those poses.

    odometry_poses: (M, 3) robot poses in the odometry frame, one per ring reading
    sonar_poses:    (K, 3) each transducer's pose in the robot frame (x, y, heading of the beam axis)
    ranges:         (M, K) metres, NaN or out-of-range where a transducer saw nothing
    anchor:         index of the odometry pose whose frame the points are expressed in (default: the last)

    Each echo is placed on its transducer's axis (a sonar cone has no bearing resolution, so the axis is the
    best single point).  The points are then ordered by bearing about the anchor, so that the polyline through
    them follows the walls around the robot; consecutive readings of one wall are what the curve joins, and
    the gap threshold of the matcher breaks it between walls.
    """
    odometry_poses = np.asarray(odometry_poses, dtype=float).reshape(-1, 3)
    sonar_poses = np.asarray(sonar_poses, dtype=float).reshape(-1, 3)
    ranges = np.asarray(ranges, dtype=float)
    if ranges.shape != (odometry_poses.shape[0], sonar_poses.shape[0]):
        raise ScanMatchError(f"ranges must have shape {(odometry_poses.shape[0], sonar_poses.shape[0])}, "
                             f"got {ranges.shape}")
    anchor_in_odom = odometry_poses[anchor]
    # Robot pose of every reading in the anchor frame, then every transducer in the anchor frame: (M, K, 3).
    robot_in_anchor = compose(inverse(anchor_in_odom), odometry_poses)
    sensor_in_anchor = compose(robot_in_anchor[:, None, :], sonar_poses[None, :, :])
    valid = np.isfinite(ranges) & (ranges > min_range) & (ranges < max_range)
    s, r = sensor_in_anchor[valid], ranges[valid]
    points = np.column_stack([s[:, 0] + r * np.cos(s[:, 2]), s[:, 1] + r * np.sin(s[:, 2])])
    order = np.argsort(np.arctan2(points[:, 1], points[:, 0]), kind="stable")
    return Scan2D.from_points(points[order])
