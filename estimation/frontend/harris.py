"""Harris corners: response, non-maximum suppression, bucketing for an even spread, sub-pixel refinement.

Image coordinates: (u, v) = (column, row), the centre of pixel (r, c) at (u, v) = (c, r).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from estimation.frontend.buffers import ScratchBuffers, scratch
from estimation.frontend.errors import FrontEndError


@dataclass(frozen=True)
class HarrisConfig:
    """Settings of the corner detector.

    k:              Harris' trace weight, R = det(M) - k·trace(M)²
    window_sigma:   σ (px) of the Gaussian window that sums the gradient products into M
    nms_size:       side (px, odd) of the square within which a corner must be the maximum
    quality:        a corner's response must exceed quality × the maximum response where corners can be reported
    max_corners:    at most this many corners per image
    grid:           (columns, rows) of buckets; each keeps at most ceil(max_corners / cells) corners
    margin:         corners closer than this (px) to the border are not reported
    """

    k: float = 0.04
    window_sigma: float = 1.0
    nms_size: int = 5
    quality: float = 1e-3
    max_corners: int = 400
    grid: tuple[int, int] = (8, 6)
    margin: int = 4


def as_gray_float32(image: np.ndarray) -> np.ndarray:
    """A 2-D float32 copy-free view when possible; colour (H, W, 3) BGR is converted to grey."""
    image = np.asarray(image)
    if image.ndim == 3 and image.shape[2] in (3, 4):
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if image.ndim != 2 or image.shape[0] < 3 or image.shape[1] < 3:
        raise FrontEndError(f"expected a grey (H, W) or colour (H, W, 3) image, got shape {image.shape}")
    return image.astype(np.float32, copy=False)


def harris_response(image: np.ndarray, k: float = 0.04, window_sigma: float = 1.0,
                    buffers: ScratchBuffers | None = None) -> np.ndarray:
    """Harris response R = det(M) - k·trace(M)² of an image (H, W) -> (H, W) float32.

    M is the Gaussian-windowed structure tensor of 3×3 Sobel gradients. With ``buffers`` the result and every
    intermediate live in reused arrays (the result is overwritten by the next call with the same buffers).
    """
    image = np.asarray(image)
    eight_bit = image.ndim == 2 and image.dtype == np.uint8 and min(image.shape) >= 3
    if eight_bit:
        shape = image.shape
    elif image.ndim == 2 and image.dtype != np.float32 and min(image.shape) >= 3:
        img = scratch(buffers, "harris_image", image.shape, np.float32)  # converted into a reused buffer
        np.copyto(img, image, casting="unsafe")
    else:
        img = as_gray_float32(image)
    if not eight_bit:
        shape = img.shape

    def buf(name: str) -> np.ndarray:
        return scratch(buffers, "harris_" + name, shape, np.float32)

    ix, iy = buf("ix"), buf("iy")
    if eight_bit:
        # both 3×3 Sobel gradients in one pass, exact in int16 (|g| ≤ 1020), then float32: the same values as
        # cv2.Sobel(CV_32F) on the float image, at about two thirds of the cost
        # the int16 gradients live in the first halves of the sxx and syy blocks, not written until they are read
        gx = buf("sxx").reshape(-1).view(np.int16)[:ix.size].reshape(shape)
        gy = buf("syy").reshape(-1).view(np.int16)[:iy.size].reshape(shape)
        cv2.spatialGradient(image, dx=gx, dy=gy, ksize=3, borderType=cv2.BORDER_REFLECT_101)
        np.copyto(ix, gx, casting="unsafe")
        np.copyto(iy, gy, casting="unsafe")
    else:
        cv2.Sobel(img, cv2.CV_32F, 1, 0, dst=ix, ksize=3)
        cv2.Sobel(img, cv2.CV_32F, 0, 1, dst=iy, ksize=3)
    side = 2 * int(np.ceil(2.0 * window_sigma)) + 1  # the Gaussian truncated at 2σ
    blur = dict(ksize=(side, side), sigmaX=window_sigma, sigmaY=window_sigma, borderType=cv2.BORDER_REFLECT_101)
    # five image-sized float arrays in all, each reused once it is dead (less memory traffic, same values)
    sxx = cv2.GaussianBlur(np.multiply(ix, ix, out=buf("sxx")), dst=buf("sxx"), **blur)
    syy = cv2.GaussianBlur(np.multiply(iy, iy, out=buf("syy")), dst=buf("syy"), **blur)
    sxy = cv2.GaussianBlur(np.multiply(ix, iy, out=ix), dst=ix, **blur)
    # R = sxx·syy - sxy² - k·(sxx + syy)², in place
    response = np.multiply(sxx, syy, out=iy)
    response -= np.multiply(sxy, sxy, out=sxy)
    trace = np.add(sxx, syy, out=sxx)
    trace *= trace
    trace *= np.float32(k)
    response -= trace
    return response


def smallest_above(threshold: float, dtype) -> np.generic:
    """The smallest value of the floating ``dtype`` strictly greater than ``threshold`` (a float64 number)."""
    value = np.dtype(dtype).type(threshold)
    return value if float(value) > threshold else np.nextafter(value, np.inf)


def non_maximum_suppression(response: np.ndarray, size: int, threshold: float, margin: int,
                            buffers: ScratchBuffers | None = None) -> np.ndarray:
    """Integer (row, col) of local maxima above ``threshold`` at least ``margin`` px inside: (N, 2) int."""
    m = max(int(margin), 1)  # the sub-pixel fit needs one neighbour on each side
    rows, cols = response.shape
    return local_maxima(response, size, threshold, (slice(m, rows - m), slice(m, cols - m)), buffers)


def local_maxima(response: np.ndarray, size: int, threshold: float, region: tuple[slice, slice],
                 buffers: ScratchBuffers | None = None, work: np.ndarray | None = None) -> np.ndarray:
    """Integer (row, col) (N, 2) of the pixels in ``region`` (row and column slices with explicit non-negative
    bounds) that are the maximum of their size × size neighbourhood and above ``threshold``, row-major order.

    work: an array like ``response`` to overwrite (else one from ``buffers``).
    """
    if size < 1 or size % 2 == 0:
        raise FrontEndError(f"nms_size must be odd and positive, got {size}")
    top, left = region[0].start, region[1].start
    inner_shape = (region[0].stop - top, region[1].stop - left)
    if inner_shape[0] <= 0 or inner_shape[1] <= 0:
        return np.zeros((0, 2), np.int64)
    if work is None:
        work = scratch(buffers, "nms_dilated", response.shape, response.dtype)
    dilated = cv2.dilate(response, np.ones((size, size), np.uint8), dst=work)
    # a peak is the maximum of its neighbourhood and above the threshold: response >= max(dilated, floor) with
    # floor the smallest representable value above the threshold (one comparison pass instead of two and an and);
    # whole contiguous arrays are faster to compare than the region's view, whose border is then cleared
    floor = smallest_above(threshold, response.dtype)
    bar = cv2.max(dilated, float(floor), dst=dilated)
    peak = np.greater_equal(response, bar, out=scratch(buffers, "nms_peak", response.shape, bool))
    peak[:top] = False
    peak[region[0].stop:] = False
    peak[:, :left] = False
    peak[:, region[1].stop:] = False
    r, c = np.divmod(np.flatnonzero(peak), response.shape[1])
    return np.stack([r, c], axis=1)


def bucket(rows: np.ndarray, cols: np.ndarray, scores: np.ndarray, shape: tuple[int, int],
           grid: tuple[int, int], max_total: int) -> np.ndarray:
    """Indices of the strongest candidates per grid cell, at most ``max_total``, strongest first.

    rows, cols, scores: (N,); shape: image (H, W); grid: (columns, rows) of cells -> (M,) int indices.
    """
    n_cols, n_rows = grid
    per_cell = -(-max_total // (n_cols * n_rows))
    cell = (rows * n_rows // shape[0]) * n_cols + cols * n_cols // shape[1]
    order = np.lexsort((-scores, cell))  # by cell, strongest first within a cell
    sorted_cell = cell[order]
    first_of_cell = np.searchsorted(sorted_cell, sorted_cell, side="left")
    rank = np.arange(len(order)) - first_of_cell
    kept = order[rank < per_cell]
    kept = kept[np.argsort(-scores[kept], kind="stable")]
    return kept[:max_total]


def subpixel_offsets(response: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertex of the parabola through the response at each peak and its two neighbours, per axis.

    Returns (du, dv), each (N,) in [-0.5, 0.5].
    """
    centre = response[rows, cols]
    # both axes at once: [0] along u (columns), [1] along v (rows)
    before = np.stack([response[rows, cols - 1], response[rows - 1, cols]])
    after = np.stack([response[rows, cols + 1], response[rows + 1, cols]])
    curvature = before - 2.0 * centre + after
    with np.errstate(divide="ignore", invalid="ignore"):
        offset = np.where(curvature < 0, 0.5 * (before - after) / curvature, 0.0)
    offset = np.clip(offset, -0.5, 0.5)
    return offset[0], offset[1]


