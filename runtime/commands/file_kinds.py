"""Which of the project's files a path holds, by its first bytes, for the one line a command says when it is given
the wrong kind: a map to ``p3at review``, a recording to ``p3at replay`` or ``p3at fuse``, a sensor log to either.
Each reader's own message ("not a Rerun recording (no b'RRF2' stream header)", "InvalidMagic: ... (80, 75, 3, 4,
...)", "not an npz archive: no zip end record") names its format's insides, not the command that reads the file."""
from __future__ import annotations

import os
import stat
from pathlib import Path

_NAMES = {"map": "a landmark map (.npz)", "recording": "a Rerun recording (.rrd)",
          "sensor log": "a sensor log segment (.mcap)"}
_READERS = {"map": "p3at fuse reads maps", "recording": "p3at review reads it and exports the maps it holds",
            "sensor log": "p3at replay reads it"}


def file_kind(path: str | Path) -> str | None:
    """'map', 'recording' or 'sensor log' when the file starts as one does (a map: a zip archive named .npz); None
    for anything else: a folder, a FIFO, a device or a file that cannot be read (never waits for a writer)."""
    head = _head(path, 8)
    if head is None:
        return None
    if head.startswith(b"RRF2"):
        return "recording"
    if head.startswith(b"\x89MCAP"):
        return "sensor log"
    if head.startswith(b"PK\x03\x04") and Path(path).suffix.lower() == ".npz":
        return "map"
    return None


def wrong_kind(path: str | Path, expected: str) -> str | None:
    """'PATH: a Rerun recording (.rrd), not a map: p3at review reads it ...' when ``path`` holds another of the
    project's files than ``expected`` ('map', 'recording' or 'sensor log'); None otherwise (the reader then says
    what it says of anything else)."""
    kind = file_kind(path)
    if kind is None or kind == expected:
        return None
    return f"{path}: {_NAMES[kind]}, not a {expected}: {_READERS[kind]}"


# what a command writes to its --out: how it is named in a refusal, what its file is, the file to give instead
_WRITTEN = {"map": ("a map", "a map is an .npz archive", "MAP.npz"),
            "noise model": ("a noise model (TOML)", "a noise model is TOML", "FILE.toml")}
_HELD = {"map": "a landmark map", "recording": "a Rerun recording", "sensor log": "a sensor log segment",
         "noise model": "a noise model (TOML)"}
_SUFFIX_KINDS = {".npz": ("map", "a landmark map's"), ".rrd": ("recording", "a Rerun recording's"),
                 ".mcap": ("sensor log", "a sensor log's"), ".toml": ("noise model", "a noise model's")}


def out_problem(path: str | Path, writing: str) -> str | None:
    """Why ``writing`` ('map' or 'noise model') must not be written to ``path`` (a command's ``--out``), or None: it
    holds another of the project's files (a map, a Rerun recording, a sensor log, a noise model: by its first bytes),
    or its suffix is another's. Written there, it replaced the file (session 48: ``p3at slam dataset ... --out
    robot1.toml`` over the robot's noise model, ``p3at slam noise ... --out robot1.npz`` over its map, exit 0)."""
    noun, nature, give = _WRITTEN[writing]
    held = "noise model" if _is_noise_model(path) else file_kind(path)
    if held is not None and held != writing:
        return f"--out {path} holds {_HELD[held]}: {noun} would overwrite it; give {give}"
    suffix = Path(path).suffix.lower()
    kind, named = _SUFFIX_KINDS.get(suffix, (writing, ""))
    if kind != writing:
        return f"--out {path}: {suffix} is {named} suffix, and {nature}; give {give}"
    return None


def _is_noise_model(path: str | Path) -> bool:
    head = _head(path, 4096)
    return head is not None and (head.startswith(b"# p3at-fusion noise model")
                                 or b'format = "p3at-noise-model"' in head)


def _head(path: str | Path, size: int) -> bytes | None:
    """The first ``size`` bytes of a regular file; None for anything else (a folder, a FIFO, a device) or a file that
    cannot be read. A FIFO's open waits for a writer (for ever): it is opened non-blocking, and only a regular file
    is read."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except (OSError, ValueError):
        return None
    try:
        return os.read(fd, size) if stat.S_ISREG(os.fstat(fd).st_mode) else None
    except OSError:
        return None
    finally:
        os.close(fd)
