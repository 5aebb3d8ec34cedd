"""The noise model's drifting heading bias (σ_b rad/m, τ s): optional [odometry] keys, round trip, bounds, the
FastSLAMConfig fields they set, its fit (odometry_consistency.fit_heading_drift) and `slam noise --heading-drift`."""
from __future__ import annotations

import json

import numpy as np
import pytest

from estimation.fastslam import FastSLAMConfig, range_bearing_config
from estimation.geometry import dead_reckoning
from estimation.noise_model import NoiseModel, NoiseModelError, OdometryNoise, RangeBearingNoise, with_fastslam
from estimation.odometry_consistency import fit_heading_drift, odometry_consistency
from tests.datasets.conftest import gauss_markov, run_cli

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


STEP = 0.25


def _drifting_log(rng, seconds: float, sigma: float, tau: float, model: NoiseModel):
    """(odometry rows, truth rows) (t, x, y, θ) every STEP s: a wandering path whose odometry has the model's random
    walk and a heading that misses a Gauss–Markov bias b (σ, τ) per metre (σ = 0: none)."""
    t = np.arange(int(seconds / STEP)) * STEP
    v = 0.3 + 0.2 * np.sin(t / 11.0)
    w = 0.4 * np.sin(t / 7.0) + 0.2 * np.sin(t / 2.3)
    true_steps = np.column_stack([v * STEP, np.zeros_like(t), w * STEP])
    bias = gauss_markov(rng, len(t), sigma, np.exp(-STEP / tau))
    o = model.odometry
    noisy = true_steps + rng.standard_normal(true_steps.shape) * np.sqrt(
        [o.xy_var_per_m * v * STEP, o.xy_var_per_m * v * STEP,
         o.theta_var_per_rad * np.abs(w) * STEP + o.theta_var_per_m * v * STEP]).T
    noisy[:, 2] -= bias * np.hypot(noisy[:, 0], noisy[:, 1])     # the truth turns b per metre more
    stamps = np.arange(len(t) + 1)[:, None] * STEP
    return (np.hstack([stamps, dead_reckoning(noisy)]), np.hstack([stamps, dead_reckoning(true_steps)]))


def test_the_fit_finds_a_drift_that_is_there_and_none_where_there_is_none():
    """10,000 s of odometry with a drifting heading bias (σ_b 0.01 rad/m, τ 20 s; a heading error of ~0.3 rad over
    300 s, where the first-order propagation still holds): the fit's σ_b is in [0.005, 0.025] (seeds 5-8: 0.012-0.022;
    the 300 s horizon rests on 33 independent windows) and makes dead reckoning consistent where the plain model is
    not (300 s windows: ≥ 85 % within the χ²₃ 95 % bound, against < 75 % without; seeds 5-8: 0.89-0.94 against
    0.41-0.52); the same path without a drift gets σ_b ≤ 0.004 (seeds: 0-0.002; a drift there only inflates a
    covariance that already fits)."""
    model = NoiseModel(OdometryNoise(0.02 ** 2, 0.02 ** 2, 0.005 ** 2))
    horizons, sigmas = (5.0, 30.0, 100.0, 300.0), tuple(0.002 * k for k in range(16))
    drifting = [_drifting_log(np.random.default_rng(5), 10_000.0, 0.01, 20.0, model)]
    fit = fit_heading_drift(drifting, model, horizons, sigmas=sigmas, stride_s=20.0)
    assert 0.005 <= fit.sigma_per_m <= 0.025 and fit.cost < 0.2 * fit.cost_without, fit
    (plain,) = odometry_consistency(drifting, model, [300.0], stride_s=20.0)
    (carried,) = odometry_consistency(drifting, model, [300.0], stride_s=20.0, heading_drift=fit.heading_drift)
    assert plain.within_chi2_95 < 0.75 and carried.within_chi2_95 >= 0.85, (plain, carried)
    clean = fit_heading_drift([_drifting_log(np.random.default_rng(6), 10_000.0, 0.0, 20.0, model)], model,
                              horizons, sigmas=sigmas, stride_s=20.0)
    assert clean.sigma_per_m <= 0.004, clean
    with pytest.raises(ValueError, match="correlation times"):
        fit_heading_drift(drifting, model, horizons, taus=(0.0,))


def test_the_noise_command_fits_and_writes_the_heading_drift(tmp_path, synthetic):
    """`p3at slam noise --heading-drift`: the two keys in the file (σ_b 0 on exact odometry: no drift helps) and
    the fit's costs in [fit]; without the option the keys stay 0 and no cost is written."""
    synthetic.write(tmp_path / "data", seconds=40.0)
    out_file = tmp_path / "noise.toml"
    base = ("slam", "noise", "mrclam", str(tmp_path / "data"), "--robot", "1", "--out", str(out_file), "--window", "2")
    status, out, err = run_cli(*base, "--heading-drift", "--json")
    assert status == 0, err
    printed = json.loads(out)
    model = NoiseModel.load(out_file)
    assert printed["odometry"]["heading_drift_sigma_per_m"] == model.odometry.heading_drift_sigma_per_m == 0.0
    assert model.fit["heading_drift_cost"] <= model.fit["heading_drift_cost_without"]
    status, out, err = run_cli(*base, "--heading-drift")
    assert status == 0, err and "drifting heading bias: none" in out
    status, out, err = run_cli(*base)
    assert status == 0, err
    assert "heading_drift_cost" not in NoiseModel.load(out_file).fit and "drifting heading bias" not in out
