"""The fleet's wire format for landmark maps and robot status: versioned, self-describing, no pickle. Pure code.

A message is a frame::

    offset  size  field
    0       4     magic b"P3MW"
    4       1     version (1)
    5       1     kind: 1 full snapshot, 2 delta, 3 status
    6       2     reserved, 0
    8       4     header length H, uint32 little-endian
    12      H     header: UTF-8 JSON object
    12+H    ...   the arrays the header lists, raw little-endian C order, back to back, nothing after them

The header names the sender (``robot``), its ``session`` (random per process start, so a restarted robot's
sequence numbers restart cleanly), the message ``sequence`` (0, 1, 2... per session), the sender's ``stamp`` (s),
the map's ``frame``, ``robots`` and free-form ``metadata``, and ``arrays``: a list of ``[name, dtype, shape]``
with dtype one of ``<f8``, ``<f4``, ``<i8``, ``|u1``. A full snapshot holds the whole map (``positions`` (N, 3),
``covariances`` (N, 3, 3), ``descriptors`` (N, D), ``ids`` (N,), ``counts`` (N,), ``seen_by`` (N, R) as 0/1,
``trajectory`` (T, 4)). A delta holds what changed since the message ``base`` of the same session: ``order``
(the new map's landmark ids, in order), ``removed`` (ids gone), the added or changed rows (``upsert_ids`` and the
five per-landmark arrays), and the trajectory rows from index ``trajectory_from`` on. A status holds no arrays:
``pose`` [x, y, θ] or null, ``landmarks``, ``health`` (a flat JSON object).

:func:`decode` validates everything before anything is used (sizes bounded, known version and kind, names,
dtypes, shapes, finite numbers, unique ids, consistent deltas) and raises :class:`WireError` naming what is wrong.
"""
from __future__ import annotations

import json
import math
import re
import secrets
import struct
from dataclasses import dataclass, field

import numpy as np

from estimation.landmark_map import LandmarkMap

MAGIC = b"P3MW"
VERSION = 1
FULL, DELTA, STATUS = 1, 2, 3
KIND_NAMES = {FULL: "full", DELTA: "delta", STATUS: "status"}
_PREFIX = struct.Struct("<4sBBHI")

# Bounds on what a receiver accepts (a hostile header cannot make it allocate more than these imply).
MAX_MESSAGE_BYTES = 64 * 1024 * 1024
MAX_HEADER_BYTES = 256 * 1024
MAX_LANDMARKS = 100_000
MAX_DESCRIPTOR = 512
MAX_ROBOTS = 64
MAX_TRAJECTORY = 200_000
MAX_SEQUENCE = 2**53 - 1          # exact in JSON numbers
MAX_INT_DIGITS = 300              # any JSON integer in a header: within a float's range (10^308)
ROBOT_NAME = re.compile(r"[A-Za-z0-9_-]{1,64}")  # also a safe Zenoh key chunk (no / * $ # ?)
SESSION = re.compile(r"[0-9a-f]{8,32}")

_DTYPES = {"<f8": np.dtype("<f8"), "<f4": np.dtype("<f4"), "<i8": np.dtype("<i8"), "|u1": np.dtype("|u1")}
# name -> (dtype, shape pattern); "N" landmarks (or K upserted rows in a delta), "D" descriptor size,
# "R" robots, "T" trajectory rows
_FULL_ARRAYS = {
    "positions": ("<f8", ("N", 3)), "covariances": ("<f8", ("N", 3, 3)), "descriptors": ("<f4", ("N", "D")),
    "ids": ("<i8", ("N",)), "counts": ("<i8", ("N",)), "seen_by": ("|u1", ("N", "R")),
    "trajectory": ("<f8", ("T", 4)),
}
_DELTA_ARRAYS = {
    "order": ("<i8", ("N",)), "removed": ("<i8", ("M",)), "upsert_ids": ("<i8", ("K",)),
    "positions": ("<f8", ("K", 3)), "covariances": ("<f8", ("K", 3, 3)), "descriptors": ("<f4", ("K", "D")),
    "counts": ("<i8", ("K",)), "seen_by": ("|u1", ("K", "R")), "trajectory": ("<f8", ("T", 4)),
}


