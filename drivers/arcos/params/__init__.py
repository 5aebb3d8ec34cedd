"""Robot parameter sets as data files (``p3at.json``, ``p3at-sh.json``) and their loader (pure, no device I/O).

A file holds ARIA's conversion factors under ARIA's names (so values can be copied from ARIA's ``params/*.p``:
mm, angle units, degrees) and everything else in SI. The SYNC2 subtype selects the built-in set; a user may
load their own file with :func:`load_params`.
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from drivers.errors import BadFileError, DeviceNotFoundError
from drivers.fileio import InputTooLargeError, read_bounded

FORMAT = "p3at-fusion/arcos-params"
VERSION = 1
MAX_FILE_BYTES = 1 << 20  # the built-in files are ~2 kB
MAX_SONARS = 256  # the SIP numbers sonars with one byte
MAX_NUMBER = 1e6  # every factor, size and limit of a ground robot is far below (and stays finite in products)
BUILTIN_DIR = Path(__file__).resolve().parent


@dataclass(frozen=True)
class RobotParams:
    """One robot model's constants. ``sonar_poses``: (N, 3) tuples of (x m, y m, heading rad) in the robot frame."""

    robot_type: str
    subtype: str
    dist_conv_factor: float  # mm per position unit (XPOS, YPOS, MOVE)
    angle_conv_factor: float  # rad per angle unit (THPOS, CONTROL)
    vel_conv_factor: float  # mm/s per velocity unit (LVEL, RVEL)
    range_conv_factor: float  # mm per sonar range unit
    diff_conv_factor: float  # rad/s per mm/s of (right - left) / 2, when the SIP has no ROTVEL
    vel2_divisor: float  # mm/s per VEL2 unit
    radius_m: float
    width_m: float
    length_m: float
    max_velocity_m_s: float
    max_rot_velocity_rad_s: float
    max_accel_m_s2: float
    max_rot_accel_rad_s2: float
    sonar_max_range_m: float
    sonar_poses: tuple[tuple[float, float, float], ...]
    source: str = "<builtin>"  # the file it came from

    @property
    def sonar_count(self) -> int:
        return len(self.sonar_poses)


# file key -> (attribute, must be strictly positive)
_NUMBER_FIELDS: dict[str, tuple[str, bool]] = {
    "DistConvFactor": ("dist_conv_factor", True),
    "AngleConvFactor": ("angle_conv_factor", True),
    "VelConvFactor": ("vel_conv_factor", True),
    "RangeConvFactor": ("range_conv_factor", True),
    "DiffConvFactor": ("diff_conv_factor", True),
    "Vel2Divisor": ("vel2_divisor", True),
    "radius_m": ("radius_m", True),
    "width_m": ("width_m", True),
    "length_m": ("length_m", True),
    "max_velocity_m_s": ("max_velocity_m_s", True),
    "max_rot_velocity_rad_s": ("max_rot_velocity_rad_s", True),
    "max_accel_m_s2": ("max_accel_m_s2", True),
    "max_rot_accel_rad_s2": ("max_rot_accel_rad_s2", True),
    "sonar_max_range_m": ("sonar_max_range_m", True),
}
_STRING_FIELDS = {"robot_type": "robot_type", "subtype": "subtype"}
_IGNORED = {"format", "version", "_comment"}


def _field_line(text: str, key: str) -> int:
    """Line number of ``"key"`` in the JSON text, for error messages (1 if not found)."""
    index = text.find(f'"{key}"')
    return text.count("\n", 0, index) + 1 if index >= 0 else 1


