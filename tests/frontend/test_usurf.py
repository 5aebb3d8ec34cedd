"""U-SURF: hand-computed values on synthetic patches, invariances, borders, vectorisation."""
from __future__ import annotations

import numpy as np
import pytest

from estimation.frontend import FrontEndError, integral_image, usurf_descriptors
from estimation.frontend.usurf import dense_haar_responses

from .conftest import texture


def test_integral_image_sums_rectangles():
    image = np.arange(12, dtype=np.uint8).reshape(3, 4)
    integral = integral_image(image)
    assert integral.shape == (4, 5)
    assert integral[3, 4] == image.sum()
    assert integral[2, 3] - integral[1, 3] - integral[2, 1] + integral[1, 1] == image[1, 1:3].sum()


def test_haar_dx_of_a_step_is_a_triangle():
    # step of height A at column c0; a wavelet of half side h centred on corner j (between pixel j-1 and j)
    # sees A in its right half over min(h, h - (c0 - j)) columns and in its left half over (j - c0) columns,
    # so dx = A·2h·(h - |j - c0|) within h of the step, 0 farther away; dy = 0 everywhere.
    A, c0, h = 7, 10, 2
    image = np.zeros((12, 20), np.uint8)
    image[:, c0:] = A
    dx, dy = dense_haar_responses(integral_image(image), h)
    corner = np.arange(dx.shape[1]) + h  # integral column index of each response column
    expected = A * 2 * h * np.clip(h - np.abs(corner - c0), 0, None)
    np.testing.assert_array_equal(dx, np.broadcast_to(expected, dx.shape))
    np.testing.assert_array_equal(dy, 0)


@pytest.mark.parametrize("a, b", [(1.0, 0.0), (0.0, -2.0), (3.0, 1.5)])
def test_ramp_gives_the_hand_computed_descriptor(a, b):
    # On I = a·u + b·v every sample has dx = a·h³/4, dy = b·h³/4, so subregion (i, j) holds
    # W_ij·(a, b, |a|, |b|)·h³/4 with W_ij = G_i·G_j, G_i the Gaussian weights of block i's 5 samples.
    s = 1.0
    v, u = np.mgrid[0:41, 0:41].astype(float)
    image = 50.0 + a * u + b * v
    descriptors, described = usurf_descriptors(image, np.array([[20.0, 20.0]]), scale=s)
    assert described.tolist() == [True]
    g = np.exp(-(((np.arange(20) - 9.5) * s) ** 2) / (2 * (3.3 * s) ** 2))
    G = g.reshape(4, 5).sum(axis=1)
    expected = (np.outer(G, G)[:, :, None] * np.array([a, b, abs(a), abs(b)])).reshape(64)
    expected /= np.linalg.norm(expected)
    np.testing.assert_allclose(descriptors[0], expected, atol=1e-6)


def test_descriptors_are_unit_vectors():
    image = np.clip(texture((120, 160), seed=1), 0, 255).astype(np.uint8)
    points = np.random.default_rng(2).uniform([30, 30], [130, 90], size=(50, 2))
    descriptors, described = usurf_descriptors(image, points, scale=1.2)
    assert descriptors.shape == (described.sum(), 64) and described.all()
    np.testing.assert_allclose(np.linalg.norm(descriptors, axis=1), 1.0, rtol=1e-5)


def test_brightness_offset_leaves_the_descriptor_exactly_unchanged():
    image = np.rint(texture((100, 100), seed=3) * 0.8).astype(np.uint8)  # 8..196, room for the offset
    points = np.random.default_rng(4).uniform(28, 72, size=(40, 2))
    before, _ = usurf_descriptors(image, points, 2.0)
    after, _ = usurf_descriptors(image + np.uint8(37), points, 2.0)
    np.testing.assert_array_equal(before, after)


@pytest.mark.parametrize("gain", [2.0, 0.37, 1.7])
def test_contrast_scaling_is_undone_by_the_normalisation(gain):
    image = texture((100, 100), seed=5)
    points = np.random.default_rng(6).uniform(28, 72, size=(40, 2))
    before, _ = usurf_descriptors(image, points, 2.0)
    after, _ = usurf_descriptors(image * gain, points, 2.0)
    np.testing.assert_allclose(before, after, atol=1e-5)


def test_small_translations_keep_every_descriptor_nearest_to_its_own():
    image = texture((200, 200), seed=7, blur=3.0)
    rng = np.random.default_rng(11)
    points = rng.uniform(60, 140, size=(50, 2))
    original, _ = usurf_descriptors(image, points, 2.0)
    moved, _ = usurf_descriptors(image, points + rng.uniform(-0.4, 0.4, size=points.shape), 2.0)
    distances = np.linalg.norm(moved[:, None] - original[None], axis=2)
    np.testing.assert_array_equal(np.argmin(distances, axis=1), np.arange(len(points)))
    assert np.median(np.diag(distances)) < 0.1 < np.median(distances)


