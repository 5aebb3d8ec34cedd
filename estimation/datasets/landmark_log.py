"""A range-bearing landmark log: what any planar landmark data set (MRCLAM, Victoria Park, a robot's own
fiducial log) maps onto, and what the dataset runner plays through FastSLAM.

Times are seconds on one clock; poses are (x, y, θ), REP-103, metres and radians. Odometry is given as the
robot's dead-reckoned pose in its own odometry frame at each odometry time, whatever the data set records
(velocities are integrated by its reader, pose logs are taken as they are): the motion between any two times
is then ``between(pose(t_a), pose(t_b))``, which serves both the filter and the noise estimation.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..geometry import between, compose, interpolate_poses, wrap_angle
from .errors import DatasetError
from .stamps import StampQuantization


@dataclass(frozen=True)
class RangeBearingLog:
    """One robot's log.

    name:                 e.g. "MRCLAM_Dataset2/Robot3"
    odometry:             (K, 4) rows (t, x, y, θ): dead-reckoned pose in the odometry frame, t non-decreasing
    sighting_times:       (N,) s, non-decreasing
    ranges, bearings:     (N,) m (≥ 0) and rad (counter-clockwise from the robot's x axis)
    landmark_ids:         (N,) int64: the landmark each sighting is of, as the data set identifies it (≥ 0)
    ground_truth:         (G, 4) rows (t, x, y, θ) in the world frame (G = 0: none)
    truth_ids:            (L,) int64 landmark ids with a known true position (L = 0: none)
    truth_positions:      (L, 2) m, world frame
    notes:                what the reader dropped, corrected or could not verify (one sentence each)
    stamp_resolution:     the streams whose stamps the file wrote coarser than their rows (stamps.py; () = none
                          found or not looked for); reported only, the times are used as written
    truth_heading:        whose heading ground_truth holds: "mocap" (as the truth wrote it) or "travel" (turned onto
                          the direction of travel: truth_heading.align_truth_heading)
    velocities:           (V, 3) rows (t, v, w): the velocity samples the odometry was integrated from, as the file
                          wrote them (V = 0: the data set gives poses, or the reader did not keep them). Kept because
                          the integration cannot give them back where stamps are coarser than the rows (MRCLAM from
                          t = 1000 s: rows sharing a stamp integrate over no time, so one-sample changes vanish), and
                          a drive's response to its commands needs them (:mod:`estimation.odometry_stall`)
    """

    name: str
    odometry: np.ndarray
    sighting_times: np.ndarray
    ranges: np.ndarray
    bearings: np.ndarray
    landmark_ids: np.ndarray
    ground_truth: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    truth_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    truth_positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    notes: tuple[str, ...] = ()
    stamp_resolution: tuple[StampQuantization, ...] = ()
    truth_heading: str = "mocap"
    velocities: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    def __post_init__(self) -> None:
        def as_float(name, shape_tail):
            value = np.asarray(getattr(self, name), np.float64)
            value = value.reshape((-1, *shape_tail)) if value.size or shape_tail else value.reshape(-1)
            if not np.all(np.isfinite(value)):
                raise DatasetError(f"{self.name}: {name} holds non-finite values")
            object.__setattr__(self, name, value)
            return value

        odometry = as_float("odometry", (4,))
        times = as_float("sighting_times", ())
        ranges = as_float("ranges", ())
        bearings = as_float("bearings", ())
        truth = as_float("ground_truth", (4,))
        positions = as_float("truth_positions", (2,))
        velocities = as_float("velocities", (3,))
        ids = np.asarray(self.landmark_ids).reshape(-1)
        truth_ids = np.asarray(self.truth_ids).reshape(-1)
        for name, value in (("landmark_ids", ids), ("truth_ids", truth_ids)):
            if value.size and value.dtype.kind not in "iu":
                raise DatasetError(f"{self.name}: {name} must be integers, not {value.dtype}")
        object.__setattr__(self, "landmark_ids", ids.astype(np.int64))
        object.__setattr__(self, "truth_ids", truth_ids.astype(np.int64))
        n = len(times)
        if not (len(ranges) == len(bearings) == len(ids) == n):
            raise DatasetError(f"{self.name}: {n} sighting times but {len(ranges)} ranges, {len(bearings)} "
                               f"bearings and {len(ids)} landmark ids")
        if len(positions) != len(truth_ids) or len(np.unique(truth_ids)) != len(truth_ids):
            raise DatasetError(f"{self.name}: truth_ids ({len(truth_ids)}) must be unique and match "
                               f"truth_positions ({len(positions)})")
        if len(odometry) < 2:
            raise DatasetError(f"{self.name}: the odometry needs at least 2 rows, it has {len(odometry)}")
        for name, t in (("odometry", odometry[:, 0]), ("sighting_times", times), ("ground_truth", truth[:, 0]),
                        ("velocities", velocities[:, 0])):
            if np.any(np.diff(t) < 0):
                row = int(np.argmax(np.diff(t) < 0)) + 1
                raise DatasetError(f"{self.name}: {name} times go backwards at row {row}")
        if np.any(ranges < 0):
            raise DatasetError(f"{self.name}: a range is negative")
        if np.any(ids < 0):
            raise DatasetError(f"{self.name}: a landmark id is negative")

    def __len__(self) -> int:
        return len(self.sighting_times)

    @property
    def has_ground_truth(self) -> bool:
        return len(self.ground_truth) >= 2

    @property
    def start_time(self) -> float:
        return float(self.odometry[0, 0])

    def odometry_pose(self, times) -> np.ndarray:
        """Dead-reckoned poses (T, 3) at ``times`` (T,), interpolated (clamped at the log's ends)."""
        return interpolate_poses(self.odometry, times)

    def true_pose(self, times) -> np.ndarray:
        """Ground-truth poses (T, 3) at ``times`` (T,), interpolated (clamped at the ends); needs ground truth."""
        if not self.has_ground_truth:
            raise DatasetError(f"{self.name}: the log has no ground truth")
        return interpolate_poses(self.ground_truth, times)

    def odometry_increments(self, times) -> np.ndarray:
        """Motions (T-1, 3) between consecutive ``times`` (T,), each in the robot frame at its start."""
        poses = self.odometry_pose(times)
        return between(poses[:-1], poses[1:])

    def with_sightings(self, keep: np.ndarray, landmark_ids: np.ndarray | None = None) -> RangeBearingLog:
        """The log with only the sightings where ``keep`` (N,) is True, named by ``landmark_ids`` (N,) instead of
        its own ids if given; the odometry, the truth and the notes as they are."""
        keep = np.asarray(keep, bool)
        ids = self.landmark_ids if landmark_ids is None else np.asarray(landmark_ids, np.int64)
        return replace(self, sighting_times=self.sighting_times[keep], ranges=self.ranges[keep],
                       bearings=self.bearings[keep], landmark_ids=ids[keep])

    def true_landmarks(self) -> dict[int, np.ndarray]:
        """Landmark id -> true (x, y) in the world frame."""
        return {int(i): p.copy() for i, p in zip(self.truth_ids, self.truth_positions, strict=True)}

    def sightings_in_world(self) -> np.ndarray:
        """(N, 2) where each sighting puts its landmark, seen from the true pose at its time (needs ground truth)."""
        poses = self.true_pose(self.sighting_times)
        local = np.column_stack([self.ranges * np.cos(self.bearings), self.ranges * np.sin(self.bearings),
                                 np.zeros(len(self))])
        return compose(poses, local)[:, :2]


def integrate_velocities(times: np.ndarray, v: np.ndarray, w: np.ndarray, start=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Dead-reckoned rows (K, 4) (t, x, y, θ) from velocity samples held until the next sample (exact arcs).

    times (K,) non-decreasing s, v (K,) m/s, w (K,) rad/s; the last sample's velocities are not used.
    """
    dt = np.diff(times)
    v, w = v[:-1], w[:-1]
    dtheta = w * dt
    small = np.abs(dtheta) < 1e-9
    safe = np.where(small, 1.0, w)
    # the arc in the frame at its start: (v/w sin wΔt, v/w (1 - cos wΔt), wΔt); a straight line when w ≈ 0.
    # 1 - cos x is written 2 sin²(x/2): for |x| < 1e-8, cos x rounds to 1 and the difference to 0
    dx = np.where(small, v * dt, v / safe * np.sin(dtheta))
    dy = np.where(small, 0.5 * v * dt * dtheta, v / safe * 2.0 * np.sin(0.5 * dtheta) ** 2)
    theta = np.concatenate([[start[2]], start[2] + np.cumsum(dtheta)])
    c, s = np.cos(theta[:-1]), np.sin(theta[:-1])
    x = np.concatenate([[start[0]], start[0] + np.cumsum(c * dx - s * dy)])
    y = np.concatenate([[start[1]], start[1] + np.cumsum(s * dx + c * dy)])
    return np.column_stack([times, x, y, wrap_angle(theta)])