class WireError(ValueError):
    """A received message is malformed, hostile, of an unknown version, or cannot be applied."""


class StaleMessage(WireError):
    """A map older than the one the receiver holds (a query's reply overtaken by updates, or updates overtaken by a
    reply): harmless."""


class MissingBase(WireError):
    """A delta whose base message the receiver does not hold (a message was missed): ask for a snapshot."""


def new_session() -> str:
    """A random session id for one run of a publisher (so that a restart is told apart from a replay)."""
    return secrets.token_hex(8)


@dataclass
class MapDelta:
    """What changed in a map since message ``base`` (landmarks keyed by id; see the module docstring)."""

    order: np.ndarray            # (N,) int64, the new map's ids in order
    removed: np.ndarray          # (M,) int64
    upsert_ids: np.ndarray       # (K,) int64, added or changed
    positions: np.ndarray        # (K, 3)
    covariances: np.ndarray      # (K, 3, 3)
    descriptors: np.ndarray      # (K, D) float32
    counts: np.ndarray           # (K,)
    seen_by: np.ndarray          # (K, R) bool
    trajectory_from: int         # trajectory rows kept from the base
    trajectory: np.ndarray       # (T, 4) rows from trajectory_from on


@dataclass
class Message:
    """One decoded message. ``landmark_map`` for a full snapshot, ``delta`` (and ``base``) for a delta,
    ``status`` for a status."""

    kind: int
    robot: str
    session: str
    sequence: int
    stamp: float
    base: int | None = None
    wall: float | None = None    # the sender's clock (s since the epoch) when the map was made or the status sent
    landmark_map: LandmarkMap | None = None
    delta: MapDelta | None = None
    status: dict = field(default_factory=dict)
    frame: str = "start"
    robots: list[str] = field(default_factory=list)
    metadata: dict = field(default_factory=dict)

    @property
    def kind_name(self) -> str:
        return KIND_NAMES[self.kind]


# -- encoding -----------------------------------------------------------------------------------------------
def _frame(kind: int, header: dict, arrays: list[tuple[str, np.ndarray]]) -> bytes:
    header = dict(header)
    header["arrays"] = [[name, _dtype_name(a), list(a.shape)] for name, a in arrays]
    raw = json.dumps(header, separators=(",", ":"), allow_nan=False).encode()
    parts = [_PREFIX.pack(MAGIC, VERSION, kind, 0, len(raw)), raw]
    parts += [np.ascontiguousarray(a).tobytes() for _, a in arrays]
    return b"".join(parts)


def _dtype_name(a: np.ndarray) -> str:
    for name, dtype in _DTYPES.items():
        if a.dtype == dtype:
            return name
    raise TypeError(f"array of dtype {a.dtype} has no wire dtype")


def _map_header(robot: str, session: str, sequence: int, stamp: float, m: LandmarkMap,
                wall: float | None = None) -> dict:
    header = {"robot": robot, "session": session, "sequence": int(sequence), "stamp": float(stamp),
              "frame": m.frame, "robots": list(m.robots), "metadata": _jsonable(m.metadata)}
    return _with_wall(header, wall)


def _with_wall(header: dict, wall: float | None) -> dict:
    """``wall``: the sender's clock (time.time()) when the map was made or the status sent; optional (a reader
    estimates from it how old what it holds is, docs/fleet.md, session 49)."""
    if wall is not None:
        header["wall"] = float(wall)
    return header


def _jsonable(obj):
    """Metadata as plain JSON: numpy scalars and arrays become numbers and lists, non-finite numbers null (the
    decoder refuses NaN and infinity), anything else its string."""
    plain = json.loads(json.dumps(obj, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))

    def finite(v):
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, list):
            return [finite(x) for x in v]
        if isinstance(v, dict):
            return {k: finite(x) for k, x in v.items()}
        return v
    return finite(plain)


