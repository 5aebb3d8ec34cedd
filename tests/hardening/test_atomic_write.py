"""Atomic writes in both layers: temp + fsync + rename + fsync of the folder, and SIGKILL at any moment leaves
either the old file or the new one, never half of one."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import drivers.fileio
import estimation.fileio

MODULES = [estimation.fileio, drivers.fileio]


@pytest.mark.parametrize("module", MODULES, ids=lambda m: m.__name__)
def test_the_file_is_synced_then_renamed_then_the_folder_is_synced(module, tmp_path, monkeypatch) -> None:
    calls: list[tuple[str, str]] = []
    real_fsync, real_replace, real_open = os.fsync, os.replace, os.open
    names: dict[int, str] = {}

    def record_open(path, flags, *args):
        fd = real_open(path, flags, *args)
        names[fd] = str(path)
        return fd

    def record_fsync(fd):
        target = names.get(fd, "file")
        calls.append(("fsync", "folder" if target == str(tmp_path / "sub") else "file"))
        return real_fsync(fd)

    def record_replace(src, dst):
        calls.append(("replace", Path(dst).name))
        return real_replace(src, dst)

    monkeypatch.setattr(os, "open", record_open)
    monkeypatch.setattr(os, "fsync", record_fsync)
    monkeypatch.setattr(os, "replace", record_replace)
    module.atomic_write_bytes(tmp_path / "sub" / "out.bin", b"payload")
    assert calls == [("fsync", "file"), ("replace", "out.bin"), ("fsync", "folder")]
    assert (tmp_path / "sub" / "out.bin").read_bytes() == b"payload"
    assert [p.name for p in (tmp_path / "sub").iterdir()] == ["out.bin"]


@pytest.mark.parametrize("module", MODULES, ids=lambda m: m.__name__)
def test_a_failed_write_keeps_the_old_file_and_leaves_no_temporary(module, tmp_path, monkeypatch) -> None:
    target = tmp_path / "out.bin"
    module.atomic_write_bytes(target, b"old")

    def broken_fsync(fd):
        raise OSError(5, "Input/output error")
    monkeypatch.setattr(os, "fsync", broken_fsync)
    with pytest.raises(OSError):
        module.atomic_write_bytes(target, b"new")
    assert target.read_bytes() == b"old" and [p.name for p in tmp_path.iterdir()] == ["out.bin"]


WRITER = """
import sys
from {module} import atomic_write_bytes
path, n = sys.argv[1], 0
while True:
    n += 1
    atomic_write_bytes(path, (b"A" if n % 2 else b"B") * 2_000_000)
"""


@pytest.mark.parametrize("module", MODULES, ids=lambda m: m.__name__)
def test_sigkill_during_writes_leaves_a_whole_file(module, tmp_path) -> None:
    target = tmp_path / "out.bin"
    proc = subprocess.Popen([sys.executable, "-c", WRITER.format(module=module.__name__), str(target)],
                            cwd=Path(__file__).resolve().parents[2])
    try:
        # Kill after a varying number of writes: wherever it lands (mid-write, mid-rename, between), the target
        # must be whole. Waiting for the file to exist is event-driven; the extra 0-50 ms only varies the moment.
        deadline = time.monotonic() + 60
        while not target.exists():
            assert proc.poll() is None and time.monotonic() < deadline, "the writer never wrote"
            time.sleep(0.01)
        time.sleep(0.05)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    data = target.read_bytes()
    assert data in (b"A" * 2_000_000, b"B" * 2_000_000)
