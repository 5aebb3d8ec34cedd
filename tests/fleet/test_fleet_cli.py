"""The fleet's commands as a user runs them: ``p3at run --exchange zenoh:...`` publishing a virtual robot's map,
and ``p3at fuse --live`` fusing robots' maps, each its own process on loopback (random free ports).

Waits have deadlines far above what they need; nothing asserts a duration.
"""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

pytest.importorskip("zenoh")

from estimation.landmark_map import LandmarkMap  # noqa: E402
from runtime.fleet.processes import free_port  # noqa: E402
from runtime.fleet.zenoh_exchange import ZenohExchange  # noqa: E402
from tests.fleet.live_node import NODE_ENTITIES, ROOT, endpoint, p3at, stopped_after_first_fusion  # noqa: E402
from tests.runtime.rerun_helpers import entity_columns  # noqa: E402

pytestmark = pytest.mark.timeout(180)


def test_p3at_run_publishes_a_world_robot_map_under_its_name(tmp_path):
    from mocks.world import World

    port, fleet = free_port(), f"cli{os.getpid()}"
    with ZenohExchange(fleet, json.dumps({"listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]}}), "fusion") as node:
        run = p3at("run", "--name", "robot2", "--camera", "synthetic", "--seconds", "6", "--rerun", "none",
                   "--quiet", "--json", "--fusion-interval", "0", "--out", str(tmp_path / "robot2"),
                   "--exchange", endpoint("connect", port), "--fleet", fleet, stdout=subprocess.PIPE,
                   stderr=subprocess.PIPE)
        stdout, stderr = run.communicate(timeout=150)
        assert run.returncode == 0, stderr
        saved = LandmarkMap.load(tmp_path / "robot2" / "robot2.npz")

        def the_saved_map_received() -> bool:  # not any map: the one of 5 s in may be held while the last comes
            m = node.receive().get("robot2")
            return m is not None and np.array_equal(m.landmark_map.ids, saved.ids)

        end = time.monotonic() + 30.0  # the last snapshot is published as the robot stops
        while not the_saved_map_received() and time.monotonic() < end:
            time.sleep(0.05)
        assert "robot2" in node.receive(), "no map from robot2"
        received = node.receive()["robot2"].landmark_map
    np.testing.assert_array_equal(received.ids, saved.ids)
    np.testing.assert_array_equal(received.positions, saved.positions)
    assert received.metadata["true_start_pose"] == [float(v) for v in World.load(None).start_poses["robot2"]]
    assert list(json.loads(stdout)["robots"]) == ["robot2"]


def test_p3at_fuse_live_fuses_the_robots_maps_and_writes_the_merged_map(tmp_path):
    """The node is stopped (SIGTERM, as Ctrl-C) once both robots have published their last map and it has fused
    two maps: its final fusion, at the stop, holds the maps it has and writes the merged map. (The test waited for
    fused.npz to appear before the stop, but a live fusion here only finds a candidate, which no later fusion
    confirms once the maps stop changing: the file is written at the stop, and every run waited out the 90 s
    deadline. Stopped at the first fusion, before the last maps, the final fusion is aligned too.)"""
    port, fleet = free_port(), f"live{os.getpid()}"
    node = p3at("fuse", "--live", "--exchange", endpoint("listen", port), "--fleet", fleet, "--seconds", "120",
                "--interval", "1", "--out", str(tmp_path / "fused.npz"), "--json", stdout=subprocess.PIPE,
                stderr=subprocess.PIPE)
    stdout, stderr = stopped_after_first_fusion(node, port, fleet)
    assert node.returncode == 0, stderr
    result = json.loads(stdout)
    assert result["fusions"] >= 1
    pair = result["last"]["pairs"][0]
    assert pair["aligned"] and pair["error_xy"] < 0.1, pair
    assert "robot1 joined the fleet" in stderr and "robot2 joined the fleet" in stderr
    assert set(LandmarkMap.load(tmp_path / "fused.npz").metadata["fused_from"]) == {"robot1", "robot2"}


@pytest.mark.slow
@pytest.mark.timeout(600)  # ~40 s on an idle machine; 125 s measured at a load average of 28
def test_demo_processes_prints_the_mission_summary_with_an_alignment_scored_against_the_truth(tmp_path):
    """Each robot its own ``p3at run`` process (simulated time in each), the fusion node in the demo's process."""
    from runtime.rerun_read import read_recording

    demo = p3at("demo", "--processes", "--seconds", "45", "--json", "--quiet", "--out", str(tmp_path),
                stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    stdout, stderr = demo.communicate(timeout=550)
    assert demo.returncode == 0, stderr
    summary = json.loads(stdout)
    assert list(summary["robots"]) == ["robot1", "robot2"]
    assert all(r["landmarks"] > 0 and r["frames_processed"] > 0 for r in summary["robots"].values())
    (pair,) = summary["fusion"]["pairs"]
    assert pair["aligned"] and pair["error_xy"] < 0.1 and pair["error_theta"] < 0.02, pair
    assert len(LandmarkMap.load(tmp_path / "fused.npz")) == summary["fusion"]["merged_landmarks"]
    # every robot's final map is in the final fusion: from the wire, or from its file where the wire lost it
    assert summary["last_maps_missing"] == {}, (summary["last_maps_missing"], summary["last_maps_from_file"])
    contents = read_recording(tmp_path / "mission.rrd")
    assert {"robot1", "robot2", "fused"} <= set(contents.maps)
    # a robot process records its own map, never a fusion of its own on the node's entities (the node's is the fleet's)
    for robot in ("robot1", "robot2"):
        entities = entity_columns(tmp_path / robot / "mission.rrd")
        assert f"maps/{robot}" in entities, sorted(entities)
        assert [e for e in entities if e.startswith(NODE_ENTITIES)] == [], robot


def test_p3at_run_publishes_its_health_once_a_second_under_its_name(tmp_path):
    """The status a running robot sends (runtime/fleet/status.py) arrives under its name with figures that agree
    with its own summary; the fusion node's status line reads it."""
    from runtime.fleet.status import status_line

    port, fleet, seconds = free_port(), f"status{os.getpid()}", 8.0
    with ZenohExchange(fleet, json.dumps({"listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]}}), "fusion") as node:
        run = p3at("run", "--name", "robot2", "--camera", "synthetic", "--seconds", f"{seconds:g}", "--rerun",
                   "none", "--quiet", "--json", "--fusion-interval", "0", "--out", str(tmp_path / "robot2"),
                   "--exchange", endpoint("connect", port), "--fleet", fleet, stdout=subprocess.PIPE,
                   stderr=subprocess.PIPE)
        seen: dict[float, dict] = {}   # mission time -> status, as many as the polling catches while it runs
        while run.poll() is None:
            status = node.status().get("robot2")
            if status is not None and "mission_time" in status["health"]:  # a map's status before any health: {}
                seen[status["health"]["mission_time"]] = status
            time.sleep(0.05)
        stdout, stderr = run.communicate(timeout=150)
        assert run.returncode == 0, stderr
        # the mission loop's last status says the loop is over (the robot then saves its files, and a fleet that
        # hears nothing more knows it is not stuck); it may still be on the way
        end = time.monotonic() + 30.0
        while time.monotonic() < end and node.status().get("robot2", {}).get("health", {}).get(
                "mission_over") is not True:
            time.sleep(0.05)
        last = node.status().get("robot2")
    assert last is not None, "no status from robot2"
    assert last["health"]["mission_over"] is True, last
    seen[last["health"]["mission_time"]] = last
    over = [seen[t]["health"]["mission_over"] for t in sorted(seen)]
    assert False in over and over == sorted(over)  # not over while the mission ran; over only at its end
    summary = json.loads(stdout)["robots"]["robot2"]
    times = sorted(seen)
    frames = [seen[t]["health"]["frames_processed"] for t in times]
    assert frames == sorted(frames), "frames processed must not go back"
    h = last["health"]
    assert h["clock"] == "simulated" and seconds - 1.5 <= h["mission_time"] <= seconds
    # sent by the health tick, or with the last map snapshot (which carries the latest health figures)
    assert last["stamp"] >= h["mission_time"] - 1e-3 and h["wall_time"] > 0
    assert 0 < h["frames_processed"] <= h["frames_received"] and h["frames_processed"] <= summary["frames_processed"]
    assert h["frames_dropped"] == 0  # in simulated time the SLAM stage never falls behind (docs/runtime.md)
    assert h["ms_update"] > 0 and h["link"] == "up" and 10.0 < h["battery_volts"] < 15.0  # a P3-AT's 12 V lead
    assert h["last_error"] is None and isinstance(h["route_done"], bool)
    assert 0 < last["landmarks"] <= summary["landmarks"] + 50  # the last snapshot's map, a moment before the end
    assert last["pose"] is not None and np.all(np.isfinite(last["pose"])) and np.hypot(*last["pose"][:2]) < 10.0
    line = status_line("robot2", last)
    assert line.startswith("status robot2: t=") and f"{h['frames_processed']} frames (0 dropped)" in line
    assert "link up" in line and "\n" not in line


def listen(port: int) -> str:
    return "zenoh:" + json.dumps({"listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]}})


@pytest.mark.parametrize("as_json", [True, False])
def test_p3at_fuse_live_with_no_robot_says_it_had_nothing_to_fuse(as_json):
    """It ended with exit 0 and, without --json, printed nothing at all: a script could not tell it fused nothing."""
    port, fleet = free_port(), f"none{os.getpid()}"
    node = p3at("fuse", "--live", "--exchange", listen(port), "--fleet", fleet, "--seconds", "2",
                *(["--json"] if as_json else []), stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    stdout, stderr = node.communicate(timeout=120)
    assert node.returncode == 1, stderr
    said = [line for line in stderr.splitlines() if line.startswith("p3at fuse:")]
    # the node's own time: 2 s and what its start and end took on a loaded machine
    assert len(said) == 1 and re.fullmatch(f"p3at fuse: nothing to fuse: no robot of fleet '{fleet}' sent a map in "
                                           r"\d+ s", said[0]), stderr
    if as_json:
        result = json.loads(stdout)
        assert result["fusions"] == 0 and result["last"] is None and result["robots_with_maps"] == []
        assert said[0].endswith(result["nothing_to_fuse"])
    else:
        assert stdout == ""


def test_p3at_fuse_live_with_one_robot_names_it_and_says_a_fusion_needs_two(tmp_path):
    port, fleet = free_port(), f"one{os.getpid()}"
    node = p3at("fuse", "--live", "--exchange", listen(port), "--fleet", fleet, "--json", "--out",
                str(tmp_path / "fused.npz"), stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(node.stderr), daemon=True)  # the node's events, as they come
    reader.start()
    robot = subprocess.Popen([sys.executable, "-m", "runtime.fleet.synthetic", "--names", "robot1", "--exchange",
                              endpoint("connect", port), "--fleet", fleet, "--steps", "3", "--period", "0.3"], cwd=ROOT,
                             stdout=subprocess.DEVNULL)
    try:
        end = time.monotonic() + 90.0
        while not any("first map from robot1" in line for line in lines) and time.monotonic() < end:
            assert node.poll() is None, "".join(lines)
            time.sleep(0.1)
        assert any("first map from robot1" in line for line in lines), "".join(lines)
        node.send_signal(signal.SIGTERM)   # as Ctrl-C would
        stdout = node.stdout.read()
        node.wait(timeout=60)
        reader.join(timeout=30)
    finally:
        robot.kill()
        robot.wait()
        if node.poll() is None:
            node.kill()
    assert node.returncode == 1, "".join(lines)
    result = json.loads(stdout)
    assert result["fusions"] == 0 and result["robots_with_maps"] == ["robot1"]
    assert result["nothing_to_fuse"].startswith(f"only robot1 of fleet '{fleet}' sent a map in ")
    assert result["nothing_to_fuse"].endswith("; a fusion needs the maps of two robots")
    said = [line.rstrip("\n") for line in lines if line.startswith("p3at fuse:")]
    assert said == [f"p3at fuse: nothing to fuse: {result['nothing_to_fuse']}"], "".join(lines)
    assert not (tmp_path / "fused.npz").exists()
