"""Estimating a noise model from logs with ground truth (estimation/noise_estimation.py): synthetic logs made with
known noise, and MRCLAM data set 2 (skipped without ../shared/data). The model and its TOML file are tested in
test_noise_model.py."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from estimation.datasets import RangeBearingLog, read_mrclam
from estimation.geometry import between, compose, wrap_angle
from estimation.noise_estimation import estimate_noise


def _chain(steps: np.ndarray) -> np.ndarray:
    """Poses (n + 1, 3) from the origin composing steps (n, 3) (closed form of repeated `compose`)."""
    heading = np.concatenate([[0.0], np.cumsum(steps[:, 2])])
    c, s = np.cos(heading[:-1]), np.sin(heading[:-1])
    xy = np.vstack([[0.0, 0.0], np.cumsum(np.column_stack([c * steps[:, 0] - s * steps[:, 1],
                                                             s * steps[:, 0] + c * steps[:, 1]]), axis=0)])
    return np.column_stack([xy, wrap_angle(heading)])


def test_closed_form_chain_is_composition():
    steps = np.random.default_rng(0).normal(0, 0.3, (50, 3))
    pose = np.zeros(3)
    for step in steps:
        pose = compose(pose, step)
    np.testing.assert_allclose(_chain(steps)[-1], pose, atol=1e-12)


def _synthetic_log(rng, q_xy, q_theta_rad, q_theta_m, scale, sigma_r, slope_r, sigma_b, offset_b, rho_b=0.0,
                   heading_bias=0.0, lag=0.0, switching=False, forward_deficit=0.0):
    """A robot circling (wiggling) for 30 min at 50 Hz among 12 landmarks; odometry = (true increments +
    random-walk noise) / scale, its heading short of the truth by ``heading_bias`` rad per metre driven (the
    robot curves where its odometry says straight), stamped ``lag`` s before the motion it reports (commanded
    velocity, which the robot follows late); ``switching``: the wiggle's turn rate switches between two values
    (as commanded turns do) instead of varying smoothly; ``forward_deficit``: the odometry's distance exceeds the
    truth's by that many metres per radian turned (a robot that covers less ground in turns than commanded);
    sightings within a camera's range."""
    dt, n = 0.02, 90_000
    t = np.arange(n + 1) * dt
    v = 0.2 + 0.1 * np.sin(t[:-1] / 7.0)
    w = 2 * np.pi / 60.0 + 0.3 * (np.sign if switching else np.asarray)(np.sin(t[:-1] / 5.0))   # a 60 s loop of
    #                                                                        # ~2 m radius, wiggling
    true_steps = np.column_stack([v * dt, np.zeros(n), w * dt])
    truth = np.zeros((n + 1, 3))
    truth[1:] = np.cumsum(true_steps[:, 2])[:, None] * [0, 0, 1]
    # integrate the truth step by step (exactly the composition the estimator inverts)
    c, s = np.cos(np.concatenate([[0.0], truth[1:-1, 2]])), np.sin(np.concatenate([[0.0], truth[1:-1, 2]]))
    truth[1:, 0] = np.cumsum(c * true_steps[:, 0])
    truth[1:, 1] = np.cumsum(s * true_steps[:, 0])
    d = np.abs(true_steps[:, 0])
    noisy = true_steps + rng.standard_normal((n, 3)) * np.sqrt(np.column_stack(
        [q_xy * d, q_xy * d, q_theta_rad * np.abs(true_steps[:, 2]) + q_theta_m * d]))
    noisy[:, 2] -= heading_bias * d
    noisy[:, 0] += forward_deficit * np.abs(true_steps[:, 2])
    noisy = noisy / [scale, scale, scale]
    odometry = _chain(noisy)
    landmarks = rng.uniform(-6, 6, (12, 2)) + truth[:, :2].mean(axis=0)
    times = t[::25]
    poses = truth[::25]
    ids = rng.integers(0, 12, len(times))
    delta = landmarks[ids] - poses[:, :2]
    r = np.hypot(delta[:, 0], delta[:, 1])
    b = wrap_angle(np.arctan2(delta[:, 1], delta[:, 0]) - poses[:, 2])
    ranges = r + rng.standard_normal(len(r)) * (sigma_r + slope_r * r)
    # bearing noise: an AR(1) series per landmark, lag-1 correlation rho_b between its consecutive sightings
    white = rng.standard_normal(len(r))
    noise_b = white.copy()
    for landmark in range(12):
        k = np.flatnonzero(ids == landmark)
        for i in range(1, len(k)):
            noise_b[k[i]] = rho_b * noise_b[k[i - 1]] + np.sqrt(1 - rho_b ** 2) * white[k[i]]
    bearings = b + offset_b + noise_b * sigma_b
    seen = (r > 0.5) & (r < 6.0)                                       # a camera's range
    return RangeBearingLog("synthetic", np.column_stack([t - lag, odometry]), times[seen], np.abs(ranges[seen]),
                           bearings[seen], ids[seen] + 6, np.column_stack([t, truth]), np.arange(6, 18), landmarks)


