"""Reader for CARMEN laser logs (plain or gzip): the FLASER lines.

``FLASER n r1 … rn x y θ odom_x odom_y odom_θ ipc_timestamp hostname logger_timestamp`` — n ranges in
metres over 180° from -90° to +90° in equal steps, the laser pose (x, y, θ) and the odometry pose.  PARAM,
NEFF, ODOM, SYNC, other message lines and ``#`` comments are skipped; a malformed FLASER line raises
:class:`LogFormatError` naming the file and the line number.

Bounds: a line of at most ``MAX_LINE_BYTES`` (read no further: a file without newlines cannot fill the
memory), at most ``MAX_BEAMS`` ranges per line, at most ``MAX_READINGS`` readings per log (a plain or
decompressed log past it is refused, not truncated), at most ``MAX_LINES`` lines of any kind (a small gzip of
blank lines cannot keep the reader busy for minutes).

Damage: :func:`read_laser_log` raises :class:`TruncatedLogError` (a LogFormatError) for a log that cannot be
read to its end, whether the stream breaks (a ``.gz`` corrupted or cut in the middle: ``zlib.error``, a bad
CRC, EOF) or a FLASER line is malformed (which is what a corrupted ``.gz`` usually decompresses to). The
message names the file and the line; the error carries the readings before the damage (``.readings``), which
a caller may choose to use (``p3at scanmatch --allow-truncated`` does, and says so). Nothing is skipped
silently.
"""
from __future__ import annotations

import gzip
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimation.fileio import open_input
from estimation.scanmatch.errors import LogFormatError
from estimation.scanmatch.scan import DEFAULT_MAX_RANGE, DEFAULT_MIN_RANGE, Scan2D, laser_angles, laser_scan

_FIELDS_AFTER_RANGES = 9   # x y θ odom_x odom_y odom_θ ipc_timestamp hostname logger_timestamp
MAX_LINE_BYTES = 1 << 20  # a FLASER line of MAX_BEAMS ranges is under 100 kB
MAX_BEAMS = 8192
MAX_READINGS = 500_000  # the MIT/Intel/ACES logs hold 5,000 - 30,000
# lines of any kind (ODOM, PARAM, ... beside FLASER; blank): a 300 kB gzip of 300 M newlines kept the reader busy
# for minutes (over 120 s) before it said "no FLASER lines"; 10 M lines take a few seconds
MAX_LINES = 20 * MAX_READINGS


class TruncatedLogError(LogFormatError):
    """The log could not be read to its end; ``readings`` holds the FLASER readings before the damage (filled
    by :func:`read_laser_log`) and ``line`` the number of lines read whole."""

    def __init__(self, message: str, readings: list[LaserReading], line: int) -> None:
        super().__init__(message)
        self.readings = readings
        self.line = line


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
    if not 2 <= n <= MAX_BEAMS:
        raise LogFormatError(f"{where}: FLASER reading count {n} is not in 2..{MAX_BEAMS}")
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
    """The FLASER readings of a CARMEN log (``.gz`` read directly), in file order.

    Raises LogFormatError for a malformed line and for a log that cannot be read to its end (after yielding
    what came before the damage)."""
    path = Path(path)
    try:
        file = open_input(path)  # never waits on a FIFO (a folder: IsADirectoryError)
    except FileNotFoundError:
        raise LogFormatError(f"{path}: no such log file") from None
    except OSError as error:
        raise LogFormatError(f"{path}: cannot read the log ({error.strerror or error})") from None
    line_number = 0
    try:
        with file, (gzip.GzipFile(fileobj=file, mode="rb") if path.suffix == ".gz" else file) as stream:
            while True:
                raw = stream.readline(MAX_LINE_BYTES + 1)
                if not raw:
                    return
                line_number += 1
                if len(raw) > MAX_LINE_BYTES:
                    raise LogFormatError(f"{path}:{line_number}: line longer than {MAX_LINE_BYTES} bytes")
                if line_number > MAX_LINES:
                    raise LogFormatError(f"{path}:{line_number}: more than {MAX_LINES} lines (the reader's bound; "
                                         "split the log)")
                if raw.startswith(b"FLASER"):
                    yield parse_flaser(raw.decode("ascii"), source=str(path), line_number=line_number)
    except UnicodeDecodeError as error:
        raise LogFormatError(f"{path}:{line_number}: not ASCII text ({error.reason} at byte {error.start})") from None
    except (OSError, EOFError, zlib.error) as error:
        where = f"after line {line_number}" if line_number else "at the start"
        raise TruncatedLogError(f"{path}: cannot read the log {where} ({type(error).__name__}: {error})", [],
                                line_number) from None


def read_laser_log(path: str | Path, limit: int | None = None) -> list[LaserReading]:
    """The FLASER readings of a CARMEN log (the first ``limit`` if given); raises LogFormatError if there are
    none, TruncatedLogError (with the readings before the damage) if the file is damaged before its end."""
    readings: list[LaserReading] = []
    iterator = iter_laser(path)
    try:
        for reading in iterator:
            readings.append(reading)
            if limit is not None and len(readings) >= limit:
                break
            if len(readings) > MAX_READINGS:
                raise LogFormatError(f"{path}: more than {MAX_READINGS} FLASER readings (split the log)")
    except LogFormatError as error:  # a damaged stream or a malformed line: the log is unusable from there on
        if not readings:
            raise
        line = error.line if isinstance(error, TruncatedLogError) else (readings[-1].line if readings else 0)
        raise TruncatedLogError(f"{error} ({len(readings)} readings before it)", readings, line) from None
    finally:
        iterator.close()
    if not readings:
        raise LogFormatError(f"{path}: no FLASER lines")
    return readings
