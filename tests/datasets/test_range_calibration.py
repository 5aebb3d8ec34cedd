"""The range calibration of a camera that reports depth along its axis, not range (noise_model, Session 8), and
localization on a known map (run_landmark_log(known_map=True), the floor of docs/fastslam-history.md "Session 8")."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from estimation.dataset_slam import run_landmark_log
from estimation.datasets import RangeBearingLog, read_mrclam
from estimation.fastslam import range_bearing_config
from estimation.geometry import wrap_angle
from estimation.noise_estimation import estimate_noise
from estimation.noise_model import NoiseModel, NoiseModelError, RangeBearingNoise

FOV_HALF = 0.55          # rad: MRCLAM's cameras see ±0.55-0.58 rad


def _camera_log(rng, *, scale=1.0, offset=0.0, yaw=0.0, depth=True, sigma_r=0.02, sigma_b=0.005,
                minutes=12.0) -> RangeBearingLog:
    """A robot wandering for ``minutes`` among 15 posts, Vicon-exact truth, near-exact odometry; its camera
    reports a post in view every 0.25 s with bearing φ + noise and, with ``depth``, range
    ``offset + scale · r · cos(φ − yaw)`` + noise (the depth along an axis yawed by ``yaw``), else r + noise."""
    dt = 0.02
    t = np.arange(int(minutes * 60 / dt) + 1) * dt
    heading = np.cumsum(np.concatenate([[0.0], (0.25 + 0.4 * np.sin(t[:-1] / 9.0)) * dt]))
    speed = 0.25 + 0.1 * np.sin(t / 13.0)
    x = np.cumsum(np.concatenate([[0.0], speed[:-1] * np.cos(heading[:-1]) * dt]))
    y = np.cumsum(np.concatenate([[0.0], speed[:-1] * np.sin(heading[:-1]) * dt]))
    truth = np.column_stack([t, x, y, heading])
    posts = rng.uniform(-5, 5, (15, 2)) + [x.mean(), y.mean()]
    odometry = truth.copy()
    odometry[:, 1:3] += np.cumsum(rng.normal(0, 2e-4, (len(t), 2)), axis=0)
    rows = []
    for k in range(0, len(t), 12):                       # 0.24 s frames
        delta = posts - truth[k, 1:3]
        r = np.hypot(delta[:, 0], delta[:, 1])
        phi = wrap_angle(np.arctan2(delta[:, 1], delta[:, 0]) - truth[k, 3])
        for i in np.flatnonzero((np.abs(phi) < FOV_HALF) & (r > 0.6) & (r < 7.0)):
            reported = offset + scale * r[i] * np.cos(phi[i] - yaw) if depth else r[i]
            rows.append((t[k], reported + rng.normal(0, sigma_r), phi[i] + rng.normal(0, sigma_b), i + 1))
    rows = np.array(rows)
    return RangeBearingLog("camera", odometry, rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3].astype(np.int64),
                           truth, np.arange(1, 16), posts)


def _range_residuals(log: RangeBearingLog, sensor: RangeBearingNoise) -> np.ndarray:
    pose = log.true_pose(log.sighting_times)
    target = log.truth_positions[np.searchsorted(log.truth_ids, log.landmark_ids)]
    return sensor.corrected(log.ranges, log.bearings)[0] - np.hypot(*(target - pose[:, :2]).T)


def test_a_camera_reporting_depth_is_calibrated_out_of_sample():
    made = dict(scale=0.97, offset=0.06, yaw=0.03)
    fitted = estimate_noise([_camera_log(np.random.default_rng(1), **made)], range_calibration=True).model
    plain = estimate_noise([_camera_log(np.random.default_rng(1), **made)]).model
    fresh = _camera_log(np.random.default_rng(2), **made)             # another run of the same camera
    calibrated_rms = float(np.sqrt(np.mean(_range_residuals(fresh, fitted.range_bearing) ** 2)))
    plain_rms = float(np.sqrt(np.mean(_range_residuals(fresh, plain.range_bearing) ** 2)))
    # the depth model is the polynomial to second order in φ: what is left is the noise (0.02 m) and the
    # fourth-order term (r φ⁴ / 24 · scale ≤ 7 · 0.55⁴ / 24 ≈ 0.027 m at the far edge, far less on average)
    assert calibrated_rms < 0.03 < 3 * calibrated_rms < plain_rms
    rb = fitted.range_bearing
    assert rb.range_scale_per_rad2 == pytest.approx(rb.range_scale / 2, rel=0.15)      # 1/cos φ ≈ 1 + φ²/2
    assert rb.range_scale == pytest.approx(1 / made["scale"], rel=0.02)
    assert rb.range_scale_per_rad == pytest.approx(-made["yaw"] * rb.range_scale, abs=0.01)
    # the noise model describes the residuals that are left, not the bias: σ_r near the camera's 0.02 m
    assert float(rb.range_sigma(3.0)) < 0.035 < float(plain.range_bearing.range_sigma(3.0))


def test_a_camera_reporting_range_gets_the_identity():
    log = _camera_log(np.random.default_rng(3), depth=False)
    rb = estimate_noise([log], range_calibration=True).model.range_bearing
    assert rb.range_offset_m == pytest.approx(0.0, abs=0.01) and rb.range_scale == pytest.approx(1.0, abs=0.005)
    assert abs(rb.range_scale_per_rad) < 0.01 and abs(rb.range_scale_per_rad2) < 0.02
    default = estimate_noise([log]).model.range_bearing
    assert (default.range_offset_m, default.range_scale, default.range_scale_per_rad,
            default.range_scale_per_rad2) == (0.0, 1.0, 0.0, 0.0)          # off by default: the identity


def test_calibration_round_trips_and_old_files_load(tmp_path):
    model = estimate_noise([_camera_log(np.random.default_rng(4), scale=1.03)], range_calibration=True).model
    model.save(tmp_path / "cal.toml")
    assert NoiseModel.load(tmp_path / "cal.toml") == model
    old = "\n".join(line for line in model.to_toml().splitlines() if not line.startswith("range_scale")
                    and not line.startswith("range_offset"))
    (tmp_path / "old.toml").write_text(old)
    loaded = NoiseModel.load(tmp_path / "old.toml").range_bearing
    r, phi = np.array([1.0, 4.0]), np.array([0.3, -0.5])
    np.testing.assert_array_equal(loaded.corrected(r, phi)[0], r)          # absent keys: the identity
    (tmp_path / "bad.toml").write_text(model.to_toml().replace("range_scale = ", "range_scale = 3.0 #"))
    with pytest.raises(NoiseModelError, match="range_scale must lie in") as error:
        NoiseModel.load(tmp_path / "bad.toml")
    assert "\n" not in str(error.value) and "bad.toml" in str(error.value)


def test_localization_on_the_true_map_is_the_floor_and_the_calibration_lowers_it():
    """On the true map, with a camera reporting depth: the calibrated model localizes better than the plain one,
    fitted on another run of the same camera (out of sample), through the product's runner."""
    made = dict(scale=1.0, offset=0.0, yaw=0.0, sigma_b=0.01, minutes=6.0)
    log = _camera_log(np.random.default_rng(6), **made)
    other = _camera_log(np.random.default_rng(7), **made)
    ates = {}
    for calibrate in (False, True):
        noise = estimate_noise([other], range_calibration=calibrate).model
        run = run_landmark_log(log, range_bearing_config(n_particles=30), np.random.default_rng(0), noise=noise,
                               association="id", known_map=True)
        assert run.metrics["landmarks"] == 15 and run.metrics["landmark_error_median_m"] < 0.01   # kept as given
        ates[calibrate] = run.metrics["ate_m"]
    assert ates[True] < ates[False]
    with pytest.raises(ValueError, match="known_map needs association='id'"):
        run_landmark_log(log, range_bearing_config(n_particles=5), np.random.default_rng(0), noise=noise,
                         association="unknown", known_map=True)


