"""Atomic file writes: a reader never sees half a file, a crash (even SIGKILL or a power cut) never loses the old one.

temp file in the same folder -> write -> fsync -> rename over the target -> fsync the folder, so that the rename
itself is on disk when the call returns (without the last step a power cut can leave the old name, or none).

drivers/fileio.py holds the same functions: drivers and estimation are independent packages (import-linter), and
there is no lower one to share. Change both; tests/hardening/test_atomic_write.py runs its tests on both.
"""
from __future__ import annotations

import errno
import os
import stat
import tempfile
from pathlib import Path
from typing import BinaryIO

# mkstemp creates 0600 files; give the final file the permissions open() would (read once: umask is process-wide).
_UMASK = os.umask(0)
os.umask(_UMASK)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path``: temporary file in the same folder, fsync, ``os.replace``, fsync of the folder.

    A path where a FIFO, a device or a socket is raises OSError (EINVAL) and leaves it there: the rename would
    replace it with a plain file (``/dev/null``, for a process allowed to write in /dev)."""
    target = Path(path)
    kind = special_file_kind(target)
    if kind is not None:
        raise OSError(errno.EINVAL, f"not a regular file ({kind}), which the atomic write would replace with a file",
                      str(target))
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_UMASK)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    fsync_folder(target.parent)


def special_file_kind(path: str | os.PathLike) -> str | None:
    """What ``path`` is when it exists but is neither a regular file nor a folder ("a FIFO", "a device", "a
    socket"), following links; None otherwise (nothing there, a file, a folder, a path that cannot be looked at)."""
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):
        return None
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return None


def fsync_folder(folder: str | os.PathLike) -> None:
    """Make the folder's entries (a rename, a new file) durable. A no-op where folders cannot be opened."""
    try:
        fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:  # e.g. Windows: no directory handles; NTFS journals the rename itself
        return
    try:
        os.fsync(fd)
    except OSError as exc:  # some file systems refuse fsync on a folder (EINVAL): nothing more can be done there
        if exc.errno not in (errno.EINVAL, errno.ENOTSUP, errno.EBADF):
            raise
    finally:
        os.close(fd)


def open_input(path: str | os.PathLike) -> BinaryIO:
    """``path`` opened for binary reading without ever waiting: a folder is refused (IsADirectoryError); a FIFO is
    opened without waiting for a writer (a plain ``open`` waits forever), so one that nothing writes to reads as
    empty, while a pipe that is written to (``<(command)``) reads as usual. A device (``/dev/zero``) reads as it
    does: the callers bound what they read."""
    nonblocking = getattr(os, "O_NONBLOCK", 0)  # POSIX; elsewhere open() does not wait on a pipe's writer
    fd = os.open(path, os.O_RDONLY | nonblocking | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_BINARY", 0))
    try:
        if stat.S_ISDIR(os.fstat(fd).st_mode):
            raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), str(path))
        if nonblocking:
            os.set_blocking(fd, True)  # reads wait for data again; only the open must not wait
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


class InputTooLargeError(ValueError):
    """A file larger than its reader takes; the message says how large ("N bytes" or "more than M bytes")."""


def read_bounded(path: str | os.PathLike, max_bytes: int) -> bytes:
    """The bytes of ``path`` (opened by :func:`open_input`: never waits on a FIFO), at most ``max_bytes``: a larger
    regular file is refused by its size before any read, and whatever the path is (a file still growing, a pipe,
    ``/dev/zero``) at most ``max_bytes + 1`` bytes are read. Raises InputTooLargeError, or OSError as ``open`` does."""
    with open_input(path) as stream:
        size = os.fstat(stream.fileno()).st_size
        if size > max_bytes:
            raise InputTooLargeError(f"{size} bytes")
        data = stream.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise InputTooLargeError(f"more than {max_bytes} bytes")
    return data
