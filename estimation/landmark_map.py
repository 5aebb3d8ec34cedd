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

``metadata`` is free-form JSON; simulated maps put their true start pose in the world there
(``"true_start_pose": [x, y, θ]``) so that fusion can be scored against the truth.
"""
from __future__ import annotations

import io
import json
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import MapFileError
from .fileio import atomic_write_bytes

FORMAT_NAME = "p3at-landmark-map"
FORMAT_VERSION = 1


@dataclass
class LandmarkMap:
    """A 3-D point-landmark map with per-landmark uncertainty and appearance.

    positions (N, 3), covariances (N, 3, 3), descriptors (N, D), ids (N,), counts (N,),
    seen_by (N, R) bool over ``robots``; ``robot`` built it, ``frame`` names its coordinate frame.
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
        )

    # -- files ---------------------------------------------------------------------------------
    def save(self, path: str | os.PathLike) -> None:
        """Write the map atomically (see the module docstring for the format)."""
        buf = io.BytesIO()
        meta = {"robot": self.robot, "frame": self.frame, "robots": self.robots, "metadata": self.metadata}
        np.savez_compressed(
            buf,
            format=_json_bytes({"format": FORMAT_NAME, "version": FORMAT_VERSION}),
            positions=self.positions, covariances=self.covariances, descriptors=self.descriptors,
            ids=self.ids, counts=self.counts, seen_by=self.seen_by, trajectory=self.trajectory,
            meta=_json_bytes(meta),
        )
        atomic_write_bytes(path, buf.getvalue())

    @classmethod
    def load(cls, path: str | os.PathLike) -> LandmarkMap:
        """Read a map written by :meth:`save`; any defect raises :class:`MapFileError` naming the file."""
        path = Path(path)
        if path.is_file() and not zipfile.is_zipfile(path):
            # np.load would guess "pickle" for any non-npz bytes; say what is really wrong.
            raise MapFileError(f"{path}: not a landmark-map file (not an npz archive)")
        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
        except FileNotFoundError:
            raise MapFileError(f"{path}: no such map file") from None
        except (OSError, ValueError, zipfile.BadZipFile, EOFError) as e:
            raise MapFileError(f"{path}: not a readable landmark-map file ({e})") from None
        for key in ("format", "positions", "covariances", "descriptors", "ids", "counts", "meta"):
            if key not in arrays:
                raise MapFileError(f"{path}: field '{key}' is missing")
        header = _json_load(path, "format", arrays["format"])
        if header.get("format") != FORMAT_NAME:
            raise MapFileError(f"{path}: field 'format' is {header.get('format')!r}, not {FORMAT_NAME!r}")
        if header.get("version") != FORMAT_VERSION:
            raise MapFileError(f"{path}: format version {header.get('version')!r} is not supported "
                               f"(this reader knows version {FORMAT_VERSION})")
        meta = _json_load(path, "meta", arrays["meta"])
        n = len(arrays["positions"])
        expected = {"positions": (n, 3), "covariances": (n, 3, 3), "ids": (n,), "counts": (n,)}
        for key, shape in expected.items():
            if arrays[key].shape != shape:
                raise MapFileError(f"{path}: field '{key}' has shape {arrays[key].shape}, expected {shape}")
        if arrays["descriptors"].ndim != 2 or len(arrays["descriptors"]) != n:
            raise MapFileError(f"{path}: field 'descriptors' has shape {arrays['descriptors'].shape}, "
                               f"expected ({n}, D)")
        for key in ("positions", "covariances", "descriptors"):
            if not np.all(np.isfinite(arrays[key])):
                raise MapFileError(f"{path}: field '{key}' holds non-finite values")
        if len(np.unique(arrays["ids"])) != n:
            raise MapFileError(f"{path}: field 'ids' holds duplicate landmark ids")
        robots = meta.get("robots") or [meta.get("robot", "robot")]
        seen_by = arrays.get("seen_by")
        if seen_by is not None and seen_by.shape != (n, len(robots)):
            raise MapFileError(f"{path}: field 'seen_by' has shape {seen_by.shape}, expected {(n, len(robots))}")
        try:
            return cls(
                arrays["positions"], arrays["covariances"], arrays["descriptors"], arrays["ids"],
                arrays["counts"], str(meta.get("robot", "robot")), str(meta.get("frame", "map")),
                [str(r) for r in robots], seen_by, arrays.get("trajectory", np.zeros((0, 4))),
                dict(meta.get("metadata", {})),
            )
        except ValueError as e:
            raise MapFileError(f"{path}: {e}") from None

    def export_ply(self, path: str | os.PathLike, binary: bool = False) -> None:
        """Write the map as a PLY point cloud with colour, robot and covariance per point (see estimation.ply)."""
        from .ply import write_ply  # ply.py imports this module

        write_ply(self, path, binary)


def _json_bytes(obj) -> np.ndarray:
    return np.frombuffer(json.dumps(obj).encode(), dtype=np.uint8)


def _json_load(path: Path, key: str, raw: np.ndarray) -> dict:
    try:
        value = json.loads(raw.astype(np.uint8).tobytes().decode())
    except (UnicodeDecodeError, json.JSONDecodeError, ValueError) as e:
        raise MapFileError(f"{path}: field '{key}' is not valid JSON ({e})") from None
    if not isinstance(value, dict):
        raise MapFileError(f"{path}: field '{key}' is not a JSON object")
    return value