def encode_full(robot: str, session: str, sequence: int, stamp: float, m: LandmarkMap,
                wall: float | None = None) -> bytes:
    """A full snapshot of map ``m`` (``wall``: when it was made, on the sender's clock; optional)."""
    arrays = [("positions", m.positions.astype("<f8")), ("covariances", m.covariances.astype("<f8")),
              ("descriptors", m.descriptors.astype("<f4")), ("ids", m.ids.astype("<i8")),
              ("counts", m.counts.astype("<i8")), ("seen_by", m.seen_by.astype("|u1")),
              ("trajectory", m.trajectory.astype("<f8"))]
    return _frame(FULL, _map_header(robot, session, sequence, stamp, m, wall), arrays)


def can_delta(base: LandmarkMap, new: LandmarkMap) -> bool:
    """A delta needs the same robots columns and descriptor size as its base."""
    return list(base.robots) == list(new.robots) and base.descriptor_size == new.descriptor_size


def encode_delta(robot: str, session: str, sequence: int, base_sequence: int, stamp: float,
                 base: LandmarkMap, new: LandmarkMap, wall: float | None = None) -> bytes:
    """What changed from ``base`` (sent as message ``base_sequence``) to ``new``: rows added or changed (exactly
    compared), ids removed, the new order, and the trajectory from the first row that differs."""
    if not can_delta(base, new):
        raise ValueError("a delta needs the base's robots and descriptor size; send a full snapshot")
    base_row = {int(i): k for k, i in enumerate(base.ids)}
    changed = np.ones(len(new), bool)
    rows = np.array([base_row.get(int(i), -1) for i in new.ids], dtype=np.int64)
    known = rows >= 0
    if known.any():
        b = rows[known]
        same = (np.all(base.positions[b] == new.positions[known], axis=1)
                & np.all(base.covariances[b] == new.covariances[known], axis=(1, 2))
                & np.all(base.descriptors[b] == new.descriptors[known], axis=1)
                & (base.counts[b] == new.counts[known])
                & np.all(base.seen_by[b] == new.seen_by[known], axis=1))
        changed[np.flatnonzero(known)[same]] = False
    removed = np.setdiff1d(base.ids, new.ids).astype("<i8")
    t_base, t_new = base.trajectory, new.trajectory
    common = min(len(t_base), len(t_new))
    differs = np.flatnonzero(np.any(t_base[:common] != t_new[:common], axis=1))
    trajectory_from = int(differs[0]) if len(differs) else common
    header = _map_header(robot, session, sequence, stamp, new, wall)
    header["base"] = int(base_sequence)
    header["trajectory_from"] = trajectory_from
    arrays = [("order", new.ids.astype("<i8")), ("removed", removed), ("upsert_ids", new.ids[changed].astype("<i8")),
              ("positions", new.positions[changed].astype("<f8")),
              ("covariances", new.covariances[changed].astype("<f8")),
              ("descriptors", new.descriptors[changed].astype("<f4")), ("counts", new.counts[changed].astype("<i8")),
              ("seen_by", new.seen_by[changed].astype("|u1")),
              ("trajectory", t_new[trajectory_from:].astype("<f8"))]
    return _frame(DELTA, header, arrays)


def encode_status(robot: str, session: str, sequence: int, stamp: float, pose=None, landmarks: int = 0,
                  health: dict | None = None, has_map: bool = True, wall: float | None = None) -> bytes:
    """A robot's status: its latest pose estimate [x, y, θ] (or None), map size, and health figures.
    ``sequence``: the robot's latest map message (what its queryable answers); ``has_map`` False: it has published
    no map yet (``sequence`` is then 0 and names nothing)."""
    header = {"robot": robot, "session": session, "sequence": int(sequence), "stamp": float(stamp),
              "pose": None if pose is None else [float(v) for v in pose], "landmarks": int(landmarks),
              "health": _jsonable(health or {}), "has_map": bool(has_map)}
    return _frame(STATUS, _with_wall(header, wall), [])


