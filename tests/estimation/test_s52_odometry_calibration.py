"""The stereo smoother's odometry self-calibration (``smooth(calibrate_odometry=True)``, session 52): the odometry's
distance scale s_d and turn scale s_θ (measured / true) as two more unknowns with the prior N(1, σ²), as Kümmerle et
al. (IROS 2011) do in graph SLAM; each odometry factor predicts (s_d·bx, s_d·by, s_θ·bθ) from
(bx, by, bθ) = between(x_k, x_{k+1}). Checked: the scales found against the truth they were drawn with, the poses'
and landmarks' covariances (the marginals with the scales unknown) against a dense inverse of the documented model's
information matrix and against Monte Carlo, the white and sandwich paths, ``smoothed_map``'s option, and refusals."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.stats import chi2

from estimation.fastslam import FastSLAMConfig
from estimation.geometry import between, compose, wrap_angle
from estimation.landmark_map import LandmarkMap
from estimation.stereo_readings import KeyframeRule, ReadingsRecorder, SmoothingRefused, smoothed_map
from estimation.stereo_smoothing import (
    ODOMETRY_SCALE_SIGMA,
    RANGE_CHANGE,
    VIEW_CHANGE,
    StereoLogProblem,
    StereoSmoothingError,
    smooth,
)


def _dead_reckoning(increments: np.ndarray) -> np.ndarray:
    out = [np.zeros(3)]
    for d in increments:
        out.append(compose(out[-1], d))
    return np.array(out)


class _Loop:
    """A robot driving a rectangle ``laps`` times (sides of 4–8 steps of 0.2 m, corners of 4 turns of π/8 on the
    spot), 30 landmarks around it read within a 1.4 rad, 0.5–4 m field of view with range-growing covariances, and
    the odometry's random-walk variances (as tests/estimation/test_stereo_smoothing_sandwich.py's loop). ``draw``
    gives a log whose odometry is the true increments scaled by (s_d, s_d, s_θ) plus white noise of those variances,
    and whose readings carry white noise of their covariances."""

    def __init__(self, seed: int, laps: int = 2):
        rng = np.random.default_rng(seed)
        sides = rng.integers(4, 9, 2)
        legs = []
        for side in (sides[0], sides[1], sides[0], sides[1]):
            legs += [(0.2, 0.0)] * int(side) + [(0.0, np.pi / 8)] * 4
        self.true_inc = np.array([(d, 0.0, a) for d, a in legs * laps])
        self.poses = _dead_reckoning(self.true_inc)
        w, h = 0.2 * sides
        self.landmarks = np.column_stack([rng.uniform(-1.5, w + 1.5, 30), rng.uniform(-1.5, h + 1.5, 30),
                                          rng.uniform(0.2, 1.5, 30)])
        trans = np.hypot(self.true_inc[:, 0], self.true_inc[:, 1])
        self.var = np.column_stack([0.02 ** 2 * trans + 1e-8, 0.02 ** 2 * trans + 1e-8,
                                    0.03 ** 2 * np.abs(self.true_inc[:, 2]) + 0.01 ** 2 * trans + 1e-8])
        pi, li, local, covs = [], [], [], []
        for k, p in enumerate(self.poses):
            c, s = np.cos(p[2]), np.sin(p[2])
            d = self.landmarks[:, :2] - p[:2]
            loc = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], self.landmarks[:, 2]])
            r = np.hypot(loc[:, 0], loc[:, 1])
            for j in np.flatnonzero((loc[:, 0] > 0.5) & (r < 4.0) & (np.abs(np.arctan2(loc[:, 1], loc[:, 0])) < 0.7)):
                pi.append(k)
                li.append(j)
                local.append(loc[j])
                covs.append(np.diag([(0.015 + 0.005 * r[j] ** 2) ** 2, 0.015 ** 2, 0.015 ** 2]))
        self.pi, self.li, self.local, self.covs = np.array(pi), np.array(li), np.array(local), np.array(covs)

    def draw(self, seed: int, scales=(1.0, 1.0)) -> StereoLogProblem:
        rng = np.random.default_rng(seed)
        sd, st_ = scales
        increments = self.true_inc * np.array([sd, sd, st_]) + rng.standard_normal(self.true_inc.shape) * np.sqrt(
            self.var)
        points = self.local + (np.linalg.cholesky(self.covs) @ rng.standard_normal((len(self.pi), 3, 1)))[:, :, 0]
        return StereoLogProblem(increments, self.var, self.pi, self.li, points, self.covs, len(self.landmarks))

    def start(self, problem: StereoLogProblem, seed: int) -> tuple[np.ndarray, np.ndarray]:
        """Where a smoothing starts: the odometry's dead reckoning and the landmarks 5 cm off."""
        rng = np.random.default_rng(seed + 10_000)
        return _dead_reckoning(problem.increments), self.landmarks + 0.05 * rng.standard_normal(self.landmarks.shape)


