"""A recording passed through Rerun's own ``rerun rrd optimize`` (the way to get a copy that ``rerun rrd verify``
accepts, docs/recording.md) still reads back: optimize stores a logged row's components in separate chunks (a map
snapshot's scalars apart from its arrays), and the reader joins them by the row's id. Before, every map of such a
file was refused ("entity 'maps/robot1' does not hold a complete map")."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

from runtime.cli import main
from runtime.rerun_log import MissionLog
from runtime.rerun_read import read_recording
from runtime.rerun_sink import open_recording
from runtime.rerun_style import mission_blueprint

from .rerun_helpers import ROBOTS, landmark_map, log_small_mission


def test_an_optimized_copy_gives_back_the_same_maps_alignment_and_summary(tmp_path, capsys):
    original, optimized = tmp_path / "mission.rrd", tmp_path / "optimized.rrd"
    log = MissionLog(open_recording(str(original), blueprint=mission_blueprint(ROBOTS)), ROBOTS, blueprint=False)
    log_small_mission(log)
    rng = np.random.default_rng(1)
    for t in (5.0, 10.0):   # snapshots the size of a demo's (~700 landmarks, 64-float descriptors): optimize splits
        for robot in ROBOTS:
            m = landmark_map(robot, 700, rng)
            m.descriptors = rng.normal(size=(700, 64)).astype(np.float32)
            log.log_map(robot, t, m)
    log.close()
    rerun = Path(sys.executable).with_name("rerun")
    done = subprocess.run([str(rerun), "rrd", "optimize", str(original), "-o", str(optimized)], capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    import rerun.chunk as rrchunk

    pieces = [set(chunk.to_record_batch().schema.names)
              for chunk in rrchunk.RrdReader(optimized).stream().filter(content=["+ /maps/robot1"])]
    assert any("size" in names and "positions" not in names for names in pieces), "optimize no longer splits rows"
    before, after = read_recording(original), read_recording(optimized)
    assert sorted(after.maps) == sorted(before.maps) == ["fused", "robot1", "robot2"]
    for name, m in before.maps.items():
        for field in ("positions", "covariances", "descriptors", "ids", "counts", "seen_by", "trajectory"):
            np.testing.assert_array_equal(getattr(after.maps[name], field), getattr(m, field), err_msg=name)
    assert after.alignments == before.alignments and after.summary == before.summary and not after.damaged
    assert main(["review", str(optimized), "--no-export"]) == 0
    assert "map robot1" in capsys.readouterr().out