class MapEncoder:
    """The publisher's side: numbers messages, sends a delta against the previous message, and a full
    snapshot every ``full_every`` messages (and whenever a delta is impossible)."""

    def __init__(self, robot: str, session: str | None = None, full_every: int = 10) -> None:
        if not ROBOT_NAME.fullmatch(robot):
            raise ValueError(f"robot name {robot!r} must be 1-64 of A-Z a-z 0-9 _ -")
        if full_every < 1:
            raise ValueError("full_every must be at least 1")
        self.robot = robot
        self.session = session or new_session()
        self.full_every = full_every
        self.sequence = -1
        self.latest: LandmarkMap | None = None
        self.latest_stamp = 0.0
        self.latest_wall: float | None = None

    def encode(self, m: LandmarkMap, stamp: float, full: bool = False,
               wall: float | None = None) -> tuple[int, bytes]:
        """(kind, bytes) of the next message carrying map ``m``; ``full``: a full snapshot whatever the count (the
        message before it will not be sent, so no receiver holds the base a delta would need); ``wall``: when the map
        was made, on this sender's clock (time.time()), carried by it and by the snapshots that answer queries."""
        base, base_sequence = self.latest, self.sequence
        self.sequence += 1
        self.latest, self.latest_stamp, self.latest_wall = m, float(stamp), wall
        if full or base is None or self.sequence % self.full_every == 0 or not can_delta(base, m):
            return FULL, encode_full(self.robot, self.session, self.sequence, stamp, m, wall)
        return DELTA, encode_delta(self.robot, self.session, self.sequence, base_sequence, stamp, base, m, wall)

    def snapshot(self) -> bytes | None:
        """The latest map as a full snapshot with the latest sequence number (what a query is answered)."""
        if self.latest is None:
            return None
        return encode_full(self.robot, self.session, self.sequence, self.latest_stamp, self.latest, self.latest_wall)


# -- decoding -----------------------------------------------------------------------------------------------
def decode(data: bytes | bytearray | memoryview, max_bytes: int = MAX_MESSAGE_BYTES) -> Message:
    """Parse and validate one message; :class:`WireError` says what is wrong with it."""
    data = memoryview(data).cast("B")
    if len(data) > max_bytes:
        raise WireError(f"message of {len(data)} bytes exceeds the {max_bytes}-byte limit")
    if len(data) < _PREFIX.size:
        raise WireError(f"message of {len(data)} bytes is shorter than the {_PREFIX.size}-byte prefix")
    magic, version, kind, reserved, header_len = _PREFIX.unpack_from(data)
    if magic != MAGIC:
        raise WireError(f"magic is {bytes(magic)!r}, not {MAGIC!r}")
    if version != VERSION:
        raise WireError(f"version {version} is not supported (this reader knows version {VERSION})")
    if kind not in KIND_NAMES:
        raise WireError(f"kind {kind} is unknown")
    if reserved != 0:
        raise WireError(f"reserved field is {reserved}, not 0")
    if header_len > MAX_HEADER_BYTES or _PREFIX.size + header_len > len(data):
        raise WireError(f"header length {header_len} exceeds the message or the {MAX_HEADER_BYTES}-byte limit")
    try:
        header = json.loads(bytes(data[_PREFIX.size:_PREFIX.size + header_len]).decode("utf-8"),
                            parse_constant=_reject_constant, parse_int=_bounded_int)
    except WireError:
        raise
    except (ValueError, RecursionError) as e:  # UnicodeDecodeError and JSONDecodeError are ValueErrors
        raise WireError(f"header is not valid JSON ({str(e)[:200]})") from None
    if not isinstance(header, dict):
        raise WireError("header is not a JSON object")
    message = _common_fields(kind, header)
    body = data[_PREFIX.size + header_len:]
    if kind == STATUS:
        if _field(header, "arrays", list) or len(body):
            raise WireError("a status message carries no arrays")
        message.status = _status_fields(header)
        return message
    message.frame = _field(header, "frame", str, limit=256)
    robots = _field(header, "robots", list)
    if not 1 <= len(robots) <= MAX_ROBOTS or not all(isinstance(r, str) and ROBOT_NAME.fullmatch(r) for r in robots):
        raise WireError(f"field 'robots' must list 1-{MAX_ROBOTS} robot names")
    if len(set(robots)) != len(robots):
        raise WireError("field 'robots' names a robot twice")
    message.robots = robots
    message.metadata = _field(header, "metadata", dict)
    arrays = _arrays(header, body, _FULL_ARRAYS if kind == FULL else _DELTA_ARRAYS, len(robots))
    if kind == FULL:
        message.landmark_map = _full_map(message, arrays)
    else:
        message.base = _int_field(header, "base", MAX_SEQUENCE)
        if message.base >= message.sequence:
            raise WireError(f"delta base {message.base} is not before its sequence {message.sequence}")
        message.delta = _delta(header, arrays)
    return message


