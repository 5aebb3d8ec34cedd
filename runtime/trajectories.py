"""A robot's trajectories (estimated, odometry, true) kept during a mission and written in TUM format.

TUM format (the TUM RGB-D benchmark's, which ``evo``, ``rpg_trajectory_evaluation`` and most SLAM tools read):
one pose per line, ``t x y z qx qy qz qw``, t in seconds, position in metres, orientation a unit quaternion;
``#`` starts a comment. Planar poses (x, y, θ) are written with z = 0 and a rotation about z.

:class:`TrajectoryRecorder` keeps one row per processed frame, all in the map frame (the robot's start frame):
FastSLAM's best pose, odometry alone (dead reckoning, what FastSLAM improves on), and on the virtual robots the
true pose, interpolated at the frame's time from the truth sampled at each SIP. Memory: 3 × 4 float64 per frame,
96 bytes (10 minutes at 15 frames/s: under 1 MB), plus the last ``truth_horizon`` truth samples.
"""
from __future__ import annotations

import math
import os
import threading
from array import array
from collections import deque
from collections.abc import Callable
from pathlib import Path

import numpy as np

from estimation.fileio import atomic_write_bytes
from estimation.geometry import between, wrap_angle
from runtime.textfile import read_bounded_text

MAX_TUM_BYTES = 1 << 30        # a TUM file larger than this is refused before it is read
KINDS = ("estimated", "odometry", "truth")


class TrajectoryFileError(ValueError):
    """A TUM file is missing or malformed; the message names the file, the line and what is wrong."""


class TrajectoryRecorder:
    """Thread-safe: ``add_truth`` from the driver's thread at each SIP, ``add_frame`` from the SLAM thread."""

    def __init__(self, true_start: np.ndarray | None = None, truth_horizon: int = 200) -> None:
        self.true_start = None if true_start is None else np.asarray(true_start, float)
        self._truth: deque[tuple[float, np.ndarray]] = deque(maxlen=truth_horizon)  # recent (t, world pose)
        # flat float64 arrays (t, x, y, θ, t, x, ...): 32 bytes a pose, no Python object per number
        self._rows: dict[str, array] = {k: array("d") for k in KINDS}
        self._lock = threading.Lock()

    def add_truth(self, t: float, truth: Callable[[], np.ndarray]) -> None:
        """Sample the true world pose (``truth()``, mocks only) at a SIP stamped ``t``."""
        if self.true_start is None:
            return
        try:
            pose = np.asarray(truth(), float)
        except LookupError:  # the virtual robot is already gone
            return
        with self._lock:
            if not self._truth or t > self._truth[-1][0]:
                self._truth.append((float(t), pose))

    def add_frame(self, t: float, estimate: np.ndarray, odometry: np.ndarray | None) -> None:
        """One processed frame: FastSLAM's best pose and odometry alone, both (3,) in the map frame."""
        with self._lock:
            self._rows["estimated"].extend((float(t), *map(float, estimate[:3])))
            if odometry is not None:
                self._rows["odometry"].extend((float(t), *map(float, odometry[:3])))
            true = self._truth_at(float(t))
            if true is not None:
                self._rows["truth"].extend((float(t), *map(float, between(self.true_start, true))))

    def _truth_at(self, t: float) -> np.ndarray | None:
        samples = self._truth
        if not samples or t < samples[0][0] or t > samples[-1][0]:
            return None
        for (t0, p0), (t1, p1) in zip(samples, list(samples)[1:], strict=False):
            if t0 <= t <= t1:
                s = 0.0 if t1 == t0 else (t - t0) / (t1 - t0)
                return np.array([p0[0] + s * (p1[0] - p0[0]), p0[1] + s * (p1[1] - p0[1]),
                                 wrap_angle(p0[2] + s * wrap_angle(p1[2] - p0[2]))])
        return samples[-1][1] if t == samples[-1][0] else None

    def get(self, kind: str) -> np.ndarray:
        """(T, 4) rows (t, x, y, θ) of ``kind`` (``estimated``, ``odometry`` or ``truth``)."""
        with self._lock:
            return np.frombuffer(self._rows[kind], float).reshape(-1, 4).copy()

    def write_tum(self, folder: str | os.PathLike, robot: str) -> dict[str, Path]:
        """``<robot>.tum``, ``<robot>-odometry.tum``, ``<robot>-truth.tum`` in ``folder`` (those with rows)."""
        written = {}
        for kind, suffix in (("estimated", ""), ("odometry", "-odometry"), ("truth", "-truth")):
            rows = self.get(kind)
            if len(rows):
                path = Path(folder) / f"{robot}{suffix}.tum"
                write_tum(path, rows, comment=f"{robot}: {kind} trajectory in its map frame (its start frame)")
                written[kind] = path
        return written


def tum_text(rows: np.ndarray, comment: str = "") -> str:
    """TUM lines of planar rows (T, 4) (t, x, y, θ); numbers written exactly (shortest round-trip repr)."""
    rows = np.asarray(rows, float).reshape(-1, 4)
    lines = [f"# {comment}"] if comment else []
    lines.append("# t x y z qx qy qz qw")
    for t, x, y, theta in rows:
        lines.append(" ".join(repr(float(v)) for v in (t, x, y, 0.0, 0.0, 0.0, math.sin(theta / 2),
                                                       math.cos(theta / 2))))
    return "\n".join(lines) + "\n"


def write_tum(path: str | os.PathLike, rows: np.ndarray, comment: str = "") -> None:
    """Write planar rows (T, 4) (t, x, y, θ) as a TUM file, atomically."""
    atomic_write_bytes(path, tum_text(rows, comment).encode("ascii"))


def read_tum(path: str | os.PathLike) -> np.ndarray:
    """(T, 8) rows (t, x, y, z, qx, qy, qz, qw) of a TUM file, validated: 8 finite numbers a line, unit
    quaternions (within 1e-6), timestamps strictly increasing. Raises :class:`TrajectoryFileError`."""
    path = Path(path)
    text = read_bounded_text(path, MAX_TUM_BYTES, "trajectory file", TrajectoryFileError, encoding="ascii")
    rows = []
    for number, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        fields = line.replace(",", " ").split()
        if len(fields) != 8:
            raise TrajectoryFileError(f"{path}:{number}: {len(fields)} numbers, a TUM line holds 8 "
                                      "(t x y z qx qy qz qw)")
        try:
            values = [float(v) for v in fields]
        except ValueError:
            raise TrajectoryFileError(f"{path}:{number}: not a number in {line[:60]!r}") from None
        if not all(math.isfinite(v) for v in values):
            raise TrajectoryFileError(f"{path}:{number}: non-finite number")
        if abs(math.hypot(*values[4:]) - 1.0) > 1e-6:
            raise TrajectoryFileError(f"{path}:{number}: quaternion norm {math.hypot(*values[4:]):.6g}, not 1")
        if rows and values[0] <= rows[-1][0]:
            raise TrajectoryFileError(f"{path}:{number}: timestamp {values[0]} does not increase")
        rows.append(values)
    return np.array(rows, float).reshape(-1, 8)


def planar(rows: np.ndarray) -> np.ndarray:
    """(T, 4) (t, x, y, θ) of TUM rows (T, 8) whose rotation is about z (θ from the quaternion)."""
    rows = np.asarray(rows, float).reshape(-1, 8)
    return np.column_stack([rows[:, 0], rows[:, 1], rows[:, 2], 2 * np.arctan2(rows[:, 6], rows[:, 7])])


__all__ = ["KINDS", "TrajectoryFileError", "TrajectoryRecorder", "planar", "read_tum", "tum_text", "write_tum"]
