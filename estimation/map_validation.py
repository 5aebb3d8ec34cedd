"""What a landmark-map file must hold to be trusted (see :mod:`estimation.landmark_map` for the format).

Bounds (a map past them is refused, not truncated): at most ``MAX_LANDMARKS`` landmarks, descriptors of at
most ``MAX_DESCRIPTOR_SIZE`` floats, ``MAX_ROBOTS`` robots, ``MAX_TRAJECTORY_ROWS`` trajectory rows, JSON fields
of ``MAX_JSON_BYTES``; coordinates within ``MAX_COORDINATE`` metres; covariances symmetric, positive definite
(smallest eigenvalue at least ``MIN_VARIANCE``) and at most ``MAX_VARIANCE`` m² (a landmark known to a
micrometre, or to no better than a kilometre, is a corrupt one; fusion's Kalman update needs them invertible).

The two JSON fields are checked with pydantic models in strict mode: they give each wrong type with its
path (``meta.robots[1]``), refuse unknown keys, and their JSON parser bounds nesting depth (a deeply nested
``metadata`` is an error, not a ``RecursionError``).
"""
from __future__ import annotations

from typing import Annotated, Any

import numpy as np
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, FiniteFloat, ValidationError

from .errors import MapFileError
from .safe_npz import ArraySpec

FORMAT_NAME = "p3at-landmark-map"
FORMAT_VERSION = 1

MAX_LANDMARKS = 2_000_000
MAX_DESCRIPTOR_SIZE = 1024
MAX_ROBOTS = 256
MAX_TRAJECTORY_ROWS = 10_000_000
MAX_JSON_BYTES = 1 << 20
MAX_COORDINATE = 1e6  # m
MIN_VARIANCE = 1e-12  # m²
MAX_VARIANCE = 1e6  # m²
_SYMMETRY_TOLERANCE = 1e-9  # relative to the largest entry
_PSD_TOLERANCE = 1e-9  # a drift covariance may be singular (zero at the start), not negative beyond rounding
MAX_FOOTPRINT_RADIUS = 10.0  # m: a robot whose inscribed disc is wider than 20 m is a corrupt field
CLOCK_KEY = "clock"  # metadata: the name of the trajectory's time base (fusion/colocation.py)
FOOTPRINT_KEY = "footprint_radius_m"  # metadata: the radius of the disc inscribed in the robot's footprint

_FLOAT, _INT, _BOOL, _BYTES = "f", "iu", "b", "u"
MEMBERS: dict[str, ArraySpec] = {
    "format": ArraySpec(_BYTES, (MAX_JSON_BYTES,)),
    "meta": ArraySpec(_BYTES, (MAX_JSON_BYTES,)),
    "positions": ArraySpec(_FLOAT + _INT, (MAX_LANDMARKS, 3)),
    "covariances": ArraySpec(_FLOAT + _INT, (MAX_LANDMARKS, 3, 3)),
    "descriptors": ArraySpec(_FLOAT + _INT, (MAX_LANDMARKS, MAX_DESCRIPTOR_SIZE)),
    "ids": ArraySpec(_INT, (MAX_LANDMARKS,)),
    "counts": ArraySpec(_INT, (MAX_LANDMARKS,)),
    "seen_by": ArraySpec(_BOOL, (MAX_LANDMARKS, MAX_ROBOTS)),
    "trajectory": ArraySpec(_FLOAT + _INT, (MAX_TRAJECTORY_ROWS, 4)),
    # optional, both or neither (session 10; a file without them reads as before): the map frame's drift per landmark
    "drift_covariances": ArraySpec(_FLOAT + _INT, (MAX_LANDMARKS, 3, 3)),
    "drift_origins": ArraySpec(_FLOAT + _INT, (MAX_LANDMARKS, 2)),
    # optional (session 11): the spread of the robot's sightings of each landmark about it
    "sighting_covariances": ArraySpec(_FLOAT + _INT, (MAX_LANDMARKS, 3, 3)),
}
REQUIRED = ("format", "positions", "covariances", "descriptors", "ids", "counts", "meta")

