"""``FastSLAM.candidate_gate``: the plain gate's d² for every (particle, reading, landmark near the view).

Checked against the robot-frame form written out independently (ν = z − Rᵀ(μ − t), S = Rᵀ Σ R + Q), and against
what the update itself does with the same reading, under FastSLAM 1.0 and 2.0 (whose gate adds the unsampled
pose's uncertainty): a landmark inside the gate is matched, one outside is not.
"""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.fastslam import FastSLAM, range_bearing_config, range_bearing_observations
from estimation.landmark_map import LandmarkMap
from estimation.observations import OdometryIncrement, StereoObservations

coordinate = st.floats(-8.0, 8.0)
heading = st.floats(-np.pi, np.pi)
sigma = st.floats(0.02, 0.6)


def _filter_with_one_landmark(pose, landmark, cov, version=1):
    """One particle (FastSLAM 1.0: no pose term in S) at ``pose`` holding one landmark (μ, Σ)."""
    slam = FastSLAM(range_bearing_config(n_particles=1, version=version), np.random.default_rng(0),
                    initial_pose=pose)
    ids = slam.load_prior_map(LandmarkMap(np.array([landmark], float), np.array([cov], float), np.zeros((1, 0)),
                                          counts=np.array([10])))
    return slam, int(ids[0])


def _spd(a, b, c):
    """A 3×3 symmetric positive definite matrix with standard deviations a, b, c in a rotated frame."""
    rot = np.array([[np.cos(c), -np.sin(c), 0.0], [np.sin(c), np.cos(c), 0.0], [0.0, 0.0, 1.0]])
    return rot @ np.diag([a * a, b * b, 0.01]) @ rot.T


@settings(max_examples=60, deadline=None)
@given(coordinate, coordinate, heading, coordinate, coordinate, sigma, sigma, heading, sigma, sigma, heading)
def test_d2_is_the_robot_frame_mahalanobis_distance(x, y, theta, lx, ly, sa, sb, sc, qa, qb, qc):
    pose, landmark, cov = np.array([x, y, theta]), np.array([lx, ly, 0.0]), _spd(sa, sb, sc)
    slam, lid = _filter_with_one_landmark(pose, landmark, cov)
    rot = np.array([[np.cos(theta), -np.sin(theta), 0.0], [np.sin(theta), np.cos(theta), 0.0], [0.0, 0.0, 1.0]])
    z = rot.T @ (landmark - [x, y, 0.0]) + np.array([0.3, -0.2, 0.05])
    q = _spd(qa, qb, qc)
    gate = slam.candidate_gate(StereoObservations(z[None], q[None], np.zeros((1, 0)), np.zeros((0, 2)), 0.0))
    cfg = slam.config
    s = rot.T @ cov @ rot + cfg.observation_cov_scale * q + cfg.observation_var_floor * np.eye(3)
    nu = z - rot.T @ (landmark - [x, y, 0.0])
    assert gate.m.tolist() == [0] and gate.j.tolist() == [0] and gate.lid.tolist() == [lid]
    np.testing.assert_allclose(gate.d2, [nu @ np.linalg.solve(s, nu)], rtol=1e-7)
    np.testing.assert_allclose(gate.log_det, [np.log(np.linalg.det(rot @ s @ rot.T))], rtol=1e-7, atol=1e-9)


@settings(max_examples=40, deadline=None)
@given(st.sampled_from([1, 2]), st.floats(-1.5, 1.5), st.floats(-0.4, 0.4))
def test_the_update_matches_exactly_the_landmarks_inside_that_gate(version, range_error, bearing_error):
    """After a 1 m drive (2.0: a pose not sampled yet, whose covariance widens the gate; 1.0: a sampled pose)."""
    slam, lid = _filter_with_one_landmark((-1.0, 0.0, 0.0), (3.0, 1.0, 0.0), np.diag([0.04, 0.04, 1e-4]), version)
    slam.predict(OdometryIncrement(1.0, 0.0, 0.05, 0.0, 1.0))
    x, y, theta = slam.poses[0]
    dx, dy = 3.0 - x, 1.0 - y
    obs = range_bearing_observations([np.hypot(dx, dy) + range_error],
                                     [np.arctan2(dy, dx) - theta + bearing_error], 0.1, 0.05)
    d2 = float(slam.candidate_gate(obs).d2[0])
    report = slam.update(obs)
    inside = d2 < slam.config.mahalanobis_gate
    assert (int(report.best_matches[0]) == lid) == inside
    assert (int(report.new_landmark_ids[0]) >= 0) == (not inside)


def test_the_unsampled_pose_widens_only_fastslam_2s_gate():
    """The same reading after the same drive: 2.0's gate is the wider (its S holds the pose term), 1.0's not."""
    d2 = {}
    for version in (1, 2):
        slam, _ = _filter_with_one_landmark((-1.0, 0.0, 0.0), (3.0, 1.0, 0.0), np.diag([0.04, 0.04, 1e-4]),
                                            version)
        slam.predict(OdometryIncrement(1.0, 0.0, 0.0, 0.0, 1.0))
        slam.poses[:] = 0.0     # the same pose for both (1.0 sampled its own in predict)
        obs = range_bearing_observations([np.hypot(3.0, 1.0)], [np.arctan2(1.0, 3.0) + 0.15], 0.1, 0.05)
        d2[version] = float(slam.candidate_gate(obs).d2[0])
    assert d2[2] < d2[1]


def test_a_filter_without_landmarks_has_no_candidates():
    slam = FastSLAM(range_bearing_config(n_particles=3), np.random.default_rng(0))
    gate = slam.candidate_gate(range_bearing_observations([2.0], [0.1], 0.1, 0.05))
    assert len(gate.m) == len(gate.d2) == 0 and gate.innovation.shape == (3, 0)
