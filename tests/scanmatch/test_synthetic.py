"""The matchers against exact ground truth: a polygonal room seen by a noiseless laser from two poses."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from estimation.geometry import between, compose, inverse
from estimation.scanmatch import MatchConfig, Polyline, Scan2D, eicp_cost, laser_scan, match_scans
from estimation.scanmatch.common import apply_pose, point_to_line_pose, procrustes

POSE_A = np.array([0.2, -0.4, 0.3])
POSE_B = np.array([0.55, -0.2, 0.42])            # 0.40 m and 6.9° from A
TIGHT = MatchConfig(tolerance_translation=1e-12, tolerance_rotation=1e-12, max_iterations=100)


def two_views(laser, pose_a=POSE_A, pose_b=POSE_B, n_beams=360, fov=2 * np.pi * 359 / 360):
    scan_a = laser_scan(laser(pose_a, n_beams, fov), np.linspace(-fov / 2, fov / 2, n_beams))
    scan_b = laser_scan(laser(pose_b, n_beams, fov), np.linspace(-fov / 2, fov / 2, n_beams))
    return scan_a, scan_b, between(pose_a, pose_b)


def pose_error(estimate, truth):
    d = between(truth, estimate)
    return np.hypot(d[0], d[1]), abs(d[2])


@pytest.mark.parametrize("method", ["eicp", "plicp"])
def test_exact_room_recovered_to_numerical_precision(laser, method):
    scan_a, scan_b, truth = two_views(laser)
    result = match_scans(scan_a, scan_b, method, initial=compose(truth, [0.15, -0.1, 0.05]), config=TIGHT)
    t_err, r_err = pose_error(result.pose, truth)
    assert t_err < 1e-9 and r_err < 1e-9, (method, result)
    assert result.converged
    assert result.residual < 1e-9


def test_exact_room_from_identity_with_a_laser_sweep(laser):
    # The 180° sweep of the real logs; starting from the identity 0.4 m / 7° away.
    scan_a, scan_b, truth = two_views(laser, n_beams=180, fov=np.pi)
    result = match_scans(scan_a, scan_b, "eicp", config=TIGHT)
    t_err, r_err = pose_error(result.pose, truth)
    assert t_err < 1e-9 and r_err < 1e-9


def test_rigid_mesh_variant_reaches_the_same_minimum(laser):
    scan_a, scan_b, truth = two_views(laser)
    config = MatchConfig(tolerance_translation=1e-9, tolerance_rotation=1e-9, max_iterations=300)
    result = match_scans(scan_a, scan_b, "eicp-mesh", initial=compose(truth, [0.1, -0.05, 0.03]), config=config)
    t_err, r_err = pose_error(result.pose, truth)
    assert t_err < 1e-5 and r_err < 1e-5


def test_alternating_eicp_solver_converges_to_the_truth(laser):
    scan_a, scan_b, truth = two_views(laser)
    config = MatchConfig(eicp_solver="alternating", tolerance_translation=1e-10, tolerance_rotation=1e-10,
                         max_iterations=2000)
    result = match_scans(scan_a, scan_b, "eicp", initial=compose(truth, [0.1, -0.05, 0.03]), config=config)
    assert max(pose_error(result.pose, truth)) < 1e-6


def test_point_to_point_icp_is_biased_by_sampling_where_eicp_is_not(laser):
    # The two views sample the walls at different places: closest-point pairs are never exact.
    scan_a, scan_b, truth = two_views(laser)
    icp = match_scans(scan_a, scan_b, "icp", initial=truth, config=TIGHT)
    assert pose_error(icp.pose, truth)[0] > 1e-5
    assert eicp_cost(scan_a, scan_b, truth) < 1e-20
    config = MatchConfig()
    assert eicp_cost(scan_a, scan_b, truth, config) < eicp_cost(scan_a, scan_b, icp.pose, config)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.floats(-5, 5), st.floats(-5, 5), st.floats(-np.pi, np.pi),
       st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.floats(-0.2, 0.2))
def test_cost_is_independent_of_the_frame(laser, gx, gy, gtheta, dx, dy, dtheta):
    """Moving both scans by one rigid motion G leaves the cost unchanged at the conjugated pose G ξ G⁻¹."""
    scan_a, scan_b, truth = two_views(laser, n_beams=180, fov=np.pi)
    pose = compose(truth, [dx, dy, dtheta])          # any pose, not only the optimum
    g = np.array([gx, gy, gtheta])
    moved_a = Scan2D(apply_pose(g, scan_a.points), scan_a.beam_index)
    moved_b = Scan2D(apply_pose(g, scan_b.points), scan_b.beam_index)
    conjugated = compose(compose(g, pose), inverse(g))
    assert eicp_cost(moved_a, moved_b, conjugated) == pytest.approx(eicp_cost(scan_a, scan_b, pose),
                                                                      rel=1e-9, abs=1e-12)


def test_matching_is_equivariant_to_the_frame(laser):
    scan_a, scan_b, truth = two_views(laser, n_beams=180, fov=np.pi)
    g = np.array([3.0, -1.0, 2.0])
    moved_a = Scan2D(apply_pose(g, scan_a.points), scan_a.beam_index)
    moved_b = Scan2D(apply_pose(g, scan_b.points), scan_b.beam_index)
    guess = compose(truth, [0.1, 0.1, -0.05])
    plain = match_scans(scan_a, scan_b, "eicp", initial=guess, config=TIGHT)
    moved = match_scans(moved_a, moved_b, "eicp", initial=compose(compose(g, guess), inverse(g)), config=TIGHT)
    np.testing.assert_allclose(compose(compose(inverse(g), moved.pose), g), plain.pose, atol=1e-9)


def test_covariance_is_symmetric_positive_and_shrinks_with_noise(laser):
    rng = np.random.default_rng(3)
    scan_a, scan_b, truth = two_views(laser, n_beams=180, fov=np.pi)
    covariances = []
    for sigma in (0.002, 0.02):
        noisy_b = Scan2D(scan_b.points + rng.normal(0.0, sigma, scan_b.points.shape), scan_b.beam_index)
        result = match_scans(scan_a, noisy_b, "eicp", initial=truth)
        cov = result.covariance
        np.testing.assert_allclose(cov, cov.T)
        assert np.all(np.linalg.eigvalsh(cov) > 0)
        covariances.append(cov)
    assert np.all(np.diag(covariances[0]) < np.diag(covariances[1]))


@pytest.mark.parametrize("method", ["eicp", "eicp-mesh", "icp", "plicp"])
def test_noisy_room_within_a_centimetre(laser, method):
    rng = np.random.default_rng(11)
    scan_a, scan_b, truth = two_views(laser, n_beams=180, fov=np.pi)
    noisy_b = Scan2D(scan_b.points + rng.normal(0.0, 0.01, scan_b.points.shape), scan_b.beam_index)
    result = match_scans(scan_a, noisy_b, method, initial=compose(truth, [0.1, -0.1, 0.05]))
    t_err, r_err = pose_error(result.pose, truth)
    assert t_err < 0.01 and r_err < np.radians(0.5), (method, result)
    assert 100 < result.n_correspondences <= len(noisy_b)


def test_projection_matches_brute_force_distance_to_the_polyline(laser):
    rng = np.random.default_rng(5)
    scan = laser_scan(laser(POSE_A))
    curve = Polyline(scan, gap=0.5)
    queries = scan.points + rng.normal(0.0, 0.15, scan.points.shape)
    projection = curve.project(queries)
    # Brute force over every segment of the curve and every vertex.
    a = scan.points[:-1][curve.segment_valid]
    b = scan.points[1:][curve.segment_valid]
    ab = b - a
    t = np.clip(np.einsum("nkj,kj->nk", queries[:, None, :] - a[None], ab) / np.sum(ab**2, axis=1), 0.0, 1.0)
    foot = a[None] + t[..., None] * ab[None]
    brute = np.sqrt(np.min(np.sum((queries[:, None, :] - foot) ** 2, axis=-1), axis=1))
    brute = np.minimum(brute, np.min(np.linalg.norm(queries[:, None, :] - scan.points[None], axis=-1), axis=1))
    np.testing.assert_allclose(projection.distance, brute, atol=1e-12)
    np.testing.assert_allclose(curve.evaluate(projection.arc), projection.point, atol=1e-12)


def test_polyline_breaks_at_gaps_and_dropouts():
    points = np.array([[0.0, 0.0], [0.1, 0.0], [0.2, 0.0], [2.0, 0.0], [2.1, 0.0], [2.2, 0.0], [2.3, 0.0]])
    beam_index = np.array([0, 1, 2, 3, 4, 6, 7])    # a dropout between beams 4 and 6
    curve = Polyline(Scan2D(points, beam_index), gap=0.5)
    np.testing.assert_array_equal(curve.segment_valid, [True, True, False, True, False, True])
    # A query beside the gap projects onto a piece end, not onto the missing chord.
    projection = curve.project(np.array([[1.0, 0.0]]))
    np.testing.assert_allclose(projection.point, [[0.2, 0.0]])
    # Shifting λ past a piece end and clamping stays on that piece.
    piece = curve.piece_at(projection.arc)
    np.testing.assert_allclose(curve.evaluate(curve.clamp_to_piece(projection.arc + 5.0, piece)), [[0.2, 0.0]])


@settings(max_examples=60, deadline=None)
@given(st.floats(-3, 3), st.floats(-3, 3), st.floats(-np.pi, np.pi), st.integers(0, 2**31))
def test_procrustes_recovers_any_rigid_motion(x, y, theta, seed):
    points = np.random.default_rng(seed).normal(0.0, 2.0, (30, 2))
    truth = np.array([x, y, theta])
    estimate = procrustes(points, apply_pose(truth, points))
    np.testing.assert_allclose(estimate[:2], truth[:2], atol=1e-9)
    assert abs(np.angle(np.exp(1j * (estimate[2] - theta)))) < 1e-9


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31))
def test_point_to_line_closed_form_is_the_global_minimum(seed):
    rng = np.random.default_rng(seed)
    source = rng.normal(0.0, 3.0, (25, 2))
    anchor = rng.normal(0.0, 3.0, (25, 2))
    normal = rng.normal(size=(25, 2))
    normal /= np.linalg.norm(normal, axis=1)[:, None]

    def cost(pose):
        return np.sum(np.sum(normal * (apply_pose(pose, source) - anchor), axis=1) ** 2)

    best = point_to_line_pose(source, anchor, normal)
    # Against a dense search over θ with the (linear) optimal translation for each θ, all θ at once.
    theta = np.linspace(-np.pi, np.pi, 1441)
    c, s = np.cos(theta)[:, None], np.sin(theta)[:, None]
    rotated = np.stack([c * source[:, 0] - s * source[:, 1], s * source[:, 0] + c * source[:, 1]], axis=-1)
    gap = np.sum(normal * (anchor - rotated), axis=-1)                     # (T, N) residual before t
    t = np.linalg.solve(normal.T @ normal, (gap @ normal).T).T             # (T, 2) least-squares translation
    costs = np.sum((gap - t @ normal.T) ** 2, axis=1)
    assert cost(best) <= costs.min() + 1e-9


@pytest.mark.parametrize("method", ["eicp", "plicp", "icp"])
def test_corridor_leaves_the_along_axis_free_and_says_so(method):
    # Two long parallel walls seen from the middle: nothing fixes x along the corridor.
    rng = np.random.default_rng(2)
    x = np.linspace(-4.0, 4.0, 90)
    walls = np.concatenate([np.column_stack([x, np.full_like(x, 1.0)]), np.column_stack([x, np.full_like(x, -1.0)])])
    reference = Scan2D(walls + rng.normal(0.0, 0.005, walls.shape), np.r_[np.arange(90), np.arange(100, 190)])
    current = Scan2D(walls + rng.normal(0.0, 0.005, walls.shape), np.r_[np.arange(90), np.arange(100, 190)])
    result = match_scans(reference, current, method, initial=[0.0, 0.05, 0.02])
    assert abs(result.pose[1]) < 0.01 and abs(result.pose[2]) < 0.01
    variances = np.diag(result.covariance)
    assert np.all(np.isfinite(result.covariance))
    if method != "icp":   # point-to-point pairs pin x to the sampling; the line-based costs do not
        # Only noise in the normals and the wall ends constrain x: its variance dwarfs y's.
        assert variances[0] > 30 * variances[1]
