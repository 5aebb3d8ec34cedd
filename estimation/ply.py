"""PLY export of a landmark map: a point cloud any viewer opens (MeshLab, CloudCompare, Open3D, plyfile).

One vertex per landmark with these properties, in this order::

    x y z                 float64  position (m) in the map's frame
    red green blue        uint8    the colour of the robot that observed it (COMMON_COLOUR if several did)
    robot                 uint8    index in the map's robot list (a ``comment robot <i> <name>`` line each)
                                   of the first robot that observed it
    seen_by               uint32   bit i set when robot i observed it
    id count              int32    landmark id, number of observations
    cov_xx cov_xy cov_xz cov_yy cov_yz cov_zz   float64   the upper triangle of its covariance (m²)

``ascii 1.0`` (the default: the existing tools and tests read it as text) or ``binary_little_endian 1.0``.
"""
from __future__ import annotations

import os
from typing import TYPE_CHECKING

import numpy as np

from .fileio import atomic_write_bytes

if TYPE_CHECKING:
    from .landmark_map import LandmarkMap

# Robot colours (Okabe-Ito, readable by colour-blind readers), cycled past eight robots.
ROBOT_COLOURS = np.array([[230, 159, 0], [86, 180, 233], [0, 158, 115], [240, 228, 66], [0, 114, 178],
                          [213, 94, 0], [204, 121, 167], [120, 120, 120]], np.uint8)
COMMON_COLOUR = np.array([255, 255, 255], np.uint8)   # landmarks observed by more than one robot
COVARIANCE_TERMS = (("xx", 0, 0), ("xy", 0, 1), ("xz", 0, 2), ("yy", 1, 1), ("yz", 1, 2), ("zz", 2, 2))

VERTEX_DTYPE = np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("red", "u1"), ("green", "u1"), ("blue", "u1"),
                         ("robot", "u1"), ("seen_by", "<u4"), ("id", "<i4"), ("count", "<i4")]
                        + [(f"cov_{name}", "<f8") for name, _, _ in COVARIANCE_TERMS])
_PLY_TYPES = {"<f8": "double", "|u1": "uchar", "<u4": "uint", "<i4": "int"}


def vertices(landmark_map: LandmarkMap) -> np.ndarray:
    """The map's landmarks as a structured array of :data:`VERTEX_DTYPE` (N,)."""
    m = landmark_map
    n = len(m)
    seen = np.asarray(m.seen_by, bool).reshape(n, len(m.robots))
    if seen.shape[1] > 32:
        raise ValueError(f"a PLY export holds at most 32 robots, this map names {seen.shape[1]}")
    out = np.zeros(n, VERTEX_DTYPE)
    for axis, name in enumerate("xyz"):
        out[name] = m.positions[:, axis]
    observed = seen.any(axis=1)
    first = np.where(observed, seen.argmax(axis=1), 0)
    colours = ROBOT_COLOURS[first % len(ROBOT_COLOURS)]
    colours[seen.sum(axis=1) > 1] = COMMON_COLOUR
    out["red"], out["green"], out["blue"] = colours.T
    out["robot"] = first
    out["seen_by"] = (seen.astype(np.uint64) << np.arange(seen.shape[1], dtype=np.uint64)).sum(axis=1)
    out["id"], out["count"] = m.ids, m.counts
    for name, i, j in COVARIANCE_TERMS:
        out[f"cov_{name}"] = m.covariances[:, i, j]
    return out


def ply_bytes(landmark_map: LandmarkMap, binary: bool = False) -> bytes:
    """The PLY file's bytes (see the module docstring)."""
    data = vertices(landmark_map)
    header = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0",
              f"comment p3at-fusion landmark map of {landmark_map.robot} in frame {landmark_map.frame}"]
    header += [f"comment robot {i} {name}" for i, name in enumerate(landmark_map.robots)]
    header += ["comment units: metres; cov_* are the covariance's upper triangle in m^2",
               f"element vertex {len(data)}"]
    header += [f"property {_PLY_TYPES[VERTEX_DTYPE[name].str]} {name}" for name in VERTEX_DTYPE.names]
    header.append("end_header")
    head = ("\n".join(header) + "\n").encode("ascii")
    if binary:
        return head + data.tobytes()
    rows = [" ".join(repr(float(v)) if isinstance(v, np.floating) else str(int(v)) for v in row) for row in data]
    return head + ("".join(r + "\n" for r in rows)).encode("ascii")


def write_ply(landmark_map: LandmarkMap, path: str | os.PathLike, binary: bool = False) -> None:
    """Write the map as PLY atomically (ASCII, or binary little-endian with ``binary``)."""
    atomic_write_bytes(path, ply_bytes(landmark_map, binary))


__all__ = ["COMMON_COLOUR", "ROBOT_COLOURS", "VERTEX_DTYPE", "ply_bytes", "vertices", "write_ply"]
