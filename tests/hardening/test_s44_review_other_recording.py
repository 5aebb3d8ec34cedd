"""`p3at review A.rrd B.rrd` where B is another recording (session 44, A). MORE.rrd is "more files of the same
recording" (a fleet whose processes each saved their own, under one recording id), but nothing checked it: two
demos' recordings were read as one, the second's robot1 map (157 landmarks) replacing the first's (76) in the
summary and in the exported robot1.npz, exit 0. A file of another recording is now refused: one line naming it and
both recording ids, exit 2, nothing exported."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from runtime.cli import main
from runtime.rerun_read import RecordingReadError, read_recording
from tests.runtime.test_rerun_fleet import ROBOT_PROCESS

ROOT = Path(__file__).resolve().parents[2]


def _recording(path: Path, robot: str, recording_id: str) -> Path:
    done = subprocess.run([sys.executable, "-c", ROBOT_PROCESS, robot, str(path), recording_id], cwd=ROOT,
                          capture_output=True, timeout=120)
    assert done.returncode == 0, done.stderr.decode(errors="replace")[-2000:]
    return path


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("recordings")
    return {"first": _recording(folder / "first.rrd", "robot1", "mission-one"),
            "other": _recording(folder / "other.rrd", "robot1", "mission-two"),
            "same": _recording(folder / "same.rrd", "robot2", "mission-one")}


def test_a_file_of_another_recording_is_refused(files):
    with pytest.raises(RecordingReadError) as error:
        read_recording(files["first"], files["other"])
    message = str(error.value)
    assert message.startswith(str(files["other"])) and "mission-two" in message and "mission-one" in message


def test_review_says_it_in_one_line_and_exports_nothing(files, tmp_path, capsys):
    export = tmp_path / "maps"
    assert main(["review", str(files["first"]), str(files["other"]), "--export", str(export)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "mission-two" in err[0] and "Traceback" not in err[0]
    assert not export.exists() or not any(export.iterdir())


def test_files_of_one_recording_still_read_as_one(files):
    contents = read_recording(files["first"], files["same"])
    assert contents.robots == ["robot1", "robot2"]
