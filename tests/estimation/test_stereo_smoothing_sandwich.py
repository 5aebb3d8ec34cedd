"""The stereo smoother's sandwich covariance (``smooth(view_model="sandwich")``): the white model's estimate, its
covariance under an error shared by a landmark's readings from about the same view and range."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.stats import chi2

from estimation.geometry import compose, wrap_angle
from estimation.stereo_smoothing import RANGE_CHANGE, VIEW_CHANGE, StereoLogProblem, StereoSmoothingError, smooth


def _rho(poses, landmarks, pose_index, landmark_index, view_change=VIEW_CHANGE, range_change=RANGE_CHANGE):
    """(K, K) the view model's correlations as documented: ρ_ij = max(0, 1 − Δφ/view_change) · max(0, 1 − |Δ ln r| /
    range_change) between readings of one landmark (Δφ: the angle between the directions from the landmark to the
    robot; r: the horizontal range), 0 between readings of different landmarks, 1 on the diagonal."""
    p, m = poses[pose_index], landmarks[landmark_index]
    phi = np.arctan2(p[:, 1] - m[:, 1], p[:, 0] - m[:, 0])
    log_r = np.log(np.hypot(p[:, 1] - m[:, 1], p[:, 0] - m[:, 0]))
    d = np.abs(wrap_angle(phi[:, None] - phi[None, :]))
    dr = np.abs(log_r[:, None] - log_r[None, :])
    rho = np.maximum(0.0, 1.0 - d / view_change) * np.maximum(0.0, 1.0 - dr / range_change)
    return rho * (landmark_index[:, None] == landmark_index[None, :])


def _rotation(theta):
    """(K, 3, 3) a world-frame offset's effect on a reading in base_link (R_z(θ)ᵀ)."""
    c, s = np.cos(theta), np.sin(theta)
    r = np.zeros((len(theta), 3, 3))
    r[:, 0, 0], r[:, 0, 1], r[:, 1, 0], r[:, 1, 1], r[:, 2, 2] = c, s, -s, c, 1.0
    return r


def _stops_and_turns(stops: int, laps: int = 1):
    """A square loop driven ``laps`` times with ``stops`` frames standing still on each side (a view read over and
    over) and 25 landmarks around it; the readings (pose, landmark) a 1.4 rad, 0.5–4 m field of view takes; each
    reading's covariance (range-growing, never below 0.015² m² per axis); the odometry's variances."""
    rng = np.random.default_rng(2026)
    legs = [(0.2, 0.0)] * 5 + [(0.0, 0.0)] * stops + [(0.2, 0.0)] * 5 + [(0.0, np.pi / 8)] * 4
    true_inc = np.array([(d, 0.0, a) for d, a in legs * 4 * laps])
    poses = [np.zeros(3)]
    for inc in true_inc:
        poses.append(compose(poses[-1], inc))
    poses = np.array(poses)
    landmarks = np.column_stack([rng.uniform(-2, 4, 25), rng.uniform(-2, 4, 25), rng.uniform(0.2, 1.5, 25)])
    trans = np.hypot(true_inc[:, 0], true_inc[:, 1])
    var = np.column_stack([0.02 ** 2 * trans + 1e-8, 0.02 ** 2 * trans + 1e-8,
                           0.03 ** 2 * np.abs(true_inc[:, 2]) + 0.01 ** 2 * trans + 1e-8])
    pi, li, local, covs = [], [], [], []
    for k, p in enumerate(poses):
        c, s = np.cos(p[2]), np.sin(p[2])
        d = landmarks[:, :2] - p[:2]
        loc = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], landmarks[:, 2]])
        r = np.hypot(loc[:, 0], loc[:, 1])
        for j in np.flatnonzero((loc[:, 0] > 0.5) & (r < 4.0) & (np.abs(np.arctan2(loc[:, 1], loc[:, 0])) < 0.7)):
            pi.append(k)
            li.append(j)
            local.append(loc[j])
            covs.append(np.diag([(0.015 + 0.005 * r[j] ** 2) ** 2, 0.015 ** 2, 0.015 ** 2]))
    return poses, landmarks, true_inc, var, np.array(pi), np.array(li), np.array(local), np.array(covs)