def _reject_constant(name: str):
    raise WireError(f"header holds the non-finite number {name}")


def _bounded_int(text: str) -> int:
    """A JSON integer a float can hold: a 400-digit one made ``float()`` and ``math.isfinite`` raise OverflowError
    in the field checks (stamp, pose, health, metadata), and 4300 digits made ``int()`` raise ValueError."""
    if len(text) > MAX_INT_DIGITS:
        raise WireError(f"header holds an integer of {len(text)} digits (at most {MAX_INT_DIGITS})")
    return int(text)


def _field(header: dict, key: str, kind: type, limit: int | None = None):
    if key not in header:
        raise WireError(f"field '{key}' is missing")
    value = header[key]
    if not isinstance(value, kind) or isinstance(value, bool) and kind is not bool:
        raise WireError(f"field '{key}' is not a {kind.__name__}")
    if limit is not None and len(value) > limit:
        raise WireError(f"field '{key}' is longer than {limit}")
    return value


def _int_field(header: dict, key: str, maximum: int) -> int:
    value = _field(header, key, int)
    if not 0 <= value <= maximum:
        raise WireError(f"field '{key}' is {value}, outside [0, {maximum}]")
    return value


def _common_fields(kind: int, header: dict) -> Message:
    robot = _field(header, "robot", str, limit=64)
    if not ROBOT_NAME.fullmatch(robot):
        raise WireError(f"field 'robot' {robot[:64]!r} is not a robot name (A-Z a-z 0-9 _ -)")
    session = _field(header, "session", str, limit=32)
    if not SESSION.fullmatch(session):
        raise WireError("field 'session' is not 8-32 lowercase hex digits")
    sequence = _int_field(header, "sequence", MAX_SEQUENCE)
    stamp = header.get("stamp")
    if not isinstance(stamp, int | float) or isinstance(stamp, bool) or not math.isfinite(stamp):
        raise WireError("field 'stamp' is not a finite number")
    wall = header.get("wall")   # optional (senders before session 49 send none)
    if wall is not None and (not isinstance(wall, int | float) or isinstance(wall, bool) or not math.isfinite(wall)):
        raise WireError("field 'wall' is not a finite number")
    return Message(kind, robot, session, sequence, float(stamp), wall=None if wall is None else float(wall))


def _status_fields(header: dict) -> dict:
    pose = header.get("pose")
    if pose is not None and not (isinstance(pose, list) and len(pose) == 3
                                 and all(isinstance(v, int | float) and not isinstance(v, bool)
                                         and math.isfinite(v) for v in pose)):
        raise WireError("field 'pose' is not null or three finite numbers")
    landmarks = _int_field(header, "landmarks", MAX_LANDMARKS)
    health = _field(header, "health", dict)
    has_map = header.get("has_map", True)   # absent (a sender before session 19): its sequence names a map
    if not isinstance(has_map, bool):
        raise WireError("field 'has_map' is not a boolean")
    if len(health) > 64 or not all(isinstance(k, str) and len(k) <= 64 and (
            v is None or isinstance(v, str | bool) or isinstance(v, int | float) and math.isfinite(v))
            for k, v in health.items()):
        raise WireError("field 'health' must be a flat object of at most 64 finite numbers, strings or booleans")
    return {"pose": pose, "landmarks": landmarks, "health": health, "has_map": has_map}