def detect_corners(image: np.ndarray, config: HarrisConfig = HarrisConfig(),
                   buffers: ScratchBuffers | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Harris corners of an image (H, W).

    Returns (pixels (N, 2) float64 sub-pixel (u, v), responses (N,) float32), strongest first.

    The response is computed only where corners can be reported (``margin`` px inside) plus the reach of the
    suppression window and of the gradient and window filters, so every value used equals the whole image's;
    ``quality`` is relative to the strongest response where corners can be reported.
    """
    image = np.asarray(image)
    if image.ndim < 2:
        raise FrontEndError(f"expected a grey (H, W) or colour (H, W, 3) image, got shape {image.shape}")
    height, width = image.shape[:2]
    m = max(int(config.margin), 1)  # the sub-pixel fit needs one neighbour on each side
    if height <= 2 * m or width <= 2 * m:
        return np.zeros((0, 2)), np.zeros(0, np.float32)
    reach = config.nms_size // 2 + 1 + int(np.ceil(2.0 * config.window_sigma))  # NMS + Sobel + Gaussian window
    r0, c0 = max(m - reach, 0), max(m - reach, 0)
    r1, c1 = min(height - m + reach, height), min(width - m + reach, width)
    response = harris_response(image[r0:r1, c0:c1], config.k, config.window_sigma, buffers)
    region = (slice(m - r0, height - m - r0), slice(m - c0, width - m - c0))
    peak_max = cv2.minMaxLoc(response[region])[1]  # reads the strided view directly: twice numpy's speed
    if peak_max <= 0.0:
        return np.zeros((0, 2)), np.zeros(0, np.float32)
    # the suppression overwrites harris_response's dead sxx buffer: memory just touched, still in the cache
    dead = scratch(buffers, "harris_sxx", response.shape, np.float32) if response.dtype == np.float32 else None
    peaks = local_maxima(response, config.nms_size, config.quality * peak_max, region, buffers, dead)
    rows, cols = peaks[:, 0], peaks[:, 1]
    scores = response[rows, cols]
    keep = bucket(rows + r0, cols + c0, scores, (height, width), config.grid, config.max_corners)
    rows, cols, scores = rows[keep], cols[keep], scores[keep]
    du, dv = subpixel_offsets(response, rows, cols)
    return np.stack([cols + c0 + du, rows + r0 + dv], axis=1).astype(np.float64), scores
