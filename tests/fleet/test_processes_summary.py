"""``p3at demo --processes`` reports the mission's length as the in-process demo does: the robots' simulated seconds,
with the wall time beside it. It printed "Mission: 2 robot(s), 19.1 s" for a ``--seconds 30`` mission (113 frames at
3.75 Hz): the wall time of the demo's own process, in the place where the in-process demo puts the mission's."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("zenoh")

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.timeout(600)  # ~10 s on an idle machine; a loaded one only takes longer
def test_the_summary_gives_the_robots_simulated_seconds_and_the_wall_time_beside_them(tmp_path):
    seconds = 4.0
    demo = subprocess.run([sys.executable, "-m", "runtime.cli", "demo", "--processes", "--seconds", f"{seconds:g}",
                           "--json", "--quiet", "--rerun", "none", "--out", str(tmp_path)],
                          cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True,
                          timeout=550)
    assert demo.returncode == 0, demo.stderr
    summary = json.loads(demo.stdout)
    assert summary["clock"] == "simulated" and summary["duration"] == summary["sim_seconds"]
    assert seconds - 0.5 <= summary["duration"] <= seconds + 0.5, summary["duration"]   # the robots' mission time
    assert summary["wall_seconds"] > 0 and summary["realtime_factor"] == pytest.approx(
        summary["duration"] / summary["wall_seconds"], rel=1e-2)
    assert list(summary["robots"]) == ["robot1", "robot2"]


def test_the_mission_length_is_the_longest_robots_sim_seconds_as_it_gave_them():
    """The robots' ``sim_seconds`` (3 decimals), not their ``duration`` (rounded to 2): on the wall clock (--realtime)
    a mission ends between ticks, and the summary gave 4.01 s for a robot's 4.0137 s."""
    from runtime.fleet.processes import mission_timing

    robots = {"robot1": {"clock": "wall", "duration": 4.01, "sim_seconds": 4.0137, "wall_seconds": 4.2},
              "robot2": {"clock": "wall", "duration": 3.61, "sim_seconds": 3.6052, "wall_seconds": 3.8}}
    timing = mission_timing(robots, wall=8.0)
    assert timing == {"duration": 4.01, "clock": "wall", "sim_seconds": 4.0137, "wall_seconds": 8.0,
                      "realtime_factor": round(4.0137 / 8.0, 3)}
    # robots that disagree on the clock, or give no mission time: the wall time alone, said as a duration
    assert mission_timing({**robots, "robot3": {"clock": "simulated", "sim_seconds": 5.0}}, wall=8.0) == {
        "duration": 8.0}
    assert mission_timing({"robot1": {"robots": {}}}, wall=8.04) == {"duration": 8.04}
