"""`p3at demo --processes`: a robot process that dies without its summary (killed) is said in one line naming the
signal, and the map its periodic saves left goes into the final fusion when it is newer than the map the fusion node
holds (session 24). Session 23 named the signal and the file but fused the node's map: a robot killed one simulated
second in left 47 landmarks on disk while the node fused its first map, of 0."""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from estimation.landmark_map import LandmarkMap
from runtime.exchange import MapMessage
from runtime.fleet.processes import LeftMap, map_left, robot_process_failure_line

ROOT = Path(__file__).resolve().parents[2]


def _map(robot: str = "robot1", n: int = 5, frames: int | None = 10, seed: int = 0) -> LandmarkMap:
    rng = np.random.default_rng(seed)
    m = LandmarkMap(rng.uniform(-5, 5, (n, 3)), np.tile(np.eye(3) * 1e-2, (n, 1, 1)),
                    rng.normal(size=(n, 8)).astype(np.float32), robot=robot,
                    trajectory=[[0.0, 0, 0, 0], [2.5, 1, 0, 0]])
    if frames is not None:
        m.metadata["slam_frames"] = {"received": frames, "processed": frames, "dropped": 0, "without_odometry": 0}
    return m


def _held(m: LandmarkMap, sequence: int = 3) -> MapMessage:
    return MapMessage(m.robot, sequence, 2.0, m)


def test_a_killed_robot_is_named_with_its_signal_and_what_became_of_its_map() -> None:
    line = robot_process_failure_line("robot1", -signal.SIGKILL, "", "the final fusion reads its last saved map M")
    assert line == "robot1 (exit -9): killed by SIGKILL, no summary; the final fusion reads its last saved map M"
    assert "killed by SIGTERM" in robot_process_failure_line("robot2", -signal.SIGTERM, "a warning\n", "x")
    assert robot_process_failure_line("robot2", -200, "", "it saved no map").endswith(
        "killed by signal 200, no summary; it saved no map")


def test_a_robot_that_failed_says_its_last_line() -> None:
    line = robot_process_failure_line("robot1", 1, "starting\np3at run: mission failed: robot1 slam: boom\n",
                                      "it saved no map")
    assert line == "robot1 (exit 1): p3at run: mission failed: robot1 slam: boom; it saved no map"
    assert robot_process_failure_line("robot1", 3, "", "x").startswith("robot1 (exit 3): no summary, nothing on stderr")


def test_the_left_map_is_fused_when_newer_than_the_one_held_or_when_none_is_held(tmp_path) -> None:
    saved = _map(n=7, frames=12, seed=1)
    saved.save(tmp_path / "robot1.npz")
    for have in (_held(_map(n=5, frames=10)), None):
        left = LeftMap(tmp_path / "robot1.npz")
        message = map_left("robot1", left, have)
        assert left.used and left.landmarks == 7 and message is not None
        assert message.robot == "robot1" and message.sequence == (4 if have else -1) and message.stamp == 2.5
        assert np.array_equal(message.landmark_map.positions, saved.positions)
        assert left.said.startswith(f"the final fusion reads its last saved map {tmp_path / 'robot1.npz'} "
                                    "(7 landmarks from 12 frames)")
        assert ("newer than the map the node received last (5 landmarks from 10 frames)" in left.said) == bool(have)


@pytest.mark.parametrize(("case", "says"), [
    ("older", "(7 landmarks from 8 frames) is no newer than the map the node received last (5 landmarks from 10 "
              "frames), which the final fusion has"),
    ("same", "is the map the node received last, in the final fusion"),
    ("no counts", "cannot be told older or newer than the map the node received last (no frame counts)"),
    ("other robot", "is not used (it is robot2's map, not robot1's); the final fusion has the map the node received "
                    "last (5 landmarks)"),
    ("empty", "is not used (it holds no landmark)"),
    ("cut", "its map file is not used ("),
    ("absent", "it saved no map; the final fusion has the map the node received last (5 landmarks)")])
