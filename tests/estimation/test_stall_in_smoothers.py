"""The stall after a dip of the command (estimation.odometry_stall) in the smoothers outside the data set's run: the
chain's named smoothing (named_problem, with and without the path variances) and the camera's self-calibration take
the noise model's stall variance on the increments that hold a dip, and nothing changes without the term or without
a dip (the data set's own filter and smoother: tests/datasets/test_command_stall.py)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.camera_calibration import self_calibrate
from estimation.datasets import RangeBearingLog
from estimation.datasets.landmark_log import integrate_velocities
from estimation.fastslam import range_bearing_config
from estimation.fastslam.motion import increment_variance
from estimation.geometry import between
from estimation.named_smoothing import named_problem, smooth_named
from estimation.noise_model import NoiseModel, OdometryNoise, RangeBearingNoise, with_fastslam
from tests.estimation.test_camera_calibration import _log, _model

DT = 0.02          # the command's sample interval (MRCLAM's 50 Hz)
FRAME_S = 0.25     # a sighting frame every this many seconds
V, W = 0.2, 0.3    # the command: an arc


def _arc_log(dip_samples, seconds: float = 12.0, turn: float = 1.0) -> RangeBearingLog:
    """A robot commanded on an arc (V m/s, ``turn``·W rad/s) at 50 Hz, with a one-sample zero of the command at
    ``dip_samples``; its odometry the integrated command; two posts sighted every FRAME_S s (the ranges and bearings
    only need to be sightings: the odometry factors are what is tested)."""
    n = int(seconds / DT) + 1
    t = np.arange(n) * DT
    v, w = np.full(n, V), np.full(n, turn * W)
    v[list(dip_samples)] = w[list(dip_samples)] = 0.0
    frames = np.arange(0.1, seconds - 0.5, FRAME_S)
    times = np.repeat(frames, 2)
    ids = np.tile([3, 7], len(frames)).astype(np.int64)
    return RangeBearingLog("synthetic/arc", integrate_velocities(t, v, w), times, np.where(ids == 3, 2.0, 3.5),
                           np.where(ids == 3, 0.3, -0.2), ids, velocities=np.column_stack([t, v, w]))


def _noise(stall_sigma_s: float, lag_s: float = 0.0) -> NoiseModel:
    odometry = OdometryNoise(0.01 ** 2, 0.01 ** 2, 0.01 ** 2, translation_scale=0.95, rotation_scale=1.1,
                             lag_s=lag_s, stall_sigma_s=stall_sigma_s)
    return NoiseModel(odometry, RangeBearingNoise(0.02, 0.01, 0.01, fov_rad=1.2, max_range_m=8.0))


@settings(max_examples=30, deadline=None)
@given(st.lists(st.integers(20, 500), min_size=1, max_size=5, unique=True), st.floats(0.01, 1.0),
       st.sampled_from([0.0, 0.18]), st.sampled_from([-1.0, 1.0]), st.sampled_from([None, 0.1]))
def test_the_chain_s_smoothing_adds_the_stall_on_the_increments_that_hold_a_dip(samples, sigma, lag, turn, path):
    dips = sorted(s for s in samples if all(abs(s - o) >= 3 for o in samples if o < s))   # isolated samples
    log = _arc_log(dips, turn=turn)
    steady = _arc_log([], turn=turn)
    names = log.landmark_ids.copy()
    config = range_bearing_config()

    def variances(the_log, noise):
        return named_problem(the_log, names, noise, config, path_step_s=path).problem.increment_variances

    plain = variances(log, _noise(0.0, lag))
    if path is None:   # without the term: the chord's random walk, as before the term
        problem = named_problem(log, names, _noise(0.0, lag), config).problem
        assert np.array_equal(plain, increment_variance(problem.increments, with_fastslam(_noise(0.0, lag), config),
                                                        problem.increment_seconds))
    # without a dip in the command: the same factors with the term as without, bit for bit
    assert np.array_equal(variances(steady, _noise(sigma, lag)), variances(steady, _noise(0.0, lag)))
    stalled = variances(log, _noise(sigma, lag))
    # the increment k (between frames k - 1 and k; frame -1 is frame 0's time) holds a dip at t when the odometry
    # read lag s early spans it: t_{k-1} - lag <= t < t_k - lag
    frame_times = np.unique(log.sighting_times)
    frame_times = np.concatenate([frame_times[:1], frame_times]) - lag
    holds = np.array([np.sum((np.array(dips) * DT >= a) & (np.array(dips) * DT < b))
                      for a, b in zip(frame_times[:-1], frame_times[1:], strict=True)])
    assert np.array_equal(stalled[holds == 0], plain[holds == 0])
    at = holds > 0
    # the command before each dip is the arc's: (k_r ω σ_s)² on the heading per dip, (k_t v σ_s)² on x and y at least
    # (exactly on the chord; along the path the heading's stall also swings the rest of the increment sideways)
    np.testing.assert_allclose(stalled[at, 2] - plain[at, 2], holds[at] * (1.1 * W * sigma) ** 2, rtol=1e-9)
    extra_xy = holds[at] * (0.95 * V * sigma) ** 2
    if path is None:
        np.testing.assert_allclose(stalled[at, :2] - plain[at, :2], extra_xy[:, None] * [1.0, 1.0], rtol=1e-9)
    else:
        assert np.all(stalled[at, :2] - plain[at, :2] >= extra_xy[:, None] * (1.0 - 1e-9))


def test_the_smoothed_named_solution_moves_with_the_stall_only_where_it_applies():
    """The chain's smoother (smooth_named through named_problem) weighs the dip's increment less: its solution differs
    from the one without the term, and is the same bit for bit with the term and no dip."""
    log = _arc_log([101, 262])
    config = range_bearing_config()
    rng = np.random.default_rng(2)
    bumped = dataclasses.replace(log, bearings=log.bearings + rng.normal(0.0, 0.01, len(log)),
                                 ranges=log.ranges + rng.normal(0.0, 0.02, len(log)))
    steady = dataclasses.replace(_arc_log([]), bearings=bumped.bearings, ranges=bumped.ranges)
    names = log.landmark_ids.copy()

    def poses(the_log, noise):
        return smooth_named(the_log, names, noise, config)[1].poses

    plain = poses(bumped, _noise(0.0))
    assert np.array_equal(poses(steady, _noise(0.3)), poses(steady, _noise(0.0)))
    assert not np.array_equal(poses(bumped, _noise(0.3)), plain)


def _with_command(log: RangeBearingLog, dip_every: int | None) -> RangeBearingLog:
    """``log`` with the velocity samples its truth was driven by (v, ω between consecutive truth rows), a one-sample
    zero every ``dip_every`` samples (None: no dip)."""
    t = log.ground_truth[:, 0]
    step = between(log.ground_truth[:-1, 1:], log.ground_truth[1:, 1:])
    dt = np.diff(t)
    v = np.append(np.hypot(step[:, 0], step[:, 1]) / dt, 0.0)
    w = np.append(step[:, 2] / dt, 0.0)
    if dip_every is not None:
        at = np.arange(dip_every, len(t) - 2, dip_every)
        v[at] = w[at] = 0.0
    return dataclasses.replace(log, velocities=np.column_stack([t, v, w]))


def _stalling(model: NoiseModel, sigma: float) -> NoiseModel:
    return dataclasses.replace(model, odometry=dataclasses.replace(model.odometry, stall_sigma_s=sigma))


@pytest.mark.timeout(1200)  # CPU-bound: four self-calibrations, 13 s of CPU. test_camera_calibration's σ_φ test (21 s)
# ran past the 300 s default in a .ci/run at nice 5 beside five helpers' jobs (session 46): over 14x its CPU in wall
# time, which would make this one's 185 s
def test_the_self_calibration_weighs_the_dips_increments_by_the_stall_and_nothing_else_changes():
    log = _log(np.random.default_rng(1))
    dipped, steady = _with_command(log, 300), _with_command(log, None)
    model = _model()
    base = self_calibrate(steady, model)
    assert base.problem is None
    # without the term, or without a dip: the same calibration, bit for bit
    for same in (self_calibrate(dipped, model), self_calibrate(log, _stalling(model, 0.2))):
        assert np.array_equal(same.values, base.values) and np.array_equal(same.covariance, base.covariance)
        assert same.chi2_per_dof == base.chi2_per_dof
    stalled = self_calibrate(dipped, _stalling(model, 0.2))
    assert stalled.problem is None
    # the odometry weighed less on the dips' increments (119, one every 6 s): the metric the odometry gives the range
    # scale and the heading that pins the bearing offset are known less well, and the cost at the solution is lower
    se, base_se = stalled.standard_errors, base.standard_errors
    assert se[1] > base_se[1] and se[4] > base_se[4]
    assert stalled.chi2_per_dof < base.chi2_per_dof


def test_the_odometry_s_variance_factor_scales_the_stall_as_it_did_in_the_solve():
    log = _with_command(_log(np.random.default_rng(3)), 300)
    model = _stalling(_model(), 0.2)
    calibration = self_calibrate(log, model, noise_components=("odometry", "range", "bearing"))
    assert calibration.problem is None
    factor = float(calibration.noise_components.factors[0])
    written = calibration.applied(model, "synthetic", "self-calibrated")
    assert written.odometry.stall_sigma_s == pytest.approx(0.2 * math.sqrt(factor), rel=1e-12)
    assert written.odometry.xy_var_per_m == pytest.approx(model.odometry.xy_var_per_m * factor, rel=1e-12)
