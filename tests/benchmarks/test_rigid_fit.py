"""The benchmarks' frame fits are estimation.landmark_scores.rigid_fit_2d (benchmarks/eval_fusion.py had a twin;
before it was removed the two agreed to 1.4e-12 m and 8.7e-15 rad on 5000 random rigid motions with noise).

Here: with noise, the fit is the least-squares pose a general solver finds, and eval_fusion.frame_fit places a map
whose landmarks carry their identities by it."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import least_squares

from benchmarks import eval_fusion
from estimation.geometry import inverse, transform_points, wrap_angle
from estimation.landmark_map import LandmarkMap
from estimation.landmark_scores import rigid_fit_2d

motions = st.tuples(st.floats(-50, 50), st.floats(-50, 50), st.floats(-np.pi, np.pi))


def _moved(pose, points: np.ndarray) -> np.ndarray:
    return transform_points(np.asarray(pose, float), np.column_stack([points, np.zeros(len(points))]))[:, :2]


def _jacobian(pose, points: np.ndarray) -> np.ndarray:
    """d(pose ⊕ point_i)/d(x, y, θ), the rows of the residuals (x_0, y_0, x_1, ...)."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    j = np.zeros((len(points), 2, 3))
    j[:, 0, 0] = j[:, 1, 1] = 1.0
    j[:, 0, 2] = -s * points[:, 0] - c * points[:, 1]
    j[:, 1, 2] = c * points[:, 0] - s * points[:, 1]
    return j.reshape(-1, 3)


@settings(max_examples=300)
@given(motions, st.integers(3, 40), st.sampled_from([1e-3, 0.05, 0.5]), st.integers(0, 2**32 - 1))
def test_with_noise_the_fit_is_the_least_squares_pose(motion, k, noise, seed):
    rng = np.random.default_rng(seed)
    local = rng.uniform(-10, 10, (k, 2)) + rng.uniform(-30, 30, 2)
    world = _moved(motion, local) + rng.normal(0, noise, (k, 2))
    fit = rigid_fit_2d(local, world)
    reference = least_squares(lambda p: (_moved(p, local) - world).ravel(), np.add(motion, [0.3, -0.2, 0.1]),
                              jac=lambda p: _jacobian(p, local), method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15).x
    cost = np.sum((_moved(fit, local) - world) ** 2)
    assert cost <= np.sum((_moved(reference, local) - world) ** 2) * (1 + 1e-9) + 1e-18
    np.testing.assert_allclose(fit[:2], reference[:2], atol=1e-6)
    assert abs(wrap_angle(fit[2] - reference[2])) < 1e-7


def test_eval_fusion_fits_with_the_estimation_function():
    assert eval_fusion.rigid_fit_2d is rigid_fit_2d


@settings(max_examples=50)
@given(motions, st.integers(0, 2**32 - 1))
def test_frame_fit_places_a_map_with_identities_in_its_true_frame(motion, seed):
    rng = np.random.default_rng(seed)
    truth = {int(i): tuple(rng.uniform(-20, 20, 2)) for i in rng.choice(1000, 12, replace=False)}
    ids = list(truth)
    world = np.array([truth[i] for i in ids])
    frame = np.array(motion)
    # the map's rows: the true landmarks seen from ``frame`` (world = frame ⊕ local), plus one unattributed row
    local = transform_points(inverse(frame), np.column_stack([world, np.zeros(len(world))]))
    positions = np.vstack([local, [[1.0, 2.0, 0.0]]])
    m = LandmarkMap(positions, np.repeat(np.eye(3)[None] * 1e-4, len(positions), 0),
                    np.zeros((len(positions), 0), np.float32), robot="robot1",
                    metadata={"external_ids": [*ids, -1]})
    fit, err, got_ids = eval_fusion.frame_fit(m, truth)
    np.testing.assert_allclose(fit[:2], frame[:2], atol=1e-7)
    assert abs(wrap_angle(fit[2] - frame[2])) < 1e-9
    assert np.all(err[:-1] < 1e-7) and np.isnan(err[-1])
    assert list(got_ids) == [*ids, -1]


def _grid_map(frame: np.ndarray, metadata: dict) -> tuple[LandmarkMap, dict]:
    """A 5 × 3 lattice of 1 m (a layout geometry alone cannot place: shifted by a column it fits 12 of 15) seen
    from ``frame``, without identities."""
    xs, ys = np.meshgrid(np.arange(5.0), np.arange(3.0))
    world = np.column_stack([xs.ravel(), ys.ravel()])
    local = transform_points(inverse(frame), np.column_stack([world, np.zeros(len(world))]))
    m = LandmarkMap(local, np.repeat(np.eye(3)[None] * 1e-4, len(local), 0), np.zeros((len(local), 0), np.float32),
                    robot="robot1", metadata=metadata)
    return m, {100 + i: tuple(p) for i, p in enumerate(world)}


# a robot starts among the landmarks it maps, so a start pose's heading error moves none of them far (here ≤ 0.3 m)
starts_among_the_lattice = st.tuples(st.floats(-1, 5), st.floats(-1, 3), st.floats(-np.pi, np.pi))


@settings(max_examples=20, deadline=None)
@given(starts_among_the_lattice, st.floats(-0.1, 0.1), st.floats(-0.1, 0.1), st.floats(-0.04, 0.04))
def test_frame_fit_places_a_map_geometry_cannot_by_its_true_start_pose(start, dx, dy, dtheta):
    frame = np.array(start)
    m, truth = _grid_map(frame, {"true_start_pose": list(frame + [dx, dy, dtheta])})
    assert np.isnan(eval_fusion.frame_fit(_grid_map(frame, {})[0], truth)[0]).all()   # geometry alone cannot
    fit, err, ids = eval_fusion.frame_fit(m, truth)
    np.testing.assert_allclose(fit[:2], frame[:2], atol=1e-7)
    assert abs(wrap_angle(fit[2] - frame[2])) < 1e-9
    assert list(ids) == sorted(truth) and np.all(err < 1e-7)


def test_frame_fit_leaves_a_map_it_cannot_place_unscored_rather_than_crash():
    m, truth = _grid_map(np.array([2.0, -1.0, 0.3]), {})
    fit, err, ids = eval_fusion.frame_fit(m, truth)
    assert np.isnan(fit).all() and np.isnan(err).all() and np.all(ids == -1)