def _pose_errors(out, poses):
    return np.column_stack([out.poses[:, :2] - poses[:, :2], wrap_angle(out.poses[:, 2] - poses[:, 2])])[1:]


def _pose_nees(out, poses):
    e = _pose_errors(out, poses)
    return np.einsum("ta,tab,tb->t", e, np.linalg.inv(out.pose_covariances[1:]), e)


# -- the scales found ----------------------------------------------------------------------------------------------
@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), s_d=st.floats(0.95, 1.05), s_theta=st.floats(0.92, 1.06))
def test_the_scales_found_are_the_ones_the_odometry_was_drawn_with_within_their_sigma(seed, s_d, s_theta):
    loop = _Loop(seed % 7)
    problem = loop.draw(seed, (s_d, s_theta))
    out = smooth(problem, *loop.start(problem, seed), calibrate_odometry=True)
    sd = np.sqrt(np.diag(out.odometry_scale_covariance))
    assert np.all(sd > 0) and np.all(sd < 0.02)          # ~16 m and ~12.6 rad driven pin them to about 1 %
    # each within 5 σ (a 1-in-1.7-million miss for a Gaussian; the calibration of σ itself: the Monte Carlo below)
    z = (out.odometry_scales - np.array([s_d, s_theta])) / sd
    assert np.all(np.abs(z) < 5.0), (out.odometry_scales, sd)


def test_over_many_draws_the_scales_and_poses_are_as_close_to_the_truth_as_their_covariances_say():
    # 40 logs of one loop with odometry 3 % short and turns 6 % short: the scales' (estimate − truth) / σ are N(0, 1)
    # and the poses' NEES χ²₃ under the model (to first order; the prior's pull to 1 is (σ / 0.05)² of 3–6 %, a few
    # hundredths of σ). The mean of 40 draws' z² (each a χ²₁ / 1) lies within χ²₄₀'s 10⁻⁶ quantiles / 40 (0.29,
    # 2.2) for each scale; a draw's mean pose NEES spreads at most as one χ²₃, so 40 draws' mean of it within χ²₁₂₀'s
    # (1.94, 4.5). Seen (these seeds): z² 1.06 and 0.85, pose NEES 3.17; without the scales 3.55.
    loop = _Loop(3)
    truth = np.array([0.97, 0.94])
    draws = 40
    z2, cal, plain = [], [], []
    for seed in range(draws):
        problem = loop.draw(seed, truth)
        start = loop.start(problem, seed)
        out = smooth(problem, *start, robust=False, calibrate_odometry=True)
        z2.append((out.odometry_scales - truth) ** 2 / np.diag(out.odometry_scale_covariance))
        cal.append(_pose_nees(out, loop.poses).mean())
        plain.append(_pose_nees(smooth(problem, *start, robust=False), loop.poses).mean())
    z2 = np.mean(z2, axis=0)
    low, high = chi2.ppf(1e-6, draws) / draws, chi2.isf(1e-6, draws) / draws
    assert np.all((low < z2) & (z2 < high)), z2
    low, high = chi2.ppf(1e-6, 3 * draws) / draws, chi2.isf(1e-6, 3 * draws) / draws
    assert low < np.mean(cal) < high
    assert np.mean(plain) > np.mean(cal)                 # unbiased increments assumed: the poses overconfident