class _Draws:
    """Noisy logs of one geometry: readings whose error is the view-shared part (world frame, cov(d_i, d_j) =
    view_floor · ρ_ij · I between readings of one landmark, view_floor · I alone) plus a white part Q_i − view_floor·I,
    so that each reading's covariance is its Q_i and two readings of a landmark share view_floor · ρ_ij; odometry with
    its own variances."""

    def __init__(self, view_floor: float, stops: int):
        (self.poses, self.landmarks, self.true_inc, self.var, self.pi, self.li, self.local,
         self.covs) = _stops_and_turns(stops)
        rho = _rho(self.poses, self.landmarks, self.pi, self.li)
        self.shared = np.linalg.cholesky(view_floor * rho + 1e-12 * np.eye(len(rho)))
        self.white = np.linalg.cholesky(self.covs - view_floor * np.eye(3))
        self.rot = _rotation(self.poses[self.pi, 2])

    def draw(self, seed: int) -> StereoLogProblem:
        rng = np.random.default_rng(seed)
        d = self.shared @ rng.standard_normal((len(self.pi), 3))                 # world-frame offsets
        points = (self.local + (self.rot @ d[:, :, None])[:, :, 0]
                  + (self.white @ rng.standard_normal((len(self.pi), 3, 1)))[:, :, 0])
        increments = self.true_inc + rng.standard_normal(self.true_inc.shape) * np.sqrt(self.var)
        return StereoLogProblem(increments, self.var, self.pi, self.li, points, self.covs, len(self.landmarks))


def _nees(out, poses, landmarks):
    """(landmark NEES (L,), pose NEES (T − 1,)) of a solution against the truth."""
    e = out.landmarks - landmarks
    ln = np.einsum("la,lab,lb->l", e, np.linalg.inv(out.landmark_covariances), e)
    pe = np.column_stack([out.poses[:, :2] - poses[:, :2], wrap_angle(out.poses[:, 2] - poses[:, 2])])[1:]
    pn = np.einsum("ta,tab,tb->t", pe, np.linalg.inv(out.pose_covariances[1:]), pe)
    return ln, pn


def test_the_sandwich_covers_a_view_shared_error_that_the_white_covariances_do_not():
    # 15-frame stops: one view read 15 times; a view-shared error of 1.2 cm of each reading's ≥ 1.5 cm (per axis)
    view_floor, draws = 1.5e-4, 100
    model = _Draws(view_floor, stops=15)
    white_l, white_p, sand_l, sand_p = [], [], [], []
    for seed in range(draws):
        problem = model.draw(seed)
        white = smooth(problem, model.poses, model.landmarks, robust=False)
        sand = smooth(problem, model.poses, model.landmarks, robust=False, view_floor=view_floor,
                      view_model="sandwich")
        np.testing.assert_array_equal(sand.poses, white.poses)             # the estimate is the white model's
        np.testing.assert_array_equal(sand.landmarks, white.landmarks)
        for out, lms, ps in ((white, white_l, white_p), (sand, sand_l, sand_p)):
            ln, pn = _nees(out, model.poses, model.landmarks)
            lms.append(ln.mean())
            ps.append(pn.mean())
    # Under the model (linear-Gaussian to first order) each landmark's and each pose's NEES is χ²₃. A draw's mean over
    # the landmarks (or the poses) has mean 3 and spreads at most as one χ²₃ does (all of them fully correlated); the
    # mean of 100 independent draws then spreads at most as χ²₃₀₀ / 100, whose 10⁻⁶ quantiles bound it (1.98, 4.31).
    # Seen (these seeds): landmarks 2.91, poses 2.85; the white model's landmarks 11.1, poses 3.87.
    low, high = chi2.ppf(1e-6, 3 * draws) / draws, chi2.isf(1e-6, 3 * draws) / draws
    assert low < np.mean(sand_l) < high
    assert low < np.mean(sand_p) < high
    assert np.mean(white_l) > high                                         # the white covariances: overconfident
    assert np.mean(white_p) > np.mean(sand_p)


def test_with_no_view_shared_error_the_sandwich_is_the_white_covariance_exactly():
    model = _Draws(1.5e-4, stops=5)
    problem = model.draw(1)
    white = smooth(problem, model.poses, model.landmarks, landmark_floor=2e-4)
    sand = smooth(problem, model.poses, model.landmarks, landmark_floor=2e-4, view_floor=0.0, view_model="sandwich")
    for name in ("poses", "landmarks", "pose_covariances", "landmark_covariances", "inliers"):
        np.testing.assert_array_equal(getattr(sand, name), getattr(white, name))
    assert (sand.chi2, sand.dof, sand.iterations) == (white.chi2, white.dof, white.iterations)


