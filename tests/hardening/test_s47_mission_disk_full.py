"""A disk that refuses the mission's files at its end (session 47, F): the run's summary and its other files survive.

A file-size limit (``ulimit -f``, RLIMIT_FSIZE: every write past it fails with EFBIG, as a full disk fails with
ENOSPC; Python ignores the SIGXFSZ that would otherwise kill the process) stands in for a full disk. Before: an
``OSError`` out of the final map save, the sensor log's close or Rerun's flush left ``Mission.run`` as an exception:
no summary, the files after the failing one never written, and one line that named no file (``p3at run: mission
failed: [Errno 27] File too large``; a dead recording: ``File-writer thread shut down prematurely``). Now each is a
failure of its stage naming its file, the other files are written, the summary is printed, and stderr holds one
``mission failed`` line (the first failure, and how many more the summary lists), exit 1.
"""
from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest

from estimation.landmark_map import LandmarkMap

REPO = Path(__file__).resolve().parents[2]
RUN = [sys.executable, "-m", "runtime.cli", "run", "--camera", "synthetic", "--particles", "20", "--camera-rate",
       "5", "--quiet", "--json"]


def _run_with_file_limit(limit: int, *args: str) -> subprocess.CompletedProcess:
    def limit_file_size() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    env = dict(os.environ, PYTHONPATH=str(REPO), OPENBLAS_NUM_THREADS="1")
    return subprocess.run(RUN + list(args), cwd=REPO, env=env, capture_output=True, text=True, timeout=600,
                          preexec_fn=limit_file_size)


def _our_lines(stderr: str) -> list[str]:
    """The command's own lines (Rerun's writer thread logs its own error line, which this test leaves alone)."""
    return [line for line in stderr.splitlines() if line.startswith("p3at run:")]


@pytest.mark.timeout(1200)
def test_a_final_map_the_disk_refuses_is_one_line_naming_it_and_the_summary_is_printed(tmp_path):
    out = tmp_path / "run"
    done = _run_with_file_limit(4000, "--seconds", "5", "--rerun", "none", "--map-save-interval", "0",
                                "--out", str(out))
    assert done.returncode == 1, done.stderr
    summary = json.loads(done.stdout)  # the summary is there: the mission ended as a failed run ends
    failed = {(f["robot"], f["stage"]) for f in summary["failures"]}
    assert ("robot1", "map save") in failed
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in done.stderr, done.stderr
    assert lines[0].startswith("p3at run: mission failed: robot1: the map save stage failed")
    # the first map saved is the filter's, kept beside the smoothed one (the smoothing is on by default)
    assert "File too large" in lines[0] and str(out / "robot1-filter.npz") in lines[0]
    assert summary["robots"]["robot1"]["smoothing"]["smoothed"] is True
    assert not (out / "robot1-filter.npz").exists() and not (out / "robot1.npz").exists()  # nothing half-written
    assert not [p.name for p in out.iterdir() if p.name.endswith(".tmp")]


@pytest.mark.timeout(1200)
def test_a_sensor_log_the_disk_refuses_is_one_failure_of_the_log_and_the_maps_are_still_written(tmp_path):
    out = tmp_path / "run"
    # the log's segment grows past 60 kB within seconds (the mission sees its writer's error and stops; closing
    # the log then raised it again); the map and TUM files of those seconds stay below it
    done = _run_with_file_limit(60_000, "--seconds", "120", "--rerun", "none", "--map-save-interval", "0",
                                "--log-sensors", "--out", str(out))
    assert done.returncode == 1, done.stderr
    summary = json.loads(done.stdout)
    assert [(f["robot"], f["stage"]) for f in summary["failures"]] == [("robot1", "sensor log")]
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "robot1-log" in lines[0] and "File too large" in lines[0], done.stderr
    assert len(LandmarkMap.load(out / "robot1.npz")) == summary["robots"]["robot1"]["landmarks"]
    assert (out / "robot1.tum").exists() and (out / "robot1.ply").exists()


@pytest.mark.timeout(1200)
def test_a_recording_whose_writer_died_is_named_and_the_maps_and_summary_survive(tmp_path):
    out = tmp_path / "run"
    # the recording grows past 300 kB within the first seconds; the map (~70 kB) and TUM files stay below it
    done = _run_with_file_limit(300_000, "--seconds", "60", "--map-save-interval", "0", "--out", str(out))
    assert done.returncode == 1, done.stderr
    summary = json.loads(done.stdout)
    assert ("mission", "recording") in {(f["robot"], f["stage"]) for f in summary["failures"]}
    lines = _our_lines(done.stderr)
    # session 48: the writer's death is said at once (a warning), and the end's one 'mission failed' line names it
    warned = [line for line in lines if line.startswith("p3at run: warning: ")]
    failed = [line for line in lines if line not in warned]
    assert len(warned) == 1 and f"the Rerun recording {out / 'mission.rrd'} is incomplete" in warned[0], lines
    assert len(failed) == 1 and "Traceback" not in done.stderr, done.stderr
    assert str(out / "mission.rrd") in failed[0]
    assert len(LandmarkMap.load(out / "robot1.npz")) == summary["robots"]["robot1"]["landmarks"] > 0
    assert (out / "robot1.tum").exists() and (out / "robot1.ply").exists()
