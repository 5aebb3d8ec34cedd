"""The simulated building shared by every mock: walls, decorations, features, robots' ground truth.

Pure numpy (no I/O beyond loading the data file); the robot registry is thread-safe.

Data file format (``mocks/data/building.json``, JSON, ``"version": 1``)
----------------------------------------------------------------------
Top-level object::

    {
      "format": "p3at-fusion-world",      # optional, checked when present
      "description": "...",                # optional free text (keys starting with "_" are comments)
      "version": 1,                        # required; only 1 is understood
      "name": "...",                       # required, non-empty string
      "default_wall_height": 2.7,          # optional (metres), used by walls without "height"
      "feature_seed": 20240,               # optional int: seeds the feature descriptors
      "door_frame": {"width": 0.1, "height": 2.1},   # optional: the frame drawn beside every doorway
      "walls": [ WALL, ... ],              # required, at least one
      "start_poses": {"robot1": [x, y, theta], ...},   # optional, metres / radians
      "routes": {"robot1": [[x, y], [x, y], ...], ...} # optional, at least 2 waypoints each
    }

    WALL = {
      "id": "corridor_south",             # optional label used in error messages
      "from": [x0, y0], "to": [x1, y1],   # required, metres, world frame (REP-103), non-zero length
      "height": 2.7,                      # optional, metres > 0
      "openings": [[s0, s1], ...],        # optional doorways: gaps in the wall, s along the wall from "from"
      "baseboard": {"height": 0.1, "sides": [1, -1]},  # optional: a strip along the bottom of each piece
      "decorations": [ DECORATION, ... ]  # optional
    }

    DECORATION = {"kind": "poster", "s0": 1.0, "s1": 1.6, "z0": 1.1, "z1": 1.9, "side": 1, "seed": 7}
      # s along the wall (from "from", as written in the file), z height, side +1 = the left face of
      # from->to (its left normal), -1 the right face; "seed" optional (derived from the position).

Walls with openings are split into pieces; ``World.walls`` holds the pieces and every ``Decoration.wall``
indexes a piece, with ``s`` measured from the piece's start. A decoration must lie inside one piece and
below its wall's height. Doorways get a "door_frame" decoration on both faces of both sides.
Unknown keys are errors (a misspelt "heigth" must not pass silently); keys starting with "_" are comments.
A malformed file raises :class:`WorldFileError` (a ``ValueError``) naming the file and the field.

Bounds (checked before the work they would cause): a file of at most ``MAX_FILE_BYTES``, JSON nested at most
as deep as Python's parser allows, at most ``MAX_WALLS`` walls, ``MAX_PER_WALL`` openings and decorations per
wall, ``MAX_WAYPOINTS`` per route, coordinates and heights within ``MAX_COORDINATE`` metres.
"""

from __future__ import annotations

import json
import math
import threading
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from estimation.fileio import InputTooLargeError, read_bounded

DEFAULT_WORLD_PATH = Path(__file__).resolve().parent / "data" / "building.json"
FORMAT_NAME = "p3at-fusion-world"
SUPPORTED_VERSIONS = (1,)
DESCRIPTOR_SIZE = 64
_EPS = 1e-9
_RAY_CHUNK = 2048  # rays per vectorised block: keeps the (rays × walls) temporaries in cache
MAX_FILE_BYTES = 16 << 20  # the packaged building is ~20 kB
MAX_WALLS = 10_000
MAX_PER_WALL = 1_000  # openings, decorations
MAX_WAYPOINTS = 100_000
MAX_COORDINATE = 1e5  # metres: any building, and far from float overflow in lengths and areas


MAX_ROBOT_NAME = 64


def robot_name_problem(name: str) -> str | None:
    """Why ``name`` cannot be a robot's name (None: it can). The name names the robot's files (OUT/NAME.npz,
    NAME-log/, NAME.tum): one with a slash, '..' or a character that does not print wrote them outside the output
    folder (a world's robot '../escape': OUT/../escape.npz)."""
    if not 1 <= len(name) <= MAX_ROBOT_NAME or name in (".", "..") or "/" in name or "\\" in name \
            or not name.isprintable() or name != name.strip():
        return (f"a robot's name is 1-{MAX_ROBOT_NAME} printable characters without a slash or surrounding spaces, "
                "not '.' or '..' (it names the robot's files)")
    return None


def _robot_name(r, name: str, where: str) -> None:
    if (problem := robot_name_problem(name)) is not None:
        raise r.fail(f"{where}.{name[:40]!r}", problem)


class WorldFileError(ValueError):
    """A world data file that cannot be used; the message names the file and the field."""

    def __init__(self, path: str | Path, field: str, problem: str) -> None:
        self.path = str(path)
        self.field = field    # "" where the problem is the file as a whole (unreadable, not JSON, too large)
        self.problem = problem
        super().__init__(f"{self.path}: {field}: {problem}" if field else f"{self.path}: {problem}")