def test_estimation_recovers_the_noise_that_made_the_log():
    rng = np.random.default_rng(5)
    q = dict(q_xy=0.04 ** 2, q_theta_rad=0.08 ** 2, q_theta_m=0.05 ** 2)
    log = _synthetic_log(rng, **q, scale=1.08, sigma_r=0.03, slope_r=0.03, sigma_b=0.02, offset_b=-0.015)
    model = estimate_noise([log], window_s=5.0).model
    o, rb = model.odometry, model.range_bearing
    # 360 windows: a variance is estimated to ~10 % (1/√(n/2)); allow 30 %
    assert o.xy_var_per_m == pytest.approx(q["q_xy"], rel=0.3)
    assert o.theta_var_per_rad + o.theta_var_per_m == pytest.approx(q["q_theta_rad"] + q["q_theta_m"], rel=0.35)
    assert o.translation_scale == pytest.approx(1.08, abs=0.01) and o.rotation_scale == pytest.approx(1.08, abs=0.02)
    assert rb.bearing_offset_rad == pytest.approx(-0.015, abs=0.002)
    assert rb.range_correlation < 0.1 and rb.bearing_correlation < 0.1 and rb.variance_inflation()[0] < 1.25
    assert rb.bearing_sigma_rad == pytest.approx(0.02, rel=0.1)
    for r in (3.0, 5.0):   # where the sightings are (2.6-5.9 m): a line fitted there is not checked elsewhere
        assert float(rb.range_sigma([r])[0]) == pytest.approx(0.03 + 0.03 * r, rel=0.15)
    # calibrated short increments (0.2 s: chords are paths) match the truth on average
    t = log.ground_truth[::10, 0]
    fixed = model.calibrate_increments(log.odometry_increments(t))
    true = between(log.true_pose(t[:-1]), log.true_pose(t[1:]))
    assert abs(np.sum(fixed[:, 0]) / np.sum(true[:, 0]) - 1.0) < 0.01


