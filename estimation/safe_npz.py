"""Reading ``.npz`` archives without trusting them.

Everything a file claims is checked before it is allocated: the member count and the central directory's
size from the zip's end record, each member's uncompressed size from the zip directory (bounded alone, in
total, and against the file's own size, which refuses zip bombs), each ``.npy`` header's dtype (numbers and
booleans only, never objects, so never pickle) and shape (bounded per axis, and ``prod(shape) * itemsize``
must be exactly the member's size, so a header claiming 10¹² rows is refused without allocating). Only then
is the data read, into one buffer of the size already checked.

The caller gives an :class:`ArraySpec` per member and an error class; every defect raises that class with
one line naming the file and the field.
"""
from __future__ import annotations

import io
import math
import os
import struct
import zipfile
import zlib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

_EOCD = struct.Struct("<4s4H2LH")  # end of central directory record (zip APPNOTE 4.3.16)
_EOCD_SIGNATURE = b"PK\x05\x06"
_MAX_COMMENT = 0xFFFF
_NPY_MAX_HEADER = 10_000  # numpy's own default bound on a .npy header


@dataclass(frozen=True)
class ArraySpec:
    """What one member may hold: dtype kinds (numpy ``dtype.kind`` letters: "f" float, "i"/"u" integer,
    "b" bool), the number of dimensions and an upper bound for each axis."""

    kinds: str
    max_shape: tuple[int, ...]


@dataclass(frozen=True)
class NpzLimits:
    """Bounds on an archive: members, bytes per member and in total, and the decompression ratio allowed past
    ``ratio_floor`` bytes (deflate reaches about 1000:1 on constant data; real maps stay far below 50:1)."""

    max_file_bytes: int = 1 << 30
    max_members: int = 32
    max_total_bytes: int = 512 << 20
    max_ratio: float = 100.0
    ratio_floor: int = 16 << 20


def read_npz(path: str | os.PathLike, specs: Mapping[str, ArraySpec], error: type[Exception],
             limits: NpzLimits = NpzLimits(), what: str = "npz") -> dict[str, np.ndarray]:
    """The arrays of the archive at ``path`` whose names are in ``specs`` (an unknown member is an error).

    Raises ``error`` (one line: file, field, what is wrong) for a missing, unreadable, oversized or malformed
    archive or member. Shapes are only bounded here; how they must agree is the caller's business.
    """
    path = Path(path)
    try:
        size = path.stat().st_size
        if not path.is_file():
            raise error(f"{path}: not a file")
        with open(path, "rb") as fh:
            return _read_archive(fh, size, str(path), specs, error, limits, what)
    except FileNotFoundError:
        raise error(f"{path}: no such {what} file") from None
    except OSError as exc:
        raise error(f"{path}: cannot read ({type(exc).__name__}: {exc})") from None


def read_npz_bytes(data: bytes, name: str, specs: Mapping[str, ArraySpec], error: type[Exception],
                   limits: NpzLimits = NpzLimits(), what: str = "npz") -> dict[str, np.ndarray]:
    """:func:`read_npz` of an archive held in memory (``name`` stands for its file in the messages): a writer
    checks the bytes it is about to write with the very checks its reader will make."""
    return _read_archive(io.BytesIO(data), len(data), name, specs, error, limits, what)


def _read_archive(fh, size: int, path: str, specs: Mapping[str, ArraySpec], error: type[Exception],
                  limits: NpzLimits, what: str) -> dict[str, np.ndarray]:
    try:
        if size > limits.max_file_bytes:
            raise error(f"{path}: {size} bytes, more than the {limits.max_file_bytes} a {what} file may have")
        _check_end_record(fh, size, path, error, limits, what)
        with zipfile.ZipFile(fh) as archive:
            infos = _check_directory(archive, size, specs, path, error, limits)
            return {name: _read_member(archive, info, specs[name], name, path, error)
                    for name, info in infos.items()}
    except zipfile.BadZipFile as exc:
        raise error(f"{path}: not a readable {what} archive ({exc})") from None
    except (OSError, EOFError, zlib.error, NotImplementedError, RuntimeError, UnicodeDecodeError) as exc:
        # UnicodeDecodeError: zipfile decodes a member's local name as UTF-8 when its header's flag says so
        raise error(f"{path}: cannot read ({type(exc).__name__}: {exc})") from None


