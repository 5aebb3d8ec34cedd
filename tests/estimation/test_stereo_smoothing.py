"""The stereo smoother (estimation.stereo_smoothing) on synthetic planar-robot stereo logs with known truth."""
from __future__ import annotations

import numpy as np
import pytest

from estimation.geometry import compose, wrap_angle
from estimation.stereo_smoothing import StereoLogProblem, StereoSmoothingError, smooth

CHI2_3_95 = 7.815


def _synthetic(seed: int, wrong: float = 0.0, shared: float = 0.0, view: float = 0.0, stops: int = 0):
    """A robot driving a square loop twice past 3-D points, odometry with the filter's random-walk noise, stereo
    points with depth-growing noise; ``wrong``: the share of observations given a wrong landmark; ``shared`` (m): the
    σ of an error common to all the readings of one landmark (each landmark seen where it is not); ``view`` (m): the σ
    of an error shared by a landmark's readings from about the same view (per axis: independent offsets every
    2π/32 rad of the direction from the landmark to the robot, interpolated between: a corner found at the same
    wrong point while the view hardly changes); ``stops``: frames the robot stands still after each side's first
    metre (the same view again and again)."""
    rng = np.random.default_rng(seed)
    legs = [(0.2, 0.0)] * 5 + [(0.0, 0.0)] * stops + [(0.2, 0.0)] * 10 + [(0.0, np.pi / 8)] * 4
    true_inc = np.array([(d, 0.0, a) for d, a in legs * 8])
    poses = [np.zeros(3)]
    for inc in true_inc:
        poses.append(compose(poses[-1], inc))
    poses = np.array(poses)
    landmarks = np.column_stack([rng.uniform(-3, 6, 150), rng.uniform(-3, 6, 150), rng.uniform(0.2, 2.0, 150)])
    seen_at = landmarks + shared * rng.standard_normal(landmarks.shape)
    view_offsets = view * np.random.default_rng((seed, 1)).standard_normal((len(landmarks), 32, 3))
    trans = np.hypot(true_inc[:, 0], true_inc[:, 1])
    var = np.column_stack([0.03 ** 2 * trans + 1e-8, 0.03 ** 2 * trans + 1e-8,
                           0.05 ** 2 * np.abs(true_inc[:, 2]) + 0.02 ** 2 * trans + 1e-8])
    increments = true_inc + rng.standard_normal(true_inc.shape) * np.sqrt(var)
    pi, li, pts, covs = [], [], [], []
    for k, p in enumerate(poses):
        c, s = np.cos(p[2]), np.sin(p[2])
        d = seen_at[:, :2] - p[:2]
        local = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], seen_at[:, 2]])
        r = np.hypot(local[:, 0], local[:, 1])
        seen = np.flatnonzero((local[:, 0] > 0.5) & (r < 4.0) & (np.abs(np.arctan2(local[:, 1], local[:, 0])) < 0.7))
        at = 32 * (np.arctan2(p[1] - landmarks[:, 1], p[0] - landmarks[:, 0]) % (2 * np.pi)) / (2 * np.pi)
        for j in seen:
            q = np.diag([(0.01 + 0.01 * r[j] ** 2) ** 2, 0.01 ** 2, 0.01 ** 2])
            node, w = int(at[j]) % 32, at[j] % 1.0
            o = (1 - w) * view_offsets[j, node] + w * view_offsets[j, (node + 1) % 32]       # world frame
            pi.append(k)
            li.append(j)
            pts.append(local[j] + [c * o[0] + s * o[1], -s * o[0] + c * o[1], o[2]]
                       + rng.multivariate_normal(np.zeros(3), q))
            covs.append(q)
    li = np.array(li)
    n_wrong = int(wrong * len(li))
    bad = rng.choice(len(li), n_wrong, replace=False)
    li[bad] = (li[bad] + rng.integers(1, len(landmarks), n_wrong)) % len(landmarks)
    problem = StereoLogProblem(increments, var, np.array(pi), li, np.array(pts), np.array(covs), len(landmarks))
    dead = [np.zeros(3)]
    for inc in increments:
        dead.append(compose(dead[-1], inc))
    dead = np.array(dead)
    start = np.zeros((len(landmarks), 3))
    p, z = dead[problem.pose_index], problem.points
    c, s = np.cos(p[:, 2]), np.sin(p[:, 2])
    placed = np.column_stack([p[:, 0] + c * z[:, 0] - s * z[:, 1], p[:, 1] + s * z[:, 0] + c * z[:, 1], z[:, 2]])
    for j in range(len(landmarks)):   # each landmark at the median of its observations placed by dead reckoning
        k = problem.landmark_index == j
        if k.any():
            start[j] = np.median(placed[k], axis=0)
    return problem, poses, landmarks, dead, start, bad