def _printable(name: str) -> str:
    """A name is printed (fuse's report, review, the viewer): a control character in it (a newline, an escape
    sequence's ESC, C1 controls) would add lines or drive the user's terminal."""
    bad = next((c for c in name if not c.isprintable()), None)
    if bad is not None:
        raise ValueError(f"a name is printable text; this one holds the control character {bad!r}")
    return name


_Name = Annotated[str, Field(min_length=1, max_length=256), AfterValidator(_printable)]


class _Header(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid")
    format: str
    version: int


_Int64 = Annotated[int, Field(ge=-(1 << 63), lt=1 << 63)]


class _IdentityConflict(BaseModel):
    """One entry of ``metadata["identity_conflicts"]`` (fusion/merging.py writes them; ``p3at fuse`` prints them)."""

    model_config = ConfigDict(strict=True, extra="allow")
    identity: _Int64
    robot: _Name
    distance_m: FiniteFloat
    mahalanobis_d2: FiniteFloat
    gate_d2: FiniteFloat


class _Metadata(BaseModel):
    """The free-form ``metadata``; only the keys the project reads are typed, the others pass through."""

    model_config = ConfigDict(strict=True, extra="allow")
    true_start_pose: Annotated[list[FiniteFloat], Field(min_length=3, max_length=3)] | None = None
    # what the co-location test (fusion/colocation.py) needs; a map without them is not tested, and says so
    clock: _Name | None = None
    footprint_radius_m: Annotated[FiniteFloat, Field(gt=0.0, le=MAX_FOOTPRINT_RADIUS)] | None = None
    # each landmark's identity (barcode, fiducial; -1 none), read by the alignment (fusion/ransac.py) and the map's
    # fingerprint: whole numbers in int64 (a string, a float, a nested list or a 30-digit number is a corrupt field;
    # a list whose length is not the map's is ignored by the alignment, as documented there)
    external_ids: Annotated[list[_Int64], Field(max_length=MAX_LANDMARKS)] | None = None
    identity_conflicts: Annotated[list[_IdentityConflict], Field(max_length=MAX_LANDMARKS)] | None = None


def colocation_metadata(metadata: dict) -> tuple[str | None, float | None]:
    """(clock, footprint radius m) of a map's ``metadata`` (None where absent), checked as a map file's are:
    ``clock`` names the time base of the trajectory's t column (two maps whose clocks are equal strings share it),
    ``footprint_radius_m`` the radius of the disc inscribed in the robot's footprint about its trajectory's point.
    Raises ValueError with one line for a hostile value (not a string, empty, NaN, negative, zero, huge)."""
    clock, radius = metadata.get(CLOCK_KEY), metadata.get(FOOTPRINT_KEY)
    if clock is not None and not (isinstance(clock, str) and 0 < len(clock) <= 256):
        raise ValueError(f"metadata '{CLOCK_KEY}' names a time base (a string of 1-256 characters); got "
                         f"{repr(clock)[:80]}")
    if radius is not None:
        ok = isinstance(radius, (int, float)) and not isinstance(radius, bool) and np.isfinite(radius) \
            and 0.0 < radius <= MAX_FOOTPRINT_RADIUS
        if not ok:
            raise ValueError(f"metadata '{FOOTPRINT_KEY}' is a radius in metres in (0, {MAX_FOOTPRINT_RADIUS:g}]; got "
                             f"{repr(radius)[:80]}")
        radius = float(radius)
    return clock, radius


class _Meta(BaseModel):
    model_config = ConfigDict(strict=True, extra="forbid")
    robot: _Name = "robot"
    frame: _Name = "map"
    robots: Annotated[list[_Name], Field(min_length=1, max_length=MAX_ROBOTS)] | None = None
    metadata: _Metadata = _Metadata()


def read_map_arrays(arrays: dict[str, np.ndarray], source: str, build: Any) -> Any:
    """Check the arrays of a map file (read by :func:`estimation.safe_npz.read_npz` with :data:`MEMBERS`) and
    return ``build(positions, covariances, descriptors, ids, counts, robot, frame, robots, seen_by, trajectory,
    metadata, drift_covariances, drift_origins, sighting_covariances)`` (the drift pair None when the file has no
    drift, the sightings' spread None when it has none). Raises
    :class:`MapFileError` naming ``source`` and the field."""
    def bad(key: str, problem: str) -> MapFileError:
        return MapFileError(f"{source}: field '{key}' {problem}")

    for key in REQUIRED:
        if key not in arrays:
            raise bad(key, "is missing")
    header = _json(source, "format", arrays["format"], _Header)
    if header.format != FORMAT_NAME:
        raise bad("format", f"is {header.format!r}, not {FORMAT_NAME!r}")
    if header.version != FORMAT_VERSION:
        raise MapFileError(f"{source}: format version {header.version!r} is not supported "
                           f"(this reader knows version {FORMAT_VERSION})")
    meta = _json(source, "meta", arrays["meta"], _Meta)
    robots = meta.robots if meta.robots is not None else [meta.robot]
    if len(set(robots)) != len(robots):
        raise bad("meta.robots", "names a robot twice")

    n = arrays["positions"].shape[0]
    expected = {"positions": (n, 3), "covariances": (n, 3, 3), "ids": (n,), "counts": (n,)}
    for key, shape in expected.items():
        if arrays[key].shape != shape:
            raise bad(key, f"has shape {arrays[key].shape}, expected {shape}")
    if arrays["descriptors"].shape[0] != n:
        raise bad("descriptors", f"has shape {arrays['descriptors'].shape}, expected ({n}, D)")
    seen_by = arrays.get("seen_by")
    if seen_by is not None and seen_by.shape != (n, len(robots)):
        raise bad("seen_by", f"has shape {seen_by.shape}, expected {(n, len(robots))}")

    positions = _floats(arrays["positions"], "positions", bad, MAX_COORDINATE)
    covariances = _floats(arrays["covariances"], "covariances", bad, MAX_VARIANCE)
    descriptors = _floats(arrays["descriptors"], "descriptors", bad, np.finfo(np.float32).max, np.float32)
    trajectory = _floats(arrays.get("trajectory", np.zeros((0, 4))), "trajectory", bad, np.inf)
    if trajectory.size and float(np.max(np.abs(trajectory[:, 1:3]))) > MAX_COORDINATE:
        raise bad("trajectory", f"holds a position beyond {MAX_COORDINATE:.3g} m")
    _check_covariances(covariances, bad)
    ids = _integers(arrays["ids"], "ids", bad)
    if len(np.unique(ids)) != n:
        raise bad("ids", "holds duplicate landmark ids")
    counts = _integers(arrays["counts"], "counts", bad)
    if np.any(counts < 0):
        raise bad("counts", "holds a negative observation count")
    drift = _drift(arrays, n, bad)
    sightings = None
    if "sighting_covariances" in arrays:
        if arrays["sighting_covariances"].shape != (n, 3, 3):
            raise bad("sighting_covariances", f"has shape {arrays['sighting_covariances'].shape}, expected {(n, 3, 3)}")
        sightings = _floats(arrays["sighting_covariances"], "sighting_covariances", bad, MAX_VARIANCE)
        _check_semidefinite(sightings, "sighting_covariances", bad)
    metadata = meta.metadata.model_dump()
    for key in ("true_start_pose", CLOCK_KEY, FOOTPRINT_KEY, "external_ids", "identity_conflicts"):
        if metadata.get(key) is None:
            metadata.pop(key, None)
    try:
        return build(positions, covariances, descriptors, ids, counts, meta.robot, meta.frame, list(robots),
                     seen_by, trajectory, metadata, *drift, sightings)
    except ValueError as exc:
        raise MapFileError(f"{source}: {exc}") from None


def _drift(arrays: dict[str, np.ndarray], n: int, bad) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The optional drift members: (N, 3, 3) symmetric positive semi-definite pose covariances (x, y, θ) and (N, 2)
    positions, both or neither; (None, None) when absent."""
    present = [key for key in ("drift_covariances", "drift_origins") if key in arrays]
    if not present:
        return None, None
    if len(present) == 1:
        other = "drift_origins" if present[0] == "drift_covariances" else "drift_covariances"
        raise bad(other, f"is missing (a map with '{present[0]}' needs both)")
    for key, shape in (("drift_covariances", (n, 3, 3)), ("drift_origins", (n, 2))):
        if arrays[key].shape != shape:
            raise bad(key, f"has shape {arrays[key].shape}, expected {shape}")
    covariances = _floats(arrays["drift_covariances"], "drift_covariances", bad, MAX_VARIANCE)
    origins = _floats(arrays["drift_origins"], "drift_origins", bad, MAX_COORDINATE)
    _check_semidefinite(covariances, "drift_covariances", bad)
    return covariances, origins


def _check_semidefinite(covariances: np.ndarray, key: str, bad) -> None:
    """(N, n, n): symmetric and positive semi-definite up to rounding (may be singular: zero drift at the start, a
    landmark seen once, sightings in a plane)."""
    if not len(covariances):
        return
    scale = _check_symmetric(covariances, key, bad)
    low = np.linalg.eigvalsh(covariances)[:, 0]
    worst = int(np.argmin(low / scale))
    if low[worst] < -_PSD_TOLERANCE * scale[worst]:
        raise bad(f"{key}[{worst}]", f"is not positive semi-definite (eigenvalue {low[worst]:.3g})")


def _check_symmetric(covariances: np.ndarray, key: str, bad) -> np.ndarray:
    """(N, n, n) symmetric up to rounding, relative to each matrix's largest entry; returns those scales."""
    scale = np.maximum(np.abs(covariances).max(axis=(1, 2)), MIN_VARIANCE)
    asymmetry = np.abs(covariances - covariances.transpose(0, 2, 1)).max(axis=(1, 2))
    worst = int(np.argmax(asymmetry / scale))
    if asymmetry[worst] > _SYMMETRY_TOLERANCE * scale[worst]:
        raise bad(f"{key}[{worst}]", f"is not symmetric (asymmetry {asymmetry[worst]:.3g})")
    return scale


def _json(source: str, key: str, raw: np.ndarray, model: type[BaseModel]) -> Any:
    try:
        return model.model_validate_json(raw.tobytes())
    except ValidationError as exc:
        first = exc.errors()[0]
        where = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in first["loc"])
        if first["type"] == "json_invalid":
            raise MapFileError(f"{source}: field '{key}' is not valid JSON ({first['msg']})") from None
        got = "" if first["type"] == "missing" else f" (got {repr(first['input'])[:80]})"
        raise MapFileError(f"{source}: field '{key}{where}': {first['msg']}{got}") from None