def test_a_heading_bias_per_metre_is_recovered_and_calibrated_away():
    """Odometry whose heading misses -0.03 rad per metre (a robot that curves right on a straight run, UMBmark's
    type-A error): the fit finds the bias, and the calibrated dead reckoning keeps its heading where the scales
    alone let it drift by ~10 rad over the log; a log without a bias gets none (within its standard error)."""
    q = dict(q_xy=0.04 ** 2, q_theta_rad=0.08 ** 2, q_theta_m=0.05 ** 2)
    log = _synthetic_log(np.random.default_rng(7), **q, scale=1.0, sigma_r=0.03, slope_r=0.03, sigma_b=0.02,
                         offset_b=0.0, heading_bias=-0.03)
    model = estimate_noise([log], heading_bias=True).model
    se = model.fit["heading_bias_per_m_standard_error"]
    assert 0 < se < 0.01 and model.odometry.heading_bias_per_m == pytest.approx(-0.03, abs=3 * se)
    assert model.odometry.rotation_scale == pytest.approx(1.0, abs=0.02)
    t = log.ground_truth[::10, 0]
    true_heading = np.sum(between(log.true_pose(t[:-1]), log.true_pose(t[1:]))[:, 2])
    calibrated = np.sum(model.calibrate_increments(log.odometry_increments(t))[:, 2])
    unbiased = estimate_noise([log]).model        # the default: the scales alone
    assert unbiased.odometry.heading_bias_per_m == 0.0
    scales_only = np.sum(unbiased.calibrate_increments(log.odometry_increments(t))[:, 2])
    assert abs(calibrated - true_heading) < 0.2 * abs(scales_only - true_heading)
    plain = estimate_noise([_synthetic_log(np.random.default_rng(8), **q, scale=1.0, sigma_r=0.03, slope_r=0.03,
                                           sigma_b=0.02, offset_b=0.0)], heading_bias=True).model
    assert abs(plain.odometry.heading_bias_per_m) < 3 * plain.fit["heading_bias_per_m_standard_error"]


def test_an_odometry_that_leads_the_motion_is_found_and_read_that_much_later():
    """Odometry stamped 0.2 s before the motion it reports (a commanded velocity the drive follows late), its turn
    rate switching as commanded turns do (where a lag shows: a smooth wiggle hides it in the random walk): the fit
    finds the lag, and the heading increments read that much earlier lose most of their error; odometry without
    a lag gets none; the option is off by default."""
    q = dict(q_xy=0.02 ** 2, q_theta_rad=0.03 ** 2, q_theta_m=0.01 ** 2, scale=1.0, sigma_r=0.03, slope_r=0.03,
             sigma_b=0.02, offset_b=0.0, switching=True)
    log = _synthetic_log(np.random.default_rng(9), **q, lag=0.2)
    model = estimate_noise([log], odometry_lag=True).model
    assert model.odometry.lag_s == pytest.approx(0.2, abs=0.015)
    # read 0.2 s earlier, the 0.25 s heading increments keep only the random walk's error; as stamped, twice that
    t = np.arange(1.0, log.ground_truth[-1, 0], 0.25)
    true = between(log.true_pose(t[:-1]), log.true_pose(t[1:]))
    walk = float(np.sqrt(np.mean(q["q_theta_rad"] * np.abs(true[:, 2]) + q["q_theta_m"] * np.abs(true[:, 0]))))
    assert model.fit["odometry_lag_heading_rms_rad"] == pytest.approx(walk, rel=0.15)
    assert model.fit["odometry_no_lag_heading_rms_rad"] > 1.5 * walk
    np.testing.assert_allclose(model.odometry_times([10.0, 20.0]), [10.0 - model.odometry.lag_s,
                                                                    20.0 - model.odometry.lag_s])
    assert estimate_noise([log]).model.odometry.lag_s == 0.0
    plain = estimate_noise([_synthetic_log(np.random.default_rng(10), **q)], odometry_lag=True).model
    assert plain.odometry.lag_s <= 0.015


def test_real_dataset2_odometry_leads_the_motion(mrclam_dir):
    # MRCLAM's odometry is the commanded velocity: the robots follow it ~0.17 s late
    # (docs/fastslam-history.md "Session 9")
    model = estimate_noise([read_mrclam(mrclam_dir, 2, until=600.0)], odometry_lag=True).model
    assert 0.1 <= model.odometry.lag_s <= 0.3
    assert model.fit["odometry_lag_heading_rms_rad"] < model.fit["odometry_no_lag_heading_rms_rad"]


def test_estimation_refuses_a_log_without_ground_truth():
    log = RangeBearingLog("x", np.array([[0.0, 0, 0, 0], [1.0, 1, 0, 0]]), [0.5], [1.0], [0.0], [6])
    with pytest.raises(ValueError, match="needs ground truth"):
        estimate_noise([log])