def _pose_error(est, truth):
    return np.hypot(est[:, 0] - truth[:, 0], est[:, 1] - truth[:, 1]), np.abs(wrap_angle(est[:, 2] - truth[:, 2]))


@pytest.mark.parametrize("seed", range(4))
def test_smoothing_recovers_the_truth_better_than_dead_reckoning_with_honest_covariances(seed):
    problem, poses, landmarks, dead, start, _ = _synthetic(seed)
    out = smooth(problem, dead, start)
    xy0, th0 = _pose_error(dead, poses)
    xy1, th1 = _pose_error(out.poses, poses)
    assert np.sqrt(np.mean(xy1 ** 2)) < 0.5 * np.sqrt(np.mean(xy0 ** 2))
    assert np.sqrt(np.mean(th1 ** 2)) < 0.5 * np.sqrt(np.mean(th0 ** 2))
    np.testing.assert_array_equal(out.poses[0], np.zeros(3))        # the gauge: the map frame is pose 0
    held = out.held
    e = out.landmarks[held] - landmarks[held]
    nees = np.einsum("la,lab,lb->l", e, np.linalg.inv(out.landmark_covariances[held]), e)
    assert held.sum() > 100
    assert np.mean(nees <= CHI2_3_95) >= 0.85                      # 95 % expected: covariances cover the errors
    assert np.mean(nees <= 0.35) < 0.5                              # and do not hide them by being huge (χ²₃ 5 %)
    pe = np.column_stack([out.poses[:, :2] - poses[:, :2], wrap_angle(out.poses[:, 2] - poses[:, 2])])[1:]
    pn = np.einsum("ta,tab,tb->t", pe, np.linalg.inv(out.pose_covariances[1:]), pe)
    assert np.mean(pn <= CHI2_3_95) >= 0.8                          # pose marginals too (correlated along the path)
    assert 0.7 < out.chi2_per_dof < 1.3


def _nees_share(out, landmarks):
    held = out.held
    e = out.landmarks[held] - landmarks[held]
    nees = np.einsum("la,lab,lb->l", e, np.linalg.inv(out.landmark_covariances[held]), e)
    return float(np.mean(nees <= CHI2_3_95))


@pytest.mark.parametrize("seed", range(3))
def test_an_error_shared_by_a_landmarks_readings_needs_the_floor_for_honest_covariances(seed):
    problem, poses, landmarks, dead, start, _ = _synthetic(seed, shared=0.03)
    plain = smooth(problem, dead, start)
    floored = smooth(problem, dead, start, landmark_floor=0.03 ** 2)
    np.testing.assert_array_equal(floored.landmarks, plain.landmarks)    # the estimates are the same
    np.testing.assert_array_equal(floored.poses, plain.poses)
    assert _nees_share(plain, landmarks) < 0.7                           # overconfident without it
    assert _nees_share(floored, landmarks) >= 0.85


def test_wrong_associations_are_cut_and_do_not_spoil_the_solution():
    problem, poses, landmarks, dead, start, bad = _synthetic(7, wrong=0.05)
    out = smooth(problem, dead, start)
    assert np.mean(~out.inliers[bad]) > 0.8                         # most wrong ones dropped
    assert np.mean(out.inliers[np.setdiff1d(np.arange(len(out.inliers)), bad)]) > 0.97
    clean = smooth(*_synthetic(7)[:1], dead, start)
    xy, th = _pose_error(out.poses, poses)
    xyc, thc = _pose_error(clean.poses, poses)
    assert np.sqrt(np.mean(th ** 2)) < 2 * np.sqrt(np.mean(thc ** 2)) + 1e-3


