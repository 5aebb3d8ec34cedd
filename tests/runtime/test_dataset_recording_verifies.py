"""A data set run's recording (``p3at slam dataset ... --rerun FILE.rrd``) is written whole after the run, so it ends
with Rerun's footer: ``rerun rrd verify`` (Rerun's own checker) accepts it, and Rerun's reader indexes it without
scanning. (A mission's recording leaves the footer out: its index grows in memory while the mission runs.)"""
from __future__ import annotations

import subprocess
import sys
import warnings
from pathlib import Path

from tests.datasets.conftest import run_cli
from tests.datasets.conftest import synthetic as synthetic  # noqa: F401 - the fixture, used by name


def test_rerun_rrd_verify_accepts_a_data_set_runs_recording(tmp_path, synthetic):  # noqa: F811
    synthetic.write(tmp_path / "data", seconds=40.0)
    noise = tmp_path / "noise.toml"   # as tests/datasets/test_dataset_recording.py: a log this short needs one given
    assert run_cli("slam", "noise", "mrclam", str(tmp_path / "data"), "--robot", "1", "--out", str(noise),
                   "--window", "2")[0] == 0
    recording = tmp_path / "robot1.rrd"
    status, _, err = run_cli("slam", "dataset", "mrclam", str(tmp_path / "data"), "--robot", "1", "--out",
                             str(tmp_path / "robot1.npz"), "--particles", "10", "--noise", str(noise), "--no-smooth",
                             "--rerun", str(recording))
    assert status == 0, err
    rerun = Path(sys.executable).with_name("rerun")
    verified = subprocess.run([str(rerun), "rrd", "verify", str(recording)], capture_output=True, text=True,
                              timeout=300)
    assert verified.returncode == 0, verified.stdout + verified.stderr
    import rerun.chunk as rrchunk

    with warnings.catch_warnings():
        warnings.simplefilter("error")          # "RRD file has no footer/manifest ... legacy format" would raise
        assert rrchunk.RrdReader(recording).recordings()
