"""Triangulation: projection round trip, frames, covariance against Monte Carlo, dropping far points."""
from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.frontend import (
    StereoGeometry,
    TriangulationNoise,
    camera_to_base,
    triangulate,
    triangulation_covariances,
)
from estimation.frontend.triangulation import keep_triangulable


def project(points: np.ndarray, g: StereoGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Left pixels and disparities of left-camera points (the pinhole model, written independently)."""
    X, Y, Z = points.T
    u = g.fx * X / Z + g.cx
    v = g.fy * Y / Z + g.cy
    return np.stack([u, v], axis=1), g.fx * g.baseline / Z


@settings(max_examples=50, deadline=None)
@given(st.floats(-3, 3), st.floats(-2, 2), st.floats(0.5, 12), st.floats(300, 900), st.floats(0.05, 0.3))
def test_triangulate_inverts_the_projection(X, Y, Z, f, baseline):
    g = StereoGeometry(fx=f, fy=0.98 * f, cx=300.0, cy=250.0, baseline=baseline)
    pixels, d = project(np.array([[X, Y, Z]]), g)
    np.testing.assert_allclose(triangulate(pixels, d, g), [[X, Y, Z]], rtol=1e-9, atol=1e-9)


def test_default_geometry_maps_camera_points_into_base_link_as_specified():
    points = np.array([[0.3, -0.2, 4.0], [0.0, 0.0, 1.0]])
    base, _ = camera_to_base(points, np.zeros((2, 3, 3)))
    expected = np.stack([points[:, 2] + 0.12, -points[:, 0] + 0.045, -points[:, 1] + 0.50], axis=1)
    np.testing.assert_allclose(base, expected, atol=1e-12)


def test_head_matrix_round_trip_and_a_turned_head():
    g = StereoGeometry(head_pose=(0.1, -0.2, 0.6, 0.05, -0.1, np.pi / 2))
    again = StereoGeometry.with_head_matrix(g.head_to_base())
    np.testing.assert_allclose(again.left_camera_to_base(), g.left_camera_to_base(), atol=1e-12)
    # a head yawed +90° looks along base_link +y; its left camera sits behind it at -x
    turned = StereoGeometry(head_pose=(0.0, 0.0, 0.5, 0.0, 0.0, np.pi / 2))
    base, _ = camera_to_base(np.array([[0.0, 0.0, 2.0]]), np.zeros((1, 3, 3)), turned)
    np.testing.assert_allclose(base, [[-0.045, 2.0, 0.5]], atol=1e-12)
    direct = StereoGeometry.with_camera_matrix(turned.left_camera_to_base())
    np.testing.assert_allclose(direct.left_camera_to_base(), turned.left_camera_to_base())


def test_covariance_matches_monte_carlo():
    g = StereoGeometry()
    noise = TriangulationNoise()
    rng = np.random.default_rng(42)
    pixels, d = np.array([[420.0, 150.0]]), np.array([25.0])
    n = 200_000
    samples_px = pixels + rng.normal(0.0, [noise.sigma_u, noise.sigma_v], size=(n, 2))
    samples_d = d + rng.normal(0.0, noise.sigma_d, size=n)
    cloud = triangulate(samples_px, samples_d, g)
    empirical = np.cov(cloud.T)
    predicted = triangulation_covariances(pixels, d, g, noise)[0]
    # first order in σ_d / d = 1.2 %: agreement to a few per cent, element by element in the scale of each axis
    scale = np.sqrt(np.outer(np.diag(predicted), np.diag(predicted)))
    np.testing.assert_allclose(empirical / scale, predicted / scale, atol=0.04)
    # and in base_link the rotated covariance still describes the rotated cloud
    cloud_base, _ = camera_to_base(cloud, np.zeros((n, 3, 3)), g)
    _, predicted_base = camera_to_base(np.zeros((1, 3)), triangulation_covariances(pixels, d, g, noise), g)
    np.testing.assert_allclose(np.cov(cloud_base.T) / scale.max(), predicted_base[0] / scale.max(), atol=0.04)


@settings(max_examples=50, deadline=None)
@given(st.floats(0, 640), st.floats(0, 480), st.floats(3, 200))
def test_covariances_are_symmetric_positive_definite(u, v, d):
    cov = triangulation_covariances(np.array([[u, v]]), np.array([d]))
    _, cov_base = camera_to_base(np.zeros((1, 3)), cov)
    for c in (cov[0], cov_base[0]):
        np.testing.assert_allclose(c, c.T, rtol=1e-12, atol=1e-18)
        assert np.all(np.linalg.eigvalsh(c) > 0)


def test_far_and_tiny_disparities_are_dropped():
    g, noise = StereoGeometry(), TriangulationNoise()  # fx·B = 46.8 px·m: 12 m is d = 3.9 px
    keep = keep_triangulable(np.array([2.0, 3.5, 3.9, 4.0, 60.0, -5.0]), g, noise)
    assert keep.tolist() == [False, False, True, True, True, False]


_finite = st.floats(-10.0, 10.0, allow_nan=False)


@given(fx=st.floats(1.0, 5000.0), fy=st.floats(1.0, 5000.0), cx=_finite, cy=_finite, baseline=st.floats(0.01, 1.0),
       head_pose=st.tuples(*[_finite] * 6), left=st.none() | st.tuples(*[_finite] * 16))
def test_geometry_settings_round_trip(fx, fy, cx, cy, baseline, head_pose, left):
    """A sensor log's settings hold the geometry as plain numbers (JSON); reading them back gives the same geometry."""
    g = StereoGeometry(fx, fy, cx, cy, baseline, head_pose, left)
    assert StereoGeometry.from_dict(json.loads(json.dumps(g.to_dict()))) == g


def test_geometry_settings_without_a_field_name_it():
    d = StereoGeometry().to_dict()
    del d["baseline"]
    with pytest.raises(KeyError, match="baseline"):
        StereoGeometry.from_dict(d)
