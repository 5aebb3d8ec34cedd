"""The frame's reliability (estimation.frame_reliability) with sighting offsets, as the unknown-association chain's
last smoothings carry them: each sighting's redundancy block is still the dense one of the smoother's own Jacobian
(its offset's columns included) and the frame's covariance the joint covariance's (the sole groups' σ² I included);
with one group per landmark the offsets change no redundancy nor effect, only the frame's covariance by σ² g gᵀ."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.frame_reliability import frame_reliability
from estimation.geometry import dead_reckoning
from estimation.landmark_scores import rigid_functional
from estimation.landmark_smoother import (
    HeadingDrift,
    SightingOffset,
    landmarks_from_first_sightings,
    smooth,
    sole_offset_groups,
    solution_jacobian,
)
from tests.estimation.frame_helpers import LANDMARKS, joint_frame_covariance

from .test_frame_reliability import _log_problem


def _grouped(problem, split: bool):
    """Offset groups as a chain makes them: with ``split`` each even landmark's sightings in two visits (before and
    after pose 70, two groups: explicit offsets), landmarks 1 and 3 sharing one group (two chained names merged in
    one group), the rest each its own group (sole: marginalised by the smoother)."""
    landmark, pose = problem.landmark_index, problem.pose_index
    raw = 10 * landmark + np.where(split & (landmark % 2 == 0), (pose > 70).astype(int), 0)
    raw = np.where(split & np.isin(landmark, [1, 3]), 10, raw)
    return dataclasses.replace(_timed(problem), offset_index=np.unique(raw, return_inverse=True)[1].astype(int))


def _timed(problem):
    """``problem`` with each increment 0.25 s long (a heading drift needs the increments' durations)."""
    return dataclasses.replace(problem, increment_seconds=np.full(problem.n_poses, 0.25))


def _solved(problem, sigma: float | None, drift: bool):
    poses = dead_reckoning(problem.increments)
    return smooth(problem, poses, landmarks_from_first_sightings(problem, poses),
                  heading_drift=HeadingDrift(0.16, 10.0, sigma_per_rad=0.3) if drift else None,
                  sighting_offset=None if sigma is None else SightingOffset(sigma))


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), first=st.sampled_from([1, 3]), sigma=st.floats(0.01, 0.1),
       drift=st.booleans())
def test_with_offsets_the_blocks_are_the_dense_ones_and_the_frame_s_covariance_the_joint_one(seed, first, sigma,
                                                                                          drift):
    problem = _grouped(_log_problem(np.random.default_rng(seed), first), split=True)
    solution = _solved(problem, sigma, drift)
    assert solution.offsets is not None and len(sole_offset_groups(problem)) > 0
    rel = frame_reliability(problem, solution)
    jac, _ = solution_jacobian(problem, solution)
    dense = jac.toarray()
    assert dense.shape[1] > 3 * problem.n_poses + 2 * len(solution.landmarks)      # explicit offsets' columns
    dense = dense[:, np.any(dense != 0, axis=0)]
    hat = dense @ np.linalg.solve(dense.T @ dense, dense.T)
    kept = np.flatnonzero(solution.inliers)
    rows = 3 * problem.n_poses + 2 * kept[:, None] + np.arange(2)
    np.testing.assert_allclose(rel.redundancy[kept], np.eye(2) - hat[rows[:, :, None], rows[:, None, :]], atol=1e-7)
    assert np.all(np.isnan(rel.redundancy[~solution.inliers]))
    np.testing.assert_allclose(rel.frame_covariance, joint_frame_covariance(problem, solution), rtol=1e-7)


@pytest.mark.parametrize("first", [1, 3])
def test_one_group_per_landmark_changes_no_redundancy_nor_effect_only_the_frame_s_covariance(first):
    problem = _timed(_log_problem(np.random.default_rng(first), first))
    assert len(sole_offset_groups(problem)) == len(np.unique(problem.landmark_index))
    plain, offset = _solved(problem, None, True), _solved(problem, 0.03, True)
    a, b = frame_reliability(problem, plain), frame_reliability(problem, offset)
    np.testing.assert_allclose(b.redundancy, a.redundancy, atol=1e-9)
    np.testing.assert_allclose(b.frame_effect, a.frame_effect, rtol=1e-6, atol=1e-9)
    seen = np.unique(problem.landmark_index[plain.inliers])
    g = rigid_functional(plain.landmarks[seen])
    np.testing.assert_allclose(b.frame_covariance, a.frame_covariance + 0.03 ** 2 * g @ g.T, rtol=1e-6)
    assert np.all(b.frame_sd > a.frame_sd)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), n_groups=st.integers(1, 12), default=st.booleans())
def test_the_sole_groups_are_each_a_landmark_s_only_group_and_hold_it_alone(seed, n_groups, default):
    """The one rule the smoother marginalises by and the frame's covariance adds σ² I by (sole_offset_groups), against
    its definition read landmark by landmark; with the default grouping (no offset_index) every sighted landmark's."""
    rng = np.random.default_rng(seed)
    problem = _log_problem(rng, 1)
    if not default:      # about half the landmarks in a group of their own, the rest's sightings in shared groups
        alone = rng.random(len(LANDMARKS)) < 0.5
        landmarks = problem.landmark_index
        problem = dataclasses.replace(problem, offset_index=np.where(
            alone[landmarks], n_groups + landmarks, rng.integers(0, n_groups, len(landmarks))))
    groups, landmarks = problem.offset_groups, problem.landmark_index
    expected = [(landmark, own[0]) for landmark in np.unique(landmarks)
                if len(own := np.unique(groups[landmarks == landmark])) == 1
                and np.all(landmarks[groups == own[0]] == landmark)]
    np.testing.assert_array_equal(sole_offset_groups(problem), np.array(expected, int).reshape(-1, 2))
    assert default or len(expected) >= np.sum(alone[np.unique(landmarks)])
    if default:
        np.testing.assert_array_equal(sole_offset_groups(problem)[:, 0], np.unique(landmarks))
