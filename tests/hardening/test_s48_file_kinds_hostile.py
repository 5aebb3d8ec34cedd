"""Hostile files given to ``p3at review`` / ``replay`` / ``fuse``, whose kind check (runtime/commands/file_kinds.py,
session 48) reads a path's first bytes before the reader does (session 48, H). A FIFO made that check wait for a
writer for ever: ``open(fifo, "rb")`` blocks, so all three commands hung where they said 'not a regular file' before
the check. Now the check opens without blocking and reads regular files only. Byte-level: any short file, or one
that starts as a map, a recording or an MCAP segment does and then holds garbage or stops, is told apart or left to
the reader, never an exception."""
from __future__ import annotations

import os
import threading

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from runtime.cli import main
from runtime.commands.file_kinds import file_kind, wrong_kind

_MAGICS = [b"", b"RRF2", b"\x89MCAP0\r\n", b"PK\x03\x04"]


def _run_unblocked(argv, fifo):
    """main(argv) in a thread; if it is still waiting after 20 s (a FIFO's open waits for a writer), a writer is
    opened so that it goes on, and the test fails: the command would have hung for ever."""
    out = {}
    thread = threading.Thread(target=lambda: out.setdefault("rc", main(argv)), daemon=True)
    thread.start()
    thread.join(20)
    hung = thread.is_alive()
    if hung:
        fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)   # a reader waits: this open succeeds and frees it
        os.close(fd)
        thread.join(60)
    assert not hung, f"{argv} waited for a writer on the FIFO {fifo}"
    return out.get("rc")


@pytest.mark.parametrize("command, name", [("review", "mission.rrd"), ("replay", "robot1-log_0.mcap"),
                                           ("fuse", "robot1.npz")])
def test_a_fifo_is_refused_without_waiting_for_a_writer(tmp_path, capsys, command, name):
    fifo = tmp_path / name
    os.mkfifo(fifo)
    argv = {"review": ["review", "--no-export", str(fifo)], "replay": ["replay", str(fifo)],
            "fuse": ["fuse", str(fifo), str(tmp_path / "other.npz"), "--out", str(tmp_path / "out.npz")]}[command]
    assert _run_unblocked(argv, fifo) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(fifo) in err[0] and "Traceback" not in err[0], err


def test_special_and_huge_files_are_no_kind(tmp_path):
    sparse = tmp_path / "huge.npz"
    with open(sparse, "wb") as f:
        f.truncate(100 << 30)   # sparse: nothing written
    folder = tmp_path / "folder.rrd"
    folder.mkdir()
    for path in (sparse, folder, "/dev/zero", "/proc/self/mem", tmp_path / "missing.rrd", "a\0b.rrd"):
        assert file_kind(path) is None, path
        assert wrong_kind(path, "map") is None, path


@settings(max_examples=200)
@given(magic=st.sampled_from(_MAGICS), cut=st.integers(0, 8), tail=st.binary(max_size=24),
       suffix=st.sampled_from([".rrd", ".npz", ".mcap", "", ".NPZ"]),
       expected=st.sampled_from(["map", "recording", "sensor log"]))
@example(magic=b"", cut=0, tail=b"", suffix=".rrd", expected="recording")             # empty
@example(magic=b"\x89MCAP0\r\n", cut=4, tail=b"", suffix=".mcap", expected="map")     # a cut magic
@example(magic=b"PK\x03\x04", cut=4, tail=b"\xff" * 3, suffix=".rrd", expected="map")  # a zip not named .npz
def test_any_short_or_damaged_file_gets_a_kind_or_none(tmp_path_factory, magic, cut, tail, suffix, expected):
    data = magic[:cut] + tail
    path = tmp_path_factory.mktemp("k") / f"f{suffix}"
    path.write_bytes(data)
    kind = file_kind(path)
    whole = {"recording": b"RRF2", "sensor log": b"\x89MCAP", "map": b"PK\x03\x04"}
    if kind is None:
        assert not any(data.startswith(m) for k, m in whole.items() if k != "map" or suffix.lower() == ".npz")
    else:
        assert data.startswith(whole[kind])
    line = wrong_kind(path, expected)
    if kind in (None, expected):
        assert line is None
    else:
        assert line.startswith(f"{path}: ") and "\n" not in line and f"not a {expected}: p3at " in line