def _check_end_record(fh, size: int, path: str, error: type[Exception], limits: NpzLimits, what: str) -> None:
    """Member count and central-directory size from the end record, before zipfile parses the directory."""
    tail_size = min(size, _EOCD.size + _MAX_COMMENT)
    fh.seek(size - tail_size)
    tail = fh.read(tail_size)
    at = tail.rfind(_EOCD_SIGNATURE)
    if at < 0 or len(tail) - at < _EOCD.size:
        raise error(f"{path}: not a {what} file (not an npz archive: no zip end record)")
    _, _, _, _, members, directory_size, _, _ = _EOCD.unpack_from(tail, at)
    if members > limits.max_members:  # 0xFFFF (zip64: more than 65535 members) lands here too
        raise error(f"{path}: the archive claims {members} members, more than {limits.max_members}")
    if directory_size > limits.max_members * (46 + 3 * 0xFFFF) or directory_size > size:
        raise error(f"{path}: the archive's directory claims {directory_size} bytes")
    fh.seek(0)


def _check_directory(archive: zipfile.ZipFile, size: int, specs: Mapping[str, ArraySpec], path: str,
                     error: type[Exception], limits: NpzLimits) -> dict[str, zipfile.ZipInfo]:
    infos: dict[str, zipfile.ZipInfo] = {}
    total = 0
    for info in archive.infolist():
        name = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
        if name not in specs:
            raise error(f"{path}: member {info.filename!r} is not a field of this format "
                        f"(known: {', '.join(sorted(specs))})")
        if name in infos:
            raise error(f"{path}: field '{name}' appears twice")
        if info.flag_bits & 0x1:
            raise error(f"{path}: field '{name}' is encrypted")
        if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
            raise error(f"{path}: field '{name}' uses zip compression method {info.compress_type} "
                        "(only stored and deflated are read)")
        total += info.file_size
        if info.file_size > limits.max_total_bytes or total > limits.max_total_bytes:
            raise error(f"{path}: field '{name}' would take the archive past {limits.max_total_bytes} "
                        f"uncompressed bytes ({info.file_size} claimed)")
        infos[name] = info
    if total > limits.ratio_floor and total > limits.max_ratio * size:
        raise error(f"{path}: {total} uncompressed bytes from a {size}-byte file (ratio {total / size:.0f}:1, "
                    f"more than {limits.max_ratio:.0f}:1): refused as a zip bomb")
    return infos


def _read_member(archive: zipfile.ZipFile, info: zipfile.ZipInfo, spec: ArraySpec, name: str, path: str,
                 error: type[Exception]) -> np.ndarray:
    def bad(problem: str) -> Exception:
        return error(f"{path}: field '{name}' {problem}")

    with archive.open(info) as f:
        try:
            version = np.lib.format.read_magic(f)
            if version == (1, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_1_0(f, max_header_size=_NPY_MAX_HEADER)
            elif version == (2, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_2_0(f, max_header_size=_NPY_MAX_HEADER)
            else:
                raise bad(f"has .npy format version {version}, not 1.0 or 2.0")
        except (ValueError, SyntaxError, TypeError, OverflowError) as exc:
            raise bad(f"is not a readable .npy array ({exc})") from None
        header_size = f.tell()
        if dtype.hasobject or dtype.fields is not None or dtype.subdtype is not None or dtype.kind not in spec.kinds:
            raise bad(f"has dtype {dtype.str!r}; expected {_kind_names(spec.kinds)}")
        if len(shape) != len(spec.max_shape):
            raise bad(f"has {len(shape)} dimensions {tuple(shape)}, expected {len(spec.max_shape)}")
        for axis, (n, limit) in enumerate(zip(shape, spec.max_shape, strict=True)):
            if n > limit:
                raise bad(f"claims {n} entries along axis {axis}, more than {limit}")
        nbytes = math.prod(shape) * dtype.itemsize  # Python ints: no overflow
        if header_size + nbytes != info.file_size:
            raise bad(f"header claims shape {tuple(shape)} of {dtype.str} ({nbytes} bytes) but the member holds "
                      f"{info.file_size - header_size} bytes of data")
        buffer = bytearray(nbytes)
        view = memoryview(buffer)
        got = 0
        while got < nbytes:
            n = f.readinto(view[got:])
            if not n:
                raise bad(f"is truncated ({got} of {nbytes} bytes)")
            got += n
    return np.frombuffer(buffer, dtype).reshape(shape, order="F" if fortran else "C")


def _kind_names(kinds: str) -> str:
    names = {"f": "float", "i": "signed integer", "u": "unsigned integer", "b": "bool"}
    return " or ".join(names.get(k, k) for k in kinds)