def test_keypoints_near_the_border_are_dropped():
    image = texture((80, 100), seed=8)
    s = 2.0  # window 40 px plus the wavelet: needs ~22 px on each side
    points = np.array([[50.0, 40.0], [5.0, 40.0], [50.0, 78.0], [80.0, 40.0], [-3.0, 10.0]])
    descriptors, described = usurf_descriptors(image, points, s)
    assert described.tolist() == [True, False, False, False, False]
    assert len(descriptors) == 1


def test_vectorised_equals_one_at_a_time():
    image = np.clip(texture((150, 150), seed=9), 0, 255).astype(np.uint8)
    points = np.random.default_rng(10).uniform(25, 125, size=(30, 2))
    together, _ = usurf_descriptors(image, points, 1.6)
    alone = np.concatenate([usurf_descriptors(image, p[None], 1.6)[0] for p in points])
    np.testing.assert_allclose(together, alone, atol=1e-6)  # BLAS may block the matmul differently


def test_flat_patch_and_bad_scale():
    flat = np.full((60, 60), 90, np.uint8)
    descriptors, described = usurf_descriptors(flat, np.array([[30.0, 30.0]]), 1.0)
    assert len(descriptors) == 0 and not described.any()
    with pytest.raises(FrontEndError):
        usurf_descriptors(flat, np.array([[30.0, 30.0]]), 0.0)


@pytest.mark.parametrize("scale", [1.0, 2.0, 3.0])
def test_lattice_gather_equals_the_dense_responses_exactly(scale):
    # integer scales read the wavelets straight off the integral image; the dense path is the reference
    from estimation.frontend.usurf import haar_half_size, lattice_aligned, sample_corners, usurf_from_haar

    image = np.clip(texture((160, 200), seed=13), 0, 255).astype(np.uint8)
    points = np.random.default_rng(14).uniform(0, [200, 160], size=(300, 2))
    points[:5] = np.floor(points[:5]) + 0.5  # sub-pixel positions exactly between pixels
    half = haar_half_size(scale)
    cols, rows, _ = sample_corners(points, scale, half, (161, 201))
    assert lattice_aligned(cols, rows, half)  # the lattice path is the one taken
    dense_dx, dense_dy = dense_haar_responses(integral_image(image), half)
    expected, expected_ok = usurf_from_haar(dense_dx, dense_dy, points, scale, half)
    descriptors, described = usurf_descriptors(image, points, scale)
    assert 0 < described.sum() < len(points)  # some windows leave the image
    np.testing.assert_array_equal(described, expected_ok)
    np.testing.assert_array_equal(descriptors, expected)


@pytest.mark.parametrize("scale", [2.0, 1.5])
def test_both_images_at_once_equal_one_at_a_time(scale):
    from estimation.frontend.usurf import usurf_descriptors_of_images

    rng = np.random.default_rng(21)
    images = [np.clip(texture((120, 160), seed=s), 0, 255).astype(np.uint8) for s in (22, 23)]
    points = [rng.uniform(0, [160, 120], size=(n, 2)) for n in (40, 0)] + [rng.uniform(0, [160, 120], size=(30, 2))]
    images.append(images[0])
    together = usurf_descriptors_of_images(images, points, scale)
    assert len(together) == 3 and together[1][0].shape == (0, 64)
    for (descriptors, described), image, keypoints in zip(together, images, points, strict=True):
        alone, alone_ok = usurf_descriptors(image, keypoints, scale)
        np.testing.assert_array_equal(described, alone_ok)
        np.testing.assert_allclose(descriptors, alone, atol=1e-6)
    with pytest.raises(FrontEndError):
        usurf_descriptors_of_images(images, points[:2], scale)


def test_separable_pooling_weights_are_the_gaussian_of_each_subregion():
    # pooling runs as two products with the (4, 20) per-axis weights; their Kronecker square must give every
    # sample (a, b) the weight exp(-(o_a² + o_b²) / 2σ²), σ = 3.3s, in its own subregion and 0 in the others
    from estimation.frontend.usurf import subregion_weights

    for scale in (1.0, 2.0, 2.5):
        offsets = (np.arange(20) - 9.5) * scale
        g = np.exp(-(offsets**2) / (2 * (3.3 * scale) ** 2))
        expected = np.zeros((16, 400))
        for a in range(20):
            for b in range(20):
                expected[(a // 5) * 4 + b // 5, a * 20 + b] = g[a] * g[b]
        weights = subregion_weights(scale)
        np.testing.assert_allclose(np.kron(weights, weights), expected, rtol=1e-6)
