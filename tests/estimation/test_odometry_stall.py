"""The stall after a one-sample dip of the commanded velocity (estimation.odometry_stall): the dips found in the
command, the variance they add to the increments that hold them, σ_s fitted from a log whose stalls are known, the
noise model's key (TOML round trip, refusals) and the filter taking the variance."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.datasets import RangeBearingLog
from estimation.datasets.landmark_log import integrate_velocities
from estimation.fastslam import FastSLAM, FastSLAMConfig
from estimation.noise_estimation import estimate_noise
from estimation.noise_model import NoiseModel, NoiseModelError, OdometryNoise
from estimation.observations import OdometryIncrement
from estimation.odometry_stall import CommandDips, command_dips, command_stall_variance, fit_stall, stall_variance

DT, LAG = 0.02, 0.18


@settings(max_examples=60, deadline=None)
@given(st.integers(20, 400), st.data())
def test_the_dips_found_are_the_isolated_zero_samples_amid_motion(n, data):
    rates = data.draw(st.lists(st.floats(0.05, 1.0), min_size=n, max_size=n))
    v = np.array(rates) * 0.2
    w = np.array(rates) * data.draw(st.sampled_from([-1.0, 1.0]))
    # dips three or more samples apart, not at the ends; a run of two zeros and a zero at the start are no dips
    candidates = data.draw(st.lists(st.integers(2, n - 3), unique=True, max_size=8))
    dips = []
    for i in sorted(candidates):
        if all(abs(i - j) >= 3 for j in dips):
            dips.append(i)
    v[dips] = w[dips] = 0.0
    v[0] = w[0] = 0.0
    if n > 40 and all(abs(i - 30) > 4 for i in dips):
        v[30:32] = w[30:32] = 0.0
    rows = np.column_stack([np.arange(n) * DT, v, w])
    found = command_dips(rows)
    assert np.array_equal(found.times, rows[dips, 0])
    assert np.array_equal(found.speeds, v[np.array(dips, int) - 2]) and np.array_equal(found.turn_rates,
                                                                                       w[np.array(dips, int) - 2])


def test_no_velocity_samples_no_dips():
    assert len(command_dips(np.zeros((0, 3)))) == 0 and len(command_dips(np.zeros((2, 3)))) == 0


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0.0, 10.0), min_size=0, max_size=6), st.floats(0.0, 0.5), st.floats(0.5, 2.0),
       st.floats(0.5, 2.0))
def test_each_dip_adds_its_stalls_variance_to_the_increment_that_holds_it(dip_times, sigma, kt, kr):
    times = np.array([0.5, 1.0, 2.5, 2.75, 6.0, 9.0])
    dips = CommandDips(np.array(sorted(dip_times)), np.full(len(dip_times), 0.1), np.full(len(dip_times), -0.4))
    extra = stall_variance(dips, times, sigma, (kt, kr))
    assert extra.shape == (5, 3)
    count = np.array([np.sum((dips.times >= a) & (dips.times < b)) for a, b in zip(times[:-1], times[1:], strict=True)])
    np.testing.assert_allclose(extra[:, 0], count * (kt * 0.1 * sigma) ** 2, atol=1e-15)
    np.testing.assert_allclose(extra[:, 1], extra[:, 0])
    np.testing.assert_allclose(extra[:, 2], count * (kr * 0.4 * sigma) ** 2, atol=1e-15)


def _stalled_log(rng, stalls_rms: float, seconds: float = 900.0, truth_noise_m: float = 5e-4) -> RangeBearingLog:
    """A robot on arcs (0.1 m/s, ±0.3 rad/s, the sign changing every 20 s) commanded at 50 Hz, with a one-sample zero
    of the command every 3-7 s; the truth follows the command LAG s late, except that after each dip it stops for a
    stall drawn |N(0, 1)|·``stalls_rms`` (its RMS: the σ_s the fit should give) from LAG + 0.02 s after the dip.
    The truth's positions carry white noise of ``truth_noise_m``; the odometry is the integrated command."""
    n = int(seconds / DT)
    t = np.arange(n) * DT
    v = np.full(n, 0.1)
    w = 0.3 * np.where(np.floor(t / 20.0) % 2 == 0, 1.0, -1.0)
    dips = np.cumsum(rng.integers(150, 350, size=n // 150))
    dips = dips[dips < n - 200]
    v[dips] = w[dips] = 0.0
    shift = int(round(LAG / DT))
    vt, wt = np.r_[np.zeros(shift), v[:-shift]], np.r_[np.zeros(shift), w[:-shift]]
    moving = np.ones(n, bool)
    for i, s in zip(dips, np.abs(rng.standard_normal(len(dips))) * stalls_rms, strict=True):
        start = i + shift + 1
        moving[start:start + int(round(s / DT))] = False
    truth = integrate_velocities(t, vt * moving, wt * moving, start=(1.0, 2.0, 0.3))
    truth[:, 1:3] += truth_noise_m * rng.standard_normal((n, 2))
    return RangeBearingLog("synthetic/stalls", integrate_velocities(t, v, w), np.zeros(0), np.zeros(0), np.zeros(0),
                           np.zeros(0, np.int64), ground_truth=truth, velocities=np.column_stack([t, v, w]))


@pytest.mark.parametrize("rms", [0.0, 0.1, 0.2])
def test_the_fit_gives_back_the_stalls_rms(rms):
    log = _stalled_log(np.random.default_rng(7), rms)
    sigma, fit = fit_stall([log], LAG, lambda increments: increments)
    assert fit["stall_dips"] == len(command_dips(log.velocities)) > 100
    assert fit["stall_dips_measured_heading"] > 50 and fit["stall_dips_measured_travel"] > 50
    assert sigma == pytest.approx(rms, abs=0.03 + 0.15 * rms)


def test_too_few_dips_fit_nothing_and_say_why():
    log = _stalled_log(np.random.default_rng(1), 0.2, seconds=40.0)
    sigma, fit = fit_stall([log], LAG, lambda increments: increments)
    assert sigma == 0.0 and "not fitted" in fit["stall_note"]
    without = dataclasses.replace(log, velocities=np.zeros((0, 3)))
    assert fit_stall([without], LAG, lambda increments: increments)[0] == 0.0


def test_the_noise_model_fits_writes_and_reads_the_stall(tmp_path):
    log = _stalled_log(np.random.default_rng(3), 0.15)
    model = estimate_noise([log], odometry_lag=True, command_stall=True).model
    assert model.odometry.stall_sigma_s == pytest.approx(0.15, abs=0.05)
    assert model.fit["stall_dips"] > 100 and "stall_variance_s2" in model.fit
    assert estimate_noise([log], odometry_lag=True).model.odometry.stall_sigma_s == 0.0
    model.save(tmp_path / "m.toml")
    assert NoiseModel.load(tmp_path / "m.toml") == model
    text = (tmp_path / "m.toml").read_text()
    old = "\n".join(line for line in text.splitlines() if not line.startswith("stall_sigma_s"))
    (tmp_path / "old.toml").write_text(old)
    assert NoiseModel.load(tmp_path / "old.toml").odometry.stall_sigma_s == 0.0     # absent: no term
    assert command_stall_variance(log.velocities, NoiseModel.load(tmp_path / "old.toml"), [0.0, 1.0]) is None


@pytest.mark.parametrize("value", [-0.1, 1.5, "nan"])
def test_an_impossible_stall_is_refused_in_one_line(tmp_path, value):
    text = NoiseModel(OdometryNoise(0.01, 0.01, 0.0)).to_toml().replace(
        "stall_sigma_s = 0.0", f"stall_sigma_s = {value}")
    (tmp_path / "bad.toml").write_text(text)
    with pytest.raises(NoiseModelError, match="stall_sigma_s") as caught:
        NoiseModel.load(tmp_path / "bad.toml")
    assert "\n" not in str(caught.value)


def test_the_filter_spreads_its_particles_by_the_extra_variance():
    def spread(extra):
        slam = FastSLAM(FastSLAMConfig(n_particles=400, version=1), np.random.default_rng(0))
        slam.predict(OdometryIncrement(0.1, 0.0, 0.1, 0.0, 1.0), extra)
        return np.std(slam.poses[:, 2])
    assert spread(np.array([0.0, 0.0, 0.05 ** 2])) > 2.0 * spread(None)
