"""The stall after a dip of the command in the dead-reckoning windows (estimation/odometry_consistency.py with a log's
command, and `p3at slam noise`, which passes it): the windows that hold a dip take the variance the filter gives it,
the others and every window without the command or the term stay bit for bit what they were."""
from __future__ import annotations

import gzip
import json
from dataclasses import replace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.datasets import read_mrclam
from estimation.datasets.landmark_log import integrate_velocities
from estimation.fastslam.config import FastSLAMConfig
from estimation.fastslam.motion import increment_variance
from estimation.geometry import between, compose
from estimation.noise_model import NoiseModel, OdometryNoise
from estimation.odometry_consistency import CHI2_3_MEDIAN, dead_reckoned_windows, nees, odometry_consistency
from estimation.odometry_stall import command_dips, stall_variance
from tests.datasets.conftest import run_cli

STEP, DT = 0.25, 0.05          # the windows' step; the command's sample interval


def _model(sigma_s: float) -> NoiseModel:
    return NoiseModel(OdometryNoise(0.004 ** 2, 0.01 ** 2, 0.002 ** 2, stall_sigma_s=sigma_s), None)


def _log(rng, sigma_s: float, seconds: float = 1000.0, dips_until: float = 500.0):
    """(odometry rows, truth rows, command rows): arcs at 0.3 m/s, ±0.5 rad/s (sign every 7 s); a one-sample dip of
    the command 2.1 s into every 5 s up to ``dips_until``; the odometry misses the truth by the model's random walk on
    every STEP and, on the steps that hold a dip, by a stall drawn from the model's stall variance (σ_s)."""
    t = np.arange(int(seconds / DT)) * DT
    v = np.full(len(t), 0.3)
    w = 0.5 * np.where(np.floor(t / 7.0) % 2 == 0, 1.0, -1.0)
    true_v, true_w = v.copy(), w.copy()              # the robot drives through the command's hiccup
    dips = np.flatnonzero((np.arange(len(t)) % int(round(5.0 / DT)) == int(round(2.1 / DT))) & (t < dips_until))
    v[dips] = w[dips] = 0.0
    command = np.column_stack([t, v, w])
    truth = integrate_velocities(t, true_v, true_w)[::int(round(STEP / DT))]
    true_steps = between(truth[:-1, 1:], truth[1:, 1:])
    model = _model(sigma_s)
    config = replace(FastSLAMConfig(), **{k: v for k, v in model.fastslam_overrides().items() if k.startswith("odom")})
    variance = increment_variance(true_steps, config, np.diff(truth[:, 0]))
    variance = variance + stall_variance(command_dips(command), truth[:, 0], sigma_s)
    steps = true_steps + rng.standard_normal(true_steps.shape) * np.sqrt(variance)
    poses = [np.zeros(3)]
    for step in steps:
        poses.append(compose(poses[-1], step))
    odometry = np.column_stack([truth[:, 0], np.array(poses)])
    return odometry, truth, command, t[dips]


def test_the_windows_that_hold_a_dip_take_its_stall_and_the_others_stay_as_they_were():
    odometry, truth, command, dip_times = _log(np.random.default_rng(0), 0.4)
    model = _model(0.4)
    plain = dead_reckoned_windows(odometry, truth, model, 5.0)
    stalled = dead_reckoned_windows(odometry, truth, model, 5.0, command=command)
    assert np.array_equal(plain.start, stalled.start) and len(plain.start) == 199
    holds = np.array([np.any((dip_times >= s) & (dip_times < s + 5.0)) for s in plain.start])
    assert holds.sum() == 100
    before, after = nees(plain), nees(stalled)
    assert np.array_equal(before[~holds], after[~holds])                       # bit for bit where no dip falls
    assert np.array_equal(plain.covariance[~holds], stalled.covariance[~holds])
    assert np.all(after[holds] < before[holds])
    # the errors are the model's with the stall: scored with it, the windows with a dip look like χ²₃, without it not
    assert np.median(before[holds]) > 2.0 * CHI2_3_MEDIAN
    assert 0.7 * CHI2_3_MEDIAN < np.median(after[holds]) < 1.4 * CHI2_3_MEDIAN
    assert 0.7 * CHI2_3_MEDIAN < np.median(after[~holds]) < 1.4 * CHI2_3_MEDIAN
    # the report: lower where the windows hold dips; the horizon-long windows of the half without dips unchanged
    (with_term,), (without,) = (odometry_consistency([(odometry, truth)], model, [5.0], commands=c)
                                for c in ([command], None))
    assert with_term.nees_median < without.nees_median and with_term.within_chi2_95 > without.within_chi2_95


