"""Reading processes (runtime/rrd_salvage.ReadingProcesses) leave when their parent is killed as they start.

A forked child cannot wait for its pipe's end (it holds its own and its elder siblings' ends), so it leaves when its
parent is gone. A child that runs its first line only after a SIGKILL of the parent (forked just before it, on a busy
machine) must still know whose child it was: a scratch run killing the parent right after ``warm()`` left 8 children
behind in 15 kills when the child asked ``os.getppid()`` for its parent at start, 0 once the parent passes its pid.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
ENV = dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1")
KILLS = 5

WARM_THEN_WAIT = """
import multiprocessing, time
from runtime.rrd_salvage import ReadingProcesses
from tests.runtime.test_reading_processes_start import reads_anything
reading = ReadingProcesses(reads_anything, multiprocessing.get_context("fork"))
reading.warm()
print(*(p.pid for p in multiprocessing.active_children()), flush=True)
time.sleep(120)
"""


def reads_anything(candidate: Path) -> bool:
    return True


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


def test_reading_processes_leave_when_their_parent_is_killed_as_they_start():
    left: list[int] = []
    for _ in range(KILLS):
        parent = subprocess.Popen([sys.executable, "-c", WARM_THEN_WAIT], stdout=subprocess.PIPE, text=True, env=ENV,
                                  cwd=ROOT)
        try:
            children = [int(pid) for pid in parent.stdout.readline().split()]
        finally:
            parent.send_signal(signal.SIGKILL)   # at once: the spare may not have run a line yet
            parent.wait(timeout=60)
        assert len(children) == 2     # the reading one and its spare
        deadline = time.monotonic() + 30  # each looks for its parent every second
        while any(_alive(pid) for pid in children) and time.monotonic() < deadline:
            time.sleep(0.2)
        stuck = [pid for pid in children if _alive(pid)]
        for pid in stuck:  # do not leave them to the machine
            os.kill(pid, signal.SIGKILL)
        left += stuck
    assert not left