def test_the_sandwich_keeps_the_robust_white_solution_and_its_cut():
    model = _Draws(1.5e-4, stops=10)
    problem = model.draw(2)
    white = smooth(problem, model.poses, model.landmarks)
    sand = smooth(problem, model.poses, model.landmarks, view_floor=1.5e-4, view_model="sandwich")
    design = smooth(problem, model.poses, model.landmarks, view_floor=1.5e-4)
    for name in ("poses", "landmarks", "inliers"):
        np.testing.assert_array_equal(getattr(sand, name), getattr(white, name))
    assert (sand.chi2, sand.dof) == (white.chi2, white.dof)
    assert not np.array_equal(design.poses, white.poses)                 # the design effect moves the estimate
    assert not np.allclose(sand.landmark_covariances, white.landmark_covariances, rtol=0.1)


def test_readings_of_one_view_the_gls_mean_and_its_closed_form():
    # one landmark read n times from pose 0 (the map frame, fixed): the estimate is the readings' mean, its covariance
    # under a shared part v (ρ = 1: one view) is Q/n + v(n − 1)/n · I; the landmark floor F adds to it
    n, v, floor = 12, 2e-4, 3e-4
    q = np.diag([4e-4, 3e-4, 2.5e-4])
    rng = np.random.default_rng(0)
    points = np.array([1.5, 0.2, 0.8]) + 0.01 * rng.standard_normal((n, 3))
    problem = StereoLogProblem(np.array([[0.1, 0.0, 0.0]]), np.full((1, 3), 1e-4), np.zeros(n), np.zeros(n), points,
                               np.tile(q, (n, 1, 1)), 1)
    out = smooth(problem, np.array([[0, 0, 0], [0.1, 0, 0]]), points[:1], robust=False, landmark_floor=floor,
                 view_floor=v, view_model="sandwich")
    np.testing.assert_allclose(out.landmarks[0], points.mean(axis=0), rtol=0, atol=1e-12)
    np.testing.assert_allclose(out.landmark_covariances[0], q / n + (v * (n - 1) / n + floor) * np.eye(3), rtol=1e-9,
                               atol=0)
    np.testing.assert_allclose(out.pose_covariances[1], np.diag([1e-4] * 3), rtol=1e-9)   # no reading: odometry alone


def _small_problem(seed: int, n_poses: int = 7, n_landmarks: int = 4, scale: float = 1.0):
    """Readings without noise (every residual 0 at the truth, so the estimate's derivative is H⁻¹JᵀW exactly),
    random positive definite reading covariances (smallest variance ≥ 2e-4 · scale), a robot that drives, stops and
    turns."""
    rng = np.random.default_rng(seed)
    inc = np.column_stack([rng.choice([0.0, 0.15], n_poses - 1), np.zeros(n_poses - 1),
                           rng.uniform(-0.3, 0.3, n_poses - 1)])
    poses = [np.zeros(3)]
    for d in inc:
        poses.append(compose(poses[-1], d))
    poses = np.array(poses)
    landmarks = np.column_stack([rng.uniform(1, 3, n_landmarks), rng.uniform(-1.5, 1.5, n_landmarks),
                                 rng.uniform(0.2, 1.5, n_landmarks)])
    pi, li = np.meshgrid(np.arange(n_poses), np.arange(n_landmarks), indexing="ij")
    keep = rng.random(pi.shape) < 0.8
    pi, li = pi[keep], li[keep]
    d = landmarks[li, :2] - poses[pi, :2]
    c, s = np.cos(poses[pi, 2]), np.sin(poses[pi, 2])
    points = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], landmarks[li, 2]])
    a = rng.standard_normal((len(pi), 3, 3)) * 0.01
    covs = scale * (a @ np.swapaxes(a, 1, 2) + 2e-4 * np.eye(3))
    var = scale * rng.uniform(0.5e-4, 2e-4, (n_poses - 1, 3))
    return StereoLogProblem(inc, var, pi, li, points, covs, n_landmarks), poses, landmarks


