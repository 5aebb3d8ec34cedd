"""The landmark map: what FastSLAM produces and fusion reads, and its file format.

File format (``.npz``, version 1, read with ``allow_pickle=False``, so no pickle ever): arrays

    format       uint8 JSON bytes: {"format": "p3at-landmark-map", "version": 1}
    positions    (N, 3) float64, metres, in ``frame``
    covariances  (N, 3, 3) float64, m²
    descriptors  (N, D) float32
    ids          (N,) int64, unique within the map
    counts       (N,) int64, how many times each landmark was observed
    seen_by      (N, R) bool, which of ``robots`` observed each landmark
    trajectory   (T, 4) float64, rows (t, x, y, θ) of the robot that built the map (may be empty)
    meta         uint8 JSON bytes: {"robot", "frame", "robots", "metadata"}

and, optional (both or neither; session 10, a file without them reads as before):

    drift_covariances  (N, 3, 3) float64, the covariance of the robot's pose (x, y, θ) relative to the map's frame
                       when it made each landmark (m², m·rad, rad²): the map frame's drift at the landmark
    drift_origins      (N, 2) float64, metres, where the robot was when it made each landmark

A FastSLAM map's ``covariances`` already hold that drift's effect on each landmark (``mixture+drift``); the drift
kept apart says which landmarks share it (those made from one stretch of the route move together), so that fusion
can tell the error an alignment removes (rigid) from the map's bend (``fusion.shape_covariance``).

and, optional (session 11, a file without it reads as before):

    sighting_covariances  (N, 3, 3) float64, m²: the scatter of the robot's own sightings of each landmark, each
                          placed by the map's trajectory (the robot's pose when it made the sighting), about the
                          landmark's estimate (``estimation.sighting_spread``): how well the map agrees with itself
                          at the landmark, which neither the EKF part (conditional on the trajectory) nor the drift
                          (mostly rigid) says

``metadata`` is free-form JSON; simulated maps put their true start pose in the world there
(``"true_start_pose": [x, y, θ]``) so that fusion can be scored against the truth.

Reading trusts nothing the file claims: sizes are bounded before allocation (:mod:`estimation.safe_npz`), values
and JSON types after (:mod:`estimation.map_validation`, which lists the bounds); any defect is a
:class:`~estimation.errors.MapFileError` naming the file and the field.
"""
from __future__ import annotations

import io
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import MapFileError
from .fileio import atomic_write_bytes
from .map_validation import FORMAT_NAME, FORMAT_VERSION, MEMBERS, read_map_arrays
from .ply import write_ply
from .safe_npz import read_npz, read_npz_bytes


