"""Weights that compare only particles that made a landmark together (``weight_evidence="shared_creation"``).

The scene for the filter: a robot drives 20 m straight down a corridor of posts, each in view for a few frames and
then left behind, so after the first posts every reading is of a landmark the particles made themselves; then it
drives back and sees the first posts again. The odometry is exact; the cloud's spread comes from the motion
model (and FastSLAM 2.0's proposal against each particle's own posts).
"""
from __future__ import annotations

from functools import cache

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose

from estimation.fastslam import FastSLAM, range_bearing_config, range_bearing_observations
from estimation.fastslam.resampling import normalise_log_weights
from estimation.fastslam.shared_evidence import CreationTokens
from estimation.geometry import wrap_angle
from estimation.observations import OdometryIncrement

THETA_SD_PER_M = 0.02     # the motion model's heading random walk, rad per √m
STEP_M = 0.25


def _tokens(rows: np.ndarray) -> CreationTokens:
    tokens = CreationTokens(rows.shape[1])
    tokens.tokens = np.asarray(rows, np.int64)
    return tokens


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 12).flatmap(lambda m: st.tuples(
    st.lists(st.floats(-20, 0), min_size=m, max_size=m),
    st.lists(st.floats(-30, 0), min_size=m, max_size=m),
    st.lists(st.integers(0, 3), min_size=m, max_size=m),
    st.lists(st.booleans(), min_size=m, max_size=m))))
def test_a_reading_keeps_each_creation_groups_total_weight(draw):
    log_w, term, token, holds = (np.array(v) for v in draw)
    total = _tokens(token[None]).log_likelihood(log_w, term[:, None], np.array([0]), holds[:, None])
    before, after = normalise_log_weights(log_w), normalise_log_weights(log_w + total)
    group = np.where(holds, token, -1)
    for g in np.unique(group):
        assert_allclose(after[group == g].sum(), before[group == g].sum(), rtol=1e-9, atol=1e-12)
        inside = np.flatnonzero(group == g)   # within a group: the reading's likelihood, as without the rule
        assert_allclose(after[inside] / after[inside].sum(),
                        normalise_log_weights(log_w[inside] + term[inside]), rtol=1e-9, atol=1e-12)


def test_one_shared_creation_weighs_as_the_plain_filter_and_separate_ones_not_at_all():
    rng = np.random.default_rng(0)
    log_w, terms = rng.normal(0, 1, 8), rng.normal(-3, 2, (8, 3))
    holds = np.ones((8, 3), bool)
    shared = _tokens(np.zeros((3, 8))).log_likelihood(log_w, terms, np.arange(3), holds)
    assert_allclose(normalise_log_weights(log_w + shared), normalise_log_weights(log_w + terms.sum(axis=1)))
    apart = _tokens(np.tile(np.arange(8), (3, 1))).log_likelihood(log_w, terms, np.arange(3), holds)
    assert_allclose(normalise_log_weights(log_w + apart), normalise_log_weights(log_w))


def test_tokens_follow_resampling_and_identical_poses_share_a_creation():
    tokens = CreationTokens(4)
    tokens.made(np.array([0, 0, 0, 0]), np.arange(4), np.zeros((4, 3)))          # the first frame: one pose
    tokens.made(np.array([1, 1, 1, 1]), np.arange(4), np.arange(12.0).reshape(4, 3))   # four poses
    assert len(set(tokens.tokens[0])) == 1 and len(set(tokens.tokens[1])) == 4
    tokens.resampled(np.array([2, 2, 3, 3]))
    assert tokens.tokens[1, 0] == tokens.tokens[1, 1] != tokens.tokens[1, 2] == tokens.tokens[1, 3]


@cache
def _corridor(rule: str, seed: int):
    """Out 20 m and back. Returns (cloud heading sd at the far end (rad), resamplings on the way out after the
    first posts left the view, the smallest ESS / M there, the smallest ESS / M in the last 5 m back (the first
    posts in view))."""
    rng = np.random.default_rng(seed)
    xs = np.arange(0.0, 22.0, 2.0)
    posts = np.column_stack([np.concatenate([xs, xs]), np.concatenate([np.full_like(xs, 2.0), -np.full_like(xs, 2.0)])])
    slam = FastSLAM(range_bearing_config(n_particles=60, association="id", fov_horizontal=1.6, max_range=5.0,
                                         odom_xy_var_per_m=0.02 ** 2, odom_theta_var_per_m=THETA_SD_PER_M ** 2,
                                         weight_evidence=rule), np.random.default_rng(seed + 1))
    pose = np.zeros(3)

    def look():
        rel = posts - pose[:2]
        rng_, bearing = np.hypot(*rel.T), wrap_angle(np.arctan2(rel[:, 1], rel[:, 0]) - pose[2])
        seen = np.flatnonzero((np.abs(bearing) < 0.8) & (rng_ < 5.0))
        report = slam.update(range_bearing_observations(rng_[seen] + rng.normal(0, 0.05, len(seen)),
                                                        bearing[seen] + rng.normal(0, 0.01, len(seen)), 0.05, 0.01,
                                                        ids=seen))
        return report.resampled, report.ess / 60

    look()
    out_resampled, out_ess = 0, 1.0
    for _ in range(80):
        pose = pose + np.array([STEP_M, 0.0, 0.0])
        slam.predict(OdometryIncrement(STEP_M, 0.0, 0.0))
        resampled, ess = look()
        if pose[0] > 6.0:
            out_resampled, out_ess = out_resampled + resampled, min(out_ess, ess)
    spread = float(np.std(wrap_angle(slam.poses[:, 2] - pose[2])))
    slam.predict(OdometryIncrement(0.0, 0.0, np.pi))
    pose[2] = np.pi
    back_ess = 1.0
    for _ in range(80):
        pose = pose + np.array([-STEP_M, 0.0, 0.0])
        slam.predict(OdometryIncrement(STEP_M, 0.0, 0.0))
        ess = look()[1]
        if pose[0] < 5.0:
            back_ess = min(back_ess, ess)
    return spread, out_resampled, out_ess, back_ess


def test_exploring_does_not_resample_and_the_first_posts_compare_everyone_again():
    for seed in range(2):
        _, out_resampled, out_ess, back_ess = _corridor("shared_creation", seed)
        assert out_resampled == 0 and out_ess > 0.5
        assert back_ess < 0.6   # the first posts again: made before the particles diverged, they compare all


def test_the_plain_weights_resample_on_noise_and_keep_less_heading_spread():
    for seed in range(2):
        spread, out_resampled, _, _ = _corridor("all", seed)
        assert out_resampled > 5
        assert spread < _corridor("shared_creation", seed)[0]