def test_mrclam_first_half_calibration_holds_on_the_second_half(mrclam_dir):
    """MRCLAM robot 3: fitted on the log's first half, the calibration cuts the second half's range residuals
    (the sightings within 4 robust σ) at least threefold, and b₂ ≈ b₀ / 2 (a camera that reports depth)."""
    log = read_mrclam(mrclam_dir, 3)
    half = float(np.median(log.sighting_times))
    first = read_mrclam(mrclam_dir, 3, until=half)
    rb = estimate_noise([first], range_calibration=True).model.range_bearing
    second = dataclasses.replace(log, sighting_times=log.sighting_times[log.sighting_times >= half],
                                 ranges=log.ranges[log.sighting_times >= half],
                                 bearings=log.bearings[log.sighting_times >= half],
                                 landmark_ids=log.landmark_ids[log.sighting_times >= half])
    second = dataclasses.replace(second, **{k: getattr(second, k)[np.isin(second.landmark_ids, log.truth_ids)]
                                            for k in ("sighting_times", "ranges", "bearings", "landmark_ids")})
    identity = dataclasses.replace(rb, range_offset_m=0.0, range_scale=1.0, range_scale_per_rad=0.0,
                                   range_scale_per_rad2=0.0)

    def robust_rms(sensor):
        e = _range_residuals(second, sensor)
        inside = np.abs(e - np.median(e)) < 4 * 1.4826 * np.median(np.abs(e - np.median(e)))
        return float(np.sqrt(np.mean(e[inside] ** 2)))

    assert 3 * robust_rms(rb) < robust_rms(identity)
    assert rb.range_scale_per_rad2 == pytest.approx(rb.range_scale / 2, rel=0.2)