@dataclass
class LandmarkMap:
    """A 3-D point-landmark map with per-landmark uncertainty and appearance.

    positions (N, 3), covariances (N, 3, 3), descriptors (N, D), ids (N,), counts (N,),
    seen_by (N, R) bool over ``robots``; ``robot`` built it, ``frame`` names its coordinate frame;
    drift_covariances (N, 3, 3) and drift_origins (N, 2), or None: the frame's drift at each landmark (module
    docstring); a map built otherwise (merged, transformed) has none; sighting_covariances (N, 3, 3) or None: the
    spread of the robot's sightings of each landmark about it (module docstring).
    """

    positions: np.ndarray
    covariances: np.ndarray
    descriptors: np.ndarray
    ids: np.ndarray | None = None
    counts: np.ndarray | None = None
    robot: str = "robot"
    frame: str = "map"
    robots: list[str] | None = None
    seen_by: np.ndarray | None = None
    trajectory: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    metadata: dict = field(default_factory=dict)
    drift_covariances: np.ndarray | None = None
    drift_origins: np.ndarray | None = None
    sighting_covariances: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.positions = np.asarray(self.positions, dtype=np.float64).reshape(-1, 3)
        n = len(self.positions)
        self.covariances = np.asarray(self.covariances, dtype=np.float64).reshape(n, 3, 3)
        self.descriptors = np.asarray(self.descriptors, dtype=np.float32)
        if self.descriptors.ndim != 2 or len(self.descriptors) != n:
            self.descriptors = self.descriptors.reshape(n, -1)
        self.ids = np.arange(n, dtype=np.int64) if self.ids is None else np.asarray(self.ids, np.int64)
        self.counts = np.ones(n, np.int64) if self.counts is None else np.asarray(self.counts, np.int64)
        if self.robots is None:
            self.robots = [self.robot]
        if self.seen_by is None:
            self.seen_by = np.zeros((n, len(self.robots)), bool)
            if self.robot in self.robots:
                self.seen_by[:, self.robots.index(self.robot)] = True
        self.seen_by = np.asarray(self.seen_by, bool).reshape(n, len(self.robots))
        self.trajectory = np.asarray(self.trajectory, np.float64).reshape(-1, 4)
        if self.ids.shape != (n,) or self.counts.shape != (n,):
            raise ValueError(f"ids {self.ids.shape} and counts {self.counts.shape} must have {n} rows")
        if (self.drift_covariances is None) != (self.drift_origins is None):
            raise ValueError("drift_covariances and drift_origins go together (both or neither)")
        if self.drift_covariances is not None:
            self.drift_covariances = np.asarray(self.drift_covariances, np.float64).reshape(n, 3, 3)
            self.drift_origins = np.asarray(self.drift_origins, np.float64).reshape(n, 2)
        if self.sighting_covariances is not None:
            self.sighting_covariances = np.asarray(self.sighting_covariances, np.float64).reshape(n, 3, 3)

    def __len__(self) -> int:
        return len(self.positions)

    @property
    def descriptor_size(self) -> int:
        return self.descriptors.shape[1]

    def subset(self, index) -> LandmarkMap:
        """A new map with the landmarks selected by ``index`` (boolean mask or integer array)."""
        return LandmarkMap(
            self.positions[index], self.covariances[index], self.descriptors[index], self.ids[index],
            self.counts[index], self.robot, self.frame, list(self.robots), self.seen_by[index],
            self.trajectory.copy(), dict(self.metadata),
            None if self.drift_covariances is None else self.drift_covariances[index],
            None if self.drift_origins is None else self.drift_origins[index],
            None if self.sighting_covariances is None else self.sighting_covariances[index],
        )

    # -- files ---------------------------------------------------------------------------------
    def save(self, path: str | os.PathLike) -> None:
        """Write the map atomically (see the module docstring for the format). Raises MapFileError (one line naming
        the file and the field), writing nothing and leaving an existing file as it was, where :meth:`load` would
        refuse the file: the bytes about to be written are read back first with the reader's own checks (a NaN from
        a diverged filter, a covariance that is not positive definite, a name with a control character), so that a
        map once saved is never unreadable and the last good file is never replaced by one."""
        data = self.archive_bytes()
        check_map_bytes(data, f"{path}: not written")
        atomic_write_bytes(path, data)

    def archive_bytes(self) -> bytes:
        """The .npz archive :meth:`save` writes, as it is before :meth:`save` checks it (:func:`check_map_bytes`)."""
        buf = io.BytesIO()
        meta = _json_bytes({"robot": self.robot, "frame": self.frame, "robots": self.robots,
                            "metadata": self.metadata})
        drift = {} if self.drift_covariances is None else {"drift_covariances": self.drift_covariances,
                                                            "drift_origins": self.drift_origins}
        if self.sighting_covariances is not None:
            drift["sighting_covariances"] = self.sighting_covariances
        np.savez_compressed(
            buf,
            format=_json_bytes({"format": FORMAT_NAME, "version": FORMAT_VERSION}),
            positions=self.positions, covariances=self.covariances, descriptors=self.descriptors,
            ids=self.ids, counts=self.counts, seen_by=self.seen_by, trajectory=self.trajectory,
            meta=meta, **drift,
        )
        return buf.getvalue()

    @classmethod
    def load(cls, path: str | os.PathLike) -> LandmarkMap:
        """Read a map written by :meth:`save`; any defect raises :class:`MapFileError` naming the file and field.

        Nothing the file claims is trusted: sizes are checked against bounds and the file's size before anything
        is allocated (:mod:`estimation.safe_npz`), then dtypes, shapes, finiteness, covariances (symmetric,
        positive definite, bounded) and the JSON fields' types (:func:`read_map_arrays`).
        """
        path = Path(path)
        arrays = read_npz(path, MEMBERS, MapFileError, what="map")
        return read_map_arrays(arrays, str(path), cls)

    def export_ply(self, path: str | os.PathLike, binary: bool = False) -> None:
        """Write the map as a PLY point cloud with colour, robot and covariance per point (see estimation.ply)."""
        write_ply(self, path, binary)


def check_map_bytes(data: bytes, source: str) -> None:
    """Raise :class:`MapFileError` (one line beginning ``source``) where :meth:`LandmarkMap.load` would refuse a file
    holding ``data``: the reader's own checks, on bytes about to be written."""
    read_map_arrays(read_npz_bytes(data, source, MEMBERS, MapFileError, what="map"), source, LandmarkMap)


def _json_bytes(obj) -> np.ndarray:
    return np.frombuffer(json.dumps(obj).encode(), dtype=np.uint8)

