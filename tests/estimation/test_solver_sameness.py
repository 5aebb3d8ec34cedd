"""The solvers' fast paths give the straightforward computation's numbers to the bit (session 45): the smoother's
normal equations taken apart by blocks (estimation.landmark_smoother._NormalEquations) against the whole JᵀJ sliced
and damped as a sparse sum, and dead reckoning on scalars against compose() step by step."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation import landmark_smoother
from estimation.camera_calibration import (
    FREE_WITH_SHAPE,
    TRANSLATION_SCALE,
    KnownDistance,
    _Lengths,
    _OdometryScale,
    _Shape,
)
from estimation.geometry import compose, dead_reckoning
from estimation.landmark_smoother import LandmarkLogProblem, NormalFactor, _NormalEquations, _residuals
from estimation.noise_model import RangeBearingNoise


def _problem(rng, steps: int, n_landmarks: int, n_groups: int) -> LandmarkLogProblem:
    s = 3 * steps
    return LandmarkLogProblem(rng.normal(0, 0.4, (steps, 3)), rng.uniform(0.01, 0.1, (steps, 3)),
                              rng.integers(1, steps + 1, s), rng.integers(0, n_landmarks, s),
                              rng.uniform(0.5, 4, s), rng.uniform(-1, 1, s), rng.uniform(0.02, 0.2, s),
                              rng.uniform(0.01, 0.1, s), increment_seconds=rng.uniform(0.1, 1.0, steps),
                              offset_index=rng.integers(0, n_groups, s))


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), steps=st.integers(1, 9), n_landmarks=st.integers(2, 4),
       kind=st.sampled_from(["plain", "drift", "slip", "offsets", "calibration", "calibration-tape"]),
       loss=st.booleans(), damping=st.sampled_from([1e-9, 1e-4, 10.0]))
def test_the_normal_equations_by_blocks_are_the_whole_j_t_j_s_to_the_bit(seed, steps, n_landmarks, kind, loss,
                                                                         damping):
    rng = np.random.default_rng(seed)
    problem = _problem(rng, steps, n_landmarks, 2 * n_landmarks)
    poses = dead_reckoning(problem.increments) + rng.normal(0, 0.2, (steps + 1, 3))
    poses[0] = 0
    landmarks = rng.uniform(-3, 3, (n_landmarks, 2)) + np.array([5.0, 0.0])
    weights = rng.uniform(0, 1, len(problem.ranges)) * (rng.uniform(0, 1, len(problem.ranges)) > 0.2)
    drift = offset = offsets = extra = values = None
    if kind in ("drift", "slip"):
        drift = landmark_smoother._Drift(problem, landmark_smoother.HeadingDrift(0.05, 10.0,
                                                                                 0.1 if kind == "slip" else 0.0))
    if kind == "offsets":
        offset = landmark_smoother._Offsets(problem, landmark_smoother.SightingOffset(0.05), 2 * n_landmarks)
        offsets = rng.normal(0, 0.05, (offset.count, 2))
    if kind.startswith("calibration"):
        sensor = RangeBearingNoise(0.01, 0.01, 0.01)
        free, lengths, scale = FREE_WITH_SHAPE, _Lengths.of((), np.arange(n_landmarks)), None
        values = np.array([-0.05, 0.98, 0.01, 0.02, 0.01])
        if kind == "calibration-tape":
            lengths = _Lengths.of((KnownDistance(0, 1, 2.0, 0.005),), np.arange(n_landmarks))
            scale = _OdometryScale.of(problem, 1.0)
            free, values = np.append(free, TRANSLATION_SCALE), np.append(values, 1.02)
        extra = _Shape(sensor, problem.ranges, problem.bearings, problem.range_sigmas, free, lengths, scale)
        problem = extra.applied(problem, values)
    width = landmark_smoother._width(drift)
    rows = landmark_smoother._jacobian_rows(problem, poses, landmarks, n_landmarks, weights, drift, offset, offsets,
                                            extra, values, _residuals(problem, poses, landmarks) if extra else None)
    jac = rows.csr()
    reference = jac.copy()
    reference.has_sorted_indices = False
    reference.sort_indices()            # the rows' columns were ascending already: the flag set on them holds
    assert np.array_equal(reference.indices, jac.indices) and np.array_equal(reference.data, jac.data)
    if loss:                            # the heading rows scaled by √w, as _row_scaled scales the whole Jacobian
        heading_weights = rng.uniform(0.1, 1.0, steps)
        jac = landmark_smoother._row_scaled(jac, steps, heading_weights)
        rows.values[0][2::3] *= np.sqrt(heading_weights)[:, None]
    residual = rng.normal(0, 1, jac.shape[0])
    # the straightforward way: the whole JᵀJ, damped as a sparse sum, sliced by NormalFactor
    normal = (jac.T @ jac).tocsc()
    whole = NormalFactor(normal + sp.diags(damping * np.maximum(normal.diagonal(), 1e-9), format="csc"), steps,
                         width)
    blocks = _NormalEquations(rows, residual, steps, width)
    fast = blocks.damped(damping)
    assert np.array_equal(blocks.gradient, jac.T @ residual)
    for name in ("band", "pl", "x"):
        assert np.array_equal(getattr(fast, name), getattr(whole, name)), name
    assert np.array_equal(fast.schur[0], whole.schur[0])
    assert np.array_equal(fast.solve(blocks.gradient), whole.solve(jac.T @ residual))


@settings(max_examples=100, deadline=None)
@given(increments=st.lists(st.tuples(*[st.floats(-50, 50, allow_nan=False)] * 3), max_size=40))
def test_dead_reckoning_is_compose_step_by_step_to_the_bit(increments):
    steps = np.array(increments, float).reshape(-1, 3)
    expected = [np.zeros(3)]
    for step in steps:
        expected.append(compose(expected[-1], step))
    assert np.array_equal(dead_reckoning(steps), np.array(expected))
    assert np.array_equal(dead_reckoning(increments), np.array(expected))
