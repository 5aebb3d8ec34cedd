"""Whitespace-separated numeric tables (``.dat`` or ``.dat.gz``), read with bounded memory and checked line by line.

A table has a fixed number of numeric columns per line; blank lines and lines starting with ``#`` are skipped.
Memory is bounded whatever the file claims or holds: at most ``max_rows`` rows and ``max_line`` characters per
line are ever read (a gzip bomb or a file without newlines stops at the bound with an error), and time too: at most
``MAX_LINES`` lines of any kind (a gzip of blank lines). Every defect is
one :class:`DatasetError` line naming the file, the line and the field.
"""
from __future__ import annotations

import gzip
import io
import zlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from estimation.fileio import open_input

from .errors import DatasetError

MAX_LINE = 4096           # characters: far above any numeric row of these formats
MAX_ROWS = 5_000_000      # rows per table: 5 M × 5 columns × 8 B = 200 MB at most
# lines of any kind (rows, comments, blank): a 200 kB gzip of 200 M newlines kept the reader busy for 77 s before
# it said "fewer than 2 rows"; 10 M lines take a few seconds
MAX_LINES = 2 * MAX_ROWS
# integer fields (ids, barcodes) up to 2^31 - 1: 1e20 passed the integer check and its cast to int64 gave a
# RuntimeWarning on stderr and a wrong id (session 25)
MAX_INTEGER = 2**31 - 1
_CHUNK = 65536            # rows converted at once (one numpy call; per-line checks only when it fails)


def find_table(folder: Path, stem: str) -> Path:
    """``folder/stem.dat`` or else ``folder/stem.dat.gz``; a DatasetError naming both if neither is a file."""
    for name in (f"{stem}.dat", f"{stem}.dat.gz"):
        if (folder / name).is_file():
            return folder / name
    for name in (f"{stem}.dat", f"{stem}.dat.gz"):  # there, but a folder, a FIFO or a link to nothing
        if (folder / name).is_symlink() or (folder / name).exists():
            return folder / name                      # read_table names what it is
    raise DatasetError(f"{folder}: neither {stem}.dat nor {stem}.dat.gz is there")


def read_table(path: Path, columns: Sequence[str], *, max_rows: int = MAX_ROWS, max_line: int = MAX_LINE,
               integer_columns: Sequence[str] = (), until: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rows (R, len(columns)) float64 of a numeric table and their 1-based line numbers (R,) int64.

    Non-finite numbers are refused; columns in ``integer_columns`` must hold integers. ``until``: stop before
    the first row whose first column exceeds it (a time-sorted table's prefix, read without the rest).
    """
    path = Path(path)
    k = len(columns)
    rows: list[np.ndarray] = []
    line_numbers: list[np.ndarray] = []
    tokens: list[list[str]] = []
    numbers: list[int] = []
    total = 0
    try:
        with _open_text(path) as stream:
            line_number = 0
            while True:
                line = stream.readline(max_line + 1)
                if not line:
                    break
                line_number += 1
                if len(line) > max_line and not line.endswith("\n"):
                    raise DatasetError(f"{path}:{line_number}: line longer than {max_line} characters")
                if line_number > MAX_LINES:
                    raise DatasetError(f"{path}:{line_number}: more than {MAX_LINES} lines (the reader's bound)")
                fields = line.split()
                if not fields or fields[0].startswith("#"):
                    continue
                if len(fields) != k:
                    raise DatasetError(f"{path}:{line_number}: {len(fields)} fields, expected {k} "
                                       f"({' '.join(columns)})")
                total += 1
                if total > max_rows:
                    raise DatasetError(f"{path}:{line_number}: more than {max_rows} rows (the reader's bound)")
                tokens.append(fields)
                numbers.append(line_number)
                if len(tokens) == _CHUNK:
                    rows.append(_convert(path, tokens, numbers, columns, integer_columns))
                    line_numbers.append(np.array(numbers, np.int64))
                    tokens, numbers = [], []
                    if until is not None and rows[-1][-1, 0] > until:
                        break
    except (OSError, EOFError, zlib.error, UnicodeDecodeError) as error:
        # gzip.BadGzipFile is an OSError; a truncated gzip stream raises EOFError
        raise DatasetError(f"{path}: cannot read the file ({error})") from None
    if tokens:
        rows.append(_convert(path, tokens, numbers, columns, integer_columns))
        line_numbers.append(np.array(numbers, np.int64))
    if not rows:
        return np.zeros((0, k)), np.zeros(0, np.int64)
    table, lines = np.concatenate(rows), np.concatenate(line_numbers)
    if until is not None:
        beyond = np.flatnonzero(table[:, 0] > until)
        if len(beyond):
            table, lines = table[: beyond[0]], lines[: beyond[0]]
    return table, lines


def _open_text(path: Path) -> io.TextIOBase:
    try:
        raw = open_input(path)  # never waits on a FIFO (a folder: IsADirectoryError)
    except FileNotFoundError:
        raise DatasetError(f"{path}: no such file") from None
    except OSError as error:
        raise DatasetError(f"{path}: cannot read the file ({error.strerror or error})") from None
    magic = raw.peek(2)[:2]  # not read: a pipe cannot seek back
    if magic == b"\x1f\x8b":  # by content, not by name: a .dat that is really gzip still reads
        return io.TextIOWrapper(_ClosingGzip(fileobj=raw, mode="rb"), encoding="ascii", errors="strict", newline=None)
    return io.TextIOWrapper(raw, encoding="ascii", errors="strict", newline=None)


class _ClosingGzip(gzip.GzipFile):
    """A GzipFile that closes the file it was given (``gzip.open`` of a path does; of a file object, not)."""

    def close(self) -> None:
        fileobj = self.fileobj
        try:
            super().close()
        finally:
            if fileobj is not None:
                fileobj.close()


def _convert(path: Path, tokens: list[list[str]], numbers: list[int], columns: Sequence[str],
             integer_columns: Sequence[str]) -> np.ndarray:
    try:
        values = np.array(tokens, dtype=np.float64)
    except (ValueError, OverflowError):
        values = None
    if values is None or not np.all(np.isfinite(values)):
        _explain(path, tokens, numbers, columns)
    for name in integer_columns:
        column = values[:, list(columns).index(name)]
        bad = np.flatnonzero((column != np.round(column)) | (np.abs(column) > MAX_INTEGER))
        if len(bad):
            i, token = int(bad[0]), tokens[int(bad[0])][list(columns).index(name)]
            if abs(column[i]) > MAX_INTEGER:
                raise DatasetError(f"{path}:{numbers[i]}: field {name} is out of range ({token[:40]}; at most "
                                   f"{MAX_INTEGER} in magnitude)")
            raise DatasetError(f"{path}:{numbers[i]}: field {name} is not an integer: {token[:40]!r}")
    return values


def _explain(path: Path, tokens: list[list[str]], numbers: list[int], columns: Sequence[str]) -> None:
    """Find the first bad field of a chunk that failed to convert and raise its one-line error."""
    for fields, number in zip(tokens, numbers, strict=True):
        for name, token in zip(columns, fields, strict=True):
            try:
                value = float(token)
            except ValueError:
                raise DatasetError(f"{path}:{number}: field {name} is not a number: {token[:40]!r}") from None
            if not np.isfinite(value):
                raise DatasetError(f"{path}:{number}: field {name} is not finite: {token[:40]!r}")
    raise DatasetError(f"{path}: a value could not be converted")  # unreachable: float() and numpy agree