def _floats(a: np.ndarray, key: str, bad, bound: float, dtype=np.float64) -> np.ndarray:
    with np.errstate(over="ignore", invalid="ignore"):
        out = a.astype(dtype)
    if not np.all(np.isfinite(out)):
        raise bad(key, "holds non-finite values")
    if out.size and float(np.max(np.abs(out))) > bound:
        raise bad(key, f"holds a value of magnitude {float(np.max(np.abs(out))):.3g}, beyond {bound:.3g}")
    return out


def _integers(a: np.ndarray, key: str, bad) -> np.ndarray:
    info = np.iinfo(np.int64)
    if a.size and (int(a.max()) > info.max or int(a.min()) < info.min):
        raise bad(key, "holds a value outside the 64-bit signed range")
    return a.astype(np.int64)


def _check_covariances(covariances: np.ndarray, bad) -> None:
    """(N, 3, 3): symmetric, every eigenvalue in [MIN_VARIANCE, MAX_VARIANCE]."""
    if not len(covariances):
        return
    _check_symmetric(covariances, "covariances", bad)
    eigenvalues = np.linalg.eigvalsh(covariances)  # ascending, per landmark
    low = int(np.argmin(eigenvalues[:, 0]))
    if eigenvalues[low, 0] < MIN_VARIANCE:
        raise bad(f"covariances[{low}]", f"is not positive definite (smallest eigenvalue "
                                 f"{eigenvalues[low, 0]:.3g} m², need >= {MIN_VARIANCE:g})")
    high = int(np.argmax(eigenvalues[:, -1]))
    if eigenvalues[high, -1] > MAX_VARIANCE:
        raise bad(f"covariances[{high}]", f"has a variance of {eigenvalues[high, -1]:.3g} m², beyond {MAX_VARIANCE:g}")