@dataclass(frozen=True)
class Decoration:
    """Something drawn on one face of a wall piece.

    kind: "poster", "door", "window", "notice", "baseboard", "door_frame", ...
    wall: index into ``World.walls``; s0 < s1 along the piece from its start point (metres);
    z0 < z1 height above the floor (metres); side +1 = left normal of start->end, -1 right;
    seed drives the procedural texture (and the features' descriptors).
    """

    kind: str
    wall: int
    s0: float
    s1: float
    z0: float
    z1: float
    seed: int
    side: int


# ----------------------------------------------------------------------------------------------- loading


class _Reader:
    """Validating accessors that raise WorldFileError with the field path."""

    def __init__(self, path: str | Path) -> None:
        self.path = path

    def fail(self, field: str, problem: str) -> WorldFileError:
        return WorldFileError(self.path, field, problem)

    def number(self, obj: dict, key: str, field: str, default: float | None = None, positive: bool = False) -> float:
        if key not in obj:
            if default is None:
                raise self.fail(f"{field}.{key}", "missing")
            return float(default)
        value = obj[key]
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise self.fail(f"{field}.{key}", f"expected a finite number, got {_short(value)}")
        if abs(value) > MAX_COORDINATE:
            raise self.fail(f"{field}.{key}", f"{value:g} is beyond ±{MAX_COORDINATE:g}")
        if positive and value <= 0:
            raise self.fail(f"{field}.{key}", f"must be > 0, got {value!r}")
        return float(value)

    def vector(self, value: Any, n: int, field: str) -> np.ndarray:
        ok = isinstance(value, list) and len(value) == n
        ok = ok and all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                        and abs(v) <= MAX_COORDINATE for v in value)
        if not ok:
            raise self.fail(field, f"expected a list of {n} finite numbers within ±{MAX_COORDINATE:g}, "
                                   f"got {_short(value)}")
        return np.asarray(value, dtype=float)

    def obj(self, value: Any, field: str, known: frozenset[str] | None = None) -> dict:
        """A JSON object; with ``known``, any other key is an error (a typo must not pass silently)."""
        if not isinstance(value, dict):
            raise self.fail(field, f"expected an object, got {type(value).__name__}")
        if known is not None:
            for key in value:
                if key not in known and not str(key).startswith("_"):
                    where = key if field == "<top level>" else f"{field}.{key}"
                    raise self.fail(where, f"unknown field (known: {', '.join(sorted(known))})")
        return value

    def array(self, value: Any, field: str, limit: int | None = None) -> list:
        if not isinstance(value, list):
            raise self.fail(field, f"expected a list, got {type(value).__name__}")
        if limit is not None and len(value) > limit:
            raise self.fail(field, f"{len(value)} entries, more than {limit}")
        return value


def _short(value: Any) -> str:
    """A value for an error message, cut to one short line."""
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


_TOP_KEYS = frozenset({"format", "version", "name", "description", "default_wall_height", "feature_seed",
                       "door_frame", "walls", "start_poses", "routes"})
_WALL_KEYS = frozenset({"id", "from", "to", "height", "openings", "baseboard", "decorations"})
_DECORATION_KEYS = frozenset({"kind", "s0", "s1", "z0", "z1", "side", "seed"})


def _default_seed(label: str) -> int:
    return zlib.crc32(label.encode()) & 0x7FFFFFFF