@settings(max_examples=8, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2 ** 32 - 1), sigma=st.floats(0.05, 0.5), horizons=st.sampled_from([(5.0,), (5.0, 60.0)]))
def test_without_the_command_or_the_term_the_figures_are_the_random_walks_bit_for_bit(seed, sigma, horizons):
    odometry, truth, command, _ = _log(np.random.default_rng(seed), sigma, seconds=200.0, dips_until=100.0)
    pair = [(odometry, truth)]
    old = odometry_consistency(pair, _model(0.0), horizons)                    # the random walk alone
    assert odometry_consistency(pair, _model(0.0), horizons, commands=[command]) == old
    assert odometry_consistency(pair, _model(sigma), horizons) == old
    assert odometry_consistency(pair, _model(sigma), horizons, commands=[None]) == old
    assert odometry_consistency(pair, _model(sigma), horizons, commands=[command]) != old


def test_one_command_per_pair():
    odometry, truth, command, _ = _log(np.random.default_rng(1), 0.2, seconds=60.0)
    try:
        odometry_consistency([(odometry, truth)], _model(0.2), [5.0], commands=[command, command])
    except ValueError as e:
        assert "2 commands for 1" in str(e)
    else:
        raise AssertionError("two commands for one pair were taken")


def test_slam_noise_scores_its_fitted_stall_on_the_logs_command(tmp_path, synthetic):
    """A synthetic MRCLAM log whose odometry runs on after each dip of its command (by |N(0, 1)| · 0.2 s of the
    command, as a robot stalling while its integrated command goes on): `slam noise --command-stall` fits the stall
    and its horizons' NEES (the JSON's and the file's [fit]) are those of the windows with the log's command."""
    synthetic.write(tmp_path / "data", seconds=240.0)                 # a circle at 0.2 m/s, 0.1 rad/s
    t = np.round(np.arange(0.0, 240.0, 0.02), 2)
    v, w = np.full(len(t), 0.2), np.full(len(t), 0.1)
    rng = np.random.default_rng(5)
    for dip in np.flatnonzero(np.isin(t, np.round(np.arange(3.0, 236.0, 8.0), 2))):
        v[dip] = w[dip] = 0.0
        run_on = slice(dip + 1, dip + 1 + int(round(abs(rng.standard_normal()) * 0.2 / 0.02)))
        v[run_on], w[run_on] = 0.4, 0.2                                # the command's overshoot: the truth's stall
    with gzip.open(tmp_path / "data" / "Robot1_Odometry.dat.gz", "wt") as stream:
        stream.write("# Time [s]    Forward Velocity [m/s]    Angular Velocity [rad/s]\n"
                     + "".join(f"{a:.10g} {b:.10g} {c:.10g}\n" for a, b, c in zip(t, v, w, strict=True)))
    out_file = tmp_path / "noise.toml"
    status, out, err = run_cli("slam", "noise", "mrclam", str(tmp_path / "data"), "--robot", "1", "--window", "2",
                               "--command-stall", "--out", str(out_file), "--json")
    assert status == 0, err
    printed, model = json.loads(out), NoiseModel.load(out_file)
    assert model.odometry.stall_sigma_s > 0.05
    log = read_mrclam(tmp_path / "data", 1)
    pairs = [(log.odometry, log.ground_truth)]
    with_command = odometry_consistency(pairs, model, commands=[log.velocities])
    assert printed["odometry_consistency"] == [row.as_dict() for row in with_command]
    assert model.fit["odometry_nees_median_5s"] == with_command[0].nees_median
    without = odometry_consistency(pairs, model)
    assert with_command[0].horizon_s == 5.0 and with_command[0].nees_median < without[0].nees_median