def test_with_unbiased_odometry_the_scales_stay_at_one_and_the_solution_moves_within_its_noise():
    loop = _Loop(5)
    for seed in range(3):
        problem = loop.draw(seed)
        start = loop.start(problem, seed)
        plain = smooth(problem, *start)
        out = smooth(problem, *start, calibrate_odometry=True)
        sd = np.sqrt(np.diag(out.odometry_scale_covariance))
        assert np.all(np.abs(out.odometry_scales - 1.0) < 5 * sd)
        np.testing.assert_array_equal(out.inliers, plain.inliers)
        # every pose and landmark moves by much less than its own σ: the two more unknowns cost little
        dp = _pose_errors(out, plain.poses)
        assert np.max(np.abs(dp) / np.sqrt(np.diagonal(plain.pose_covariances[1:], axis1=1, axis2=2))) < 0.5
        dl = out.landmarks - plain.landmarks
        assert np.max(np.abs(dl) / np.sqrt(np.diagonal(plain.landmark_covariances, axis1=1, axis2=2))) < 0.5
        # ... and the marginals grow a little with the scales unknown (at the same point they could only grow; the
        # two solutions differ by a fraction of σ, so their variances by a few per cent at most)
        for a, b in ((out.pose_covariances[1:], plain.pose_covariances[1:]),
                     (out.landmark_covariances, plain.landmark_covariances)):
            ratio = np.diagonal(a, axis1=1, axis2=2) / np.diagonal(b, axis1=1, axis2=2)
            assert ratio.min() > 0.9 and 1.0 <= np.median(ratio) < 1.5, (ratio.min(), np.median(ratio))


def test_without_calibration_nothing_is_estimated_and_the_solution_is_the_default():
    loop = _Loop(1)
    problem = loop.draw(0, (0.98, 0.95))
    start = loop.start(problem, 0)
    a, b = smooth(problem, *start), smooth(problem, *start, calibrate_odometry=False)
    assert a.odometry_scales is None and a.odometry_scale_covariance is None
    for name in ("poses", "landmarks", "pose_covariances", "landmark_covariances", "inliers"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


# -- the covariances against a dense inverse of the documented model ------------------------------------------------
def _small(seed: int, scales=(0.97, 0.95), n_poses: int = 7, n_landmarks: int = 4):
    """A robot that drives, stops and turns past a few landmarks; readings noise-free at the truth, the odometry the
    true increments scaled (so that the scales are determined), random positive definite reading covariances."""
    rng = np.random.default_rng(seed)
    inc = np.column_stack([rng.choice([0.0, 0.3], n_poses - 1), np.zeros(n_poses - 1),
                           rng.uniform(-0.4, 0.4, n_poses - 1)])
    poses = _dead_reckoning(inc)
    landmarks = np.column_stack([rng.uniform(1, 3, n_landmarks), rng.uniform(-1.5, 1.5, n_landmarks),
                                 rng.uniform(0.2, 1.5, n_landmarks)])
    pi, li = np.meshgrid(np.arange(n_poses), np.arange(n_landmarks), indexing="ij")
    keep = rng.random(pi.shape) < 0.8
    pi, li = pi[keep], li[keep]
    d = landmarks[li, :2] - poses[pi, :2]
    c, s = np.cos(poses[pi, 2]), np.sin(poses[pi, 2])
    points = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], landmarks[li, 2]])
    a = rng.standard_normal((len(pi), 3, 3)) * 0.01
    covs = a @ np.swapaxes(a, 1, 2) + 2e-4 * np.eye(3)
    var = rng.uniform(0.5e-4, 2e-4, (n_poses - 1, 3))
    measured = inc * np.array([scales[0], scales[0], scales[1]])
    return StereoLogProblem(measured, var, pi, li, points, covs, n_landmarks), poses, landmarks


