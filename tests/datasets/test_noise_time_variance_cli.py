"""`p3at slam noise --time-variance`: the heading variance per second is fitted into the file's [odometry]
theta_var_per_s and printed; without the option the key stays 0 (the fit itself: tests/estimation/
test_heading_time_variance.py)."""
from __future__ import annotations

import json
import math

from estimation.datasets import read_mrclam
from estimation.noise_estimation import estimate_noise
from estimation.noise_model import NoiseModel
from tests.datasets.conftest import run_cli


def test_the_noise_command_fits_and_writes_the_heading_variance_per_second(tmp_path, synthetic):
    synthetic.write(tmp_path / "data", seconds=40.0)
    out_file = tmp_path / "noise.toml"
    base = ("slam", "noise", "mrclam", str(tmp_path / "data"), "--robot", "1", "--out", str(out_file), "--window", "2")
    status, out, err = run_cli(*base, "--time-variance", "--json")
    assert status == 0, err
    printed = json.loads(out)
    written = NoiseModel.load(out_file).odometry.theta_var_per_s
    expected = estimate_noise([read_mrclam(tmp_path / "data", 1)], window_s=2.0, time_variance=True)
    assert printed["odometry"]["theta_var_per_s"] == written == expected.model.odometry.theta_var_per_s
    assert math.isfinite(written) and written >= 0.0
    status, out, err = run_cli(*base, "--time-variance")
    assert status == 0, err
    assert f"heading variance per second: {written:.3g} rad²/s" in out
    status, out, err = run_cli(*base)
    assert status == 0, err
    assert NoiseModel.load(out_file).odometry.theta_var_per_s == 0.0 and "per second" not in out
