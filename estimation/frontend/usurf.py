"""U-SURF (upright SURF) descriptors at given keypoints, vectorised over keypoints on an integral image.

As in Bay et al. (ECCV 2006 / CVIU 2008) and ``../shared/reference/usurf.md``:
- a 20s × 20s axis-aligned window around the keypoint, 4 × 4 subregions of 5 × 5 samples at spacing s;
  sample k (k = 0..19) of an axis lies at offset (k - 9.5)·s from the keypoint, so the window is centred;
- at each sample the Haar wavelet responses dx, dy of size 2s, summed on the integral image;
- each response weighted by a Gaussian of σ = 3.3s centred on the keypoint (evaluated at the nominal
  sample offsets, as OpenCV's surf.cpp does with its precomputed weights);
- each subregion gives (Σdx, Σdy, Σ|dx|, Σ|dy|); the 64 values are scaled to unit length.

Discretisation (documented because the papers leave it open): the Haar wavelet has the even integer side
h = 2·max(1, round(s)) and is centred on the pixel corner nearest the sample; dx is the sum of the right
half minus the left half, dy the bottom half minus the top half (image rows grow downwards), so a ramp
I = a·u + b·v gives dx = a·h³/4, dy = b·h³/4 at every sample.

Border: a keypoint whose window (with the wavelets) does not fit inside the image is dropped; the
``described`` mask says which keypoints got a descriptor. A keypoint on a perfectly flat patch (all
responses zero, no direction to normalise) is dropped too.

Descriptor layout: subregion (row i, column j) of the window, row-major, holds the 4 values at
4·(4·i + j) .. 4·(4·i + j) + 3.
"""
from __future__ import annotations

import functools

import cv2
import numpy as np

from estimation.frontend.buffers import ScratchBuffers, scratch
from estimation.frontend.errors import FrontEndError

SAMPLES_PER_AXIS = 20  # 4 subregions × 5 samples
SUBREGIONS = 4
DESCRIPTOR_SIZE = 64
GAUSSIAN_SIGMA_IN_SCALES = 3.3


def haar_half_size(scale: float) -> int:
    """Half the side of the Haar wavelet (px) at scale s: the wavelet's side 2s rounded to an even integer ≥ 2."""
    return max(1, int(round(scale)))


def sample_offsets(scale: float) -> np.ndarray:
    """Offsets (20,) of the samples from the keypoint along one axis, px."""
    return (np.arange(SAMPLES_PER_AXIS) - (SAMPLES_PER_AXIS - 1) / 2.0) * scale


def gaussian_weights(scale: float) -> np.ndarray:
    """Weights (20, 20) [row, column] of the samples: Gaussian of σ = 3.3s centred on the keypoint."""
    offsets = sample_offsets(scale)
    sigma = GAUSSIAN_SIGMA_IN_SCALES * scale
    g = np.exp(-(offsets**2) / (2.0 * sigma**2))
    return np.outer(g, g)


@functools.lru_cache(maxsize=8)
def pooling_matrix(scale: float) -> np.ndarray:
    """(400, 16) float32: column 4·i + j holds the Gaussian weights of subregion (i, j)'s 25 samples, 0 elsewhere.

    Multiplying a keypoint's (400,) sample responses by it gives the 16 weighted subregion sums at once.
    """
    sample = np.arange(SAMPLES_PER_AXIS)
    subregion_of = sample // 5
    region = (subregion_of[:, None] * SUBREGIONS + subregion_of[None, :]).reshape(-1)  # (400,)
    pooling = np.zeros((SAMPLES_PER_AXIS**2, SUBREGIONS**2), np.float32)
    pooling[np.arange(SAMPLES_PER_AXIS**2), region] = gaussian_weights(scale).reshape(-1)
    pooling.setflags(write=False)
    return pooling


def integral_image(image: np.ndarray, buffers: ScratchBuffers | None = None) -> np.ndarray:
    """Integral image (H + 1, W + 1): entry [r, c] is the sum of image[:r, :c].

    8-bit images sum exactly in int32 (up to 2^31 / 255 ≈ 8.4 Mpx); others in float64.
    """
    image = np.asarray(image)
    if image.ndim != 2:
        raise FrontEndError(f"expected a grey (H, W) image, got shape {image.shape}")
    shape = (image.shape[0] + 1, image.shape[1] + 1)
    if image.dtype == np.uint8 and image.size < 2**31 // 255:
        return cv2.integral(image, sum=scratch(buffers, "integral_i32", shape, np.int32), sdepth=cv2.CV_32S)
    return cv2.integral(np.ascontiguousarray(image, dtype=np.float64),
                        sum=scratch(buffers, "integral_f64", shape, np.float64), sdepth=cv2.CV_64F)


