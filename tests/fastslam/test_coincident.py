"""One physical point, one reading a frame (``FastSLAMConfig.coincident_readings``, coincident.py)."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.fastslam import FastSLAM, FastSLAMConfig
from estimation.fastslam.coincident import one_per_point, twins_of_matched
from estimation.observations import StereoObservations

GATE = 7.815


def _d2(points, covariances, a, b):
    d = points[a] - points[b]
    return float(d @ np.linalg.solve(covariances[a] + covariances[b], d))


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(0, 25), spread=st.floats(0.05, 2.0))
def test_no_two_kept_readings_coincide_and_each_dropped_one_has_a_kept_twin_at_least_as_precise(seed, n, spread):
    rng = np.random.default_rng(seed)
    points = rng.uniform(-spread, spread, (n, 3)) + [3.0, 0.0, 0.5]
    sigma = rng.uniform(0.01, 0.06, n)
    covariances = sigma[:, None, None] ** 2 * np.eye(3)
    keep = one_per_point(points, covariances, GATE)
    kept, dropped = np.flatnonzero(keep), np.flatnonzero(~keep)
    for x, a in enumerate(kept):
        for b in kept[x + 1:]:
            assert _d2(points, covariances, a, b) >= GATE
    for b in dropped:
        twins = [a for a in kept if _d2(points, covariances, a, b) < GATE]
        assert twins and min(sigma[a] for a in twins) <= sigma[b]


def test_far_apart_readings_are_all_kept_and_a_zero_gate_keeps_everything():
    points = np.array([[3.0, 0.0, 0.5], [3.0, 0.5, 0.5], [3.0, 0.02, 0.5]])
    covariances = np.tile(0.02 ** 2 * np.eye(3), (3, 1, 1))
    assert one_per_point(points, covariances, GATE).tolist() == [True, True, False]
    assert one_per_point(points, covariances, 0.0).all()
    assert one_per_point(points[:2], covariances[:2], GATE).all()


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(0, 15), particles=st.integers(1, 4))
def test_twins_are_the_readings_coinciding_with_one_a_particle_matched(seed, n, particles):
    rng = np.random.default_rng(seed)
    points = rng.uniform(-0.2, 0.2, (n, 3)) + [3.0, 0.0, 0.5]
    covariances = np.tile(0.03 ** 2 * np.eye(3), (n, 1, 1))
    matched = rng.random((particles, n)) < 0.3
    m, j = np.nonzero(matched)
    twins = twins_of_matched(points, covariances, m, j, particles).reshape(particles, n)
    for p in range(particles):
        for b in range(n):
            expected = any(a != b and matched[p, a] and _d2(points, covariances, a, b) < GATE for a in range(n))
            assert twins[p, b] == expected


def _frames(rule: str) -> FastSLAM:
    """A corner and its twin 2 cm beside it (one texture blob) in four frames: each landmark takes one reading
    a frame, so without the rule the twin makes a second landmark; with it the twin is never used."""
    slam = FastSLAM(FastSLAMConfig(n_particles=5, max_observations=0, coincident_readings=rule, merge_gate=0.0),
                    np.random.default_rng(0))
    rng = np.random.default_rng(1)
    base = rng.normal(size=64)
    desc = np.stack([base, base + rng.normal(scale=0.3, size=64)]).astype(np.float32)   # alike, as one blob's
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    points = np.array([[3.0, 0.0, 0.5], [3.0, 0.02, 0.5]])
    covariances = np.tile(np.diag([0.02, 0.003, 0.003]) ** 2, (2, 1, 1))
    for k in range(4):
        slam.update(StereoObservations(points, covariances, desc, np.zeros((2, 2)), float(k)))
    return slam


def test_a_twin_reading_in_the_same_frame_makes_no_second_landmark():
    assert len(_frames("all").particle_map(0)) == 2
    assert len(_frames("one_per_point").particle_map(0)) == 1


def test_a_twin_that_looks_different_makes_no_landmark_beside_the_matched_one():
    # frame 0 makes the corner's landmark alone; from frame 1 on its twin (another look, 2 cm away) is reported too
    rng = np.random.default_rng(2)
    desc = rng.normal(size=(2, 64)).astype(np.float32)
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    points = np.array([[3.0, 0.0, 0.5], [3.0, 0.02, 0.5]])
    covariances = np.tile(np.diag([0.02, 0.003, 0.003]) ** 2, (2, 1, 1))
    sizes = {}
    for rule in ("all", "no_twin_landmark"):
        slam = FastSLAM(FastSLAMConfig(n_particles=5, max_observations=0, coincident_readings=rule, merge_gate=0.0),
                        np.random.default_rng(0))
        slam.update(StereoObservations(points[:1], covariances[:1], desc[:1], np.zeros((1, 2)), 0.0))
        for k in range(1, 4):
            report = slam.update(StereoObservations(points, covariances, desc, np.zeros((2, 2)), float(k)))
            assert report.best_matches[0] >= 0            # the corner itself is matched either way
        sizes[rule] = len(slam.particle_map(0))
    assert sizes == {"all": 2, "no_twin_landmark": 1}