def _whitened_residuals(problem, x, sigma):
    """The documented model's whitened residuals at x = (poses 1..T−1, landmarks, s_d, s_θ), written out here:
    readings (R(θ)ᵀ(m_xy − t), m_z) − z whitened by Q⁻¹'s Cholesky factor, odometry (s_d·bx, s_d·by, s_θ·bθ) − δ over
    its σ, and the prior (s − 1) / σ_s."""
    t, n_l = problem.n_poses, problem.n_landmarks
    poses = np.vstack([np.zeros(3), x[:3 * (t - 1)].reshape(-1, 3)])
    lms = x[3 * (t - 1):3 * (t - 1) + 3 * n_l].reshape(-1, 3)
    s_d, s_t = x[-2:]
    p, m = poses[problem.pose_index], lms[problem.landmark_index]
    c, s = np.cos(p[:, 2]), np.sin(p[:, 2])
    dx, dy = m[:, 0] - p[:, 0], m[:, 1] - p[:, 1]
    e = np.column_stack([c * dx + s * dy, -s * dx + c * dy, m[:, 2]]) - problem.points
    lower = np.linalg.cholesky(np.linalg.inv(problem.covariances))
    eo = between(poses[:-1], poses[1:]) * np.array([s_d, s_d, s_t]) - problem.increments
    eo[:, 2] = wrap_angle(eo[:, 2])
    return np.concatenate([(np.swapaxes(lower, 1, 2) @ e[:, :, None]).ravel(),
                           (eo / np.sqrt(problem.increment_variances)).ravel(), (x[-2:] - 1.0) / sigma])


def _dense_jacobian(problem, x, sigma, h=1e-7):
    cols = []
    for i in range(len(x)):
        a, b = x.copy(), x.copy()
        a[i] += h
        b[i] -= h
        cols.append((_whitened_residuals(problem, a, sigma) - _whitened_residuals(problem, b, sigma)) / (2 * h))
    return np.array(cols).T


def _rho(poses, landmarks, pose_index, landmark_index):
    """(K, K) the view model's documented correlations between readings of one landmark (1 on the diagonal)."""
    p, m = poses[pose_index], landmarks[landmark_index]
    phi = np.arctan2(p[:, 1] - m[:, 1], p[:, 0] - m[:, 0])
    log_r = np.log(np.hypot(p[:, 1] - m[:, 1], p[:, 0] - m[:, 0]))
    d = np.abs(wrap_angle(phi[:, None] - phi[None, :]))
    dr = np.abs(log_r[:, None] - log_r[None, :])
    rho = np.maximum(0.0, 1.0 - d / VIEW_CHANGE) * np.maximum(0.0, 1.0 - dr / RANGE_CHANGE)
    return rho * (landmark_index[:, None] == landmark_index[None, :])


@pytest.mark.parametrize("seed", [0, 4])
@pytest.mark.parametrize("view_floor", [0.0, 1.5e-4])
def test_the_marginals_are_the_dense_inverse_of_the_bordered_information_white_and_sandwich(seed, view_floor):
    sigma = 0.05
    problem, poses, landmarks = _small(seed)
    kw = dict(robust=False, calibrate_odometry=True, odometry_scale_sigma=sigma)
    if view_floor:
        kw |= dict(view_floor=view_floor, view_model="sandwich")
    out = smooth(problem, poses, landmarks, **kw)
    t, n_l = problem.n_poses, problem.n_landmarks
    x = np.concatenate([out.poses[1:].ravel(), out.landmarks.ravel(), out.odometry_scales])
    jac = _dense_jacobian(problem, x, sigma)
    hinv = np.linalg.inv(jac.T @ jac)
    # the solution is the documented model's MAP: a Gauss–Newton step from it moves nothing by more than 1e-8
    assert np.abs(hinv @ jac.T @ _whitened_residuals(problem, x, sigma)).max() < 1e-8
    cov = hinv
    if view_floor:
        # the sandwich H⁻¹ Jᵀ W Σ W J H⁻¹ with Σ the readings' Q_i plus view_floor · ρ_ij R_iᵀ R_j between two readings
        # of one landmark; whitened: the readings' rows of J carry W^½, so the middle is J_zᵀ (I + W^½ Σ' W^½) J_z
        k = len(problem.pose_index)
        theta = out.poses[problem.pose_index, 2]
        c, s = np.cos(theta), np.sin(theta)
        rot = np.zeros((k, 3, 3))
        rot[:, 0, 0], rot[:, 0, 1], rot[:, 1, 0], rot[:, 1, 1], rot[:, 2, 2] = c, s, -s, c, 1.0
        rho = _rho(out.poses, out.landmarks, problem.pose_index, problem.landmark_index)
        shared = view_floor * np.einsum("ij,iab,jcb->iajc", rho - np.eye(k), rot, rot).reshape(3 * k, 3 * k)
        half = np.swapaxes(np.linalg.cholesky(np.linalg.inv(problem.covariances)), 1, 2)
        wh = np.zeros((3 * k, 3 * k))
        for i in range(k):
            wh[3 * i:3 * i + 3, 3 * i:3 * i + 3] = half[i]
        middle = jac.T @ jac
        jz = jac[:3 * k]
        middle += jz.T @ wh @ shared @ wh.T @ jz
        cov = hinv @ middle @ hinv
    want_p = np.array([cov[3 * i:3 * i + 3, 3 * i:3 * i + 3] for i in range(t - 1)])
    o = 3 * (t - 1)
    want_l = np.array([cov[o + 3 * j:o + 3 * j + 3, o + 3 * j:o + 3 * j + 3] for j in range(n_l)])
    want_s = cov[-2:, -2:]
    np.testing.assert_allclose(out.pose_covariances[1:], want_p, rtol=0, atol=1e-6 * np.abs(want_p).max())
    np.testing.assert_allclose(out.landmark_covariances, want_l, rtol=0, atol=1e-6 * np.abs(want_l).max())
    np.testing.assert_allclose(out.odometry_scale_covariance, want_s, rtol=1e-5, atol=0)
    # the scales' marginal is narrower than their prior (the odometry and readings say something) and the prior's
    # weight shows in its χ²: the same problem without the scales gives a different covariance
    assert np.all(np.sqrt(np.diag(want_s)) < sigma)
    plain = smooth(problem, poses, landmarks, **{k: v for k, v in kw.items() if k != "calibrate_odometry"})
    assert np.abs(plain.pose_covariances[1:] - want_p).max() > 1e-3 * np.abs(want_p).max()


