"""Harris corners: positions on synthetic squares, sub-pixel shifts, bucketing, suppression."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from estimation.frontend import FrontEndError, HarrisConfig, detect_corners
from estimation.frontend.harris import bucket, non_maximum_suppression

from .conftest import texture


def square_image(top_left: tuple[float, float], side: float = 40.0, size: int = 100, oversample: int = 8):
    """A bright square on dark ground, anti-aliased by area averaging: corners at exact sub-pixel places.

    Pixel (r, c) covers [c - ½, c + ½] × [r - ½, r + ½]; the square covers [u0, u0 + side] × [v0, v0 + side].
    """
    fine = np.zeros((size * oversample, size * oversample), np.float32)
    u0, v0 = top_left
    # fine pixel centres: (k + ½) / oversample - ½ in coarse coordinates
    centres = (np.arange(size * oversample) + 0.5) / oversample - 0.5
    inside_u = (centres >= u0) & (centres < u0 + side)
    inside_v = (centres >= v0) & (centres < v0 + side)
    fine[np.ix_(inside_v, inside_u)] = 200.0
    return cv2.resize(fine, (size, size), interpolation=cv2.INTER_AREA) + 20.0


def nearest_distances(found: np.ndarray, expected: np.ndarray) -> np.ndarray:
    return np.linalg.norm(found[:, None] - expected[None], axis=2).min(axis=0)


def test_the_four_corners_of_a_square_are_found_symmetrically():
    image = square_image((30.0, 30.0))
    corners, responses = detect_corners(image, HarrisConfig(max_corners=10))
    expected = np.array([[30, 30], [70, 30], [30, 70], [70, 70]], float)
    assert len(corners) >= 4
    # the four strongest are the four corners; Harris with a σ = 1 window peaks ~0.9 px inside an L corner
    assert nearest_distances(corners[:4], expected).max() < 1.5
    np.testing.assert_allclose(corners[:4].mean(axis=0), [50.0, 50.0], atol=0.05)
    assert np.all(np.diff(responses) <= 0)


def test_subpixel_refinement_follows_a_quarter_pixel_shift():
    config = HarrisConfig(max_corners=4)
    a, _ = detect_corners(square_image((30.0, 30.0)), config)
    b, _ = detect_corners(square_image((30.25, 29.75)), config)
    a, b = a[np.lexsort(a.T)], b[np.lexsort(b.T)]
    shift = (b - a).mean(axis=0)
    np.testing.assert_allclose(shift, [0.25, -0.25], atol=0.08)


def test_bucketing_spreads_corners_over_every_cell():
    image = texture((240, 320), seed=1)
    config = HarrisConfig(max_corners=48, grid=(4, 3))
    corners, _ = detect_corners(image, config)
    assert len(corners) == 48
    cell = (corners[:, 1] * 3 // 240).astype(int) * 4 + (corners[:, 0] * 4 // 320).astype(int)
    # 4 per cell on the integer peaks; a sub-pixel offset may carry one across a cell edge
    counts = np.bincount(cell, minlength=12)
    assert counts.min() >= 3 and counts.max() <= 5


def test_bucket_keeps_the_strongest_per_cell():
    rows = np.array([0, 1, 2, 0, 50, 51])
    cols = np.array([0, 1, 2, 60, 60, 61])
    scores = np.array([1.0, 3.0, 2.0, 5.0, 0.5, 0.7])
    kept = bucket(rows, cols, scores, (100, 100), (2, 2), max_total=8)  # 2 per cell
    assert sorted(kept.tolist()) == [1, 2, 3, 4, 5]
    assert kept.tolist()[0] == 3  # strongest first


def test_non_maximum_suppression_leaves_one_peak_per_neighbourhood():
    response = np.zeros((20, 20), np.float32)
    response[10, 10], response[10, 11], response[5, 5] = 5.0, 4.0, 3.0
    peaks = non_maximum_suppression(response, 3, 1.0, margin=2)
    assert sorted(map(tuple, peaks.tolist())) == [(5, 5), (10, 10)]
    with pytest.raises(FrontEndError):
        non_maximum_suppression(response, 4, 1.0, margin=2)


def test_margin_and_flat_image():
    image = texture((120, 120), seed=2)
    corners, _ = detect_corners(image, HarrisConfig(margin=25))
    assert corners.min() >= 24.5 and corners.max() <= 120 - 25 + 0.5
    empty, _ = detect_corners(np.full((50, 50), 7, np.uint8))
    assert empty.shape == (0, 2)


def test_eight_bit_images_give_exactly_the_float_response():
    # 8-bit images take the one-pass int16 gradient route; it must not change a single value
    from estimation.frontend import harris_response

    image = np.clip(texture((90, 130), seed=4), 0, 255).astype(np.uint8)
    image[:, :3] = 255  # saturated edge: the largest gradients
    np.testing.assert_array_equal(harris_response(image), harris_response(image.astype(np.float32)))


@pytest.mark.parametrize("margin, nms_size, sigma", [(23, 5, 1.0), (6, 3, 1.5), (2, 7, 0.8)])
def test_response_computed_inside_the_margin_matches_the_whole_image(margin, nms_size, sigma):
    # detect_corners computes the response only within reach of where corners can be reported; with no
    # threshold in play (quality 0) it must find exactly what the whole-image response gives
    from estimation.frontend import harris_response
    from estimation.frontend.harris import subpixel_offsets

    image = np.clip(texture((150, 210), seed=9), 0, 255).astype(np.uint8)
    config = HarrisConfig(max_corners=60, grid=(4, 3), margin=margin, nms_size=nms_size, window_sigma=sigma,
                          quality=0.0)
    corners, scores = detect_corners(image, config)
    response = harris_response(image, config.k, config.window_sigma)
    peaks = non_maximum_suppression(response, nms_size, 0.0, margin)
    keep = bucket(peaks[:, 0], peaks[:, 1], response[peaks[:, 0], peaks[:, 1]], image.shape, config.grid, 60)
    rows, cols = peaks[keep, 0], peaks[keep, 1]
    du, dv = subpixel_offsets(response, rows, cols)
    assert len(corners) == 60
    np.testing.assert_allclose(corners, np.stack([cols + du, rows + dv], axis=1), atol=1e-4)
    np.testing.assert_allclose(scores, response[rows, cols], rtol=1e-5)