def parse_params(text: str, source: str = "<string>") -> RobotParams:
    """Parse and validate a parameter file's text. Raises :class:`BadFileError` naming source, line and field."""
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise BadFileError(f"{source}:{exc.lineno}: not valid JSON: {exc.msg}") from exc
    except RecursionError:
        raise BadFileError(f"{source}:1: not valid JSON: nested too deeply") from None
    except ValueError as exc:  # e.g. an integer of more than 4300 digits
        raise BadFileError(f"{source}:1: not valid JSON: {exc}") from None
    if not isinstance(data, dict):
        raise BadFileError(f"{source}:1: a parameter file is a JSON object")

    def fail(key: str, why: str) -> BadFileError:
        return BadFileError(f"{source}:{_field_line(text, key)}: field {key!r}: {why}")

    if data.get("format", FORMAT) != FORMAT:
        raise fail("format", f"expected {FORMAT!r}, got {data.get('format')!r}")
    if data.get("version", VERSION) != VERSION:
        raise fail("version", f"unsupported version {data.get('version')!r} (this reader knows {VERSION})")
    known = set(_NUMBER_FIELDS) | set(_STRING_FIELDS) | {"sonar_poses"} | _IGNORED
    for key in data:
        if key not in known:
            raise fail(key, f"unknown field (known: {', '.join(sorted(known - _IGNORED))})")
    values: dict[str, Any] = {}
    for key, attr in _STRING_FIELDS.items():
        value = data.get(key)
        if not isinstance(value, str) or not value:
            raise fail(key, "missing or not a non-empty string")
        values[attr] = value
    for key, (attr, positive) in _NUMBER_FIELDS.items():
        if key not in data:
            raise fail(key, "missing")
        value = data[key]
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise fail(key, f"must be a finite number, got {repr(value)[:60]}")
        if abs(value) > MAX_NUMBER:
            raise fail(key, f"{value:g} is beyond ±{MAX_NUMBER:g}")
        if positive and value <= 0:
            raise fail(key, f"must be > 0, got {value!r}")
        values[attr] = float(value)
    poses = data.get("sonar_poses")
    if not isinstance(poses, list) or len(poses) > MAX_SONARS:
        raise fail("sonar_poses", f"missing or not a list of at most {MAX_SONARS} [x, y, heading] triples")
    checked = []
    for i, pose in enumerate(poses):
        if (not isinstance(pose, list) or len(pose) != 3
                or not all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                           and abs(v) <= MAX_NUMBER for v in pose)):
            raise fail("sonar_poses", f"entry {i} must be [x m, y m, heading rad], got {repr(pose)[:60]}")
        checked.append((float(pose[0]), float(pose[1]), float(pose[2])))
    values["sonar_poses"] = tuple(checked)
    return RobotParams(**values, source=source)


def load_params(path: str | os.PathLike) -> RobotParams:
    """Load a parameter file (the built-ins or the user's own)."""
    path = Path(path)
    try:
        text = read_bounded(path, MAX_FILE_BYTES).decode("utf-8")   # never waits on a FIFO
    except InputTooLargeError as exc:
        raise BadFileError(f"{path}: {exc}; a parameter file has at most {MAX_FILE_BYTES}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise BadFileError(f"{path}: cannot read parameter file: {exc}") from exc
    return parse_params(text, str(path))


def _normalise(subtype: str) -> str:
    return subtype.strip().lower().replace("_", "-")


def builtin_subtypes() -> list[str]:
    return sorted(p.stem for p in BUILTIN_DIR.glob("*.json"))


def builtin_params(subtype: str) -> RobotParams:
    """The built-in set for a SYNC2 subtype (case-insensitive; ``p3atsh`` = ``p3at-sh``).

    Raises :class:`LookupError` (a :class:`drivers.errors.DeviceNotFoundError`) for an unknown subtype.
    """
    wanted = _normalise(subtype)
    for name in builtin_subtypes():
        if wanted in (name, name.replace("-", "")):
            return load_params(BUILTIN_DIR / f"{name}.json")
    raise DeviceNotFoundError(
        f"no built-in parameter set for robot subtype {subtype!r} (built in: {', '.join(builtin_subtypes())}); "
        "pass params=load_params(FILE) with your robot's own file"
    )
