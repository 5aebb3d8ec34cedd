"""Reading a recording leaves no ``p3at-review-*`` scratch folder behind, even when the reader is killed.

``read_recording`` needs a temporary folder only for a file cut short (its whole prefix is copied there) or a
salvage; it used to make one at the start of every reading, so a process killed while reading a sound file (31 were
in /tmp after session 18's runs) left an empty folder behind. The folder is now made only when needed and removed
on every path that made it. Each test points ``tempfile`` at a private folder and looks into it *while* Rerun's
reader runs (a process killed then would leave what is there).
"""
from __future__ import annotations

import tempfile

import pytest

from runtime import rerun_read
from runtime.cli import main
from runtime.commands import review

from .rerun_helpers import footed_recording
from .test_review_damaged import dies_like_a_rust_panic


@pytest.fixture(scope="module")
def whole(tmp_path_factory):
    return footed_recording(tmp_path_factory.mktemp("whole") / "mission.rrd", frames=12)


@pytest.fixture
def private_tmp(tmp_path, monkeypatch):
    """A private temporary folder for ``tempfile``, and what it held each time Rerun's reader was called."""
    folder = tmp_path / "tmp"
    folder.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(folder))
    seen: list[list[str]] = []
    read_chunks = rerun_read._read_chunks

    def watched(*args, **kwargs):
        seen.append(sorted(p.name for p in folder.iterdir()))
        return read_chunks(*args, **kwargs)

    monkeypatch.setattr(rerun_read, "_read_chunks", watched)
    return folder, seen


def test_reading_a_sound_recording_makes_no_scratch_folder(whole, private_tmp):
    rrd, contents = whole
    folder, seen = private_tmp
    again = rerun_read.read_recording(rrd)
    assert again.truncated is None and again.maps.keys() == contents.maps.keys()
    assert seen == [[]], f"while Rerun's reader ran, the temporary folder held {seen}"
    assert list(folder.iterdir()) == []


def test_a_recording_cut_short_leaves_no_scratch_folder_after_it_is_read(whole, private_tmp, tmp_path):
    rrd, _ = whole
    folder, seen = private_tmp
    cut = tmp_path / "cut.rrd"
    cut.write_bytes(rrd.read_bytes()[: int(rrd.stat().st_size * 0.9)])
    contents = rerun_read.read_recording(cut)
    assert contents.truncated and "cut short" in contents.truncated
    assert len(seen) == 1 and len(seen[0]) == 1 and seen[0][0].startswith("p3at-review-"), seen  # made, and used
    assert list(folder.iterdir()) == []


def test_a_reading_that_fails_removes_the_scratch_folder_it_made(whole, private_tmp, tmp_path, monkeypatch):
    rrd, _ = whole
    folder, _ = private_tmp
    cut = tmp_path / "cut.rrd"
    cut.write_bytes(rrd.read_bytes()[: int(rrd.stat().st_size * 0.9)])

    def interrupted(*args, **kwargs):
        assert len(list(folder.iterdir())) == 1
        raise KeyboardInterrupt

    monkeypatch.setattr(rerun_read, "_read_chunks", interrupted)
    with pytest.raises(KeyboardInterrupt):
        rerun_read.read_recording(cut)
    assert list(folder.iterdir()) == []


def test_review_removes_its_error_file_when_the_reading_process_is_killed(tmp_path, private_tmp, capsys,
                                                                          monkeypatch):
    """The reading child's stderr goes to a ``p3at-review-*.err`` file of the parent's: the child dying (here
    SIGABRT, as Rerun's reader does on some damaged messages) does not leave it behind."""
    folder, _ = private_tmp
    rrd = tmp_path / "mission.rrd"
    rrd.write_bytes(b"RRF2" + bytes(64))
    made: list[str] = []
    named = tempfile.NamedTemporaryFile

    def watched(*args, **kwargs):
        f = named(*args, **kwargs)
        made.append(f.name)
        return f

    monkeypatch.setattr(review.tempfile, "NamedTemporaryFile", watched)
    monkeypatch.setattr(review, "read_and_export", dies_like_a_rust_panic)
    assert main(["review", str(rrd), "--export", str(tmp_path / "maps")]) == 2
    assert "Timestamp type with unit of <UNKNOWN 16> not supported" in capsys.readouterr().err
    assert len(made) == 1 and made[0].startswith(str(folder)) and made[0].endswith(".err")
    assert list(folder.iterdir()) == []