def dense_haar_responses(integral: np.ndarray, half: int,
                         buffers: ScratchBuffers | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Haar responses (dx, dy) of side 2·half at every pixel corner where the wavelet fits.

    integral: (H + 1, W + 1) -> dx, dy: (H + 1 - 2·half, W + 1 - 2·half); element [i, j] is the wavelet
    centred on the corner with integral index (i + half, j + half), i.e. at (u, v) = (j + half - ½, i + half - ½).
    """
    h2 = 2 * half
    n_rows, n_cols = integral.shape[0] - h2, integral.shape[1] - h2
    if n_rows < 1 or n_cols < 1:
        raise FrontEndError(f"image too small for Haar wavelets of side {h2}")

    def buf(name: str, shape: tuple[int, int]) -> np.ndarray:
        return scratch(buffers, "haar_" + name, shape, integral.dtype)

    # strips: vertical[i, c] sums rows i .. i+2h-1 left of column c; horizontal[r, j] columns j .. j+2h-1 above row r
    vertical = np.subtract(integral[h2:], integral[:n_rows], out=buf("vertical", (n_rows, integral.shape[1])))
    horizontal = np.subtract(integral[:, h2:], integral[:, :n_cols], out=buf("horizontal", (integral.shape[0], n_cols)))
    # right half - left half = V[c+2h] - 2 V[c+h] + V[c]; bottom - top likewise along rows
    dx = np.add(vertical[:, h2:], vertical[:, :n_cols], out=buf("dx", (n_rows, n_cols)))
    dx -= vertical[:, half:half + n_cols]
    dx -= vertical[:, half:half + n_cols]
    dy = np.add(horizontal[h2:], horizontal[:n_rows], out=buf("dy", (n_rows, n_cols)))
    dy -= horizontal[half:half + n_rows]
    dy -= horizontal[half:half + n_rows]
    return dx, dy


def usurf_descriptors(image: np.ndarray, keypoints: np.ndarray, scale: float = 2.0,
                      buffers: ScratchBuffers | None = None) -> tuple[np.ndarray, np.ndarray]:
    """U-SURF descriptors of keypoints at one fixed scale.

    image: (H, W) grey; keypoints: (N, 2) sub-pixel (u, v); scale: s in px.
    Returns (descriptors (M, 64) float32 unit length, described (N,) bool) with M = described.sum().
    """
    if scale <= 0:
        raise FrontEndError(f"U-SURF scale must be positive, got {scale}")
    keypoints = np.asarray(keypoints, dtype=np.float64).reshape(-1, 2)
    half = haar_half_size(scale)
    integral = integral_image(image, buffers)
    cols, rows, inside = sample_corners(keypoints, scale, half, integral.shape)
    if float(scale) == half and lattice_aligned(cols, rows, half):
        dx, dy = lattice_haar_responses(integral, cols[:, 0], rows[:, 0], half, buffers)
    else:  # a non-integer scale: its samples are not on a lattice of the wavelet's half side
        dx_img, dy_img = dense_haar_responses(integral, half, buffers)
        dx, dy = gather_haar_responses(dx_img, dy_img, cols, rows, buffers)
    return pool_descriptors(dx, dy, inside, scale, buffers)


def sample_corners(keypoints: np.ndarray, scale: float, half: int,
                   integral_shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where each keypoint's 20 × 20 wavelets sit: (cols (M, 20), rows (M, 20), inside (N,) bool).

    cols[i, k] is the integral-image column of the left edge of the wavelet at sample column k of the i-th
    keypoint whose window fits (likewise rows, top edges), i.e. the wavelet covers integral indices
    cols .. cols + 2·half; equivalently the index into ``dense_haar_responses``' arrays.
    """
    offsets = sample_offsets(scale)
    # integral index of the corner nearest each sample, minus half -> left/top edge of the wavelet
    cols = np.floor(keypoints[:, 0:1] + offsets + 1.0).astype(np.int64) - half  # (N, 20)
    rows = np.floor(keypoints[:, 1:2] + offsets + 1.0).astype(np.int64) - half
    n_rows, n_cols = integral_shape[0] - 2 * half, integral_shape[1] - 2 * half
    inside = (cols[:, 0] >= 0) & (cols[:, -1] < n_cols) & (rows[:, 0] >= 0) & (rows[:, -1] < n_rows)
    return cols[inside], rows[inside], inside


def lattice_aligned(cols: np.ndarray, rows: np.ndarray, step: int) -> bool:
    """Whether every keypoint's sample edges (M, 20) advance by exactly ``step`` px (an integer scale)."""
    steps = step * np.arange(SAMPLES_PER_AXIS)
    return bool(np.array_equal(cols, cols[:, :1] + steps) and np.array_equal(rows, rows[:, :1] + steps))


def lattice_haar_responses(integral: np.ndarray, col0: np.ndarray, row0: np.ndarray, half: int,
                           buffers: ScratchBuffers | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Haar responses (dx, dy), each (M, 20, 20) [sample row, sample column], straight from the integral image.

    With an integer scale s the samples are s px apart and the wavelets have half side s, so all the corners
    the 400 wavelets of one keypoint need lie on one 22 × 22 lattice of integral entries s apart (starting at
    (row0, col0), the first wavelet's top-left corner): 484 look-ups per keypoint instead of dense responses
    over the whole image. Integer sums, so the values equal ``dense_haar_responses``' exactly.
    """
    n = SAMPLES_PER_AXIS + 2
    steps = half * np.arange(n)
    m = len(col0)
    flat = scratch(buffers, "usurf_lattice_index", (m, n, n), np.intp)
    np.add(((row0[:, None] + steps) * integral.shape[1])[:, :, None], (col0[:, None] + steps)[:, None, :], out=flat)
    corners = np.take(integral, flat, out=scratch(buffers, "usurf_lattice", (m, n, n), integral.dtype))
    k = SAMPLES_PER_AXIS
    # vertical strips 2·half high (M, 20, 22), then right - 2·middle + left; horizontal strips likewise for dy
    vertical = np.subtract(corners[:, 2:, :], corners[:, :k, :], out=scratch(buffers, "usurf_strips_v", (m, k, n),
                                                                             integral.dtype))
    dx = np.add(vertical[:, :, 2:], vertical[:, :, :k], out=scratch(buffers, "usurf_lattice_dx", (m, k, k),
                                                                    integral.dtype))
    dx -= vertical[:, :, 1:k + 1]
    dx -= vertical[:, :, 1:k + 1]
    horizontal = np.subtract(corners[:, :, 2:], corners[:, :, :k], out=scratch(buffers, "usurf_strips_h", (m, n, k),
                                                                               integral.dtype))
    dy = np.add(horizontal[:, 2:, :], horizontal[:, :k, :], out=scratch(buffers, "usurf_lattice_dy", (m, k, k),
                                                                        integral.dtype))
    dy -= horizontal[:, 1:k + 1, :]
    dy -= horizontal[:, 1:k + 1, :]
    return dx, dy


def gather_haar_responses(dx_img: np.ndarray, dy_img: np.ndarray, cols: np.ndarray, rows: np.ndarray,
                          buffers: ScratchBuffers | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Dense responses (see ``dense_haar_responses``) read at the samples: (dx, dy), each (M, 20, 20)."""
    m = len(cols)
    shape = (m, SAMPLES_PER_AXIS, SAMPLES_PER_AXIS)
    flat = scratch(buffers, "usurf_flat", shape, np.intp)
    np.add((rows * dx_img.shape[1])[:, :, None], cols[:, None, :], out=flat)  # sample [row, col] -> flat index
    return (np.take(dx_img, flat, out=scratch(buffers, "usurf_gathered_dx", shape, dx_img.dtype)),
            np.take(dy_img, flat, out=scratch(buffers, "usurf_gathered_dy", shape, dy_img.dtype)))


def pool_descriptors(dx: np.ndarray, dy: np.ndarray, inside: np.ndarray, scale: float,
                     buffers: ScratchBuffers | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian-weighted subregion sums of the sample responses dx, dy (M, 20, 20) -> unit descriptors.

    inside: (N,) which keypoints the M rows belong to. Returns (descriptors (K, 64) float32, described (N,) bool).
    """
    m = len(dx)
    samples = (m, SAMPLES_PER_AXIS**2)
    pooling = pooling_matrix(float(scale))
    signed, absolute = [], []
    for values, name in ((dx, "dx"), (dy, "dy")):
        response = scratch(buffers, "usurf_" + name, samples, np.float32)
        np.copyto(response, values.reshape(samples), casting="unsafe")
        signed.append(response @ pooling)
        # the weights are positive, so Σ w·|dx| = Σ |w·dx|
        absolute.append(np.abs(response, out=response) @ pooling)
    sums = np.stack(signed + absolute, axis=-1)
    sums = sums.reshape(m, DESCRIPTOR_SIZE)
    norms = np.linalg.norm(sums, axis=1)
    textured = norms > 0
    described = inside.copy()
    described[inside] = textured
    return (sums[textured] / norms[textured, None]).astype(np.float32), described


def usurf_from_haar(dx_img: np.ndarray, dy_img: np.ndarray, keypoints: np.ndarray, scale: float,
                    half: int, buffers: ScratchBuffers | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The descriptor core on precomputed dense Haar responses (see ``dense_haar_responses``)."""
    integral_shape = (dx_img.shape[0] + 2 * half, dx_img.shape[1] + 2 * half)
    cols, rows, inside = sample_corners(np.asarray(keypoints, np.float64).reshape(-1, 2), scale, half, integral_shape)
    dx, dy = gather_haar_responses(dx_img, dy_img, cols, rows, buffers)
    return pool_descriptors(dx, dy, inside, scale, buffers)
