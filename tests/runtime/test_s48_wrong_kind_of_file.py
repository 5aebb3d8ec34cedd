"""A command given another of the project's files (session 48, D): a map to ``p3at review``, a recording to ``p3at
replay`` or ``p3at fuse``, a sensor log segment to either. Each said its reader's insides ("no b'RRF2' stream
header", "InvalidMagic: ... (80, 75, 3, 4, ...)", "not an npz archive: no zip end record"); now one line naming
what the file is and which command reads it, exit 2, before any reading. Files are made by their first bytes, as a
map (np.savez), a recording and an MCAP segment begin."""
from __future__ import annotations

import numpy as np
import pytest

from runtime.cli import main


@pytest.fixture
def files(tmp_path):
    np.savez(tmp_path / "robot1.npz", positions=np.zeros((1, 3)))
    (tmp_path / "mission.rrd").write_bytes(b"RRF2" + bytes(60))
    (tmp_path / "robot1-log_0.mcap").write_bytes(b"\x89MCAP0\r\n" + bytes(60))
    return tmp_path


def _one_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


@pytest.mark.parametrize("name, said", [
    ("robot1.npz", "a landmark map (.npz), not a recording: p3at fuse reads maps"),
    ("robot1-log_0.mcap", "a sensor log segment (.mcap), not a recording: p3at replay reads it")])
def test_review_names_the_kind_and_its_command(files, name, said, capsys):
    assert main(["review", str(files / name), "--no-export"]) == 2
    assert _one_line(capsys) == f"p3at review: {files / name}: {said}"


@pytest.mark.parametrize("name, said", [
    ("robot1.npz", "a landmark map (.npz), not a sensor log: p3at fuse reads maps"),
    ("mission.rrd", "a Rerun recording (.rrd), not a sensor log: p3at review reads it and exports the maps it holds")])
def test_replay_names_the_kind_and_its_command(files, name, said, capsys):
    assert main(["replay", str(files / name)]) == 2
    assert _one_line(capsys) == f"p3at replay: {files / name}: {said}"


@pytest.mark.parametrize("name, said", [
    ("mission.rrd", "a Rerun recording (.rrd), not a map: p3at review reads it and exports the maps it holds"),
    ("robot1-log_0.mcap", "a sensor log segment (.mcap), not a map: p3at replay reads it")])
def test_fuse_names_the_kind_and_its_command(files, name, said, capsys):
    out = files / "fused.npz"
    assert main(["fuse", str(files / "robot1.npz"), str(files / name), "--out", str(out)]) == 2
    assert _one_line(capsys) == f"p3at fuse: {files / name}: {said}"
    assert not out.exists()
