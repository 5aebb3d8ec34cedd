"""What a recording's writer and its reader agree on: a landmark map as a recording holds it (``maps/<key>``), its
arrays in the types they are logged and read back in and the checksum taken over them, and the entity that says the
mission closed its recording. runtime/rerun_log.py's MissionLog writes them, runtime/rerun_read.py checks them as it
reads them back."""
from __future__ import annotations

import zlib
from collections.abc import Mapping

import numpy as np

CLOSED_ENTITY = "mission/closed"   # logged (static) when a mission closes its recording: the file is whole

# a map's arrays that only some maps have (estimation/landmark_map.py): the drift and sightings calibrations of
# fusion.fuse_all use them; a snapshot carries those its map has (recordings before session 15 carry none)
OPTIONAL_MAP_ARRAYS = {"drift_covariances": (3, 3), "drift_origins": (2,), "sighting_covariances": (3, 3)}


def map_arrays(positions, covariances, descriptors, ids, counts, seen_by, trajectory,
               **optional) -> dict[str, np.ndarray]:
    """A map's arrays in the types they are logged and read back in: what its checksum is taken over. ``optional``:
    those of OPTIONAL_MAP_ARRAYS the map has."""
    return {"positions": np.asarray(positions, float), "covariances": np.asarray(covariances, float),
            "descriptors": np.asarray(descriptors, np.float32), "ids": np.asarray(ids, np.int64),
            "counts": np.asarray(counts, np.int64), "seen_by": np.asarray(seen_by, np.uint8),
            "trajectory": np.asarray(trajectory, float),
            **{name: np.asarray(optional[name], float) for name in OPTIONAL_MAP_ARRAYS if name in optional}}


def map_checksum(arrays: Mapping[str, np.ndarray], meta: str) -> int:
    """CRC-32 of a map's arrays and metadata text. Rerun's messages carry no checksum of their own: a flipped bit
    that still decodes would change a map silently (a landmark moved, a covariance shrunk)."""
    crc = zlib.crc32(meta.encode("utf-8"))
    for name in sorted(arrays):
        crc = zlib.crc32(np.ascontiguousarray(arrays[name]).tobytes(), zlib.crc32(name.encode(), crc))
    return crc


__all__ = ["CLOSED_ENTITY", "OPTIONAL_MAP_ARRAYS", "map_arrays", "map_checksum"]
