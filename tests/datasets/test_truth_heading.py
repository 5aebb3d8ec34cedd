"""The ground truth's heading turned onto the direction of travel (estimation.datasets.truth_heading).

Synthetic drives whose reported heading is off the true one by a known offset (constant, or wandering), with a tracked
centre off the axle and position noise; then MRCLAM, where the camera is the independent check: its bearings should
agree better with the aligned truth than with Vicon's heading, never worse.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from benchmarks.mrclam_truth_heading import bearing_residuals, spread
from estimation.datasets import DatasetError, RangeBearingLog, align_truth_heading, read_mrclam, travel_heading_offset
from estimation.geometry import wrap_angle
from tests.datasets.conftest import run_cli

RATE_HZ = 50.0


def drive(seed: int, seconds: float = 900.0, *, offset=lambda t: 0.0 * t, lever_m: float = 0.0,
          reversing: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Truth rows (t, x, y, θ) of a drive of straight legs (0.05–0.3 m/s) and turns, as a motion capture reports it:
    its position is a point ``lever_m`` ahead of the axle, its heading the true one plus ``offset(t)``, with 1 mm and
    2 mrad of noise; ``reversing`` drives every third leg backwards. Returns (rows, the true heading)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 1 / RATE_HZ)
    v, w = np.empty(len(t)), np.empty(len(t))
    k, leg = 0, 0
    while k < len(t):
        n = int(rng.uniform(5, 25) * RATE_HZ)
        speed = rng.uniform(0.05, 0.3) * (-1 if reversing and leg % 3 == 2 else 1)
        v[k:k + n], w[k:k + n] = speed, rng.normal(0, 0.01)
        m = int(rng.uniform(1, 4) * RATE_HZ)
        v[k + n:k + n + m], w[k + n:k + n + m] = rng.uniform(0, 0.05), rng.choice([-1, 1]) * rng.uniform(0.3, 0.8)
        k, leg = k + n + m, leg + 1
    theta = np.concatenate([[0.0], np.cumsum(w[:-1] / RATE_HZ)])
    x = np.concatenate([[0.0], np.cumsum(v[:-1] * np.cos(theta[:-1]) / RATE_HZ)])
    y = np.concatenate([[0.0], np.cumsum(v[:-1] * np.sin(theta[:-1]) / RATE_HZ)])
    x, y = x + lever_m * np.cos(theta), y + lever_m * np.sin(theta)
    noise = rng.normal(0, [0.001, 0.001, 0.002], (len(t), 3))
    reported = wrap_angle(theta + offset(t) + noise[:, 2])
    return np.column_stack([t, x + noise[:, 0], y + noise[:, 1], reported]), theta


def heading_error(rows: np.ndarray, true_theta: np.ndarray, estimate) -> np.ndarray:
    return wrap_angle(rows[:, 3] - estimate.at(rows[:, 0]) - true_theta)


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 10_000), st.floats(-0.05, 0.05), st.floats(-0.05, 0.05))
def test_a_constant_offset_is_found_whatever_the_tracked_point(seed, offset, lever):
    rows, theta = drive(seed, offset=lambda t: np.full_like(t, offset), lever_m=lever)
    estimate = travel_heading_offset(rows)
    error = heading_error(rows, theta, estimate)
    assert abs(np.median(error)) < 0.003
    assert np.sqrt(np.mean(error ** 2)) < 0.006     # 2 mrad of reported noise, and what the smoothing follows of it


def test_a_wandering_offset_is_followed_not_averaged_away():
    wander = lambda t: 0.02 * np.sin(2 * np.pi * t / 300.0)   # noqa: E731
    rows, theta = drive(3, 1200.0, offset=wander)
    estimate = travel_heading_offset(rows)
    assert np.isfinite(estimate.width_s) and estimate.width_s <= 80.0
    given_rms = np.sqrt(np.mean(wrap_angle(rows[:, 3] - theta) ** 2))
    aligned_rms = np.sqrt(np.mean(heading_error(rows, theta, estimate) ** 2))
    assert given_rms > 0.013 and aligned_rms < 0.35 * given_rms


def test_a_steady_offset_is_kept_one_constant():
    rows, _ = drive(5, offset=lambda t: np.full_like(t, 0.012))
    assert np.isinf(travel_heading_offset(rows).width_s)


def test_reversing_legs_are_left_out_not_read_as_a_half_turn():
    rows, theta = drive(7, offset=lambda t: np.full_like(t, -0.02), reversing=True)
    error = heading_error(rows, theta, travel_heading_offset(rows))
    assert abs(np.median(error)) < 0.003


@pytest.mark.parametrize("motion", ["standing", "spinning"])
def test_a_truth_that_never_drives_straight_is_refused_in_one_line(motion):
    t = np.arange(0.0, 300.0, 0.02)
    theta = 0.5 * t if motion == "spinning" else np.zeros_like(t)
    rows = np.column_stack([t, np.zeros_like(t), np.zeros_like(t), wrap_angle(theta)])
    with pytest.raises(DatasetError, match=r"drives forward in a nearly straight line on 0 steps of 1 s \(at least 30"):
        travel_heading_offset(rows, "robot9")


def test_the_aligned_log_keeps_positions_and_says_what_it_did():
    rows, _ = drive(11, offset=lambda t: np.full_like(t, 0.015))
    log = RangeBearingLog("synthetic", rows[:, :4] * [1, 0, 0, 0], np.zeros(0), np.zeros(0), np.zeros(0),
                          np.zeros(0, np.int64), rows)
    aligned, estimate = align_truth_heading(log)
    assert np.array_equal(aligned.ground_truth[:, :3], log.ground_truth[:, :3])
    assert np.allclose(wrap_angle(log.ground_truth[:, 3] - aligned.ground_truth[:, 3]), estimate.at(rows[:, 0]))
    assert aligned.notes[-1].startswith("the ground truth's heading aligned with its direction of travel: offset "
                                        "mean +0.01")
    without_truth = RangeBearingLog("blind", log.odometry, np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0, np.int64))
    with pytest.raises(DatasetError, match="no ground truth to align"):
        align_truth_heading(without_truth)


def test_read_mrclam_refuses_an_unknown_truth_heading(tmp_path, synthetic):
    synthetic.write(tmp_path)
    with pytest.raises(ValueError, match="truth_heading must be one of mocap, travel"):
        read_mrclam(tmp_path, 1, truth_heading="vicon")


def test_self_calibration_refuses_a_truth_heading_it_would_not_read(tmp_path):
    status, _, err = run_cli("slam", "noise", "mrclam", str(tmp_path), "--robot", "1", "--self-calibrate", "--noise",
                             str(tmp_path / "n.toml"), "--truth-heading", "travel", "--out", str(tmp_path / "o.toml"))
    assert status == 2
    assert err.strip() == "p3at slam noise: --self-calibrate reads no ground truth: --truth-heading does not apply"


@pytest.mark.parametrize("robot", [1, 2, 3, 4, 5])
def test_on_mrclam_the_camera_agrees_with_the_travel_at_least_as_well_as_with_vicon(mrclam_dir, robot):
    mocap = read_mrclam(mrclam_dir, robot)
    travel = read_mrclam(mrclam_dir, robot, truth_heading="travel")
    given_rms, aligned_rms = (spread(bearing_residuals(log)[1])[0] for log in (mocap, travel))
    assert aligned_rms <= 1.01 * given_rms
    if robot == 1:   # Vicon's heading wanders on robot 1: the camera follows the travel, not the markers
        assert aligned_rms < 0.9 * given_rms
    assert np.array_equal(mocap.ground_truth[:, :3], travel.ground_truth[:, :3])


def test_a_truth_that_only_circles_cannot_be_aligned_and_the_command_says_so(tmp_path, synthetic):
    synthetic.write(tmp_path / "data")    # a circle of 0.5 rad/m: never straight enough to read a direction of travel
    status, _, err = run_cli("slam", "dataset", "mrclam", str(tmp_path / "data"), "--robot", "1", "--truth-heading",
                             "travel", "--out", str(tmp_path / "m.npz"))
    assert status == 2 and len(err.strip().splitlines()) == 1
    assert "drives forward in a nearly straight line on 0 steps" in err
    assert not (tmp_path / "m.npz").exists()


def test_a_noise_model_fitted_against_the_travel_heading_says_so_and_moves_only_the_bearing_offset(mrclam_dir,
                                                                                                    tmp_path):
    fits = {}
    for heading in ("mocap", "travel"):
        status, out, err = run_cli("slam", "noise", "mrclam", str(mrclam_dir), "--robot", "2", "--truth-heading",
                                   heading, "--out", str(tmp_path / f"{heading}.toml"), "--json")
        assert status == 0, err
        fits[heading] = json.loads(out)
    assert fits["travel"]["fit"]["truth_heading"] == "travel" and "truth_heading" not in fits["mocap"]["fit"]
    offset = read_mrclam(mrclam_dir, 2, truth_heading="travel").notes[-1]
    shift = fits["travel"]["range_bearing"]["bearing_offset_rad"] - fits["mocap"]["range_bearing"]["bearing_offset_rad"]
    # a heading turned by -c makes every bearing read c more against it: the camera's offset gives Vicon's back
    assert "offset mean +0.0136 rad" in offset and abs(shift + 0.0136) < 0.002
    assert fits["travel"]["odometry"]["xy_var_per_m"] == pytest.approx(fits["mocap"]["odometry"]["xy_var_per_m"],
                                                                        rel=0.05)


def _scored_map(start, heading=None, seed=0):
    from estimation.landmark_map import LandmarkMap

    metadata = {"true_start_pose": list(start)} | ({} if heading is None else {"truth_heading": heading})
    rng = np.random.default_rng(seed)
    return LandmarkMap(rng.uniform(-5, 5, (6, 3)), np.tile(np.eye(3) * 1e-3, (6, 1, 1)), rng.normal(size=(6, 8)),
                       robot="r", metadata=metadata)


@given(st.sampled_from([None, "mocap", "travel"]), st.sampled_from([None, "mocap", "travel"]))
def test_fusion_scores_two_starts_only_against_the_same_truth_heading(first, second):
    from fusion import true_relative_pose

    truth = true_relative_pose(_scored_map([0.0, 0.0, 0.1], first), _scored_map([1.0, 0.0, 0.3], second))
    if (first or "mocap") == (second or "mocap"):     # a map that does not say is the truth as written
        assert np.allclose(truth, [0.995004165, -0.0998334166, 0.2])
    else:
        assert truth is None


def test_fuse_says_when_the_maps_hold_starts_from_different_truths(tmp_path):
    paths = []
    for k, heading in enumerate(["mocap", "travel", "travel"]):
        paths.append(str(tmp_path / f"m{k}.npz"))
        _scored_map([float(k), 0.0, 0.0], heading, seed=k).save(paths[-1])
    _, _, err = run_cli("fuse", *paths, "--out", str(tmp_path / "merged.npz"))
    assert ("p3at fuse: warning: the maps' true starts hold headings from different truths (mocap: map 0; travel: "
            "maps 1, 2; `p3at slam dataset --truth-heading`): alignments between them are not scored") in err


def test_a_travel_map_records_its_truth_and_a_mocap_one_its_own(mrclam_dir, tmp_path):
    from estimation.landmark_map import LandmarkMap

    for heading in ("mocap", "travel"):
        status, _, err = run_cli("slam", "dataset", "mrclam", str(mrclam_dir), "--robot", "2", "--until", "60",
                                 "--truth-heading", heading, "--out", str(tmp_path / f"{heading}.npz"))
        assert status == 0, err
    mocap, travel = (LandmarkMap.load(tmp_path / f"{h}.npz") for h in ("mocap", "travel"))
    assert mocap.metadata["truth_heading"] == "mocap" and travel.metadata["truth_heading"] == "travel"
    turn = travel.metadata["true_start_pose"][2] - mocap.metadata["true_start_pose"][2]
    assert turn == pytest.approx(-0.0136, abs=0.002)
    assert travel.metadata["true_start_pose"][:2] == mocap.metadata["true_start_pose"][:2]


@pytest.mark.parametrize(("fit", "warned"), [({}, False), ({"self_calibration_range_scale": 1.0}, True),
                                             ({"truth_heading": "travel"}, True)])
def test_a_map_scored_against_another_truth_than_its_camera_s_is_warned_about(tmp_path, synthetic, fit, warned):
    from estimation.noise_model import NoiseModel, OdometryNoise, RangeBearingNoise

    synthetic.write(tmp_path / "data", seconds=20.0)
    sensor = RangeBearingNoise(0.02, 0.0, 0.01, fov_rad=synthetic.SENSOR_FOV, max_range_m=synthetic.SENSOR_RANGE)
    NoiseModel(OdometryNoise(0.01 ** 2, 0.01 ** 2, 0.01 ** 2), sensor, fit=fit).save(tmp_path / "noise.toml")
    status, out, err = run_cli("slam", "dataset", "mrclam", str(tmp_path / "data"), "--robot", "1", "--noise",
                               str(tmp_path / "noise.toml"), "--particles", "10", "--out", str(tmp_path / "m.npz"),
                               "--json")
    assert status == 0, err
    frame = [w for w in json.loads(out)["warnings"] if "referenced to the direction of travel" in w]
    expected = ("the noise model's camera is referenced to the direction of travel and the map is scored against the "
                "motion capture's heading: the start-frame figures carry their difference (up to 0.017 rad on "
                "MRCLAM); --truth-heading travel scores the map in its own frame")
    assert frame == ([expected] if warned else [])
