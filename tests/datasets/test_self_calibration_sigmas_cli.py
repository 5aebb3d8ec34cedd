"""`p3at slam noise mrclam DIR --robot N --self-calibrate --estimate-sigmas --noise FILE --out ROBOT.toml`: the
camera's calibration and its noise (the range's and the bearing's σ, variance components of the residuals) from
the robot's own log without its ground truth (estimation.camera_calibration, estimation.noise_components)."""
from __future__ import annotations

import gzip
import json
from pathlib import Path

import numpy as np
import pytest

from estimation.noise_model import NoiseModel, OdometryNoise, RangeBearingNoise
from tests.datasets import conftest
from tests.datasets.conftest import run_cli as _cli

RANGE_SIGMA, BEARING_SIGMA = 0.02, 0.01   # the noise added to the synthetic sightings


def _noise(tmp_path: Path, bearing_sigma: float) -> Path:
    sensor = RangeBearingNoise(RANGE_SIGMA, 0.0, bearing_sigma, fov_rad=conftest.SENSOR_FOV,
                               max_range_m=conftest.SENSOR_RANGE)
    path = tmp_path / "noise.toml"
    NoiseModel(OdometryNoise(0.01 ** 2, 0.01 ** 2, 0.01 ** 2), sensor).save(path)
    return path


def _noisy(folder: Path, seed: int = 0) -> None:
    """The synthetic log's sightings of landmarks given noise of σ RANGE_SIGMA, BEARING_SIGMA (the other robot's
    rows, subject 2, kept)."""
    path = folder / "Robot1_Measurement.dat.gz"
    with gzip.open(path, "rt") as stream:
        lines = stream.read().splitlines()
    rng = np.random.default_rng(seed)
    out = []
    for line in lines:
        values = line.split()
        if line.startswith("#") or not line.strip() or int(float(values[1])) == conftest.BARCODES[2]:
            out.append(line)
            continue
        r = float(values[2]) + rng.normal(0, RANGE_SIGMA)
        b = float(values[3]) + rng.normal(0, BEARING_SIGMA)
        out.append(f"{values[0]} {values[1]} {r:.6f} {b:.6f}")
    with gzip.open(path, "wt") as stream:
        stream.write("\n".join(out) + "\n")


def test_the_sigmas_are_estimated_written_and_said(tmp_path, synthetic):
    """The model given says σ_φ 0.004 rad, the sightings have 0.01: the written model has the log's σ's (within
    five of their standard errors) in [range_bearing], the given ones and the figures in [fit]; the text says so."""
    synthetic.write(tmp_path / "data", seconds=300.0)
    _noisy(tmp_path / "data")
    noise = _noise(tmp_path, BEARING_SIGMA / 2.5)
    out = tmp_path / "r1.toml"
    status, text, err = _cli("slam", "noise", "mrclam", str(tmp_path / "data"), "--robot", "1", "--self-calibrate",
                             "--estimate-sigmas", "--noise", str(noise), "--out", str(out))
    assert status == 0, err
    model = NoiseModel.load(out)
    fit = model.fit
    assert fit["self_calibration_given_bearing_sigma_rad"] == BEARING_SIGMA / 2.5
    assert fit["self_calibration_noise_groups"] == ["range", "bearing"]
    se = fit["self_calibration_bearing_sigma_rad_standard_error"]
    assert 0 < se < 0.1 * BEARING_SIGMA
    assert abs(model.range_bearing.bearing_sigma_rad - BEARING_SIGMA) < 5 * se
    se = fit["self_calibration_range_sigma_m_standard_error"]
    assert abs(model.range_bearing.range_sigma_m - RANGE_SIGMA) < 5 * se
    assert model.odometry == NoiseModel.load(noise).odometry
    assert "sensor sigmas (variance components" in text and "sigmas kept from" not in text
    assert "range and bearing sigmas" in model.source
    status, text, err = _cli("slam", "noise", "mrclam", str(tmp_path / "data"), "--robot", "1", "--self-calibrate",
                             "--estimate-sigmas", "--noise", str(noise), "--out", str(tmp_path / "again.toml"),
                             "--json")
    assert status == 0, err
    row = json.loads(text)
    assert row["sigmas"]["bearing_sigma_rad"] == model.range_bearing.bearing_sigma_rad
    assert row["calibration"]["bearing_variance_factor"] == pytest.approx(
        (model.range_bearing.bearing_sigma_rad / (BEARING_SIGMA / 2.5)) ** 2)


def test_without_the_option_the_json_has_no_sigma_figures(tmp_path, synthetic):
    synthetic.write(tmp_path / "data", seconds=300.0)
    _noisy(tmp_path / "data")
    status, text, err = _cli("slam", "noise", "mrclam", str(tmp_path / "data"), "--robot", "1", "--self-calibrate",
                             "--noise", str(_noise(tmp_path, BEARING_SIGMA)), "--out", str(tmp_path / "r1.toml"),
                             "--json")
    assert status == 0, err
    assert not any("variance_factor" in k or k.startswith("noise_") for k in json.loads(text)["calibration"])
    assert not any("variance_factor" in k for k in NoiseModel.load(tmp_path / "r1.toml").fit)


def test_exact_sightings_have_no_noise_to_estimate_and_nothing_is_written(tmp_path, synthetic):
    synthetic.write(tmp_path / "data", seconds=300.0)
    out = tmp_path / "r1.toml"
    status, text, err = _cli("slam", "noise", "mrclam", str(tmp_path / "data"), "--robot", "1", "--self-calibrate",
                             "--estimate-sigmas", "--noise", str(_noise(tmp_path, BEARING_SIGMA)), "--out", str(out))
    assert status == 1 and not out.exists(), (text, err)
    assert "not determined" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("options", [("--estimate-sigmas",), ("--estimate-sigmas", "--noise", "NOISE")])
def test_the_sigmas_without_the_self_calibration_are_refused_in_one_line(tmp_path, synthetic, options):
    synthetic.write(tmp_path / "data", seconds=20.0)
    noise = str(_noise(tmp_path, BEARING_SIGMA))
    options = [noise if o == "NOISE" else o for o in options]
    status, text, err = _cli("slam", "noise", "mrclam", str(tmp_path / "data"), "--robot", "1", *options, "--out",
                             str(tmp_path / "r1.toml"))
    assert status == 2 and "needs --self-calibrate" in err and len(err.strip().splitlines()) == 1 and text == ""
