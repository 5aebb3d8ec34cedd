"""Reader for CARMEN laser logs (plain or gzip): the FLASER lines.

``FLASER n r1 … rn x y θ odom_x odom_y odom_θ ipc_timestamp hostname logger_timestamp`` — n ranges in
metres over 180° from -90° to +90° in equal steps, the laser pose (x, y, θ) and the odometry pose.  PARAM,
NEFF, ODOM, SYNC, other message lines and ``#`` comments are skipped; a malformed FLASER line raises
:class:`LogFormatError` naming the file and the line number.
"""
from __future__ import annotations

import gzip
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimation.scanmatch.errors import LogFormatError
from estimation.scanmatch.scan import DEFAULT_MAX_RANGE, DEFAULT_MIN_RANGE, Scan2D, laser_angles, laser_scan

_FIELDS_AFTER_RANGES = 9   # x y θ odom_x odom_y odom_θ ipc_timestamp hostname logger_timestamp


@dataclass(frozen=True)
class LaserReading:
    """One FLASER line.

    ranges:    (n,) metres, beams from -90° to +90°
    pose:      (3,) laser pose (x, y, θ) in the log's world frame (for the corrected logs: the SLAM pose)
    odometry:  (3,) raw odometry pose
    timestamp: ipc_timestamp, seconds
    hostname:  the logging host
    line:      line number in the file (1-based)
    """

    ranges: np.ndarray
    pose: np.ndarray
    odometry: np.ndarray
    timestamp: float
    hostname: str
    line: int

    @property
    def angles(self) -> np.ndarray:
        return laser_angles(self.ranges.shape[0])

    def scan(self, min_range: float = DEFAULT_MIN_RANGE, max_range: float = DEFAULT_MAX_RANGE) -> Scan2D:
        """The reading as a 2-D point set in the laser frame (dropouts removed)."""
        return laser_scan(self.ranges, self.angles, min_range=min_range, max_range=max_range)


def parse_flaser(line: str, *, source: str = "<string>", line_number: int = 0) -> LaserReading:
    """One FLASER line -> LaserReading; raises LogFormatError naming ``source:line_number`` and the field."""
    where = f"{source}:{line_number}"
    tokens = line.split()
    if not tokens or tokens[0] != "FLASER":
        raise LogFormatError(f"{where}: not a FLASER line")
    try:
        n = int(tokens[1])
    except (IndexError, ValueError):
        raise LogFormatError(f"{where}: FLASER reading count missing or not an integer") from None
    if n < 2:
        raise LogFormatError(f"{where}: FLASER reading count {n} is below 2")
    expected = 2 + n + _FIELDS_AFTER_RANGES
    if len(tokens) != expected:
        raise LogFormatError(f"{where}: FLASER with {n} readings needs {expected} fields, got {len(tokens)}")
    try:
        ranges = np.array(tokens[2:2 + n], dtype=float)
    except ValueError:
        raise LogFormatError(f"{where}: a FLASER range is not a number") from None
    names = ("x", "y", "theta", "odom_x", "odom_y", "odom_theta", "ipc_timestamp")
    values = []
    for offset, name in enumerate(names):
        token = tokens[2 + n + offset]
        try:
            values.append(float(token))
        except ValueError:
            raise LogFormatError(f"{where}: FLASER field {name} is not a number: {token!r}") from None
    if not (np.all(np.isfinite(ranges)) and np.all(np.isfinite(values))):
        raise LogFormatError(f"{where}: FLASER line holds a non-finite number")
    if np.any(ranges < 0.0):
        raise LogFormatError(f"{where}: FLASER range is negative")
    return LaserReading(ranges=ranges, pose=np.array(values[0:3]), odometry=np.array(values[3:6]),
                        timestamp=values[6], hostname=tokens[2 + n + 7], line=line_number)


def iter_laser(path: str | Path) -> Iterator[LaserReading]:
    """The FLASER readings of a CARMEN log (``.gz`` read directly), in file order."""
    path = Path(path)
    opener = gzip.open if path.suffix == ".gz" else open
    try:
        with opener(path, "rt", encoding="ascii", errors="strict") as stream:
            for line_number, line in enumerate(stream, start=1):
                if line.startswith("FLASER"):
                    yield parse_flaser(line, source=str(path), line_number=line_number)
    except (OSError, EOFError, UnicodeDecodeError) as error:
        raise LogFormatError(f"{path}: cannot read the log: {error}") from error


def read_laser_log(path: str | Path) -> list[LaserReading]:
    """All FLASER readings of a CARMEN log; raises LogFormatError if there are none."""
    readings = list(iter_laser(path))
    if not readings:
        raise LogFormatError(f"{path}: no FLASER lines")
    return readings
