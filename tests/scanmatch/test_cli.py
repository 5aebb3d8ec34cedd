"""``p3at scanmatch`` through runtime.cli.main, on a log written from the synthetic room and on the real logs."""
from __future__ import annotations

import gzip
import json

import numpy as np
import pytest

from estimation.geometry import compose
from runtime.cli import main


def write_room_log(path, laser, n_scans=8):
    """A CARMEN log of a laser driving through the synthetic room (0.15 m and 3° per scan)."""
    pose = np.array([-1.5, -1.0, 0.4])
    lines = ["# synthetic", "PARAM robot_use_laser on nohost 0"]
    for index in range(n_scans):
        ranges = " ".join(f"{r:.6f}" for r in laser(pose))
        lines.append(f"FLASER 180 {ranges} {pose[0]:.9f} {pose[1]:.9f} {pose[2]:.9f} 0 0 0 {index} host {index}")
        lines.append(f"ODOM 0 0 0 0 0 0 {index} host {index}")
        pose = compose(pose, [0.15, 0.0, np.radians(3.0)])
    with gzip.open(path, "wt") as stream:
        stream.write("\n".join(lines) + "\n")


@pytest.mark.parametrize("method", ["eicp", "icp", "plicp"])
def test_scanmatch_json_on_a_synthetic_log(tmp_path, capsys, laser, method):
    log = tmp_path / "room.log.gz"
    write_room_log(log, laser)
    assert main(["scanmatch", str(log), "--matcher", method, "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["links"] == 7 and summary["matcher"] == method
    assert summary["success_share"] == 1.0
    # eICP is exact on a polygonal room; PL-ICP nearly so; point-to-point ICP is biased by the sampling.
    tolerance = {"eicp": 1e-6, "plicp": 5e-3, "icp": 3e-2}[method]
    assert summary["end_translation_error_m"] < tolerance
    assert len(summary["trajectory"]) == 8
    assert summary["config"]["max_distance"] == 1.0
    np.testing.assert_allclose(summary["trajectory"][0], summary["reference"][0])


def test_scanmatch_text_with_step(tmp_path, capsys, laser):
    log = tmp_path / "room.log.gz"
    write_room_log(log, laser)
    assert main(["scanmatch", str(log), "--step", "2", "--guess", "constant-velocity"]) == 0
    out = capsys.readouterr().out
    assert "3 links, matcher eicp, step 2" in out and "end point after" in out


def test_scanmatch_reports_bad_input_on_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.log"
    bad.write_text("FLASER 3 1 2\n")
    assert main(["scanmatch", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("p3at scanmatch: ") and "bad.log:1" in err and err.count("\n") == 1
    assert main(["scanmatch", str(tmp_path / "missing.log")]) == 2
    assert "missing.log" in capsys.readouterr().err
    assert main(["scanmatch", str(bad), "--step", "0"]) == 2  # argparse refuses it, in one line
    err = capsys.readouterr().err
    assert "--step" in err and err.count("\n") == 1
    assert main(["scanmatch", str(bad), "--matcher", "ndt"]) == 2


def test_scanmatch_on_a_real_log(laser_data_dir, capsys):
    log = laser_data_dir / "aces-corrected.log.gz"
    assert main(["scanmatch", str(log), "--guess", "reference", "--limit", "30", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["links"] == 29
    assert summary["success_share"] >= 0.75
    assert summary["median_translation_error_m"] < 0.06