def _arrays(header: dict, body: memoryview, expected: dict, n_robots: int) -> dict[str, np.ndarray]:
    listed = _field(header, "arrays", list)
    if len(listed) != len(expected):
        raise WireError(f"field 'arrays' lists {len(listed)} arrays, expected {len(expected)}")
    dims: dict[str, int] = {"R": n_robots}
    limits = {"R": MAX_ROBOTS, "N": MAX_LANDMARKS, "K": MAX_LANDMARKS, "M": MAX_LANDMARKS, "D": MAX_DESCRIPTOR,
              "T": MAX_TRAJECTORY}
    out: dict[str, np.ndarray] = {}
    offset = 0
    for entry in listed:
        if not (isinstance(entry, list) and len(entry) == 3 and isinstance(entry[0], str)):
            raise WireError("an entry of field 'arrays' is not [name, dtype, shape]")
        name, dtype_name, shape = entry
        if name not in expected or name in out:
            raise WireError(f"array {name[:40]!r} is unknown or listed twice")
        want_dtype, pattern = expected[name]
        if dtype_name != want_dtype:
            raise WireError(f"array '{name}' has dtype {str(dtype_name)[:10]!r}, expected {want_dtype!r}")
        if not (isinstance(shape, list) and len(shape) == len(pattern)
                and all(isinstance(s, int) and not isinstance(s, bool) for s in shape)):
            raise WireError(f"array '{name}' has shape {str(shape)[:40]}, expected {len(pattern)} integers")
        for size, symbol in zip(shape, pattern, strict=True):
            if isinstance(symbol, int):
                if size != symbol:
                    raise WireError(f"array '{name}' has shape {shape}, expected {list(pattern)}")
                continue
            if not 0 <= size <= limits[symbol]:
                raise WireError(f"array '{name}' dimension {symbol}={size} is outside [0, {limits[symbol]}]")
            if dims.setdefault(symbol, size) != size:
                raise WireError(f"array '{name}' has {symbol}={size}, other arrays have {dims[symbol]}")
        dtype = _DTYPES[dtype_name]
        nbytes = dtype.itemsize * math.prod(shape)
        if offset + nbytes > len(body):
            raise WireError(f"array '{name}' needs {nbytes} bytes, {len(body) - offset} left in the message")
        a = np.frombuffer(body, dtype=dtype, count=math.prod(shape), offset=offset).reshape(shape)
        offset += nbytes
        if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
            raise WireError(f"array '{name}' holds non-finite values")
        if dtype_name == "|u1" and np.any(a > 1):
            raise WireError(f"array '{name}' holds values other than 0 and 1")
        out[name] = a
    if offset != len(body):
        raise WireError(f"{len(body) - offset} bytes follow the last array")
    if "counts" in out and np.any(out["counts"] < 0):
        raise WireError("array 'counts' holds negative values")
    return out


def _unique(ids: np.ndarray, name: str) -> None:
    if len(np.unique(ids)) != len(ids):
        raise WireError(f"array '{name}' holds duplicate landmark ids")


def _full_map(message: Message, a: dict[str, np.ndarray]) -> LandmarkMap:
    _unique(a["ids"], "ids")
    return LandmarkMap(a["positions"].astype(np.float64), a["covariances"].astype(np.float64),
                       a["descriptors"].astype(np.float32), a["ids"].astype(np.int64), a["counts"].astype(np.int64),
                       message.robot, message.frame, list(message.robots), a["seen_by"].astype(bool),
                       a["trajectory"].astype(np.float64), dict(message.metadata))


def _delta(header: dict, a: dict[str, np.ndarray]) -> MapDelta:
    for name in ("order", "removed", "upsert_ids"):
        _unique(a[name], name)
    if len(np.intersect1d(a["order"], a["removed"])):
        raise WireError("a delta both keeps and removes a landmark")
    if len(np.setdiff1d(a["upsert_ids"], a["order"])):
        raise WireError("a delta changes a landmark that is not in its order")
    return MapDelta(a["order"].astype(np.int64), a["removed"].astype(np.int64), a["upsert_ids"].astype(np.int64),
                    a["positions"].astype(np.float64), a["covariances"].astype(np.float64),
                    a["descriptors"].astype(np.float32), a["counts"].astype(np.int64), a["seen_by"].astype(bool),
                    _int_field(header, "trajectory_from", MAX_TRAJECTORY), a["trajectory"].astype(np.float64))


