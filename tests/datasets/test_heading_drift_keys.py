"""The noise model's drifting heading bias (σ_b rad/m, τ s): optional [odometry] keys, round trip, bounds, and the
FastSLAMConfig fields they set."""
from __future__ import annotations

import pytest

from estimation.fastslam import FastSLAMConfig, range_bearing_config
from estimation.noise_model import NoiseModel, NoiseModelError, OdometryNoise, RangeBearingNoise, with_fastslam

HEADER = ('format = "p3at-noise-model"\nversion = 1\n[odometry]\nxy_var_per_m = 1\ntheta_var_per_rad = 1\n'
          'theta_var_per_m = 1\n')


def test_the_heading_drift_round_trips_and_sets_the_filter(tmp_path):
    model = NoiseModel(OdometryNoise(0.001, 0.002, 0.003, heading_drift_sigma_per_m=0.14, heading_drift_tau_s=20.0),
                       RangeBearingNoise(0.02, 0.04, 0.01))
    model.save(tmp_path / "n.toml")
    loaded = NoiseModel.load(tmp_path / "n.toml")
    assert loaded == model and loaded.odometry.heading_drift == (0.14, 20.0)
    config = with_fastslam(loaded, range_bearing_config())
    assert (config.odom_heading_drift_sigma_per_m, config.odom_heading_drift_tau_s) == (0.14, 20.0)


def test_an_old_file_has_no_heading_drift_and_leaves_the_filter_as_it_was(tmp_path):
    (tmp_path / "old.toml").write_text(HEADER)            # a file written before the drift existed
    old = NoiseModel.load(tmp_path / "old.toml")
    assert old.odometry.heading_drift is None
    assert (old.odometry.heading_drift_sigma_per_m, old.odometry.heading_drift_tau_s) == (0.0, 0.0)
    assert with_fastslam(old, FastSLAMConfig()) == FastSLAMConfig(odom_xy_var_per_m=1.0, odom_theta_var_per_rad=1.0,
                                                                  odom_theta_var_per_m=1.0)


@pytest.mark.parametrize(("lines", "complaint"), [
    ("heading_drift_sigma_per_m = -0.1\nheading_drift_tau_s = 10\n", "heading_drift_sigma_per_m must be a finite"),
    ("heading_drift_sigma_per_m = nan\nheading_drift_tau_s = 10\n", "heading_drift_sigma_per_m must be a finite"),
    ("heading_drift_sigma_per_m = 1.5\nheading_drift_tau_s = 10\n", r"heading_drift_sigma_per_m must lie in \[0, 1"),
    ("heading_drift_sigma_per_m = 0.1\n", "heading_drift_tau_s must be > 0 when heading_drift_sigma_per_m"),
    ("heading_drift_sigma_per_m = 0.1\nheading_drift_tau_s = 0\n", "heading_drift_tau_s must be > 0 when"),
    ("heading_drift_sigma_per_m = 0.1\nheading_drift_tau_s = inf\n", "heading_drift_tau_s must be a finite"),
    ("heading_drift_sigma_per_m = 0.1\nheading_drift_tau_s = -5\n", "heading_drift_tau_s must be a finite"),
    ('heading_drift_tau_s = "x"\n', r"\[odometry\] heading_drift_tau_s must be a number"),
])
def test_a_bad_heading_drift_is_one_line_naming_the_key(tmp_path, lines, complaint):
    (tmp_path / "bad.toml").write_text(HEADER + lines)
    with pytest.raises(NoiseModelError, match=complaint) as error:
        NoiseModel.load(tmp_path / "bad.toml")
    assert "\n" not in str(error.value) and "bad.toml" in str(error.value)


@pytest.mark.parametrize("values", [dict(odom_heading_drift_sigma_per_m=-0.1, odom_heading_drift_tau_s=10.0),
                                    dict(odom_heading_drift_sigma_per_m=0.1),
                                    dict(odom_heading_drift_sigma_per_m=0.1, odom_heading_drift_tau_s=float("nan")),
                                    dict(odom_heading_drift_sigma_per_m=float("inf"), odom_heading_drift_tau_s=1.0)])
def test_the_filter_refuses_a_bad_heading_drift(values):
    with pytest.raises(ValueError, match="odom_heading_drift"):
        FastSLAMConfig(**values)