def test_real_dataset2_noise_is_plausible_and_time_correlated(mrclam_dir):
    log = read_mrclam(mrclam_dir, 2, until=600.0)
    estimate = estimate_noise([log])
    rb = estimate.model.range_bearing
    # the camera's range error grows with the range (σ at 5 m larger than at 1 m), the bearing is good to degrees
    assert rb.range_sigma([5.0])[0] > rb.range_sigma([1.0])[0] and rb.bearing_sigma_rad < math.radians(5)
    # commanded-velocity odometry: the variance per metre grows with the window (errors correlated in time)
    by_window = estimate.odometry_by_window
    assert by_window[-1, 1] > by_window[0, 1]
    # a landmark the camera misses in one frame is likely missed in the next (occlusion, an unreadable barcode):
    # the detected / missed sequence is correlated, and the far band is detected less often than the near one
    fit = estimate.model.fit
    assert 0.3 < fit["detection_correlation"] < 0.9
    assert fit["detection_probability_beyond_5m"] < fit["detection_probability_below_3m"]
    assert estimate.model.existence_overrides()["detection_correlation"] == fit["detection_correlation"]


def test_real_dataset2_robot1_odometry_curves_right(mrclam_dir):
    # robot 1's first 900 s: its heading falls behind the commanded one by ~0.07 rad per metre driven (every
    # robot's does, 0.02-0.06 rad/m over the whole log: docs/fastslam-history.md), far beyond the fit's standard error
    model = estimate_noise([read_mrclam(mrclam_dir, 1, until=900.0)], heading_bias=True).model
    se = model.fit["heading_bias_per_m_standard_error"]
    assert model.odometry.heading_bias_per_m < -2.5 * se and se < 0.05


def test_correlated_sightings_are_measured_and_inflate_the_variance():
    """Consecutive sightings of a landmark sharing their error (AR(1), ρ = 0.6): ρ is recovered, and the variance
    inflation (1 + ρ)/(1 − ρ) = 4 is what a filter taking them as independent needs."""
    log = _synthetic_log(np.random.default_rng(6), 0.04 ** 2, 0.08 ** 2, 0.05 ** 2, 1.0, 0.03, 0.03, 0.02, 0.0,
                         rho_b=0.6)
    rb = estimate_noise([log], sensor_correlation="lag1").model.range_bearing
    # pairs are consecutive sightings within 2 s: mostly adjacent in the AR(1) series
    assert rb.bearing_correlation == pytest.approx(0.6, abs=0.1) and rb.range_correlation < 0.1
    assert rb.variance_inflation()[1] == pytest.approx((1 + rb.bearing_correlation) / (1 - rb.bearing_correlation))


def test_an_error_shared_by_a_whole_pass_is_measured_over_passes():
    """Passes of 10 sightings 0.2 s apart, each pass's bearings sharing one offset (σ 0.01) beside white noise
    (σ 0.01): consecutive sightings correlate at ρ = 0.5, whose AR(1) inflation (1 + ρ)/(1 − ρ) = 3 understates
    what a pass's mean really varies by, n·Var(m)/σ² = (10·σ_p² + σ_w²)/(σ_p² + σ_w²) = 5.5; the pass measure
    finds it, and the range (white) needs none."""
    rng = np.random.default_rng(9)
    log = _synthetic_log(rng, 0.04 ** 2, 0.08 ** 2, 0.05 ** 2, 1.0, 0.03, 0.03, 0.02, 0.0)
    times = (np.arange(590)[:, None] * 3.0 + 5.0 + np.arange(10)[None, :] * 0.2).ravel()
    ids = np.repeat(np.arange(590) % 12, 10)
    pose = log.true_pose(times)
    delta = log.truth_positions[ids] - pose[:, :2]
    bearing = wrap_angle(np.arctan2(delta[:, 1], delta[:, 0]) - pose[:, 2])
    bearing += np.repeat(rng.normal(0.0, 0.01, 590), 10) + rng.normal(0.0, 0.01, len(times))
    ranges = np.hypot(delta[:, 0], delta[:, 1]) + rng.normal(0.0, 0.05, len(times))
    log = dataclasses.replace(log, sighting_times=times, ranges=ranges, bearings=bearing, landmark_ids=ids + 6)
    lag1 = estimate_noise([log]).model                # the default: lag-1
    passes = estimate_noise([log], sensor_correlation="passes").model
    assert lag1.range_bearing.bearing_correlation == pytest.approx(0.5, abs=0.08)
    assert passes.fit["bearing_pass_inflation"] == pytest.approx(5.5, rel=0.2)
    assert passes.range_bearing.variance_inflation()[1] == pytest.approx(passes.fit["bearing_pass_inflation"])
    assert passes.range_bearing.variance_inflation()[0] < 1.5 and lag1.range_bearing.variance_inflation()[1] < 3.5
    with pytest.raises(ValueError, match="sensor_correlation"):
        estimate_noise([log], sensor_correlation="lag2")


