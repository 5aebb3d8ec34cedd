"""`p3at slam dataset ... --rerun SINK`: the run, beside its ground truth, in a Rerun recording that review reads."""
from __future__ import annotations

import json

import numpy as np
import pytest

from estimation.landmark_map import LandmarkMap
from runtime.dataset_recording import POSE_INTERVAL_S
from runtime.rerun_read import read_recording
from tests.datasets.conftest import run_cli as _cli


def test_the_run_is_recorded_with_its_map_and_figures(tmp_path, synthetic):
    synthetic.write(tmp_path / "data", seconds=40.0)
    noise = tmp_path / "noise.toml"
    assert _cli("slam", "noise", "mrclam", str(tmp_path / "data"), "--robot", "1", "--out", str(noise),
                "--window", "2")[0] == 0
    out_map, recording = tmp_path / "robot1.npz", tmp_path / "runs" / "robot1.rrd"
    status, out, err = _cli("slam", "dataset", "mrclam", str(tmp_path / "data"), "--robot", "1", "--out",
                            str(out_map), "--particles", "10", "--noise", str(noise), "--rerun", str(recording),
                            "--no-smooth", "--json")   # the filter's run: its pose NEES at every frame
    assert status == 0, err
    scores = json.loads(out)
    assert scores["recording"] == str(recording)
    contents = read_recording(recording)
    assert contents.robots == ["robot1"] and contents.ended
    # the map the recording holds is the file's, and its figures are the run's
    saved = LandmarkMap.load(out_map)
    np.testing.assert_array_equal(contents.maps["robot1"].positions, saved.positions)
    np.testing.assert_array_equal(contents.maps["robot1"].covariances, saved.covariances)
    assert contents.summary["ate_m"] == pytest.approx(scores["ate_m"])
    assert contents.summary["landmark_nees_within_bound"] == pytest.approx(scores["landmark_nees_within_bound"])
    # the plots cover the run, from its first sighting (whose pose NEES may be undefined: a cloud that has not spread
    # yet) to its last frame
    assert contents.duration == pytest.approx(scores["seconds"], abs=2 * POSE_INTERVAL_S)
    # written beside its name and renamed: nothing else is left in the folder
    assert sorted(p.name for p in recording.parent.iterdir()) == ["robot1.rrd"]


@pytest.mark.parametrize("sink", ["run.txt", "folder"])
def test_a_sink_it_cannot_write_is_refused_before_the_run(tmp_path, synthetic, sink):
    synthetic.write(tmp_path / "data", seconds=10.0)
    (tmp_path / "folder").mkdir()
    (tmp_path / "folder.rrd").mkdir()
    target = tmp_path / ("folder.rrd" if sink == "folder" else sink)
    out_map = tmp_path / "robot1.npz"
    status, out, err = _cli("slam", "dataset", "mrclam", str(tmp_path / "data"), "--robot", "1", "--out",
                            str(out_map), "--rerun", str(target))
    assert status == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and "--rerun" in err
    assert not out_map.exists()
