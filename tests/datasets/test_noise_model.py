"""Noise models (estimation/noise_model.py): the TOML file (round trip, clean errors, fuzz), the defaults, the
calibration of odometry increments and what a model sets in the filter. Estimating a model from logs with ground truth
is tested in test_noise_estimation.py."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from estimation.fastslam import range_bearing_config
from estimation.noise_model import P3AT_VIDERE_DEFAULT, NoiseModel, NoiseModelError, OdometryNoise, RangeBearingNoise


def test_round_trip_and_defaults(tmp_path):
    model = NoiseModel(OdometryNoise(0.001, 0.002, 0.003, 0.95, 1.02), RangeBearingNoise(0.02, 0.04, 0.01, -0.01),
                       robot='robot "1"', platform="test", source="a\nb", fit={"windows": 3, "note": "x"})
    model.save(tmp_path / "n.toml")
    assert NoiseModel.load(tmp_path / "n.toml") == model
    P3AT_VIDERE_DEFAULT.save(tmp_path / "p3at.toml")
    loaded = NoiseModel.load(tmp_path / "p3at.toml")
    assert loaded == P3AT_VIDERE_DEFAULT and loaded.stereo is not None and "NOT measured" in loaded.source
    assert model.fastslam_overrides() == {"odom_xy_var_per_m": 0.001, "odom_theta_var_per_rad": 0.002,
                                          "odom_theta_var_per_m": 0.003, "odom_turn_xy_inflation": 1.0,
                                          "odom_heading_drift_sigma_per_m": 0.0, "odom_heading_drift_tau_s": 0.0,
                                          "odom_theta_var_per_s": 0.0, "fov_horizontal": 2 * math.pi,
                                          "min_range": 0.0, "max_range": 30.0}
    range_bearing_config(**model.fastslam_overrides())   # every key is a FastSLAMConfig field


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(values=st.lists(st.floats(1e-6, 6.0), min_size=4, max_size=4), windows=st.integers(0, 2 ** 40))
def test_numpy_numbers_round_trip(tmp_path, values, windows):
    """A model built from numpy scalars (as a fit makes it) writes a file its reader takes: numpy's repr,
    "np.float64(1.0)", is no TOML value (found by session 15's smoothing test)."""
    a, b, c, fov = (np.float64(v) for v in values)
    model = NoiseModel(OdometryNoise(a, b, c), RangeBearingNoise(a, b, c, fov_rad=fov),
                       fit={"windows": np.int64(windows), "share": np.float32(0.5), "ok": np.bool_(True)})
    model.save(tmp_path / "n.toml")
    loaded = NoiseModel.load(tmp_path / "n.toml")
    assert loaded.odometry == model.odometry and loaded.range_bearing == model.range_bearing
    assert loaded.fit == {"windows": windows, "share": 0.5, "ok": True}


@pytest.mark.parametrize(("text", "complaint"), [
    ("", "an empty file, not a noise model"),
    ("  \n\n", "an empty file, not a noise model"),
    ("# a comment alone\n", "no key 'format' \\(a noise model says format = 'p3at-noise-model'\\)"),
    ('format = "x"\n', "key 'format' is 'x', not 'p3at-noise-model'"),
    ('format = "p3at-noise-model"\nversion = 2\n', "version 2 is not supported"),
    ('format = "p3at-noise-model"\nversion = 1\n', r"section \[odometry\] is missing"),
    ('format = "p3at-noise-model"\nversion = 1\n[odometry]\nxy_var_per_m = 1\n', "lacks theta_var_per_m"),
    ('format = "p3at-noise-model"\nversion = 1\n[odometry]\nxy_var_per_m = -1\ntheta_var_per_rad = 1\n'
     'theta_var_per_m = 1\n', "xy_var_per_m must be a finite number >= 0"),
    ('format = "p3at-noise-model"\nversion = 1\n[odometry]\nxy_var_per_m = nan\ntheta_var_per_rad = 1\n'
     'theta_var_per_m = 1\n', "xy_var_per_m must be a finite number"),
    ('format = "p3at-noise-model"\nversion = 1\n[odometry]\nxy_var_per_m = "a"\ntheta_var_per_rad = 1\n'
     'theta_var_per_m = 1\n', r"\[odometry\] xy_var_per_m must be a number"),
    ('format = "p3at-noise-model"\nversion = 1\ncolour = 3\n', "unknown key"),
    ("format = [", "not a readable TOML"),
])
def test_a_bad_file_is_one_clear_line(tmp_path, text, complaint):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(NoiseModelError, match=complaint) as error:
        NoiseModel.load(path)
    assert "\n" not in str(error.value) and "bad.toml" in str(error.value)


@settings(max_examples=200, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=st.text(max_size=300), keep=st.booleans())
def test_fuzz_a_clean_error_or_a_valid_model(tmp_path, text, keep):
    base = P3AT_VIDERE_DEFAULT.to_toml() if keep else ""
    path = tmp_path / "fuzz.toml"
    path.write_text(base + text, encoding="utf-8")
    try:
        model = NoiseModel.load(path)
    except NoiseModelError as error:
        assert "\n" not in str(error)
        return
    assert all(math.isfinite(v) and v >= 0 for v in model.fastslam_overrides().values())


def test_the_heading_bias_round_trips_is_optional_and_bounded(tmp_path):
    model = NoiseModel(OdometryNoise(0.001, 0.002, 0.003, 0.95, 1.02, -0.025), RangeBearingNoise(0.02, 0.04, 0.01))
    model.save(tmp_path / "n.toml")
    assert NoiseModel.load(tmp_path / "n.toml").odometry.heading_bias_per_m == -0.025
    np.testing.assert_allclose(model.calibrate_increments(np.array([[0.3, 0.4, 0.1]])),
                               [[0.3 * 0.95, 0.4 * 0.95, 0.1 * 1.02 - 0.025 * 0.5]])
    header = 'format = "p3at-noise-model"\nversion = 1\n[odometry]\nxy_var_per_m = 1\ntheta_var_per_rad = 1\n' \
             'theta_var_per_m = 1\n'
    (tmp_path / "old.toml").write_text(header)            # a file written before the bias existed
    assert NoiseModel.load(tmp_path / "old.toml").odometry.heading_bias_per_m == 0.0
    for value, complaint in (("0.7", r"heading_bias_per_m must lie in \[-0.5, 0.5\]"), ("nan", "finite number"),
                             ('"x"', "must be a number")):
        (tmp_path / "bad.toml").write_text(header + f"heading_bias_per_m = {value}\n")
        with pytest.raises(NoiseModelError, match=complaint) as error:
            NoiseModel.load(tmp_path / "bad.toml")
        assert "\n" not in str(error.value) and "bad.toml" in str(error.value)


def test_the_odometry_lag_round_trips_is_optional_and_bounded(tmp_path):
    model = NoiseModel(OdometryNoise(0.001, 0.002, 0.003, lag_s=0.18), RangeBearingNoise(0.02, 0.04, 0.01))
    model.save(tmp_path / "n.toml")
    assert NoiseModel.load(tmp_path / "n.toml").odometry.lag_s == 0.18
    header = 'format = "p3at-noise-model"\nversion = 1\n[odometry]\nxy_var_per_m = 1\ntheta_var_per_rad = 1\n' \
             'theta_var_per_m = 1\n'
    (tmp_path / "old.toml").write_text(header)            # a file written before the lag existed
    assert NoiseModel.load(tmp_path / "old.toml").odometry.lag_s == 0.0
    for value, complaint in (("1.5", r"lag_s must lie in \[0, 1.0\] s"), ("-0.1", "finite number >= 0")):
        (tmp_path / "bad.toml").write_text(header + f"lag_s = {value}\n")
        with pytest.raises(NoiseModelError, match=complaint) as error:
            NoiseModel.load(tmp_path / "bad.toml")
        assert "\n" not in str(error.value) and "bad.toml" in str(error.value)


def test_the_fitted_detection_rates_set_the_filters_existence_evidence():
    # the [fit] section's P(detect) per range band and outlier share become the filter's existence log-odds
    # (estimation/fastslam/existence.py); a model without them leaves the filter's constants alone
    from estimation.fastslam.existence import hit_log_odds, miss_log_odds
    from estimation.noise_model import with_fastslam
    odometry, sensor = OdometryNoise(0.001, 0.002, 0.003), RangeBearingNoise(0.02, 0.04, 0.01)
    fit = {"detection_probability_below_3m": 0.6, "detection_probability_3_to_5m": 0.4,
           "detection_probability_beyond_5m": 0.2, "sensor_outlier_fraction": 0.04}
    config = with_fastslam(NoiseModel(odometry, sensor, fit=fit), range_bearing_config())
    assert config.detection_probabilities == (0.6, 0.4, 0.2) and config.detection_range_edges == (3.0, 5.0)
    assert config.false_alarm_probability == 0.04
    ranges = np.array([1.0, 4.0, 7.0])
    np.testing.assert_allclose(miss_log_odds(config, ranges), np.log([0.4, 0.6, 0.8]))
    np.testing.assert_allclose(hit_log_odds(config, ranges), np.log([15.0, 10.0, 5.0]))
    plain = with_fastslam(NoiseModel(odometry, sensor, fit={"sensor_outlier_fraction": 0.04}), range_bearing_config())
    assert plain.detection_probabilities == () and miss_log_odds(plain, ranges) == plain.existence_miss


@settings(max_examples=50, deadline=None)
@given(increment=st.tuples(st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.floats(-1.0, 1.0)),
       deficit=st.floats(0.0, 0.5), scale=st.floats(0.5, 2.0), bias=st.floats(-0.5, 0.5))
def test_the_forward_deficit_shortens_the_chord_along_itself_to_no_less_than_zero(increment, deficit, scale, bias):
    raw = np.array([increment])
    with_deficit = NoiseModel(OdometryNoise(1e-3, 1e-3, 1e-3, scale, 1.0, bias, forward_deficit_per_rad=deficit))
    without = dataclasses.replace(with_deficit, odometry=dataclasses.replace(with_deficit.odometry,
                                                                             forward_deficit_per_rad=0.0))
    out, plain = with_deficit.calibrate_increments(raw)[0], without.calibrate_increments(raw)[0]
    distance = math.hypot(increment[0], increment[1])
    assert out[2] == plain[2] == pytest.approx(increment[2] + bias * distance)     # the turn is not touched
    expected = scale * max(distance - deficit * abs(increment[2]), 0.0)
    assert math.hypot(out[0], out[1]) == pytest.approx(expected, abs=1e-12)
    assert out[0] * increment[1] - out[1] * increment[0] == pytest.approx(0.0, abs=1e-12)   # along the chord
    assert out[0] * increment[0] + out[1] * increment[1] >= 0.0                             # never backwards
    np.testing.assert_allclose(plain, [increment[0] * scale, increment[1] * scale, increment[2] + bias * distance],
                               rtol=1e-12, atol=1e-15)   # the same arithmetic up to rounding (order of operations)


def test_the_forward_deficit_round_trips_is_optional_and_bounded(tmp_path):
    model = NoiseModel(OdometryNoise(0.001, 0.002, 0.003, 1.06, 0.96, forward_deficit_per_rad=0.092),
                       RangeBearingNoise(0.02, 0.04, 0.01))
    model.save(tmp_path / "n.toml")
    assert NoiseModel.load(tmp_path / "n.toml") == model
    np.testing.assert_allclose(model.calibrate_increments(np.array([[0.3, 0.4, 0.5], [0.0, 0.0, 0.3]])),
                               [[0.3 * 1.06 * 0.908, 0.4 * 1.06 * 0.908, 0.5 * 0.96], [0.0, 0.0, 0.3 * 0.96]])
    header = 'format = "p3at-noise-model"\nversion = 1\n[odometry]\nxy_var_per_m = 1\ntheta_var_per_rad = 1\n' \
             'theta_var_per_m = 1\n'
    (tmp_path / "old.toml").write_text(header)            # a file written before the deficit existed
    old = NoiseModel.load(tmp_path / "old.toml")
    assert old.odometry.forward_deficit_per_rad == 0.0
    np.testing.assert_array_equal(old.calibrate_increments(np.array([[0.3, 0.4, 0.5]])), [[0.3, 0.4, 0.5]])
    for value, complaint in (("0.7", r"forward_deficit_per_rad must lie in \[0, 0.5\]"),
                             ("-0.1", "finite number >= 0"), ("inf", "finite number")):
        (tmp_path / "bad.toml").write_text(header + f"forward_deficit_per_rad = {value}\n")
        with pytest.raises(NoiseModelError, match=complaint) as error:
            NoiseModel.load(tmp_path / "bad.toml")
        assert "\n" not in str(error.value) and "bad.toml" in str(error.value)