def test_a_forward_deficit_per_radian_is_recovered_and_calibrated_away():
    """Odometry that says 0.09 m more than the robot drove per radian turned (MRCLAM's Creates in arcs): the fit
    finds the deficit and the straight-line scale, the random walk left is the one that made the log (one scale for
    all motion takes the deficit as noise: q_xy several times too large), and the calibrated increments of the
    turning steps add up to the true forward travel; a log without one gets none; off by default.

    The log's 50 Hz steps carry little noise against their own turn and chord (a commanded-velocity odometry, like
    MRCLAM's, carries none): the calibration reads each step's |Δθ| and chord, so noise in them biases the fit as
    errors in variables do — E|Δθ + n| > |Δθ| raises the translation scale, and the chord's sideways noise raises c
    by E[chord / forward] (at this log's q_xy 1.3 %; at q_xy = 0.02², q_θ = 0.05² c came out 6 % and k 1 % high)."""
    q = dict(q_xy=0.01 ** 2, q_theta_rad=0.01 ** 2, q_theta_m=0.005 ** 2, sigma_r=0.03, slope_r=0.03, sigma_b=0.02,
             offset_b=0.0)
    log = _synthetic_log(np.random.default_rng(11), **q, scale=1.05, forward_deficit=0.09)
    model = estimate_noise([log], turn_translation=True).model
    se = model.fit["forward_deficit_per_rad_standard_error"]
    assert 0 < se < 0.01 and model.odometry.forward_deficit_per_rad == pytest.approx(0.09, abs=3 * se)
    assert model.odometry.translation_scale == pytest.approx(1.05, abs=0.01)
    assert model.odometry.xy_var_per_m == pytest.approx(q["q_xy"], rel=0.3)
    assert model.fit["forward_deficit_displacement_rms_m"] < 0.7 * model.fit["forward_deficit_none_displacement_rms_m"]
    scale_only = estimate_noise([log]).model
    assert scale_only.odometry.forward_deficit_per_rad == 0.0 and "forward_deficit_per_rad_standard_error" not in \
        scale_only.fit
    assert scale_only.odometry.xy_var_per_m > 2 * q["q_xy"]
    t = log.ground_truth[::10, 0]
    raw = log.odometry_increments(t)
    true = between(log.true_pose(t[:-1]), log.true_pose(t[1:]))
    turning = np.abs(true[:, 2]) / 0.2 > 0.25
    for fitted, tolerance in ((model, 0.01), (scale_only, None)):
        ratio = np.sum(fitted.calibrate_increments(raw)[turning, 0]) / np.sum(true[turning, 0])
        if tolerance is None:
            assert ratio > 1.04          # one scale: the turns' forward travel overstated
        else:
            assert abs(ratio - 1.0) < tolerance
    plain = estimate_noise([_synthetic_log(np.random.default_rng(12), **q, scale=1.05)], turn_translation=True).model
    assert plain.odometry.forward_deficit_per_rad < max(3 * plain.fit.get("forward_deficit_per_rad_standard_error",
                                                                         0.0), 0.005)
    assert plain.odometry.translation_scale == pytest.approx(1.05, abs=0.01)
