"""A saved recording whose Rerun writer dies mid-mission is said at once, in one line, and the mission goes on
(session 48, W).

Rerun 0.41's file sink writes from one thread; a write that fails (a full disk, a file-size limit) ends that thread
with an ERROR line of Rerun's own, and every later row is dropped without a word. Before, the mission learnt it only
at its end, from its last flush (session 47, F), and a flush issued as the writer died was never answered: waiting on
it hung the process (F: 4 of 14 runs; 3 of 20 here). The sink is now watched from outside, without asking Rerun
(runtime.rerun_watch.FileWriterWatch: the writer thread, and the file through a descriptor of ours) every 16 frames
logged; the logger says the failure in one line and goes on, and its close reports the recording incomplete instead
of waiting on the dead writer.

The dead sink is made reliably: a file-size limit (RLIMIT_FSIZE, set in the child process; Python ignores the
SIGXFSZ that would kill it, so a write past the limit fails with EFBIG), or the recording's folder removed (the writer
then writes on into a file nobody can open: nothing failed, and the recording is lost).
"""
from __future__ import annotations

import json
import os
import re
import resource
import shutil
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from estimation.landmark_map import LandmarkMap

REPO = Path(__file__).resolve().parents[2]


def _child(args: list[str], limit: int | None, timeout: float = 600) -> subprocess.CompletedProcess:
    """Run ``args`` in a child process, with a file-size limit of ``limit`` bytes (RLIMIT_FSIZE) when given."""
    def limit_file_size() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    env = dict(os.environ, PYTHONPATH=str(REPO), OPENBLAS_NUM_THREADS="1")
    return subprocess.run(args, cwd=REPO, env=env, capture_output=True, text=True, timeout=timeout,
                          preexec_fn=limit_file_size if limit is not None else None)


@pytest.mark.timeout(1200)
def test_a_recording_whose_writer_dies_mid_mission_is_said_in_one_line_and_the_mission_goes_on(tmp_path):
    out = tmp_path / "run"
    # the recording passes 150 kB a third of the way through the 60 s mission; the map and TUM files stay below it
    done = _child([sys.executable, "-m", "runtime.cli", "run", "--camera", "synthetic", "--particles", "20",
                   "--camera-rate", "5", "--seconds", "60", "--map-save-interval", "0", "--quiet", "--json",
                   "--out", str(out)], limit=150_000)
    recording = out / "mission.rrd"
    said = [line for line in done.stderr.splitlines() if f"the Rerun recording {recording} is incomplete" in line]
    assert len(said) == 1, done.stderr   # said once, while the mission ran (before the summary's failure line)
    assert said[0].startswith("p3at run: warning: "), said   # by the command, as its other warnings
    assert "File too large" in said[0] and "the mission goes on" in said[0]
    seen_at = float(re.search(r"seen at t = ([0-9.]+) s", said[0]).group(1))
    summary = json.loads(done.stdout)
    assert seen_at < summary["duration"] - 10   # seen mid-mission, and the mission went on to its end
    assert summary["duration"] >= 59
    # the summary says the recording is incomplete, as a failed stage: exit 1, one 'mission failed' line at the end
    failures = [f for f in summary["failures"] if (f["robot"], f["stage"]) == ("mission", "recording")]
    assert len(failures) == 1 and "incomplete" in failures[0]["error"], summary["failures"]
    assert done.returncode == 1, done.stderr
    ours = [line for line in done.stderr.splitlines() if line.startswith("p3at run:") and line not in said]
    assert len(ours) == 1 and "the recording stage failed" in ours[0] and "Traceback" not in done.stderr
    # the maps and trajectories, what the mission is for, are whole
    assert len(LandmarkMap.load(out / "robot1.npz")) == summary["robots"]["robot1"]["landmarks"] > 0
    assert (out / "robot1.tum").stat().st_size > 0 and (out / "robot1.ply").exists()


def _log_until_seen(log, seen: list[str], bound: float = 60.0) -> int:
    """Log frames (poses, particles, a plot) until the logger has said a failure (``bound``: s of wall time, a
    failure bound: it looks every 16 calls)."""
    rng = np.random.default_rng(0)
    start, k = time.monotonic(), 0
    while not seen and time.monotonic() - start < bound:
        k += 1
        log.log_pose("robot1", k / 15, k, np.array([0.01 * k, 0.0, 0.001 * k]))
        log.log_particles("robot1", k / 15, k, rng.normal(size=(300, 3)))
        log.log_scalars("robot1", k / 15, {"ess": float(k % 50)}, frame=k)
        time.sleep(0.01)
    return k


def test_a_recording_whose_folder_is_removed_is_said_and_its_close_reports_it(tmp_path):
    from runtime.rerun_log import MissionLog, RecordingError
    from runtime.rerun_sink import open_recording

    folder = tmp_path / "rec"
    seen: list[str] = []
    log = MissionLog(open_recording(str(folder / "mission.rrd")), ["robot1"], on_recording_failure=seen.append)
    log.log_pose("robot1", 0.0, 0, np.zeros(3))
    shutil.rmtree(folder)   # Rerun writes on into a file nobody can open: nothing fails, and the recording is lost
    _log_until_seen(log, seen)
    assert len(seen) == 1 and str(folder / "mission.rrd") in seen[0] and "removed" in seen[0], seen
    with pytest.raises(RecordingError, match="incomplete: its file was removed"):
        log.close()


_DYING_WRITER = textwrap.dedent("""
    import json, sys, time
    import numpy as np
    from runtime.rerun_log import MissionLog, RecordingError
    from runtime.rerun_sink import open_recording

    seen = []
    log = MissionLog(open_recording(sys.argv[1]), ["robot1"], on_recording_failure=seen.append)
    rng = np.random.default_rng(0)
    start, k, flush_errors = time.monotonic(), 0, 0
    while not seen and time.monotonic() - start < 60:
        k += 1
        log.log_particles("robot1", k / 15, k, rng.normal(size=(2000, 3)))
        log.log_pose("robot1", k / 15, k, np.zeros(3))
        try:
            log.flush()   # a flush in flight as the writer dies: Rerun never answers it
        except RecordingError:
            flush_errors += 1
    try:
        log.close()
        closed = "whole"
    except RecordingError as e:
        closed = str(e)
    print(json.dumps({"seen": seen, "closed": closed, "flush_errors": flush_errors}))
""")


@pytest.mark.timeout(1200)
def test_a_writer_that_dies_under_flushes_never_hangs_the_logger(tmp_path):
    """Flushing while the writer dies stranded a flush in Rerun 0.41 (its writer gone, the flush never answered),
    and the process then hung in its next flush or its disconnect. MissionLog.flush and close look at the writer
    between flushes of at most a second, and leave a dead one alone. Several children, each flushing every frame."""
    for attempt in range(2):
        path = tmp_path / f"run{attempt}" / "mission.rrd"
        done = _child([sys.executable, "-c", _DYING_WRITER, str(path)], limit=200_000, timeout=300)
        assert done.returncode == 0, done.stderr
        result = json.loads(done.stdout)
        assert len(result["seen"]) <= 1 and "File too large" in result["closed"], result
        assert result["closed"].startswith("incomplete: Rerun's file writer stopped"), result