def test_a_tighter_prior_holds_the_scales_nearer_one_and_a_wide_one_lets_the_log_decide():
    problem, poses, landmarks = _small(2, scales=(0.9, 0.9))
    kw = dict(robust=False, calibrate_odometry=True)
    tight = smooth(problem, poses, landmarks, odometry_scale_sigma=1e-4, **kw)
    wide = smooth(problem, poses, landmarks, odometry_scale_sigma=10.0, **kw)
    np.testing.assert_allclose(tight.odometry_scales, 1.0, atol=1e-3)
    np.testing.assert_allclose(wide.odometry_scales, 0.9, atol=1e-4)       # noise-free readings and odometry
    assert ODOMETRY_SCALE_SIGMA == 0.05


# -- smoothed_map's option -----------------------------------------------------------------------------------------
CONFIG = FastSLAMConfig()
D = CONFIG.descriptor_size


class _Obs(SimpleNamespace):
    def __len__(self) -> int:
        return len(self.points)


def _mission(scales=(0.97, 0.94), seed: int = 0):
    """A robot driving 2.5 laps of a 3 m × 2 m rectangle inside 80 landmarks on four walls; its odometry poses the true
    increments scaled by (s_d, s_d, s_θ); its filter's trajectory the truth bent by 0.02 rad a metre and its map the
    truth with 2 cm noise; every frame's readings 1 cm noise."""
    rng = np.random.default_rng(seed)
    xs, ys = np.linspace(-1.0, 4.0, 20), np.linspace(-1.0, 3.0, 20)
    world = np.vstack([np.column_stack([xs, np.full(20, 3.0), rng.uniform(0.3, 1.5, 20)]),
                       np.column_stack([xs, np.full(20, -1.5), rng.uniform(0.3, 1.5, 20)]),
                       np.column_stack([np.full(20, -1.5), ys, rng.uniform(0.3, 1.5, 20)]),
                       np.column_stack([np.full(20, 4.5), ys, rng.uniform(0.3, 1.5, 20)])])
    desc = rng.standard_normal((len(world), D)).astype(np.float32)
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    legs = ([(0.1, 0.0)] * 30 + [(0.0, np.pi / 16)] * 8 + [(0.1, 0.0)] * 20 + [(0.0, np.pi / 16)] * 8) * 2
    legs = legs * 2 + legs[:60]
    true_inc = np.array([(d, 0.0, a) for d, a in legs])
    truth = _dead_reckoning(true_inc)
    odometry = _dead_reckoning(true_inc * np.array([scales[0], scales[0], scales[1]]))
    distance = np.r_[0.0, np.cumsum(true_inc[:, 0])]
    bent = truth.copy()
    bent[:, 2] += 0.02 * distance
    times = 0.25 * np.arange(1, len(truth) + 1)
    frames = []
    for k, pose in enumerate(truth):
        c, s = np.cos(pose[2]), np.sin(pose[2])
        d = world[:, :2] - pose[:2]
        local = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], world[:, 2]])
        seen = np.flatnonzero((local[:, 0] > 0.5) & (np.abs(np.arctan2(local[:, 1], local[:, 0])) < 0.7))
        z = local[seen] + 0.01 * rng.standard_normal((len(seen), 3))
        frames.append((times[k], odometry[k], _Obs(points=z, covariances=np.tile(np.eye(3) * 1e-4, (len(seen), 1, 1)),
                                                   descriptors=desc[seen], pixels=np.zeros((len(seen), 2)))))
    positions = world + 0.02 * rng.standard_normal(world.shape)
    exported = LandmarkMap(positions, np.tile(np.eye(3) * 4e-4, (len(world), 1, 1)), desc, np.arange(len(world)),
                           np.full(len(world), 5), "robot1",
                           trajectory=np.vstack([[0.0, 0.0, 0.0, 0.0], np.column_stack([times, bent])]))
    return frames, exported, truth


