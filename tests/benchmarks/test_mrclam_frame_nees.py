"""benchmarks.mrclam_frame_nees: a map's frame error and what the landmark NEES figure says, on synthetic maps (no
data set)."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from benchmarks.mrclam_frame_nees import (
    beyond_counts,
    figure_failure,
    frame_figures,
    rigid_design,
    rigid_functional,
)

layouts = st.integers(0, 2 ** 32 - 1).map(
    lambda seed: _layout(np.random.default_rng(seed), int(np.random.default_rng(seed).integers(3, 16))))


def _layout(rng, n):
    """n landmarks 1-9 m from the frame's origin in every direction."""
    distance, angle = rng.uniform(1.0, 9.0, n), rng.uniform(-np.pi, np.pi, n)
    return np.column_stack([distance * np.cos(angle), distance * np.sin(angle)])


def _frame_map(truth, frame_sd=(0.03, 0.04, 0.06), own_sd=0.02):
    """A joint covariance of landmarks that share one frame error (dx, dy, dθ of σ ``frame_sd``) and each have an
    error of their own (``own_sd`` per axis), and its marginal blocks."""
    design = rigid_design(truth)
    joint = design @ np.diag(np.square(frame_sd)) @ design.T + own_sd ** 2 * np.eye(2 * len(truth))
    blocks = np.array([joint[2 * j:2 * j + 2, 2 * j:2 * j + 2] for j in range(len(truth))])
    return joint, blocks


@given(layouts)
def test_the_rigid_functional_undoes_the_rigid_design(truth):
    assert np.allclose(rigid_functional(truth) @ rigid_design(truth), np.eye(3), atol=1e-9)


@settings(max_examples=50)
@given(layouts, st.floats(-0.1, 0.1), st.floats(-0.1, 0.1), st.floats(-0.1, 0.1))
def test_a_map_moved_rigidly_gives_back_its_motion_and_a_rotation_moves_it_across(truth, dx, dy, dtheta):
    joint, blocks = _frame_map(truth)
    moved = truth + (rigid_design(truth) @ [dx, dy, dtheta]).reshape(-1, 2)
    f = frame_figures(moved, blocks, joint, truth)
    assert np.allclose([f["frame"]["dx_m"], f["frame"]["dy_m"], f["frame"]["dtheta_rad"]], [dx, dy, dtheta],
                       atol=1e-9)
    assert f["within_both_removed"] == 1.0
    rotated = frame_figures(truth + (rigid_design(truth) @ [0.0, 0.0, dtheta]).reshape(-1, 2), blocks, joint, truth)
    for row in rotated["landmarks"]:
        assert abs(row["radial_m"]) < 1e-9
        assert np.isclose(row["across_m"], dtheta * row["distance_m"], atol=1e-9)
    assert rotated["within_rotation_removed"] == 1.0


def test_the_frame_covariance_is_the_shared_one_plus_what_the_landmarks_own_errors_leave():
    truth = _layout(np.random.default_rng(3), 12)
    frame_sd = np.array([0.03, 0.04, 0.06])
    joint, blocks = _frame_map(truth, frame_sd, own_sd=0.02)
    functional = rigid_functional(truth)
    expected = np.diag(frame_sd ** 2) + 0.02 ** 2 * functional @ functional.T
    f = frame_figures(truth, blocks, joint, truth)
    assert np.allclose(f["frame"]["sd"], np.sqrt(np.diag(expected)))
    assert f["frame"]["nees"] == 0.0 and f["joint_nees"] == 0.0 and f["within"] == 1.0


def test_errors_drawn_from_the_joint_covariance_have_a_chi2_joint_nees():
    rng = np.random.default_rng(7)
    truth = _layout(rng, 15)
    joint, blocks = _frame_map(truth)
    root = np.linalg.cholesky(joint)
    values = [frame_figures(truth + (root @ rng.standard_normal(30)).reshape(-1, 2), blocks, joint, truth)["joint_nees"]
              for _ in range(400)]
    # χ²₃₀: mean 30, variance 60; the mean of 400 within 4 standard errors
    assert abs(np.mean(values) - 30.0) < 4 * np.sqrt(60 / 400)


def test_independent_landmarks_fail_the_figure_as_the_binomial_says_and_a_shared_frame_spreads_the_count():
    rng = np.random.default_rng(11)
    truth = _layout(rng, 15)
    own = 0.02 ** 2 * np.eye(30)
    own_blocks = np.array([own[2 * j:2 * j + 2, 2 * j:2 * j + 2] for j in range(15)])
    independent = figure_failure(beyond_counts(own, own_blocks, 40000, rng), 15)
    assert independent["allowed_beyond"] == 1
    assert abs(independent["p_fail"] - independent["p_fail_independent"]) < 0.015   # 0.171; the draws' SE 0.002
    assert abs(independent["mean_beyond"] - 0.75) < 0.03
    joint, blocks = _frame_map(truth, frame_sd=(0.05, 0.05, 0.1), own_sd=0.005)      # the frame dominates
    counts = beyond_counts(joint, blocks, 40000, rng)
    shared = figure_failure(counts, 15)
    # each landmark is still beyond 5 % of the time, but together: often none, sometimes many
    assert abs(shared["mean_beyond"] - 0.75) < 0.05
    assert np.var(counts) > 2 * 15 * 0.05 * 0.95
    assert np.mean(counts == 0) > 0.463 + 0.1                                        # independent: 0.95¹⁵ = 0.463
    assert shared["p_at_least"]["3"] > 2 * independent["p_at_least"]["3"]
