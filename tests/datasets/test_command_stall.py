"""The stall after a dip of the commanded velocity on data sets: the reader keeps the command (the dips are in it, and
gone from the integration where the stamps are coarse), `p3at slam noise --command-stall` writes the term, and the
data set's filter and smoother take its variance (the fit itself: tests/estimation/test_odometry_stall.py)."""
from __future__ import annotations

import dataclasses
import json

import numpy as np

from estimation.dataset_slam import run_landmark_log
from estimation.datasets import read_mrclam
from estimation.fastslam import range_bearing_config
from estimation.geometry import between
from estimation.noise_model import NoiseModel, OdometryNoise, RangeBearingNoise
from estimation.odometry_stall import command_dips
from tests.datasets.conftest import run_cli


def test_mrclam_dips_are_in_the_command_and_gone_from_the_integration_where_stamps_are_coarse(mrclam_dir):
    log = read_mrclam(mrclam_dir, 1)
    assert log.velocities.shape == (len(log.odometry), 3)
    dips = command_dips(log.velocities)
    assert 140 <= len(dips) <= 180                                # ~one every 12 s of motion over 1,900 s
    late = dips.times >= 1000.0
    assert late.sum() > 50
    early = dips.times[~late]
    at_x90 = np.abs(early + 0.1 - np.round(early + 0.1)) < 1e-6
    assert at_x90.mean() > 0.95                                   # at x.90 s: the commanding process's hiccup
    # the integrated odometry: rows sharing a 0.1 s stamp from t = 1000 s integrate over no time, and the dips vanish
    rows = log.odometry
    step = between(rows[:-1, 1:], rows[1:, 1:])
    timed = np.flatnonzero(np.diff(rows[:, 0]) > 0)
    still = (np.abs(step[timed, 0]) < 1e-12) & (np.abs(step[timed, 2]) < 1e-12)
    shown = timed[1:-1][still[1:-1] & ~still[:-2] & ~still[2:]]
    assert np.sum(rows[shown, 0] >= 1000.0) < 0.1 * late.sum()


def test_the_noise_command_writes_the_stall_or_says_why_not(tmp_path, synthetic):
    synthetic.write(tmp_path / "data", seconds=40.0)          # a steady command: no dip
    out_file = tmp_path / "noise.toml"
    base = ("slam", "noise", "mrclam", str(tmp_path / "data"), "--robot", "1", "--out", str(out_file), "--window", "2")
    status, out, err = run_cli(*base, "--command-stall", "--json")
    assert status == 0, err
    printed = json.loads(out)
    assert printed["odometry"]["stall_sigma_s"] == NoiseModel.load(out_file).odometry.stall_sigma_s == 0.0
    assert printed["fit"]["stall_dips"] == 0 and "not fitted" in printed["fit"]["stall_note"]
    status, out, err = run_cli(*base, "--command-stall")
    assert status == 0, err
    assert "stall after a dip of the command: none (not fitted" in out
    status, out, err = run_cli(*base)
    assert status == 0, err
    assert "stall" not in out and "stall_dips" not in NoiseModel.load(out_file).fit


def test_the_data_set_run_widens_the_increments_that_hold_a_dip(tmp_path, synthetic):
    synthetic.write(tmp_path, seconds=40.0)
    log = read_mrclam(tmp_path, 1)
    sensor = RangeBearingNoise(0.02, 0.0, 0.01, fov_rad=synthetic.SENSOR_FOV, max_range_m=synthetic.SENSOR_RANGE)
    plain = NoiseModel(OdometryNoise(0.01 ** 2, 0.01 ** 2, 0.01 ** 2), sensor)
    stalling = dataclasses.replace(plain, odometry=dataclasses.replace(plain.odometry, stall_sigma_s=0.5))
    dipped = log.velocities.copy()
    dipped[np.arange(200, len(dipped) - 10, 150), 1:] = 0.0     # a one-sample zero of the command every 3 s
    with_dips = dataclasses.replace(log, velocities=dipped)

    def run(noise, the_log):
        return run_landmark_log(the_log, range_bearing_config(n_particles=10), np.random.default_rng(4), noise=noise,
                                association="id", robot="robot1", smooth=True).map

    base = run(plain, with_dips)
    # no dip (the command as the reader gave it), or no term: the same run
    np.testing.assert_array_equal(run(stalling, log).covariances, base.covariances)
    assert run(plain, log).covariances.tolist() == base.covariances.tolist()
    wider = run(stalling, with_dips)
    assert np.all(np.trace(wider.covariances[:, :2, :2], axis1=1, axis2=2)
                  > np.trace(base.covariances[:, :2, :2], axis1=1, axis2=2))


def test_the_data_set_command_fits_the_stall_when_no_model_is_given(tmp_path, mrclam_dir):
    """Without --noise, `p3at slam dataset` fits the stall with the other calibrations (DATASET_CALIBRATIONS, since
    session 42), writes it with the map and says so; on robot 1 it is the session-41 fit (σ_s ~0.1 s)."""
    from estimation.landmark_map import LandmarkMap

    out_file = tmp_path / "r1.npz"
    status, out, err = run_cli("slam", "dataset", "mrclam", str(mrclam_dir), "--robot", "1", "--until", "60",
                               "--out", str(out_file), "--json")
    assert status == 0, err
    printed = json.loads(out)
    assert "the stall after the command's dips" in printed["noise"]
    stall = LandmarkMap.load(out_file).metadata["noise_model"]["stall_sigma_s"]
    assert 0.05 < stall < 0.2