def apply_delta(base: LandmarkMap, message: Message) -> LandmarkMap:
    """The map a delta message describes, from the map of its base message; :class:`WireError` when they do not fit."""
    d = message.delta
    if d is None:
        raise WireError("not a delta message")
    if list(base.robots) != list(message.robots):
        raise WireError(f"delta robots {message.robots} differ from its base's {base.robots}")
    if len(d.upsert_ids) and d.descriptors.shape[1] != base.descriptor_size:
        raise WireError(f"delta descriptors have size {d.descriptors.shape[1]}, its base {base.descriptor_size}")
    if len(np.setdiff1d(d.removed, base.ids)):
        raise WireError("a delta removes landmarks its base does not hold")
    if d.trajectory_from > len(base.trajectory) or d.trajectory_from + len(d.trajectory) > MAX_TRAJECTORY:
        raise WireError(f"delta trajectory starts at row {d.trajectory_from}, its base has {len(base.trajectory)}")
    base_row = {int(i): k for k, i in enumerate(base.ids)}
    upsert_row = {int(i): k for k, i in enumerate(d.upsert_ids)}
    source_base, source_upsert = [], []
    for position, i in enumerate(d.order.tolist()):
        if i in upsert_row:
            source_upsert.append((position, upsert_row[i]))
        elif i in base_row:
            source_base.append((position, base_row[i]))
        else:
            raise WireError(f"delta keeps landmark {i}, which its base does not hold")
    if len(source_base) + len(source_upsert) != len(d.order):
        raise WireError("delta order is inconsistent")
    n = len(d.order)
    out = LandmarkMap(np.zeros((n, 3)), np.zeros((n, 3, 3)), np.zeros((n, base.descriptor_size), np.float32),
                      d.order.copy(), np.zeros(n, np.int64), message.robot, message.frame, list(message.robots),
                      np.zeros((n, len(message.robots)), bool),
                      np.concatenate([base.trajectory[:d.trajectory_from], d.trajectory]), dict(message.metadata))
    for rows, source in ((source_base, base), (source_upsert, d)):
        if not rows:
            continue
        dst, src = (np.array(c, dtype=np.int64) for c in zip(*rows, strict=True))
        out.positions[dst] = source.positions[src]
        out.covariances[dst] = source.covariances[src]
        out.descriptors[dst] = source.descriptors[src]
        out.counts[dst] = source.counts[src]
        out.seen_by[dst] = source.seen_by[src]
    return out


class MapStream:
    """The receiver's side for one robot: applies full snapshots and deltas in order, across restarts.

    ``accept`` returns the robot's map after the message, or raises :class:`WireError` when the message cannot be
    applied (a delta whose base this stream does not hold: a missed message; the caller asks for a full snapshot).
    """

    def __init__(self, robot: str) -> None:
        self.robot = robot
        self.session: str | None = None
        self.sequence = -1
        self.stamp = 0.0
        self.map: LandmarkMap | None = None
        self.restarts = 0

    def accept(self, message: Message) -> LandmarkMap:
        if message.robot != self.robot:
            raise WireError(f"message from {message.robot!r} on {self.robot!r}'s stream")
        if message.kind == FULL:
            if message.session == self.session and message.sequence < self.sequence:
                raise StaleMessage(f"stale snapshot {message.sequence} (have {self.sequence})")
            if self.session is not None and message.session != self.session:
                self.restarts += 1  # a new run of the robot: its sequence numbers start again
            self.session, self.sequence = message.session, message.sequence
            self.map, self.stamp = message.landmark_map, message.stamp
            return self.map
        if message.kind != DELTA:
            raise WireError(f"a {message.kind_name} message carries no map")
        if message.session == self.session and message.sequence <= self.sequence and self.map is not None:
            # overtaken (by a snapshot query's reply): older than the map held, not a missed base
            raise StaleMessage(f"stale delta {message.sequence} (have {self.sequence})")
        if message.session != self.session or message.base != self.sequence or self.map is None:
            raise MissingBase(f"delta {message.sequence} needs message {message.base} of session {message.session}, "
                            f"have {self.sequence} of session {self.session}")
        self.map = apply_delta(self.map, message)
        self.session, self.sequence, self.stamp = message.session, message.sequence, message.stamp
        return self.map