def test_the_left_map_is_not_fused_and_the_line_says_why(case, says, tmp_path) -> None:
    have = _held(_map(n=5, frames=10))
    path = tmp_path / "robot1.npz"
    saved = {"older": _map(n=7, frames=8, seed=1), "same": have.landmark_map, "no counts": _map(n=7, frames=None),
             "other robot": _map("robot2", n=7), "empty": _map(n=0), "cut": _map(n=7), "absent": None}[case]
    if saved is not None:
        saved.save(path)
    if case == "cut":
        path.write_bytes(path.read_bytes()[:100])
    left = LeftMap(path)
    assert map_left("robot1", left, have) is None and not left.used
    assert says in left.said and "\n" not in left.said, left.said


def _holds_landmarks(path: Path) -> bool:
    """Whether the map file is there and holds a landmark (its saves are atomic: whole or absent)."""
    return path.exists() and len(LandmarkMap.load(path)) > 0


@pytest.mark.timeout(600)  # ~12 s on an idle machine; a loaded one only takes longer
def test_a_robot_killed_in_the_demo_has_its_last_saved_map_in_the_final_fusion(tmp_path) -> None:
    """The real command: robot1's process is killed (SIGKILL) as soon as a periodic save holding landmarks is on
    disk. On the wall clock (--realtime) that is about 1 s into the mission, well before robot1's second publish (5 s):
    the node holds its first map, of its first frame, and the file is newer. Should a loaded machine let the second
    publish in first, the node's map is as new, and the test checks that this is what was fused and said."""
    demo = subprocess.Popen([sys.executable, "-m", "runtime.cli", "demo", "--processes", "--realtime", "--seconds",
                             "8", "--json", "--rerun", "none", "--map-save-interval", "1", "--out", str(tmp_path)],
                            cwd=ROOT,
                            env={**os.environ, "PYTHONPATH": str(ROOT)}, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    stdout: list[str] = []
    readers = [threading.Thread(target=lambda: lines.extend(demo.stderr), daemon=True),   # the pipes read as they
               threading.Thread(target=lambda: stdout.append(demo.stdout.read()), daemon=True)]   # fill, never blocks
    for reader in readers:
        reader.start()
    saved_file = tmp_path / "robot1" / "robot1.npz"
    deadline = time.monotonic() + 500
    pid = None
    try:
        while (pid is None or not _holds_landmarks(saved_file)) and time.monotonic() < deadline and \
                demo.poll() is None:
            started = next((m for m in map(re.compile(r"robot1 \(pid (\d+)\)").search, list(lines)) if m), None)
            pid = pid or (int(started.group(1)) if started else None)
            time.sleep(0.05)
        assert pid is not None and _holds_landmarks(saved_file), "".join(lines)
        os.kill(pid, signal.SIGKILL)
        demo.wait(timeout=500)
    finally:
        if demo.poll() is None:
            demo.kill()
    for reader in readers:
        reader.join(timeout=30)
    err = "".join(lines)
    assert demo.returncode == 1, err
    failure = [line for line in err.splitlines() if "robot process failed: robot1" in line]
    assert len(failure) == 1 and "robot1 (exit -9): killed by SIGKILL, no summary; " in failure[0], err
    saved = LandmarkMap.load(saved_file)
    summary = json.loads("".join(stdout))
    used = summary["robot_processes_failed"]["robot1"]["map_used"]
    assert summary["robot_processes_failed"] == {"robot1": {"exit": -9, "map_file": str(saved_file),
                                                            "landmarks": len(saved), "map_used": used}}, failure
    saved_stamp = float(saved.trajectory[-1, 0])
    if used:   # the usual case: killed ~1 s in, before robot1's second publish (5 s)
        assert f"the final fusion reads its last saved map {saved_file} ({len(saved)} landmarks" in failure[0]
        # what the final fusion held of robot1: the file's map, stamped with its last pose's mission time
        assert summary["fused_from"]["robot1"][1] == pytest.approx(saved_stamp)
    else:      # a loaded machine let the second publish in before the kill: the node's map is as new, and is said so
        assert any(said in failure[0] for said in ("is no newer than the map the node received last",
                                                   "is the map the node received last")), failure
        assert summary["fused_from"]["robot1"][1] >= saved_stamp - 1e-9, summary["fused_from"]
    assert summary["last_maps_missing"] == {} and "robot2" in summary["fused_from"]