def test_the_sandwich_is_the_covariance_the_estimates_derivative_propagates():
    # the delta method through the public estimate alone: x̂'s derivative by each reading's point and each odometry
    # increment (central differences), propagated with the readings' covariance under the view model (Q_i, and
    # v ρ_ij R_iᵀ R_j between two readings of one landmark: a world-frame offset seen from two headings)
    v = 1.5e-4
    problem, poses, landmarks = _small_problem(3)
    out = smooth(problem, poses, landmarks, robust=False, view_floor=v, view_model="sandwich")
    np.testing.assert_allclose(out.poses, poses, atol=1e-9)                # noise-free: the truth

    def estimate(points=problem.points, increments=problem.increments):
        p = StereoLogProblem(increments, problem.increment_variances, problem.pose_index, problem.landmark_index,
                             points, problem.covariances, problem.n_landmarks)
        o = smooth(p, poses, landmarks, robust=False)
        return np.concatenate([o.poses[1:].ravel(), o.landmarks.ravel()])

    h = 1e-6
    columns = []
    for array, name in ((problem.points, "points"), (problem.increments, "increments")):
        for index in np.ndindex(array.shape):
            plus, minus = array.copy(), array.copy()
            plus[index] += h
            minus[index] -= h
            columns.append((estimate(**{name: plus}) - estimate(**{name: minus})) / (2 * h))
    jac = np.array(columns).T
    k = len(problem.pose_index)
    rho = _rho(poses, landmarks, problem.pose_index, problem.landmark_index)
    rot = _rotation(poses[problem.pose_index, 2])
    cov_z = v * np.einsum("ij,iab,jcb->iajc", rho, rot, rot).reshape(3 * k, 3 * k)
    cov_z[np.arange(3 * k), np.arange(3 * k)] = 0.0
    for i in range(k):
        cov_z[3 * i:3 * i + 3, 3 * i:3 * i + 3] = problem.covariances[i]
    cov_all = np.zeros((3 * k + problem.increments.size,) * 2)
    cov_all[:3 * k, :3 * k] = cov_z
    cov_all[3 * k:, 3 * k:] = np.diag(problem.increment_variances.ravel())
    cov = jac @ cov_all @ jac.T
    t = problem.n_poses
    want_p = np.array([cov[3 * i:3 * i + 3, 3 * i:3 * i + 3] for i in range(t - 1)])
    want_l = np.array([cov[3 * (t - 1) + 3 * j:3 * (t - 1) + 3 * j + 3, 3 * (t - 1) + 3 * j:3 * (t - 1) + 3 * j + 3]
                       for j in range(problem.n_landmarks)])
    np.testing.assert_allclose(out.pose_covariances[1:], want_p, rtol=0, atol=1e-5 * np.abs(want_p).max())
    np.testing.assert_allclose(out.landmark_covariances, want_l, rtol=0, atol=1e-5 * np.abs(want_l).max())
    white = smooth(problem, poses, landmarks, robust=False)
    assert np.abs(out.landmark_covariances - white.landmark_covariances).max() > 0.1 * np.abs(want_l).max()


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), share=st.floats(0.0, 1.0), view_change=st.floats(0.05, 2.0),
       range_change=st.floats(0.05, 2.0))
def test_the_sandwich_is_symmetric_positive_semidefinite_and_linear_in_the_view_floor(seed, share, view_change,
                                                                                     range_change):
    problem, poses, landmarks = _small_problem(seed, n_poses=5, n_landmarks=3)
    smallest = np.linalg.eigvalsh(problem.covariances)[:, 0].min()
    v = share * smallest                                                   # the shared part within each reading's
    kw = dict(robust=False, view_model="sandwich", view_change=view_change, range_change=range_change)
    zero = smooth(problem, poses, landmarks, view_floor=0.0, **kw)
    one = smooth(problem, poses, landmarks, view_floor=v, **kw)
    two = smooth(problem, poses, landmarks, view_floor=v / 2, **kw)
    for name in ("pose_covariances", "landmark_covariances"):
        c = getattr(one, name)[1:] if name == "pose_covariances" else getattr(one, name)
        np.testing.assert_allclose(c, np.swapaxes(c, 1, 2), rtol=0, atol=1e-12 * np.abs(c).max())
        assert np.linalg.eigvalsh(c).min() >= -1e-12 * np.abs(c).max()
        c0, c1, c2 = (getattr(o, name) for o in (zero, one, two))
        np.testing.assert_allclose(c1 - c0, 2 * (c2 - c0), rtol=0, atol=1e-9 * np.abs(c1).max())


def test_a_bad_view_model_or_a_view_floor_larger_than_a_reading_is_refused():
    problem, poses, landmarks = _small_problem(0)
    with pytest.raises(StereoSmoothingError, match="view_model must be one of design, sandwich"):
        smooth(problem, poses, landmarks, view_model="gls")
    smallest = np.linalg.eigvalsh(problem.covariances)[:, 0].min()
    with pytest.raises(StereoSmoothingError, match="exceeds observation .* smallest variance"):
        smooth(problem, poses, landmarks, view_floor=1.01 * smallest, view_model="sandwich")
    smooth(problem, poses, landmarks, view_floor=1.01 * smallest)          # the design effect adds it: allowed