def test_a_malformed_problem_is_refused_with_a_clear_message():
    with pytest.raises(StereoSmoothingError, match="landmark_index outside"):
        StereoLogProblem(np.zeros((2, 3)), np.ones((2, 3)), [0], [5], np.zeros((1, 3)), np.eye(3)[None], 3)
    with pytest.raises(StereoSmoothingError, match="variances"):
        StereoLogProblem(np.zeros((2, 3)), np.zeros((2, 3)), [0], [0], np.zeros((1, 3)), np.eye(3)[None], 1)
    problem = StereoLogProblem(np.zeros((2, 3)), np.ones((2, 3)), [0], [0], np.zeros((1, 3)), np.eye(3)[None], 1)
    with pytest.raises(StereoSmoothingError, match="initial poses"):
        smooth(problem, np.zeros((2, 3)), np.zeros((1, 3)))
    with pytest.raises(StereoSmoothingError, match="landmark_floor"):
        smooth(problem, np.zeros((3, 3)), np.zeros((1, 3)), landmark_floor=-1e-4)
    with pytest.raises(StereoSmoothingError, match="view_floor"):
        smooth(problem, np.zeros((3, 3)), np.zeros((1, 3)), view_floor=float("nan"))
    with pytest.raises(StereoSmoothingError, match="view_change"):
        smooth(problem, np.zeros((3, 3)), np.zeros((1, 3)), view_floor=1e-4, view_change=0.0)


def _pose_nees_share(out, poses):
    pe = np.column_stack([out.poses[:, :2] - poses[:, :2], wrap_angle(out.poses[:, 2] - poses[:, 2])])[1:]
    pn = np.einsum("ta,tab,tb->t", pe, np.linalg.inv(out.pose_covariances[1:]), pe)
    return float(np.mean(pn <= CHI2_3_95))


@pytest.mark.parametrize("seed", range(3))
def test_an_error_shared_by_readings_from_one_view_needs_the_view_floor_for_honest_poses_and_landmarks(seed):
    # session 50: the rendered demo's readings of one landmark from about the same view share an error (seed 9's
    # robot 1: its smoothed map 76 % within the bound); with stops, one view is read 20 times over
    problem, poses, landmarks, dead, start, _ = _synthetic(seed, view=0.015, stops=20)
    plain = smooth(problem, dead, start)
    viewed = smooth(problem, dead, start, view_floor=0.015 ** 2)
    assert _nees_share(plain, landmarks) < 0.5                           # the white model: confidently wrong
    assert _nees_share(viewed, landmarks) >= 0.9
    assert _pose_nees_share(viewed, poses) >= 0.9
    held = viewed.held
    e = viewed.landmarks[held] - landmarks[held]
    nees = np.einsum("la,lab,lb->l", e, np.linalg.inv(viewed.landmark_covariances[held]), e)
    assert np.mean(nees <= 0.35) < 0.5                                   # not hidden by huge covariances (χ²₃ 5 %)
    np.testing.assert_array_equal(viewed.inliers, plain.inliers)         # outliers judged by each reading's own Q
    xy0, _ = _pose_error(dead, poses)
    xy1, _ = _pose_error(viewed.poses, poses)
    assert np.sqrt(np.mean(xy1 ** 2)) < 0.5 * np.sqrt(np.mean(xy0 ** 2))


def test_without_a_view_floor_the_solution_is_the_white_models():
    problem, poses, landmarks, dead, start, _ = _synthetic(4, view=0.015)
    a = smooth(problem, dead, start)
    b = smooth(problem, dead, start, view_floor=0.0, view_change=0.5)
    np.testing.assert_array_equal(a.poses, b.poses)
    np.testing.assert_array_equal(a.landmark_covariances, b.landmark_covariances)
