"""`p3at review` exports each map of a recording as ``DIR/NAME.npz`` and ``.ply``, NAME taken from the recording's
entity path ``maps/NAME`` (session 44, A). A recording with a map under ``maps/../../escaped`` made review write
escaped.npz and escaped.ply two folders above the export folder (``a/../../x``: one above), so a hostile .rrd could
replace any .npz or .ply the user may write. A name that is not a file name is now not exported, and the summary
says so on the map's line; the other maps are exported as before."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from runtime.cli import main

ROOT = Path(__file__).resolve().parents[2]
WRITER = """
import sys
import numpy as np
from estimation.landmark_map import LandmarkMap
from runtime.rerun_log import MissionLog
from runtime.rerun_sink import open_recording
rng = np.random.default_rng(0)
a = rng.normal(size=(10, 3, 3)) * 0.1
m = LandmarkMap(positions=rng.uniform(-5, 5, (10, 3)), covariances=a @ np.swapaxes(a, 1, 2) + 0.01 * np.eye(3),
                descriptors=rng.normal(size=(10, 16)).astype(np.float32), robot="robot1")
log = MissionLog(open_recording(sys.argv[1]), ["robot1"], blueprint=False)
for key in sys.argv[2:]:
    log.log_map(key, 1.0, m, draw=False)
log.close()
"""
HOSTILE = ["..", "../../escaped", "a/../../x", "sub/name"]


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("rrd") / "hostile.rrd"
    done = subprocess.run([sys.executable, "-c", WRITER, str(path), *HOSTILE, "robot1"], cwd=ROOT,
                          capture_output=True, timeout=120)
    assert done.returncode == 0, done.stderr.decode(errors="replace")[-2000:]
    return path


def test_no_file_is_written_outside_the_export_folder(recording, tmp_path, capsys):
    export = tmp_path / "a" / "b" / "maps"
    assert main(["review", str(recording), "--export", str(export)]) == 0
    out = capsys.readouterr().out
    written = sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*") if p.is_file())
    assert written == ["a/b/maps/robot1.npz", "a/b/maps/robot1.ply"], written
    for name in HOSTILE:
        line = next(ln for ln in out.splitlines() if ln.startswith(f"  map {name} "))
        assert f"(not exported: {name!r} is not a file name)" in line, line


def test_json_says_which_maps_were_not_exported(recording, tmp_path, capsys):
    import json

    assert main(["review", str(recording), "--export", str(tmp_path / "maps"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert sorted(summary["not_exported"]) == sorted(HOSTILE) and list(summary["exported"]) == ["robot1"]