def _parse(doc: Any, path: str | Path) -> dict[str, Any]:
    """Validate a decoded JSON document and expand it into arrays; see the module docstring."""
    r = _Reader(path)
    doc = r.obj(doc, "<top level>", _TOP_KEYS)
    if "format" in doc and doc["format"] != FORMAT_NAME:
        raise r.fail("format", f"expected {FORMAT_NAME!r}, got {doc['format']!r}")
    if "version" not in doc:
        raise r.fail("version", "missing")
    if doc["version"] not in SUPPORTED_VERSIONS:
        raise r.fail("version", f"unsupported version {doc['version']!r} (supported: {SUPPORTED_VERSIONS})")
    name = doc.get("name")
    if not isinstance(name, str) or not name:
        raise r.fail("name", f"expected a non-empty string, got {name!r}")
    default_height = r.number(doc, "default_wall_height", "<top level>", default=2.7, positive=True)
    feature_seed = doc.get("feature_seed", 0)
    if not isinstance(feature_seed, int) or isinstance(feature_seed, bool) or not 0 <= feature_seed < 2**63:
        raise r.fail("feature_seed", f"expected a non-negative integer, got {feature_seed!r}")
    frame = r.obj(doc.get("door_frame", {}), "door_frame", frozenset({"width", "height"}))
    frame_width = r.number(frame, "width", "door_frame", default=0.1, positive=True)
    frame_height = r.number(frame, "height", "door_frame", default=2.1, positive=True)

    walls_in = r.array(doc.get("walls"), "walls", MAX_WALLS) if "walls" in doc else None
    if not walls_in:
        raise r.fail("walls", "missing or empty")

    pieces: list[tuple[float, float, float, float]] = []
    heights: list[float] = []
    decorations: list[Decoration] = []
    for wi, wall_doc in enumerate(walls_in):
        wf = f"walls[{wi}]"
        wall = r.obj(wall_doc, wf, _WALL_KEYS)
        label = wall.get("id", wf)
        if not isinstance(label, str):
            raise r.fail(f"{wf}.id", f"expected a string, got {label!r}")
        wf = f"walls[{wi}]({label})" if "id" in wall else wf
        if "from" not in wall or "to" not in wall:
            raise r.fail(f"{wf}.{'from' if 'from' not in wall else 'to'}", "missing")
        a = r.vector(wall["from"], 2, f"{wf}.from")
        b = r.vector(wall["to"], 2, f"{wf}.to")
        length = float(np.hypot(*(b - a)))
        if length < 1e-6:
            raise r.fail(f"{wf}.to", "wall has zero length")
        height = r.number(wall, "height", wf, default=default_height, positive=True)
        unit = (b - a) / length

        # Split at the doorways: solid intervals [(start, end)] along the wall.
        openings = []
        for oi, op in enumerate(r.array(wall.get("openings", []), f"{wf}.openings", MAX_PER_WALL)):
            s0, s1 = r.vector(op, 2, f"{wf}.openings[{oi}]")
            if not 0.0 <= s0 < s1 <= length:
                raise r.fail(f"{wf}.openings[{oi}]", f"need 0 <= s0 < s1 <= wall length {length:.3f}")
            openings.append((float(s0), float(s1), oi))
        openings.sort()
        solid, cursor = [], 0.0
        for s0, s1, oi in openings:
            if s0 < cursor - 1e-9:
                raise r.fail(f"{wf}.openings[{oi}]", "overlaps another opening")
            solid.append((cursor, s0))
            cursor = s1
        solid.append((cursor, length))
        solid = [(s0, s1) for s0, s1 in solid if s1 - s0 > 1e-6]
        first_piece = len(pieces)
        for s0, s1 in solid:
            p0, p1 = a + unit * s0, a + unit * s1
            pieces.append((p0[0], p0[1], p1[0], p1[1]))
            heights.append(height)

        def piece_of(s0: float, s1: float, field: str, solid=solid, first_piece=first_piece) -> tuple[int, float]:
            for k, (q0, q1) in enumerate(solid):
                if q0 - 1e-6 <= s0 and s1 <= q1 + 1e-6:
                    return first_piece + k, q0
            raise r.fail(field, f"s0..s1 = {s0}..{s1} is not inside one solid piece of the wall (doorway or end)")

        # Frames beside each doorway, on both faces.
        for s0, s1, oi in openings:
            for edge_lo, edge_hi in ((s0 - frame_width, s0), (s1, s1 + frame_width)):
                lo, hi = max(edge_lo, 0.0), min(edge_hi, length)
                if hi - lo < 1e-6:
                    continue
                try:
                    piece, q0 = piece_of(lo, hi, f"{wf}.openings[{oi}]")
                except WorldFileError:
                    continue  # no wall beside this edge (opening at the end or two doorways abutting)
                for side in (1, -1):
                    seed = _default_seed(f"{label}:frame:{oi}:{lo:.3f}:{side}")
                    decorations.append(
                        Decoration("door_frame", piece, lo - q0, hi - q0, 0.0, min(frame_height, height), seed, side)
                    )

        if "baseboard" in wall:
            bb = r.obj(wall["baseboard"], f"{wf}.baseboard", frozenset({"height", "sides"}))
            bb_height = r.number(bb, "height", f"{wf}.baseboard", default=0.1, positive=True)
            sides = r.array(bb.get("sides", [1, -1]), f"{wf}.baseboard.sides", 2)
            if any(s not in (1, -1) for s in sides):
                raise r.fail(f"{wf}.baseboard.sides", f"entries must be 1 or -1, got {sides!r}")
            for k, (q0, q1) in enumerate(solid):
                for side in sides:
                    seed = _default_seed(f"{label}:baseboard:{k}:{side}")
                    piece = first_piece + k
                    decorations.append(Decoration("baseboard", piece, 0.0, q1 - q0, 0.0, bb_height, seed, side))

        for di, deco_doc in enumerate(r.array(wall.get("decorations", []), f"{wf}.decorations", MAX_PER_WALL)):
            df = f"{wf}.decorations[{di}]"
            deco = r.obj(deco_doc, df, _DECORATION_KEYS)
            kind = deco.get("kind")
            if not isinstance(kind, str) or not kind:
                raise r.fail(f"{df}.kind", f"expected a non-empty string, got {kind!r}")
            s0, s1 = r.number(deco, "s0", df), r.number(deco, "s1", df)
            z0, z1 = r.number(deco, "z0", df), r.number(deco, "z1", df)
            if not s0 < s1:
                raise r.fail(f"{df}.s1", f"need s0 < s1, got {s0}..{s1}")
            if not 0.0 <= z0 < z1 <= height + 1e-9:
                raise r.fail(f"{df}.z1", f"need 0 <= z0 < z1 <= wall height {height}, got {z0}..{z1}")
            side = deco.get("side")
            if side not in (1, -1) or isinstance(side, bool):
                raise r.fail(f"{df}.side", f"expected 1 or -1, got {side!r}")
            seed = deco.get("seed", _default_seed(f"{label}:{di}:{kind}:{s0}"))
            if not isinstance(seed, int) or isinstance(seed, bool) or not 0 <= seed < 2**63:
                raise r.fail(f"{df}.seed", f"expected a non-negative integer, got {seed!r}")
            piece, q0 = piece_of(s0, s1, df)
            decorations.append(Decoration(kind, piece, s0 - q0, s1 - q0, z0, z1, seed, side))

    start_poses: dict[str, np.ndarray] = {}
    for key, value in r.obj(doc.get("start_poses", {}), "start_poses").items():
        _robot_name(r, key, "start_poses")
        start_poses[key] = r.vector(value, 3, f"start_poses.{key}")
    routes: dict[str, np.ndarray] = {}
    for key, value in r.obj(doc.get("routes", {}), "routes").items():
        _robot_name(r, key, "routes")
        points = r.array(value, f"routes.{key}", MAX_WAYPOINTS)
        if len(points) < 2:
            raise r.fail(f"routes.{key}", "a route needs at least 2 waypoints")
        routes[key] = np.stack([r.vector(p, 2, f"routes.{key}[{i}]") for i, p in enumerate(points)])

    return {
        "name": name,
        "walls": np.asarray(pieces, dtype=float).reshape(-1, 4),
        "wall_heights": np.asarray(heights, dtype=float),
        "decorations": decorations,
        "start_poses": start_poses,
        "routes": routes,
        "feature_seed": feature_seed,
    }


