"""``p3at slam dataset --json``: every warning the JSON holds is also one line on stderr (a user piping the JSON still
sees them), in the JSON's order and words, and the JSON is the same as without them on stderr; the text mode prints
the same warnings as its ``WARNING:`` lines. A run without warnings writes nothing on stderr."""
from __future__ import annotations

import gzip
import json

from estimation.noise_model import NoiseModel, OdometryNoise, RangeBearingNoise
from tests.datasets.conftest import run_cli


def _shift_the_landmarks_truth(folder, metres: float) -> None:
    """Move every landmark's true position by ``metres`` in x and y: the map is then confidently wrong."""
    table = folder / "Landmark_Groundtruth.dat.gz"
    with gzip.open(table, "rt") as f:
        rows = [line if line.startswith("#") else " ".join(
            str(float(v) + (metres if k in (1, 2) else 0.0)) for k, v in enumerate(line.split())) + "\n" for line in f]
    with gzip.open(table, "wt") as f:
        f.writelines(rows)


def test_every_warning_of_the_json_is_also_one_line_on_stderr(tmp_path, synthetic):
    """A map 0.5 m off its truth with covariances of a few cm (the NEES warning, _map_warnings) from a camera model
    referenced to the direction of travel scored against the motion capture (_frame_warnings): both on stderr."""
    synthetic.write(tmp_path / "data", seconds=40.0)
    sensor = RangeBearingNoise(0.02, 0.0, 0.01, fov_rad=synthetic.SENSOR_FOV, max_range_m=synthetic.SENSOR_RANGE)
    noise = tmp_path / "noise.toml"
    NoiseModel(OdometryNoise(0.01 ** 2, 0.01 ** 2, 0.01 ** 2), sensor, fit={"truth_heading": "travel"}).save(noise)
    args = ("slam", "dataset", "mrclam", str(tmp_path / "data"), "--robot", "1", "--out", str(tmp_path / "m.npz"),
            "--particles", "20", "--noise", str(noise), "--barcodes", "table")
    status, out, err = run_cli(*args, "--json")
    assert status == 0, err
    warnings = json.loads(out)["warnings"]
    assert len(warnings) == 1 and "referenced to the direction of travel" in warnings[0]
    assert err.splitlines() == [f"p3at slam dataset: warning: {warnings[0]}"]

    _shift_the_landmarks_truth(tmp_path / "data", 0.5)
    status, out, err = run_cli(*args, "--json")
    assert status == 0, err
    warnings = json.loads(out)["warnings"]
    assert len(warnings) == 2 and "within their covariance's χ²₂ 95 % bound" in warnings[0]
    assert err.splitlines() == [f"p3at slam dataset: warning: {w}" for w in warnings]
    status, text, err = run_cli(*args)
    assert status == 0 and err == ""
    assert [line.split("WARNING: ", 1)[1] for line in text.splitlines() if "WARNING: " in line] == warnings


def test_a_run_without_warnings_writes_nothing_on_stderr(tmp_path, synthetic):
    synthetic.write(tmp_path / "data", seconds=40.0)
    sensor = RangeBearingNoise(0.02, 0.0, 0.01, fov_rad=synthetic.SENSOR_FOV, max_range_m=synthetic.SENSOR_RANGE)
    noise = tmp_path / "noise.toml"
    NoiseModel(OdometryNoise(0.01 ** 2, 0.01 ** 2, 0.01 ** 2), sensor).save(noise)
    status, out, err = run_cli("slam", "dataset", "mrclam", str(tmp_path / "data"), "--robot", "1", "--out",
                               str(tmp_path / "m.npz"), "--particles", "20", "--noise", str(noise), "--barcodes",
                               "table", "--json")
    assert status == 0 and json.loads(out)["warnings"] == [] and err == ""
