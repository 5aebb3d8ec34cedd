"""What the estimators consume: odometry increments and one frame's 3-D stereo observations.

These types belong to the estimation layer; the runtime adapts driver data into them, so the
estimators run on any data set (rendered, recorded or real) without importing a driver.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class OdometryIncrement:
    """Motion since the previous increment, in the robot frame at its start (REP-103).

    dx, dy in metres, dtheta in radians; t0, t1 the timestamps (s) it spans.
    """

    dx: float
    dy: float
    dtheta: float
    t0: float = 0.0
    t1: float = 0.0

    @property
    def delta(self) -> np.ndarray:
        return np.array([self.dx, self.dy, self.dtheta])


@dataclass(frozen=True)
class StereoObservations:
    """One stereo frame's triangulated points, the observation set FastSLAM consumes.

    points:       (N, 3) metres, in the robot frame (base_link, REP-103) unless ``frame`` says otherwise
    covariances:  (N, 3, 3) m², the same frame
    descriptors:  (N, D) float32, unit length (U-SURF: D = 64)
    pixels:       (N, 2) left-image (u, v) of each point, pixels
    timestamp:    seconds (the camera's clock, mapped by the runtime onto the robot's)
    ids:          (N,) int64 or None: the landmark identity each observation reports, when the sensor reads one
                  (a fiducial's barcode or tag number; -1: this observation carries none). None: no identities.
    """

    points: np.ndarray
    covariances: np.ndarray
    descriptors: np.ndarray
    pixels: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    timestamp: float = 0.0
    frame: str = "base_link"
    ids: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.points)
        if self.points.shape != (n, 3) or self.covariances.shape != (n, 3, 3) or len(self.descriptors) != n:
            raise ValueError(
                f"inconsistent observation arrays: points {self.points.shape}, "
                f"covariances {self.covariances.shape}, descriptors {self.descriptors.shape}"
            )
        if len(self.pixels) not in (0, n):
            raise ValueError(f"pixels has {len(self.pixels)} rows for {n} points")
        if self.ids is not None:
            ids = np.asarray(self.ids)
            if ids.shape != (n,) or not (ids.dtype.kind in "iu" or (ids.size == 0)):
                raise ValueError(f"ids must be ({n},) integers, not {ids.shape} {ids.dtype}")
            object.__setattr__(self, "ids", ids.astype(np.int64))

    def __len__(self) -> int:
        return len(self.points)

    @classmethod
    def empty(cls, descriptor_size: int = 64, timestamp: float = 0.0) -> StereoObservations:
        return cls(np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, descriptor_size), np.float32),
                   np.zeros((0, 2)), timestamp)