def test_smoothed_map_estimates_the_scales_on_request_and_reports_them():
    frames, exported, truth = _mission()
    rec = ReadingsRecorder(D, keyframes=KeyframeRule(), config=CONFIG)
    for t, p, o in frames:
        rec.add(t, p, o)
    readings = rec.readings_kept()
    args = (readings, exported.trajectory, exported, exported.positions, exported.covariances, CONFIG)
    plain = smoothed_map(*args)
    cal = smoothed_map(*args, calibrate_odometry=True)
    assert "odometry_scales" not in plain.figures and "odometry_scales" not in plain.landmark_map.metadata["smoothed"]
    scales, sd = np.array(cal.figures["odometry_scales"]), np.array(cal.figures["odometry_scale_sd"])
    assert cal.landmark_map.metadata["smoothed"]["odometry_scales"] == cal.figures["odometry_scales"]
    assert np.all(np.abs(scales - [0.97, 0.94]) < 5 * sd) and np.all(sd < 0.04)
    assert len(cal.pose_covariances) == readings.frames
    # the keyframes' smoothed poses are nearer the truth with the scales estimated
    key = readings.frame_index

    def err(m):
        return np.sqrt(np.mean(np.sum((m.landmark_map.trajectory[1:][key, 1:3] - truth[key, :2]) ** 2, axis=1)))

    assert err(cal) < err(plain)


# -- refusals ----------------------------------------------------------------------------------------------------
def test_bad_calibration_arguments_are_refused_with_one_line():
    problem, poses, landmarks = _small(0)
    for bad in ("yes", 1, None):
        with pytest.raises(StereoSmoothingError, match="calibrate_odometry must be True or False") as info:
            smooth(problem, poses, landmarks, calibrate_odometry=bad)
        assert "\n" not in str(info.value)
    for bad in (0.0, -0.05, float("nan"), float("inf"), "0.05"):
        with pytest.raises(StereoSmoothingError, match="odometry_scale_sigma must be a finite number > 0") as info:
            smooth(problem, poses, landmarks, calibrate_odometry=True, odometry_scale_sigma=bad)
        assert "\n" not in str(info.value)
    frames, exported, _ = _mission()
    rec = ReadingsRecorder(D)
    for t, p, o in frames[:20]:
        rec.add(t, p, o)
    with pytest.raises(SmoothingRefused, match="the smoother refused: calibrate_odometry must be True or False"):
        smoothed_map(rec.readings_kept(), exported.trajectory[:21], exported, exported.positions,
                     exported.covariances, CONFIG, calibrate_odometry="on")
