"""A robot process of `p3at demo --processes` that stops making progress no longer keeps the demo waiting for ever
(session 47, F).

Found by freezing robot2's process (SIGSTOP) mid-run: the demo waited for it without a bound, saying nothing (the
audit's harness killed it after 249 s). A robot whose status, sent once a second of its mission time, has not moved
for `ROBOT_STALL_AFTER` s of wall time while its process runs is now stopped (SIGTERM, then SIGKILL: a frozen process
cannot act on SIGTERM), said in one line, and the demo goes on: its final fusion takes that robot's last saved map,
as for a robot that was killed. The bound is lowered here (the wrapper sets it) so the test takes a minute, not two.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]

DEMO_WITH_A_SHORT_BOUND = """
import sys
import runtime.fleet.processes as processes
from runtime.cli import main

processes.ROBOT_STALL_AFTER = 20.0
processes.STALL_GRACE = 5.0
sys.exit(main(sys.argv[1:]))
"""


def _robot_pid(parent: int, robot: str) -> int | None:
    """The pid of the `p3at run --name ROBOT` child of ``parent``."""
    found = subprocess.run(["ps", "-o", "pid=", "--ppid", str(parent)], capture_output=True, text=True).stdout
    for pid in (int(p) for p in found.split()):
        try:
            words = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if b"--name" in words and words[words.index(b"--name") + 1] == robot.encode():
            return pid
    return None


@pytest.mark.timeout(1200)
def test_a_frozen_robot_process_is_stopped_and_named_and_the_demo_ends_with_its_last_map(tmp_path):
    out = tmp_path / "demo"
    env = dict(os.environ, PYTHONPATH=str(REPO), OPENBLAS_NUM_THREADS="1")
    demo = subprocess.Popen(
        [sys.executable, "-c", DEMO_WITH_A_SHORT_BOUND, "demo", "--processes", "--particles", "10", "--camera-rate",
         "5", "--map-save-interval", "1", "--seconds", "60", "--rerun", "none", "--quiet", "--json", "--out", str(out)],
        cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    frozen = None
    try:
        saved = out / "robot2" / "robot2.npz"
        deadline = time.monotonic() + 600  # bounds a broken run only; start-up takes what the load makes it take
        rewrites, last = 0, None
        while rewrites < 10:  # ten saves: robot2 has run (and sent its status) for seconds of wall time
            assert demo.poll() is None and time.monotonic() < deadline, "robot2 never saved its map"
            mtime = saved.stat().st_mtime_ns if saved.exists() else None
            if mtime is not None and mtime != last:
                rewrites, last = rewrites + 1, mtime
            time.sleep(0.05)
        frozen = _robot_pid(demo.pid, "robot2")
        assert frozen is not None
        os.kill(frozen, signal.SIGSTOP)
        stdout, stderr = demo.communicate(timeout=600)  # before: no end at all
    finally:
        if demo.poll() is None:
            demo.kill()
            demo.communicate()
        if frozen is not None:
            for sig in (signal.SIGCONT, signal.SIGKILL):
                try:
                    os.kill(frozen, sig)
                except ProcessLookupError:
                    pass
    assert demo.returncode == 1, stderr
    said = [line for line in stderr.splitlines() if "robot process failed: robot2" in line]
    assert len(said) == 1 and "no progress for 20 s of wall time" in said[0], stderr
    summary = json.loads(stdout)
    assert "robot1" in summary["robots"]  # robot1 ran its mission to the end
    # robot2's last map is in the final fusion: the one the node held, or its saved file where that was newer
    assert "robot2" in summary["fused_from"], summary["fused_from"]
