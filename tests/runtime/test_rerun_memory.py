"""What keeps a mission's memory bounded on the Rerun side (docs/reliability.md, "Memory over a long mission").

Rerun's footer is an index of every chunk a file holds, kept in memory until the file is closed: it grew a
10-minute demo by ~30 MB per 100 s. A saved recording is written without it; these tests pin that, that such a
file is still read back whole, and that Rerun's warning about the missing footer is silenced without touching any
RUST_LOG the user set. No RSS or timing is asserted here: benchmarks/bench_memory.py and bench_rerun_memory.py
print the figures.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import rerun as rr

from runtime.rerun_log import MissionLog
from runtime.rerun_read import read_recording
from runtime.rerun_sink import open_recording
from runtime.rerun_style import mission_blueprint
from tests.runtime.rerun_helpers import ROBOTS, log_small_mission

ROOT = Path(__file__).resolve().parents[2]


def _save(path: Path, **options) -> dict:
    log = MissionLog(open_recording(str(path), blueprint=mission_blueprint(ROBOTS), **options), ROBOTS,
                     blueprint=False)
    logged = log_small_mission(log, frames=6)
    log.close()
    return logged


def test_a_saved_recording_is_written_without_the_in_memory_chunk_index_unless_asked(tmp_path):
    _save(tmp_path / "plain.rrd")
    _save(tmp_path / "indexed.rrd", footer=True)
    assert not rr.bindings.check_for_rrd_footer(str(tmp_path / "plain.rrd"))
    assert rr.bindings.check_for_rrd_footer(str(tmp_path / "indexed.rrd"))  # the check tells the two apart


def test_a_recording_without_the_index_is_read_back_whole(tmp_path):
    logged = _save(tmp_path / "plain.rrd")
    contents = read_recording(tmp_path / "plain.rrd")
    assert contents.truncated is None and contents.ended
    assert set(contents.robots) == set(ROBOTS)
    fused = contents.maps["fused"]
    np.testing.assert_allclose(fused.positions, logged["fused"].positions)


def test_only_a_closed_recording_reads_as_ended(tmp_path):
    """Without Rerun's footer there is no end-of-stream message: the logger's last entity (mission/closed) tells a
    finished file from one whose writer died (here: still open, everything logged so far flushed to disk)."""
    path = tmp_path / "open.rrd"
    log = MissionLog(open_recording(str(path)), ROBOTS, blueprint=False)
    log_small_mission(log, frames=4)
    log.flush()
    unfinished = read_recording(path)
    assert unfinished.truncated is None and not unfinished.ended
    assert "fused" in unfinished.maps
    log.close()
    assert read_recording(path).ended


def test_a_cut_recording_without_the_index_is_reported_cut_and_not_ended(tmp_path):
    _save(tmp_path / "plain.rrd")
    data = (tmp_path / "plain.rrd").read_bytes()
    cut = tmp_path / "cut.rrd"
    cut.write_bytes(data[: len(data) // 2])
    contents = read_recording(cut)
    assert contents.truncated and "cut short" in contents.truncated and not contents.ended


def _save_in_a_child(path: Path, rust_log: str | None) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "RUST_LOG"}
    if rust_log is not None:
        env["RUST_LOG"] = rust_log
    script = (
        "import os, sys\n"
        "from runtime.rerun_log import MissionLog\n"
        "from runtime.rerun_sink import open_recording\n"
        "log = MissionLog(open_recording(sys.argv[1]), ['robot1'], blueprint=False)\n"
        "log.log_scalars('robot1', 0.0, {'ess': 1.0})\n"
        "log.close()\n"
        "print(os.environ.get('RUST_LOG'))\n")
    # the timeout only stops a hung child (an import and a tiny file take seconds even on a loaded machine)
    return subprocess.run([sys.executable, "-c", script, str(path)], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=600, check=True)


def test_the_missing_footer_warning_is_silenced_and_rust_log_left_as_the_user_had_it(tmp_path):
    quiet = _save_in_a_child(tmp_path / "quiet.rrd", None)
    assert "write_footer" not in quiet.stderr, quiet.stderr
    assert quiet.stdout.strip() == "None"  # not set for the process's children (a spawned viewer)
    # a user's own RUST_LOG wins: at "warn" Rerun's warning shows, which is also what the silencing hides
    users = _save_in_a_child(tmp_path / "users.rrd", "warn")
    assert "write_footer" in users.stderr
    assert users.stdout.strip() == "warn"
