"""benchmarks/demo_relock.py: each unmatched re-sighting of a pre-turn landmark is judged with the filter's own gate
and descriptor test, in the association's order."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from benchmarks import demo_relock
from estimation.fastslam import FastSLAM, FastSLAMConfig
from estimation.fastslam.linalg import sym_matrices
from estimation.observations import OdometryIncrement, StereoObservations


def _observations(points: np.ndarray, sigma: float = 0.03) -> StereoObservations:
    n = len(points)
    desc = np.zeros((n, 64), np.float32)
    desc[:, 0] = 1.0
    return StereoObservations(points, np.tile(np.eye(3) * sigma ** 2, (n, 1, 1)), desc, np.zeros((n, 2)), 0.0)


@settings(max_examples=40, deadline=None)
@given(st.floats(-0.4, 0.4), st.floats(0.0, 0.6), st.floats(1.0, 6.0), st.floats(-1.0, 1.0),
       st.floats(-0.3, 0.3))
def test_the_gate_d2_is_the_filters_own(turn, forward, depth, lateral, shift):
    """A landmark made at the start, the robot turned and moved (the unsampled motion covariance of FastSLAM 2.0),
    then the landmark's point seen again from a shifted place: gate_d2 gives the d² the filter's candidate gate
    gives for that reading and landmark."""
    slam = FastSLAM(FastSLAMConfig(n_particles=1), np.random.default_rng(0))
    point = np.array([[depth, lateral, 0.8]])
    slam.update(_observations(point))
    slam.predict(OdometryIncrement(forward, 0.0, turn, 0.0, 0.25))
    c, s = np.cos(turn), np.sin(turn)
    seen = (np.array([[c, s], [-s, c]]) @ (point[0, :2] - [forward, 0.0])) + [0.0, shift]
    z = np.array([[seen[0], seen[1], 0.8]])
    observations = _observations(z)
    gate = slam.candidate_gate(observations)
    slot = slam.store.particle_slots(0)
    mean, cov = slam.store.flat_mean[slot], sym_matrices(slam.store.flat_cov[slot].T)
    q = observations.covariances[0] + slam.config.observation_var_floor * np.eye(3)
    d2 = demo_relock.gate_d2(slam.poses[0], slam._motion_cov[0], z[0], q, mean[0], cov[0])
    assert len(gate.d2) == 1
    assert np.isclose(d2, gate.d2[0], rtol=1e-9, atol=1e-9)


@settings(max_examples=100)
@given(st.floats(-np.pi, np.pi), st.floats(-5, 5), st.floats(-5, 5), st.integers(0, 2**32 - 1))
def test_the_gate_d2_does_not_depend_on_the_map_frame(angle, tx, ty, seed):
    """Pose and landmark moved together by one rigid motion of the map frame (the landmark's and the pose's
    covariances turned with it, the reading in the robot's frame unchanged): the same d²."""
    rng = np.random.default_rng(seed)
    pose = np.r_[rng.uniform(-3, 3, 2), rng.uniform(-np.pi, np.pi)]
    z = np.r_[rng.uniform(1, 6), rng.uniform(-2, 2), rng.uniform(0, 1.5)]
    a = rng.normal(size=(3, 3))
    q, sigma = 1e-3 * (a @ a.T + np.eye(3)), 1e-3 * (np.eye(3) + 0.5 * np.diag(rng.uniform(0, 1, 3)))
    mean = np.r_[pose[:2], 0.0] + rng.normal(0, 0.1, 3)
    mean[:2] += np.array([[np.cos(pose[2]), -np.sin(pose[2])], [np.sin(pose[2]), np.cos(pose[2])]]) @ z[:2]
    mean[2] = z[2] + rng.normal(0, 0.05)
    b = rng.normal(size=(3, 3))
    p = 1e-4 * (b @ b.T)   # the pose's covariance (x, y, θ): x, y turn with the frame, θ does not
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    moved_pose = np.r_[rot[:2, :2] @ pose[:2] + [tx, ty], pose[2] + angle]
    moved_mean = rot @ mean + [tx, ty, 0.0]
    before = demo_relock.gate_d2(pose, p, z, q, mean, sigma)
    after = demo_relock.gate_d2(moved_pose, rot @ p @ rot.T, z, q, moved_mean, rot @ sigma @ rot.T)
    assert np.isclose(before, after, rtol=1e-7, atol=1e-9)


def test_a_reading_is_refused_by_the_first_test_that_fails():
    threshold, gate = 0.5, 11.345
    assert demo_relock.sighting_reason(True, 0.9, 50.0, False, threshold, gate) == "matched"
    assert demo_relock.sighting_reason(False, 0.6, 50.0, False, threshold, gate) == "descriptor"
    assert demo_relock.sighting_reason(False, 0.3, 50.0, True, threshold, gate) == "gate"
    assert demo_relock.sighting_reason(False, 0.3, 2.0, True, threshold, gate) == "duplicate"
    assert demo_relock.sighting_reason(False, 0.3, 2.0, False, threshold, gate) == "other"
    assert demo_relock.sighting_reason(False, 0.5, 2.0, False, threshold, gate) == "descriptor"   # not < 0.5
    assert demo_relock.sighting_reason(False, 0.3, gate, False, threshold, gate) == "gate"        # not < gate


@settings(max_examples=50)
@given(st.integers(1, 8), st.integers(0, 2**32 - 1))
def test_the_gate_against_many_landmarks_is_the_gate_against_each(n, seed):
    rng = np.random.default_rng(seed)
    pose = np.r_[rng.uniform(-3, 3, 2), rng.uniform(-np.pi, np.pi)]
    z = np.r_[rng.uniform(1, 6), rng.uniform(-2, 2), rng.uniform(0, 1.5)]
    a, b = rng.normal(size=(3, 3)), rng.normal(size=(3, 3))
    q, p = 1e-3 * (a @ a.T + np.eye(3)), 1e-4 * (b @ b.T)
    means = rng.uniform(-6, 6, (n, 3))
    c = rng.normal(size=(n, 3, 3))
    covs = 1e-3 * (c @ c.transpose(0, 2, 1) + np.eye(3))
    many = demo_relock.gate_d2_many(pose, p, z, q, means, covs)
    one = [demo_relock.gate_d2(pose, p, z, q, m, s) for m, s in zip(means, covs, strict=True)]
    assert np.allclose(many, one, rtol=1e-9, atol=1e-12)