# ----------------------------------------------------------------------------------------------- features


def _features_from(
    walls: np.ndarray, decorations: list[Decoration], feature_seed: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Corners of every decoration as 3-D points, with the face normal they are seen from.

    Returns points (K, 3), descriptors (K, 64) float32 unit rows, normals (K, 2) unit, wall index (K,).
    Coincident corners on the same face (a baseboard end on a door frame) are kept once.
    Descriptors: a per-(kind, corner) prototype (so similar-looking corners look alike) plus a part drawn
    from the decoration's seed (so individual corners are distinguishable); both deterministic.
    """
    points, normals, wall_idx, desc = [], [], [], []
    seen: set[tuple] = set()
    proto_cache: dict[tuple[str, int], np.ndarray] = {}
    for deco in decorations:
        x0, y0, x1, y1 = walls[deco.wall]
        length = math.hypot(x1 - x0, y1 - y0)
        ux, uy = (x1 - x0) / length, (y1 - y0) / length
        nx, ny = -uy * deco.side, ux * deco.side  # left normal times side
        rng = np.random.default_rng([feature_seed, deco.seed, deco.wall])
        corners = ((deco.s0, deco.z0), (deco.s1, deco.z0), (deco.s1, deco.z1), (deco.s0, deco.z1))
        for corner, (s, z) in enumerate(corners):
            px, py = x0 + ux * s, y0 + uy * s
            key = (round(px, 4), round(py, 4), round(z, 4), deco.side, deco.wall)
            individual = rng.standard_normal(DESCRIPTOR_SIZE)
            if key in seen:
                continue
            seen.add(key)
            proto_key = (deco.kind, corner)
            if proto_key not in proto_cache:
                kind_seed = _default_seed(deco.kind)
                proto = np.random.default_rng([feature_seed, kind_seed, corner]).standard_normal(DESCRIPTOR_SIZE)
                proto_cache[proto_key] = proto / np.linalg.norm(proto)
            d = 0.4 * proto_cache[proto_key] + individual / np.linalg.norm(individual)
            desc.append(d / np.linalg.norm(d))
            points.append((px, py, z))
            normals.append((nx, ny))
            wall_idx.append(deco.wall)
    return (
        np.asarray(points, dtype=float).reshape(-1, 3),
        np.asarray(desc, dtype=np.float32).reshape(-1, DESCRIPTOR_SIZE),
        np.asarray(normals, dtype=float).reshape(-1, 2),
        np.asarray(wall_idx, dtype=np.int64),
    )


def _readonly(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


# ----------------------------------------------------------------------------------------------- footprints


def footprint_corners(pose: np.ndarray, size: tuple[float, float]) -> np.ndarray:
    """The four corners (4, 2) of a robot's body: a ``size`` = (length along x, width along y) rectangle centred
    on the pose (x, y, θ) and turned by θ; counter-clockwise from the front left."""
    return np.array(_corners(pose, size))


def _corners(pose, size) -> list[tuple[float, float]]:
    x, y, th = (float(v) for v in pose)
    hl, hw = float(size[0]) / 2.0, float(size[1]) / 2.0
    c, s = math.cos(th), math.sin(th)
    return [(x + c * u - s * v, y + s * u + c * v) for u, v in ((hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw))]


def footprint_gap(pose_a: np.ndarray, size_a: tuple[float, float],
                  pose_b: np.ndarray, size_b: tuple[float, float]) -> float:
    """Signed gap (metres) between two robots' bodies (see :func:`footprint_corners`): the distance between them
    when apart, 0 touching, minus the penetration depth (the shortest push that separates them) when they overlap.

    Both from the separating-axis theorem: the bodies overlap exactly when their projections overlap on all four
    edge normals, and then the shortest push along one of them that parts the projections is the penetration
    depth (a body inside the other's projection must go the longer way out on one side); apart, the distance is
    the nearest corner-to-edge distance (for two convex polygons the nearest points include a corner of one).
    Plain floats: a virtual robot asks this every physics step of every robot near it.
    """
    ca, cb = _corners(pose_a, size_a), _corners(pose_b, size_b)
    depth = math.inf
    for th in (float(pose_a[2]), float(pose_b[2])):
        for ax, ay in ((math.cos(th), math.sin(th)), (-math.sin(th), math.cos(th))):  # the edge normals
            pa = [x * ax + y * ay for x, y in ca]
            pb = [x * ax + y * ay for x, y in cb]
            overlap = min(max(pa) - min(pb), max(pb) - min(pa))  # the shorter push along this axis that parts them
            if overlap <= 0.0:
                return min(_corners_to_edges(ca, cb), _corners_to_edges(cb, ca))
            depth = min(depth, overlap)
    return -depth


def _corners_to_edges(points: list[tuple[float, float]], polygon: list[tuple[float, float]]) -> float:
    """Smallest distance from any of ``points`` to any edge of the closed ``polygon``."""
    best = math.inf
    for i, (ax, ay) in enumerate(polygon):
        bx, by = polygon[(i + 1) % len(polygon)]
        ex, ey = bx - ax, by - ay
        ee = ex * ex + ey * ey
        for px, py in points:
            t = min(1.0, max(0.0, ((px - ax) * ex + (py - ay) * ey) / ee))
            best = min(best, math.hypot(px - ax - t * ex, py - ay - t * ey))
    return best


def footprint_overlap(pose_a: np.ndarray, size_a: tuple[float, float],
                      pose_b: np.ndarray, size_b: tuple[float, float]) -> np.ndarray:
    """The region (k, 2) where two robots' bodies overlap, a convex polygon counter-clockwise (k = 0: they do not;
    touching along an edge gives a degenerate polygon of zero area). Body A clipped by each edge of body B
    (Sutherland–Hodgman)."""
    poly = [tuple(p) for p in footprint_corners(pose_a, size_a)]
    cb = footprint_corners(pose_b, size_b)
    for i in range(4):
        (x0, y0), (x1, y1) = cb[i], cb[(i + 1) % 4]
        ex, ey = x1 - x0, y1 - y0

        def side(p: tuple[float, float], x0=x0, y0=y0, ex=ex, ey=ey) -> float:  # > 0: inside (left of the edge)
            return ex * (p[1] - y0) - ey * (p[0] - x0)

        out: list[tuple[float, float]] = []
        for j, p in enumerate(poly):
            q = poly[(j + 1) % len(poly)]
            sp, sq = side(p), side(q)
            if sp >= 0.0:
                out.append(p)
            if (sp >= 0.0) != (sq >= 0.0):
                f = sp / (sp - sq)
                out.append((p[0] + f * (q[0] - p[0]), p[1] + f * (q[1] - p[1])))
        poly = out
        if not poly:
            break
    return np.asarray(poly, dtype=float).reshape(-1, 2)


def _footprint(size: tuple[float, float] | None) -> tuple[float, float] | None:
    if size is None:
        return None
    length, width = (float(v) for v in size)
    if not (math.isfinite(length) and math.isfinite(width) and length > 0 and width > 0):
        raise ValueError(f"a footprint is (length, width) > 0 in metres, got {size!r}")
    return length, width


def polygon_area(polygon: np.ndarray) -> float:
    """Area (m²) of a simple polygon (k, 2) (shoelace; 0 for fewer than 3 points)."""
    p = np.asarray(polygon, dtype=float).reshape(-1, 2)
    if len(p) < 3:
        return 0.0
    return 0.5 * abs(float(np.dot(p[:, 0], np.roll(p[:, 1], -1)) - np.dot(p[:, 1], np.roll(p[:, 0], -1))))


# ----------------------------------------------------------------------------------------------- the world


class World:
    """A 2.5-D building: vertical wall pieces with heights, decorations on their faces, robots' true poses.

    Geometry queries are pure and vectorised; robot registry methods take a lock.
    Attributes (arrays are read-only): name, walls (W, 4), wall_heights (W,), bounds, decorations,
    features (K, 3), feature_descriptors (K, 64) float32, feature_normals (K, 2), feature_walls (K,),
    start_poses {name: (3,)}, routes {name: (M, 2)}, source (the file it came from, or None).
    """

    def __init__(
        self,
        name: str,
        walls: np.ndarray,
        wall_heights: np.ndarray,
        decorations: list[Decoration] | None = None,
        start_poses: dict[str, np.ndarray] | None = None,
        routes: dict[str, np.ndarray] | None = None,
        feature_seed: int = 0,
        source: Path | None = None,
    ) -> None:
        self.name = name
        self.source = source
        self.walls = _readonly(np.array(walls, dtype=float).reshape(-1, 4))
        self.wall_heights = _readonly(np.array(wall_heights, dtype=float).reshape(-1))
        if len(self.wall_heights) != len(self.walls):
            raise ValueError(f"wall_heights has {len(self.wall_heights)} entries for {len(self.walls)} walls")
        self.decorations = list(decorations or [])
        self.start_poses = {k: _readonly(np.array(v, dtype=float)) for k, v in (start_poses or {}).items()}
        self.routes = {k: _readonly(np.array(v, dtype=float)) for k, v in (routes or {}).items()}
        xs, ys = self.walls[:, [0, 2]], self.walls[:, [1, 3]]
        self.bounds = (float(xs.min()), float(ys.min()), float(xs.max()), float(ys.max())) if len(xs) else (0, 0, 0, 0)
        feats, desc, normals, fwalls = _features_from(self.walls, self.decorations, feature_seed)
        self.features = _readonly(feats)
        self.feature_descriptors = _readonly(desc)
        self.feature_normals = _readonly(normals)
        self.feature_walls = _readonly(fwalls)
        # Precomputed segment data for the queries.
        self._a = self.walls[:, :2].copy()
        self._e = self.walls[:, 2:] - self.walls[:, :2]
        self._lock = threading.Lock()
        # held by a virtual robot from reading the others' poses to writing its own, so that two robots stepped by
        # different threads cannot both move into one free place (see ``moving``)
        self._motion_lock = threading.RLock()
        self._robots: dict[str, np.ndarray] = {}
        self._footprints: dict[str, tuple[float, float]] = {}  # length, width (m) of robots that gave theirs
        self._pose_sources: dict[str, Callable[[], np.ndarray]] = {}  # robots whose pose is kept elsewhere

    # ------------------------------------------------------------------ construction
    @classmethod
    def load(cls, path: str | Path | None = None) -> World:
        """Load a world data file (None -> the packaged building). Bad file -> WorldFileError."""
        file = DEFAULT_WORLD_PATH if path is None else Path(path)
        try:
            text = read_bounded(file, MAX_FILE_BYTES).decode("utf-8")   # never waits on a FIFO
        except InputTooLargeError as exc:
            raise WorldFileError(file, "", f"{exc}; a world file has at most {MAX_FILE_BYTES}") from None
        except OSError as exc:
            raise WorldFileError(file, "", f"cannot read: {exc.strerror or exc}") from exc
        except UnicodeDecodeError as exc:
            raise WorldFileError(file, "", f"not UTF-8 text: a world file is JSON text ({exc})") from exc
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as exc:
            raise WorldFileError(file, f"line {exc.lineno} column {exc.colno}", f"invalid JSON: {exc.msg}") from exc
        except RecursionError:
            raise WorldFileError(file, "", "JSON nested too deeply") from None
        except ValueError as exc:  # e.g. an integer of more than 4300 digits
            raise WorldFileError(file, "", f"invalid JSON: {exc}") from None
        return cls.from_dict(doc, source=file)

    @classmethod
    def from_dict(cls, doc: Any, source: str | Path = "<dict>") -> World:
        """Build from an already-decoded document in the file format (validated like a file)."""
        parsed = _parse(doc, source)
        return cls(source=Path(source) if not str(source).startswith("<") else None, **parsed)

    # ------------------------------------------------------------------ geometry
    def raycast(
        self, origins: np.ndarray, angles: np.ndarray, max_range: float | np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """First wall hit along each ray.

        origins (N, 2) or (2,), angles (N,) radians in the world frame, max_range scalar or (N,).
        Returns ranges (N,) metres (max_range where nothing is hit within it) and wall index (N,) int (-1: none).
        """
        angles = np.atleast_1d(np.asarray(angles, dtype=float))
        origins = np.broadcast_to(np.asarray(origins, dtype=float).reshape(-1, 2), (len(angles), 2))
        max_range = np.broadcast_to(np.asarray(max_range, dtype=float), angles.shape)
        ranges = np.array(max_range, dtype=float)
        index = np.full(angles.shape, -1, dtype=np.int64)
        if len(self.walls) == 0:
            return ranges, index
        for start in range(0, len(angles), _RAY_CHUNK):
            sl = slice(start, start + _RAY_CHUNK)
            den, t, u = self._crossings(origins[sl], np.cos(angles[sl]), np.sin(angles[sl]))
            valid = (np.abs(den) > _EPS) & (t >= 0.0) & (u >= -_EPS) & (u <= 1.0 + _EPS)
            t = np.where(valid, t, np.inf)
            best = np.argmin(t, axis=1)
            tbest = t[np.arange(len(best)), best]
            hit = tbest <= max_range[sl]
            ranges[sl] = np.where(hit, tbest, max_range[sl])
            index[sl] = np.where(hit, best, -1)
        return ranges, index

    def _crossings(self, origins: np.ndarray, dx: np.ndarray, dy: np.ndarray):
        """Where the lines o + t·d (origins (n, 2), d = (dx, dy) each (n,)) cross every wall a + u·e.

        Returns den = d × e, t = (a − o) × e / den and u = (a − o) × d / den, each (n, W); den ≈ 0 means
        parallel. Expanded into outer products so no (n, W, 2) temporaries are built.
        """
        ax, ay, ex, ey = self._a[:, 0], self._a[:, 1], self._e[:, 0], self._e[:, 1]
        ox, oy = origins[:, 0], origins[:, 1]
        outer = np.multiply.outer
        den = outer(dx, ey) - outer(dy, ex)
        t_num = (ax * ey - ay * ex)[None, :] - (outer(ox, ey) - outer(oy, ex))
        u_num = outer(dy, ax) - outer(dx, ay) - (ox * dy - oy * dx)[:, None]
        with np.errstate(all="ignore"):
            return den, t_num / den, u_num / den

    def nearest_wall_points(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nearest point on any wall piece to each point (N, 2) or (2,) -> distances (N,), points (N, 2).

        With no walls the distances are inf and the points NaN.
        """
        p = np.asarray(points, dtype=float).reshape(-1, 2)
        if len(self.walls) == 0:
            return np.full(len(p), np.inf), np.full(p.shape, np.nan)
        ap = p[:, None, :] - self._a[None, :, :]  # (N, W, 2)
        ee = np.einsum("wi,wi->w", self._e, self._e)
        s = np.clip(np.einsum("nwi,wi->nw", ap, self._e) / ee, 0.0, 1.0)
        closest = self._a[None] + s[..., None] * self._e[None]  # (N, W, 2)
        dist = np.linalg.norm(p[:, None, :] - closest, axis=2)
        k = np.argmin(dist, axis=1)
        rows = np.arange(len(p))
        return dist[rows, k], closest[rows, k]

    def distance_to_walls(self, points: np.ndarray) -> np.ndarray:
        """Distance from each point (N, 2) or (2,) to the nearest wall piece -> (N,) metres (inf: no walls)."""
        return self.nearest_wall_points(points)[0]

    def collides(self, x: float, y: float, radius: float) -> bool:
        """True when a disc of this radius at (x, y) touches or crosses any wall."""
        return bool(self.distance_to_walls(np.array([x, y]))[0] < radius)

    def line_of_sight(self, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
        """(N,) bool: no wall strictly between p0 (N, 2) or (2,) and p1 (N, 2) in the plan.

        A wall touching an end point (a feature on its own wall) does not block.
        """
        p1 = np.asarray(p1, dtype=float).reshape(-1, 2)
        p0 = np.broadcast_to(np.asarray(p0, dtype=float).reshape(-1, 2), p1.shape)
        if len(self.walls) == 0:
            return np.ones(len(p1), dtype=bool)
        out = np.empty(len(p1), dtype=bool)
        for start in range(0, len(p1), _RAY_CHUNK):
            sl = slice(start, start + _RAY_CHUNK)
            d = p1[sl] - p0[sl]  # (n, 2)
            den, t, u = self._crossings(p0[sl], d[:, 0], d[:, 1])
            length = np.linalg.norm(d, axis=1)[:, None]
            tol = 1e-6 / np.maximum(length, 1e-12)  # a micrometre, as a fraction of the segment
            blocked = (np.abs(den) > _EPS) & (t > tol) & (t < 1.0 - tol) & (u >= -_EPS) & (u <= 1.0 + _EPS)
            out[sl] = ~blocked.any(axis=1)
        return out

    def visible_features(
        self, eye_pose: np.ndarray, eye_height: float, fov: float, max_range: float, vertical_fov: float | None = None
    ) -> np.ndarray:
        """(K,) bool: features a camera at eye_pose (x, y, θ), eye_height metres, could see.

        fov is the horizontal field of view (radians) centred on θ; vertical_fov (optional) limits elevation.
        A feature must face the eye (on the front of its wall), be within max_range and in line of sight.
        """
        x, y, theta = (float(v) for v in np.asarray(eye_pose, dtype=float).reshape(3))
        if len(self.features) == 0:
            return np.zeros(0, dtype=bool)
        rel = self.features[:, :2] - np.array([x, y])
        dist = np.linalg.norm(rel, axis=1)
        bearing = np.arctan2(rel[:, 1], rel[:, 0]) - theta
        bearing = (bearing + np.pi) % (2 * np.pi) - np.pi
        ok = (dist <= max_range) & (dist > 1e-6) & (np.abs(bearing) <= fov / 2)
        ok &= np.einsum("ki,ki->k", -rel, self.feature_normals) > 0.0  # the eye is in front of the face
        if vertical_fov is not None:
            elevation = np.arctan2(self.features[:, 2] - eye_height, np.maximum(dist, 1e-9))
            ok &= np.abs(elevation) <= vertical_fov / 2
        if ok.any():
            idx = np.flatnonzero(ok)
            ok[idx] = self.line_of_sight(np.array([x, y]), self.features[idx, :2])
        return ok

    # ------------------------------------------------------------------ robots (thread-safe)
    def add_robot(self, name: str, pose: np.ndarray, footprint: tuple[float, float] | None = None) -> None:
        """Register a robot's true pose (x, y, θ) and, optionally, its body's footprint (length, width) in metres
        (:func:`footprint_corners`). A name already present -> ValueError."""
        p = np.array(pose, dtype=float).reshape(3)
        size = _footprint(footprint)
        with self._lock:
            if name in self._robots:
                raise ValueError(f"robot {name!r} is already in world {self.name!r}")
            self._robots[name] = p
            if size is not None:
                self._footprints[name] = size

    def attach_robot(self, name: str, source: Callable[[], np.ndarray],
                     footprint: tuple[float, float] | None = None) -> None:
        """Register a robot whose true pose is kept elsewhere (e.g. a virtual robot served by another process):
        ``pose(name)`` and ``robot_poses()`` call ``source()`` for it, and ``set_pose`` refuses it. A name
        already present -> ValueError."""
        size = _footprint(footprint)
        with self._lock:
            if name in self._robots:
                raise ValueError(f"robot {name!r} is already in world {self.name!r}")
            self._robots[name] = np.full(3, np.nan)  # a placeholder: the source is asked instead
            self._pose_sources[name] = source
            if size is not None:
                self._footprints[name] = size

    def remove_robot(self, name: str) -> None:
        """Forget a robot; unknown names are ignored (so closing twice is harmless)."""
        with self._lock:
            self._robots.pop(name, None)
            self._pose_sources.pop(name, None)
            self._footprints.pop(name, None)

    def footprints(self) -> dict[str, tuple[float, float]]:
        """{name: (length, width)} of the registered robots that gave their footprint."""
        with self._lock:
            return dict(self._footprints)

    def moving(self) -> threading.RLock:
        """The lock a robot holds while it looks at the others and moves (``with world.moving(): ...``): a check
        and the move it allows are one step for every other robot of this world."""
        return self._motion_lock

    def set_pose(self, name: str, pose: np.ndarray) -> None:
        """Set a registered robot's true pose; unknown name -> KeyError."""
        p = np.array(pose, dtype=float).reshape(3)
        with self._lock:
            if name not in self._robots:
                raise KeyError(f"no robot {name!r} in world {self.name!r}")
            if name in self._pose_sources:
                raise ValueError(f"robot {name!r}'s pose is kept elsewhere (attach_robot): it cannot be set here")
            self._robots[name] = p

    def pose(self, name: str) -> np.ndarray:
        """A copy of the robot's true pose (3,); unknown name -> KeyError."""
        with self._lock:
            if name not in self._robots:
                raise KeyError(f"no robot {name!r} in world {self.name!r}")
            source = self._pose_sources.get(name)
            if source is None:
                return self._robots[name].copy()
        return np.array(source(), dtype=float).reshape(3)

    def robot_names(self) -> list[str]:
        with self._lock:
            return sorted(self._robots)

    def robot_poses(self) -> dict[str, np.ndarray]:
        """A consistent snapshot {name: (3,)} of every robot's true pose."""
        with self._lock:
            poses = {k: v.copy() for k, v in self._robots.items()}
            sources = dict(self._pose_sources)
        for name, source in sources.items():
            poses[name] = np.array(source(), dtype=float).reshape(3)
        return poses
