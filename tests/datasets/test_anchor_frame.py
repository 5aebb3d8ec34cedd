"""The smoothed map's start frame: its error as one rigid motion against the landmarks' joint covariance
(estimation.landmark_scores.frame_error, the metrics ``landmark_frame_*`` of a smoothed run), and whether that
covariance carries the frame's uncertainty when the frame rests on one sighting in a turn (MRCLAM robot 1's start,
session 38 (C)): on logs drawn from the model the frame's NEES is χ²₃."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.dataset_slam import run_landmark_log
from estimation.datasets import read_mrclam
from estimation.fastslam import range_bearing_config
from estimation.geometry import dead_reckoning, wrap_angle
from estimation.landmark_scores import CHI2_95, frame_error
from estimation.landmark_smoother import LandmarkLogProblem, landmarks_from_first_sightings, smooth
from estimation.noise_model import NoiseModel, OdometryNoise, RangeBearingNoise
from tests.estimation.frame_helpers import (
    BEARING_SIGMA,
    LANDMARKS,
    RANGE_SIGMA,
    odometry_variances,
    seen_joint_covariance,
    turn_and_lap,
)


def _problem(rng: np.random.Generator, first_heading_variance_factor: float = 1.0):
    """A robot that turns on the spot at 0.4 rad/s (0.25 s frames) seeing one landmark a frame, then drives a circle
    seeing every landmark ahead; the first frame (the map's origin) sees one landmark. Odometry and sightings drawn
    from the model; ``first_heading_variance_factor`` scales the heading variance the smoother is *told* for the
    turn's increments (1: the truth's)."""
    true_increments = turn_and_lap(10)
    truth = dead_reckoning(true_increments)
    variance = odometry_variances(true_increments)
    measured = true_increments + rng.standard_normal(variance.shape) * np.sqrt(variance)
    told = variance.copy()
    told[1:11, 2] *= first_heading_variance_factor
    pose_index, landmark_index, ranges, bearings = [], [], [], []
    for k in range(1, len(truth)):
        d = LANDMARKS - truth[k, :2]
        r = np.hypot(d[:, 0], d[:, 1])
        b = wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - truth[k, 2])
        ahead = np.flatnonzero((np.abs(b) < 0.6) & (r < 6.0))
        visible = ahead[np.argsort(np.abs(b[ahead]))][:1] if k <= 11 else ahead
        pose_index += [k] * len(visible)
        landmark_index += list(visible)
        ranges += list(r[visible] + RANGE_SIGMA * rng.standard_normal(len(visible)))
        bearings += list(b[visible] + BEARING_SIGMA * rng.standard_normal(len(visible)))
    s = len(ranges)
    problem = LandmarkLogProblem(measured, told, np.array(pose_index), np.array(landmark_index), np.array(ranges),
                                 np.array(bearings), np.full(s, RANGE_SIGMA), np.full(s, BEARING_SIGMA))
    return problem, truth


def _frame(problem, truth) -> dict:
    poses = dead_reckoning(problem.increments)
    solution = smooth(problem, poses, landmarks_from_first_sightings(problem, poses))
    seen, covariance = seen_joint_covariance(problem, solution)
    return frame_error(solution.landmarks[seen], LANDMARKS[seen], covariance)


@settings(max_examples=60, deadline=None)
@given(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5), st.floats(-0.2, 0.2), st.integers(2, 12), st.integers(0, 2 ** 31),
       st.floats(0.01, 1.0))
def test_a_linear_rigid_error_is_recovered_and_its_nees_scales_with_the_covariance(dx, dy, dtheta, n, seed, sigma):
    truth = np.random.default_rng(seed).uniform(-5, 5, (n, 2))
    estimate = truth + [dx, dy] + dtheta * np.column_stack([-truth[:, 1], truth[:, 0]])
    out = frame_error(estimate, truth, sigma ** 2 * np.eye(2 * n))
    np.testing.assert_allclose(out["landmark_frame_error"], [dx, dy, dtheta], atol=1e-9)
    wider = frame_error(estimate, truth, (2 * sigma) ** 2 * np.eye(2 * n))
    np.testing.assert_allclose(wider["landmark_frame_sd"], 2 * np.array(out["landmark_frame_sd"]), rtol=1e-9)
    assert wider["landmark_frame_nees"] == pytest.approx(out["landmark_frame_nees"] / 4, rel=1e-9, abs=1e-12)


def test_one_landmark_has_no_frame_error():
    out = frame_error(np.ones((1, 2)), np.zeros((1, 2)), np.eye(2))
    assert np.all(np.isnan(out["landmark_frame_error"])) and np.isnan(out["landmark_frame_nees"])


def test_a_frame_pinned_by_one_sighting_in_a_turn_is_as_uncertain_as_the_model_says():
    """Drawn from the model, the smoothed frame's error is χ²₃ against the joint covariance (mean 3, 95 % within
    7.815); told a tenth of the turn's true heading variance, the same data's frames are far outside it: the check
    sees a covariance that leaves out the anchor's rotation."""
    honest, understated = [], []
    for seed in range(60):
        problem, truth = _problem(np.random.default_rng(seed))
        honest.append(_frame(problem, truth))
        problem, truth = _problem(np.random.default_rng(seed), first_heading_variance_factor=0.1)
        understated.append(_frame(problem, truth))
    nees = np.array([f["landmark_frame_nees"] for f in honest])
    assert 2.0 < nees.mean() < 4.2 and 0.88 <= np.mean(nees < CHI2_95[3]) <= 1.0
    # the rotation about the origin alone: its spread over the draws is the σ the covariance gives it
    rotation = np.array([f["landmark_frame_error"][2] for f in honest])
    assert 0.75 < np.std(rotation) / np.median([f["landmark_frame_sd"][2] for f in honest]) < 1.3
    worse = np.array([f["landmark_frame_nees"] for f in understated])
    assert worse.mean() > 2 * nees.mean() and np.mean(worse < CHI2_95[3]) < np.mean(nees < CHI2_95[3])


def test_a_smoothed_run_reports_its_frame_error(tmp_path, synthetic):
    synthetic.write(tmp_path, seconds=40.0)
    log = read_mrclam(tmp_path, 1)
    sensor = RangeBearingNoise(0.02, 0.0, 0.01, fov_rad=synthetic.SENSOR_FOV, max_range_m=synthetic.SENSOR_RANGE)
    noise = NoiseModel(OdometryNoise(0.01 ** 2, 0.01 ** 2, 0.01 ** 2), sensor)
    run = run_landmark_log(log, range_bearing_config(n_particles=10), np.random.default_rng(1), noise=noise,
                           association="id", robot="robot1", smooth=True)
    m = run.metrics
    # exact data: the frame is the truth's, to the solver's tolerance, and its σ are finite and positive
    assert np.all(np.abs(m["landmark_frame_error"]) < 1e-3) and m["landmark_frame_nees"] < 1e-2
    assert all(0 < s < np.inf for s in m["landmark_frame_sd"])
    unsmoothed = run_landmark_log(log, range_bearing_config(n_particles=10), np.random.default_rng(1), noise=noise,
                                  association="id", robot="robot1")
    assert "landmark_frame_nees" not in unsmoothed.metrics   # a filter's map has no joint covariance
