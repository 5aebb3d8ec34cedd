"""Which maps a fused map holds: a content fingerprint per source map, written in the fused map's
``metadata["fusion"]`` beside the robot names (``"maps"``), so that ``p3at fuse`` can tell a map the fused map already
holds (its landmarks would count twice) from another map of the same robot (new evidence).

    "fingerprints": [content_fingerprint(m) for m in the sources]      # in the order of "maps"
    "holds":        sorted union of those and of every source's own "holds" (a fused map fused again keeps them)

Session 13. Fused maps written before have neither; :func:`held_fingerprints` reads them as None (not known).
"""
from __future__ import annotations

import hashlib

import numpy as np

from estimation.landmark_map import LandmarkMap

FINGERPRINT_HEX = 16


def content_fingerprint(landmark_map: LandmarkMap) -> str:
    """First 16 hex digits of the SHA-256 of the map's positions and covariances (little-endian float64, C order,
    with their shapes) and its robot name: equal for a map and its copy or its file read back, different when one
    position moves by one bit. Stable across runs and machines (no Python ``hash``)."""
    h = hashlib.sha256()
    for arr in (landmark_map.positions, landmark_map.covariances):
        a = np.ascontiguousarray(arr, dtype="<f8")
        h.update(repr(a.shape).encode())
        h.update(a.tobytes())
    h.update(b"robot:" + landmark_map.robot.encode())
    return h.hexdigest()[:FINGERPRINT_HEX]


def held_fingerprints(landmark_map: LandmarkMap) -> set[str] | None:
    """The fingerprints of every map ``landmark_map`` holds (its sources, theirs, ...); None when it is no fused
    map or one written before fingerprints (its metadata says nothing certain)."""
    fusion = landmark_map.metadata.get("fusion")
    if not isinstance(fusion, dict):
        return None
    prints = fusion.get("holds", fusion.get("fingerprints"))
    if not isinstance(prints, list) or not all(isinstance(p, str) for p in prints):
        return None
    return set(prints)


def source_metadata(sources: list[LandmarkMap], merged: list[int] | None = None) -> dict:
    """``{"fingerprints": [...], "holds": [...]}`` for a map fused from ``sources`` (module docstring); ``merged``:
    the indices of the sources the fused map holds (default all; a map left out, unconnected, is not held)."""
    prints = [content_fingerprint(m) for m in sources]
    held = range(len(sources)) if merged is None else merged
    holds = {prints[k] for k in held}
    for k in held:
        holds |= held_fingerprints(sources[k]) or set()
    return {"fingerprints": prints, "holds": sorted(holds)}
