"""A small text file read whole, with a bound on its size: the one helper of the runtime's text readers
(TUM trajectories, route files), each raising its own error type with a one-line message naming the file; and what
a path given as a file is when it is not one (:func:`not_a_file`), for the readers of logs and recordings.

The bounded read itself is ``estimation.fileio.read_bounded`` (the drivers call their copy in ``drivers.fileio``:
they import nothing above them).

The bound holds whatever the path is and whatever it does between a look at its size and the read (a file still
being written, a pipe, ``/dev/zero``): at most ``max_bytes + 1`` bytes are ever read. A FIFO that nothing writes to
is not waited on: it reads as empty (``estimation.fileio.open_input``).
"""
from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from estimation.fileio import InputTooLargeError, read_bounded

_ENCODING_NAMES = {"ascii": "ASCII", "utf-8": "UTF-8"}


def read_bounded_text(path: str | os.PathLike, max_bytes: int, what: str, error: Callable[[str], Exception],
                      encoding: str = "utf-8") -> str:
    """The text of ``path`` (at most ``max_bytes`` bytes, decoded with ``encoding``).

    Every failure raises ``error(message)``, one line starting with the path: ``no such <what>``, ``cannot read
    the <what> (<reason>)``, ``N bytes; a <what> has at most M``, ``not a text file (byte K is not UTF-8)``.
    """
    path = Path(path)
    try:
        data = read_bounded(path, max_bytes)   # never waits on a FIFO (a folder: IsADirectoryError)
    except InputTooLargeError as e:
        raise error(f"{path}: {e}; a {what} has at most {max_bytes}") from None
    except FileNotFoundError:
        raise error(f"{path}: no such {what}") from None
    except OSError as e:
        raise error(f"{path}: cannot read the {what} ({e.strerror or e})") from None
    try:
        return data.decode(encoding)
    except UnicodeDecodeError as e:
        name = _ENCODING_NAMES.get(encoding.lower(), encoding)
        raise error(f"{path}: not a text file (byte {e.start} is not {name})") from None


def not_a_file(path: str | os.PathLike, what: str) -> str:
    """Why ``path``, which is not a regular file, cannot be read as a ``what``: "no such <what>", "a link to
    nothing", "a folder, not a <what>", "not a regular file but a FIFO, a device or a socket", or why it cannot be
    looked at."""
    path = Path(path)
    try:
        path.stat()
    except FileNotFoundError:
        return "a link to nothing" if path.is_symlink() else f"no such {what}"
    except OSError as e:
        return f"cannot read it ({e.strerror or e})"
    return f"a folder, not a {what}" if path.is_dir() else "not a regular file but a FIFO, a device or a socket"


__all__ = ["not_a_file", "read_bounded_text"]
