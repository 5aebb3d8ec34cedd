"""The /R/odom messages of a sensor log carry covariances from the robot's odometry noise model
(runtime/sensorlog.py ``OdometryCovariance``), read back with mcap's own reader and its ROS 2 decoder: they were
all zeros, which ROS tools read as a perfectly known pose."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from estimation.fastslam.config import FastSLAMConfig
from estimation.geometry import compose
from runtime.sensorlog import NOMINAL_SIP_PERIOD, UNUSED_AXIS_VARIANCE, SensorLogWriter

PLANAR = [0, 1, 5]           # x, y, rotation about Z in the 6×6
NOISE = {"odom_xy_var_per_m": 0.05 ** 2, "odom_theta_var_per_rad": 0.1 ** 2, "odom_theta_var_per_m": 0.04 ** 2,
         "odom_var_floor": 1e-8}


def _route(n: int = 60, dt: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """(times (n,), odometry poses (n, 3)): 1 s at rest, then 0.5 m/s ahead while turning 0.3 rad/s."""
    increments = np.zeros((n, 3))
    increments[11:] = (0.5 * dt, 0.0, 0.3 * dt)
    poses = np.zeros((n, 3))
    for k in range(1, n):
        poses[k] = compose(poses[k - 1], increments[k])
    return 10.0 + dt * np.arange(n), poses


def _odometry_messages(tmp_path: Path, settings: dict) -> list:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    times, poses = _route()
    folder = tmp_path / "robot1-log"
    with SensorLogWriter(folder, {"robot": "robot1", **settings}) as writer:
        for t, (x, y, theta) in zip(times, poses, strict=True):
            writer.write("odometry", {"t": t, "x": x, "y": y, "theta": theta, "v": 0.0, "w": 0.0, "stalled": 0,
                                      "sonar": np.zeros(0), "sonar_poses": np.zeros((0, 3)),
                                      "raw": np.zeros(4, np.uint8)})
    (segment,) = writer.segments
    with open(segment, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        messages = [m for _, channel, _, m in reader.iter_decoded_messages() if channel.topic == "/robot1/odom"]
    assert len(messages) == len(times)
    return messages


def _matrices(message) -> tuple[np.ndarray, np.ndarray]:
    return (np.asarray(message.pose.covariance, float).reshape(6, 6),
            np.asarray(message.twist.covariance, float).reshape(6, 6))


@pytest.mark.parametrize("settings", [{"fastslam": NOISE}, {}])
def test_the_covariances_are_valid_and_say_nothing_on_the_axes_a_planar_robot_does_not_measure(tmp_path, settings):
    for message in _odometry_messages(tmp_path, settings):
        for cov in _matrices(message):
            np.testing.assert_array_equal(cov, cov.T)
            assert np.linalg.eigvalsh(cov).min() > 0                     # positive definite: no zero, no -1
            np.testing.assert_array_equal(np.diag(cov)[[2, 3, 4]], UNUSED_AXIS_VARIANCE)
            assert np.all(np.diag(cov)[PLANAR] < 1.0)


def test_the_pose_covariance_is_the_integrated_random_walk_of_the_noise_model(tmp_path):
    """Against a Monte Carlo of the model itself: 20,000 odometry runs whose every increment is drawn with the
    model's variances; their final poses' scatter is what the last message must claim (within 5 % on each σ)."""
    messages = _odometry_messages(tmp_path, {"fastslam": NOISE})
    times, poses = _route()
    rng = np.random.default_rng(0)
    runs = np.zeros((20_000, 3))
    for k in range(1, len(poses)):
        c, s = np.cos(poses[k - 1, 2]), np.sin(poses[k - 1, 2])
        d = poses[k] - poses[k - 1]
        inc = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], np.arctan2(np.sin(d[2]), np.cos(d[2]))])
        trans = np.hypot(inc[0], inc[1])
        var = np.array([NOISE["odom_xy_var_per_m"] * trans] * 2
                       + [NOISE["odom_theta_var_per_rad"] * abs(inc[2]) + NOISE["odom_theta_var_per_m"] * trans])
        runs = compose(runs, inc + rng.standard_normal(runs.shape) * np.sqrt(var + NOISE["odom_var_floor"]))
    pose_cov = _matrices(messages[-1])[0][np.ix_(PLANAR, PLANAR)]
    np.testing.assert_allclose(np.sqrt(np.diag(pose_cov)), runs.std(axis=0), rtol=0.05)
    # grows with the distance driven: at rest only the floor, then every message more than the one before
    sigma_x = [np.sqrt(_matrices(m)[0][0, 0]) for m in messages]
    assert sigma_x[10] < 1e-3 and all(b > a for a, b in zip(sigma_x[11:], sigma_x[12:], strict=False))


def test_the_twist_covariance_is_the_increment_s_over_the_sip_period_and_the_defaults_are_fastslam_s(tmp_path):
    messages = _odometry_messages(tmp_path, {})
    default = FastSLAMConfig()
    at_rest, moving = _matrices(messages[5])[1], _matrices(messages[30])[1]
    dt = 0.1
    np.testing.assert_allclose(np.diag(at_rest)[PLANAR], default.odom_var_floor / dt ** 2, rtol=1e-6)
    step = 0.5 * dt                                      # each increment: 0.05 m ahead, then 0.03 rad of turn
    want = np.array([default.odom_xy_var_per_m * step] * 2
                    + [default.odom_theta_var_per_rad * 0.3 * dt + default.odom_theta_var_per_m * step])
    np.testing.assert_allclose(np.diag(moving)[PLANAR], (want + default.odom_var_floor) / dt ** 2, rtol=1e-6)
    first = _matrices(messages[0])[1]
    np.testing.assert_allclose(first[0, 0], default.odom_var_floor / NOMINAL_SIP_PERIOD ** 2, rtol=1e-9)


def test_a_turns_inflation_in_the_settings_widens_a_tight_arcs_increments_and_a_missing_one_is_the_default():
    from runtime.sensorlog import OdometryCovariance
    default = FastSLAMConfig()
    arc = np.array([0.02, 0.0, 0.1])                     # 5 rad/m: an increment of a turn (motion.turning)
    straight = np.array([0.05, 0.0, 0.03])               # 0.6 rad/m: not one
    for settings, factor in (({"odom_turn_xy_inflation": 5.0}, 5.0), ({"odom_turn_xy_inflation": 1}, 1.0),
                             ({"odom_turn_xy_inflation": None}, 1.0), ({}, 1.0), (None, 1.0)):
        for increment, widened in ((arc, factor), (straight, 1.0)):
            covariance = OdometryCovariance.from_settings(settings)
            covariance.update(0.0, np.zeros(3))
            twist = covariance.update(0.1, increment)[1]
            want = default.odom_xy_var_per_m * np.hypot(*increment[:2]) + default.odom_var_floor
            np.testing.assert_allclose(twist[0, 0] * 0.1 ** 2, want * widened, rtol=1e-9)


@pytest.mark.parametrize("inflation", [0.5, 0.0, 0.999])
def test_a_turns_inflation_the_filter_refuses_is_refused_with_the_filter_s_error(tmp_path, inflation):
    """One rule (FastSLAMConfig's: the turns' inflation >= 1): the sensor log's settings give its error, not the
    default in silence."""
    with pytest.raises(ValueError) as by_the_config:
        FastSLAMConfig(odom_turn_xy_inflation=inflation)
    with pytest.raises(ValueError) as by_the_log:
        SensorLogWriter(tmp_path / "robot1-log", {"robot": "robot1", "fastslam": {
            **NOISE, "odom_turn_xy_inflation": inflation}})
    assert str(by_the_log.value) == str(by_the_config.value)
    assert "odom_turn_xy_inflation must be ≥ 1" in str(by_the_log.value)
    assert not (tmp_path / "robot1-log").exists()   # a refused log leaves no empty folder behind


@pytest.mark.parametrize(("key", "value"), [("odom_xy_var_per_m", -1e-4), ("odom_var_floor", float("nan")),
                                            ("odom_theta_var_per_rad", "0.01"), ("odom_turn_xy_inflation", True)])
def test_any_other_bad_odometry_noise_in_the_settings_is_an_error_too(key, value):
    from runtime.sensorlog import OdometryCovariance
    with pytest.raises(ValueError, match="must be"):
        OdometryCovariance.from_settings({**NOISE, key: value})
