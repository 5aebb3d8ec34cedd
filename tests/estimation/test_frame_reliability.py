"""Reliability of a smoothed map's frame (estimation.frame_reliability): the redundancy blocks against a dense inverse,
their sum, the frame's external effect against a re-solve, and a frame tied by one lone first sighting flagged where
one tied by several is not."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.linalg
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.frame_reliability import (
    DELTA_0,
    SelectedInverse,
    band_inverse,
    frame_reliability,
    reliability_metrics,
    reliability_warning,
)
from estimation.landmark_scores import rigid_functional
from estimation.landmark_smoother import (
    HeadingDrift,
    LandmarkLogProblem,
    _Drift,
    _jacobian,
    smooth,
    solution_jacobian,
)
from tests.estimation.frame_helpers import (
    LANDMARKS,
    glimpses_then_lap,
    joint_frame_covariance,
    solved,
)


@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 40), half=st.integers(0, 9), seed=st.integers(0, 2 ** 32 - 1))
def test_the_band_of_the_inverse_is_the_dense_inverse_s(n, half, seed):
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((n, n))
    a = a @ a.T + n * np.eye(n)
    a[np.abs(np.subtract.outer(np.arange(n), np.arange(n))) > half] = 0.0
    band = np.zeros((half + 1, n))
    for d in range(min(half, n - 1) + 1):
        band[half - d, d:] = np.diagonal(a, d)
    z = band_inverse(scipy.linalg.cholesky_banded(band, lower=False))
    inverse = np.linalg.inv(a)
    for d in range(half + 1):
        expected = np.concatenate([np.diagonal(inverse, d), np.zeros(min(d, n))]) if d < n else np.zeros(n)
        np.testing.assert_allclose(z[d], expected, rtol=1e-9, atol=1e-12)


def _random_problem(rng, steps: int, n_landmarks: int) -> tuple[LandmarkLogProblem, np.ndarray, np.ndarray]:
    s = 3 * steps
    problem = LandmarkLogProblem(rng.normal(0, 0.4, (steps, 3)), rng.uniform(0.01, 0.1, (steps, 3)),
                                 rng.integers(1, steps + 1, s), np.arange(s) % n_landmarks, rng.uniform(0.5, 4, s),
                                 rng.uniform(-0.6, 0.6, s), rng.uniform(0.02, 0.2, s), rng.uniform(0.01, 0.1, s),
                                 rng.uniform(0.05, 1.0, steps))
    poses = rng.normal(0, 0.5, (steps + 1, 3))
    poses[0] = 0
    landmarks = rng.uniform(-3, 3, (n_landmarks, 2)) + np.array([5.0, 0.0])
    return problem, poses, landmarks


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), steps=st.integers(2, 12), n_landmarks=st.integers(1, 4),
       slip=st.sampled_from([None, 0.0, 0.2]))
def test_the_redundancy_blocks_are_the_dense_ones_and_sum_to_rows_less_unknowns(seed, steps, n_landmarks, slip):
    """I − J_G H⁻¹ J_Gᵀ for every factor's rows (an increment's three, a sighting's two, each heading drift's one),
    from the band and the Schur complement, against a dense inverse; the traces add up to rows − unknowns (with a
    heading drift, one or two bias states per pose: the band is 7 or 9 wide)."""
    rng = np.random.default_rng(seed)
    problem, poses, landmarks = _random_problem(rng, steps, n_landmarks)
    drift = None if slip is None else _Drift(problem, HeadingDrift(0.1, 20.0, slip))
    width = 3 if drift is None else 3 + drift.n
    jac = _jacobian(problem, poses, landmarks, n_landmarks, np.ones(len(problem.ranges)), drift)
    t, s = steps, len(problem.ranges)
    inverse = SelectedInverse(jac, np.ones(jac.shape[1], bool), t, width)
    increments = 3 * np.arange(t)[:, None] + np.arange(3)
    sightings = 3 * t + 2 * np.arange(s)[:, None] + np.arange(2)
    priors = np.arange(3 * t + 2 * s, jac.shape[0])[:, None]
    dense = jac.toarray()
    hat = dense @ np.linalg.solve(dense.T @ dense, dense.T)
    total = 0.0
    for groups in (increments, sightings, priors):
        blocks = inverse.hat_blocks(groups)
        np.testing.assert_allclose(blocks, hat[groups[:, :, None], groups[:, None, :]], rtol=1e-7, atol=1e-9)
        total += np.sum(1.0 - np.diagonal(blocks, axis1=1, axis2=2))
    assert total == pytest.approx(jac.shape[0] - jac.shape[1], rel=1e-7, abs=1e-7)


def _log_problem(rng, first_landmarks: int, exact: bool = False) -> LandmarkLogProblem:
    """A robot at the origin sees ``first_landmarks`` landmarks from its first pose, then turns on the spot by 3 rad
    in 30 frames seeing nothing (MRCLAM's odometry: σ_θ² 0.0087 per radian), then drives a lap of a 1.5 m circle
    seeing every landmark ahead. With one first landmark, that bearing alone ties the map's heading to pose 0 beyond
    the turn's odometry (σ 0.16 rad); with several, each is checked by the others."""
    return glimpses_then_lap(rng, first_landmarks, lone_glimpses=False, noise=0.0 if exact else 1.0)


def test_the_frame_s_sd_is_the_joint_covariance_s_and_every_sighting_has_a_redundancy_in_0_2():
    problem = _log_problem(np.random.default_rng(0), 1)
    solution = solved(problem)
    rel = frame_reliability(problem, solution)
    np.testing.assert_allclose(rel.frame_covariance, joint_frame_covariance(problem, solution), rtol=1e-8)
    r = rel.redundancy_numbers
    assert np.all((r > 0) & (r < 2))
    # the dense check on the smoother's own Jacobian (all rows): the blocks are those of I − J H⁻¹ Jᵀ
    jac, _ = solution_jacobian(problem, solution)
    dense = jac.toarray()
    dense = dense[:, np.any(dense != 0, axis=0)]                 # a landmark never sighted has no column
    hat = dense @ np.linalg.solve(dense.T @ dense, dense.T)
    rows = 3 * problem.n_poses + 2 * np.arange(len(r))[:, None] + np.arange(2)
    np.testing.assert_allclose(rel.redundancy, np.eye(2) - hat[rows[:, :, None], rows[:, None, :]], atol=1e-8)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_frame_tied_by_one_lone_first_sighting_is_flagged_and_one_tied_by_several_is_not(seed):
    """One landmark seen from the first pose before a long turn on the spot: that bearing is the only tie of the
    map's heading to the frame beyond the turn's odometry: its redundancy is near 0 and the least error the data
    could find in it turns the frame by many of its σ. Two or four landmarks seen there: each bearing is checked by the
    others and no sighting moves any of the frame's coordinates by δ₀ σ (two are enough)."""
    rng = np.random.default_rng(seed)
    lone = _log_problem(rng, 1)
    solution = solved(lone)
    rel = frame_reliability(lone, solution)
    assert rel.redundancy[0, 1, 1] < 0.05                      # the first sighting's bearing: nothing checks it
    assert rel.heading_effect()[0, 1] > 3 * DELTA_0 * rel.frame_sd[2]          # 20 σ on seeds 0-5
    times = np.arange(1, lone.n_poses + 1) * 0.25
    m = reliability_metrics(lone, solution, times, np.arange(len(LANDMARKS)) + 6)
    assert m["frame_reliability_unchecked"]
    first = m["frame_reliability_heading_sighting"]
    assert first["time_s"] == 0.25 and first["component"] == "bearing" and first["component_redundancy"] < 0.05
    assert m["frame_reliability_effect_sd"][2] > 3 * DELTA_0
    warning = reliability_warning(m)
    assert "bearing of the sighting at 0.25 s" in warning and "turn the frame" in warning

    for first in (2, 4):            # the worst coordinate moves 3.0-3.4 σ on seeds 0-5
        several = _log_problem(rng, first)
        solution = solved(several)
        rel = frame_reliability(several, solution)
        assert np.all(rel.redundancy[:first, 1, 1] > 0.3)
        m = reliability_metrics(several, solution, np.arange(1, several.n_poses + 1) * 0.25, np.arange(8) + 6)
        assert not m["frame_reliability_unchecked"] and max(m["frame_reliability_effect_sd"]) < DELTA_0
        assert reliability_warning(m) is None


def _frame_of(solution, functional, seen):
    return functional @ solution.landmarks[seen].ravel()


@pytest.mark.parametrize("lone", [1, 4])
def test_the_external_effect_is_what_a_re_solve_with_that_bias_moves_the_frame(lone):
    """Add a small fraction of ∇₀ to one sighting's range or bearing and solve again: the frame's (dx, dy, dθ) moves
    by that fraction of the predicted effect, for the sighting that moves it most and for two others. The linear
    case: exact data (the residuals 0 at the solution, so JᵀJ is the cost's Hessian; with noisy data it lacks the
    residuals' curvature, Σ rᵢ ∇²rᵢ) and a small bias (the second order negligible)."""
    problem = _log_problem(np.random.default_rng(4), lone, exact=True)
    solution = solved(problem)
    rel = frame_reliability(problem, solution)
    seen = np.unique(problem.landmark_index)                     # a landmark never sighted is no part of the frame
    functional = rigid_functional(solution.landmarks[seen])
    before = _frame_of(solution, functional, seen)
    effect = np.nan_to_num(rel.heading_effect())
    picks = [tuple(np.unravel_index(np.argmax(effect), effect.shape)), (len(problem.ranges) - 1, 0), (5, 1)]
    fraction = 0.01
    for s, c in picks:
        field = "ranges" if c == 0 else "bearings"
        values = getattr(problem, field).copy()
        values[s] += fraction * rel.minimal_bias[s, c]
        biased = dataclasses.replace(problem, **{field: values})
        again = smooth(biased, solution.poses, solution.landmarks)
        assert again.inliers.all()
        moved = _frame_of(again, functional, seen) - before
        predicted = fraction * rel.frame_effect[s, c]
        np.testing.assert_allclose(moved, predicted, rtol=0.03, atol=1e-6 + 0.03 * np.max(np.abs(predicted)))


def _landmarks_kept(problem: LandmarkLogProblem, landmarks: list[int]) -> LandmarkLogProblem:
    """``problem`` with the sightings of ``landmarks`` only, renumbered 0, 1, ... in that order."""
    keep = np.isin(problem.landmark_index, landmarks)
    index = np.searchsorted(np.sort(landmarks), problem.landmark_index[keep])
    return LandmarkLogProblem(problem.increments, problem.increment_variances, problem.pose_index[keep], index,
                              problem.ranges[keep], problem.bearings[keep], problem.range_sigmas[keep],
                              problem.bearing_sigmas[keep])


def test_no_frame_without_two_landmarks_and_no_figures_then():
    problem = _log_problem(np.random.default_rng(0), 1)
    one = _landmarks_kept(problem, [int(problem.landmark_index[0])])
    solution = solved(one)
    with pytest.raises(ValueError, match="two landmarks"):
        frame_reliability(one, solution)
    assert reliability_metrics(one, solution, np.arange(one.n_poses) + 1.0, np.array([6])) == {}
    assert reliability_warning({}) is None
    # two landmarks make a frame: the figures are there
    two = _landmarks_kept(problem, [int(problem.landmark_index[0]), int(problem.landmark_index[-1])])
    m = reliability_metrics(two, solved(two), np.arange(two.n_poses) + 1.0, np.array([6, 7]))
    assert np.all(np.isfinite(m["frame_reliability_sd"])) and m["sighting_redundancy_min"] >= 0


def test_an_error_that_is_not_the_missing_frame_is_not_taken_for_it():
    """Only fewer than two landmarks with a kept sighting mean "no figures" ({}): a solution that is not finite (a
    diverged solve) is an error of its own and is raised, not reported as a run without a frame."""
    problem = _log_problem(np.random.default_rng(0), 1)
    solution = solved(problem)
    landmarks = solution.landmarks.copy()
    landmarks[3] = np.nan
    diverged = dataclasses.replace(solution, landmarks=landmarks)
    with pytest.raises(ValueError, match="infs or NaNs"):
        reliability_metrics(problem, diverged, np.arange(problem.n_poses) + 1.0, np.arange(len(LANDMARKS)) + 6)


def test_design_figures_merge_the_figures_or_say_why_there_are_none():
    from estimation.frame_reliability import design_figures, reliability_warning

    assert design_figures(lambda: {"a": 1}, lambda: {"b": 2}) == {"a": 1, "b": 2}

    def singular() -> dict:
        raise np.linalg.LinAlgError("Matrix is not positive definite")

    failed = design_figures(lambda: {"a": 1}, singular)
    assert failed == {"reliability_unavailable": "LinAlgError: Matrix is not positive definite"}
    assert "could not be computed (LinAlgError: Matrix is not positive definite)" in reliability_warning(failed)
    with pytest.raises(KeyError):                        # not a numerical failure: a bug, raised
        design_figures(lambda: {}["missing"])
