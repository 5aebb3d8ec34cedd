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
LATTICE_BATCH = 256  # keypoints per batch of the lattice path


def haar_half_size(scale: float) -> int:
    """Half the side of the Haar wavelet (px) at scale s: the wavelet's side 2s rounded to an even integer ≥ 2."""
    return max(1, int(round(scale)))


def sample_offsets(scale: float) -> np.ndarray:
    """Offsets (20,) of the samples from the keypoint along one axis, px."""
    return (np.arange(SAMPLES_PER_AXIS) - (SAMPLES_PER_AXIS - 1) / 2.0) * scale


def axis_weights(scale: float) -> np.ndarray:
    """Gaussian weights (20,) of the samples along one axis, σ = 3.3s centred on the keypoint; sample (a, b) of the
    window weighs axis_weights[a]·axis_weights[b]."""
    offsets = sample_offsets(scale)
    sigma = GAUSSIAN_SIGMA_IN_SCALES * scale
    return np.exp(-(offsets**2) / (2.0 * sigma**2))


def integral_image(image: np.ndarray, buffers: ScratchBuffers | None = None,
                   out: np.ndarray | None = None) -> np.ndarray:
    """Integral image (H + 1, W + 1): entry [r, c] is the sum of image[:r, :c].

    8-bit images sum exactly in int32 (up to 2^31 / 255 ≈ 8.4 Mpx); others in float64. ``out``: an int32
    (H + 1, W + 1) array for an 8-bit image's sums.
    """
    image = np.asarray(image)
    if image.ndim != 2:
        raise FrontEndError(f"expected a grey (H, W) image, got shape {image.shape}")
    shape = (image.shape[0] + 1, image.shape[1] + 1)
    if image.dtype == np.uint8 and image.size < 2**31 // 255:
        out = scratch(buffers, "integral_i32", shape, np.int32) if out is None else out
        return cv2.integral(image, sum=out, sdepth=cv2.CV_32S)
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
    return usurf_descriptors_of_images([image], [keypoints], scale, buffers)[0]


def usurf_descriptors_of_images(images: list[np.ndarray], keypoints: list[np.ndarray], scale: float = 2.0,
                                buffers: ScratchBuffers | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """``usurf_descriptors`` of several images at once (e.g. both of a stereo pair): one gather and one pooling
    for all keypoints when the images are 8-bit of one size and the scale is an integer, else one by one.

    images: (H, W) each; keypoints: (N_i, 2) each. Returns [(descriptors (M_i, 64), described (N_i,))].
    """
    if scale <= 0:
        raise FrontEndError(f"U-SURF scale must be positive, got {scale}")
    if len(images) != len(keypoints) or not images:
        raise FrontEndError(f"need one keypoint array per image, got {len(images)} images, {len(keypoints)} arrays")
    keypoints = [np.asarray(k, dtype=np.float64).reshape(-1, 2) for k in keypoints]
    images = [np.asarray(image) for image in images]
    half = haar_half_size(scale)
    shape = images[0].shape
    stackable = all(im.dtype == np.uint8 and im.ndim == 2 and im.shape == shape and im.size < 2**31 // 255
                    for im in images)  # 8-bit sums of one size, exact in int32
    if len(images) > 1 and not stackable:
        return [usurf_descriptors_of_images([image], [points], scale, buffers)[0]
                for image, points in zip(images, keypoints, strict=True)]
    if len(images) == 1:
        integrals = integral_image(images[0], buffers)[None]
    else:  # one block, so that one flat index reaches every image's integral
        integrals = scratch(buffers, "integral_stack", (len(images), shape[0] + 1, shape[1] + 1), np.int32)
        for image, integral in zip(images, integrals, strict=True):
            integral_image(image, out=integral)
    counts = [len(k) for k in keypoints]
    cols, rows, inside = sample_corners(np.concatenate(keypoints), scale, half, integrals.shape[1:])
    plane = np.repeat(np.arange(len(images)), counts)[inside]  # which image each described keypoint is in
    if float(scale) == half and lattice_aligned(cols, rows, half):
        # in batches, so that the keypoint-last work arrays stay in the cache (twice the keypoints took 3× as long)
        sums = np.zeros((len(cols), DESCRIPTOR_SIZE), np.float32)
        for start in range(0, len(cols), LATTICE_BATCH):
            batch = slice(start, start + LATTICE_BATCH)
            responses = response_buffer(len(cols[batch]), buffers)
            lattice_haar_responses(integrals, cols[batch, 0], rows[batch, 0], half, responses, buffers, plane[batch])
            sums[batch] = pooled_sums(responses, scale)
    else:  # a non-integer scale: its samples are not on a lattice of the wavelet's half side
        responses = response_buffer(len(cols), buffers)
        for index, integral in enumerate(integrals):
            mine = plane == index
            if not mine.any():
                continue
            dx_img, dy_img = dense_haar_responses(integral, half, buffers)
            part = gather_haar_responses(dx_img, dy_img, cols[mine], rows[mine], response_buffer(mine.sum()),
                                         buffers)
            responses[..., mine] = part
        sums = pooled_sums(responses, scale)
    descriptors, described = normalised(sums, inside)
    out, keypoint_start, descriptor_start = [], 0, 0
    for count in counts:
        mine = described[keypoint_start:keypoint_start + count]
        described_here = int(np.count_nonzero(mine))
        out.append((descriptors[descriptor_start:descriptor_start + described_here], mine))
        keypoint_start, descriptor_start = keypoint_start + count, descriptor_start + described_here
    return out


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


def response_buffer(m: int, buffers: ScratchBuffers | None = None) -> np.ndarray:
    """(20, 4, 20, M) float32: [sample row, value, sample column, keypoint] for dx, dy, |dx|, |dy|.

    Keypoints run along the last, contiguous axis, so every step below is a long contiguous vector operation;
    the sample row leads so that pooling starts with one matrix product over it.
    """
    return scratch(buffers, "usurf_responses", (SAMPLES_PER_AXIS, 4, SAMPLES_PER_AXIS, m), np.float32)


@functools.lru_cache(maxsize=8)
def _lattice_offsets(step: int, row_stride: int) -> np.ndarray:
    """(22, 22, 1) flat offsets of a lattice ``step`` apart in an array of ``row_stride`` columns."""
    steps = step * np.arange(SAMPLES_PER_AXIS + 2)
    offsets = (steps[:, None] * row_stride + steps[None, :])[:, :, None]
    offsets.setflags(write=False)
    return offsets


def lattice_haar_responses(integral: np.ndarray, col0: np.ndarray, row0: np.ndarray, half: int,
                           out: np.ndarray, buffers: ScratchBuffers | None = None,
                           plane: np.ndarray | None = None) -> np.ndarray:
    """Haar responses of M keypoints' samples straight from the integral image, into ``out[:, 0]`` (dx) and
    ``out[:, 1]`` (dy) of ``response_buffer(M)``; returns out.

    With an integer scale s the samples are s px apart and the wavelets have half side s, so all the corners
    the 400 wavelets of one keypoint need lie on one 22 × 22 lattice of integral entries s apart (starting at
    (row0, col0), the first wavelet's top-left corner): 484 look-ups per keypoint instead of dense responses
    over the whole image. The sums are integers, so the values equal ``dense_haar_responses``' exactly.
    integral: (H + 1, W + 1), or (P, H + 1, W + 1) integrals of P images with ``plane`` (M,) saying which one
    each keypoint is in.
    """
    n, k, m = SAMPLES_PER_AXIS + 2, SAMPLES_PER_AXIS, len(col0)
    row_stride = integral.shape[-1]
    base = row0 * row_stride + col0
    if plane is not None:
        base += plane * (integral.shape[-2] * row_stride)
    flat = scratch(buffers, "usurf_lattice_index", (n, n, m), np.intp)
    np.add(_lattice_offsets(half, row_stride), base, out=flat)
    # every index is inside (sample_corners checked the windows), so skip take's bounds check
    corners = np.take(integral, flat, out=scratch(buffers, "usurf_lattice", (n, n, m), integral.dtype), mode="clip")

    def work(name: str, shape: tuple[int, int, int]) -> np.ndarray:
        return scratch(buffers, "usurf_" + name, shape, integral.dtype)

    second = work("second_difference", (k, k, m))

    # dx: strips 2·half high (20, 22, M), then right - 2·middle + left = the second difference along columns
    strips = np.subtract(corners[2:], corners[:k], out=work("strips", (k, n, m)))
    steps = np.subtract(strips[:, 1:], strips[:, :-1], out=work("steps", (k, n - 1, m)))
    np.copyto(out[:, 0], np.subtract(steps[:, 1:], steps[:, :-1], out=second), casting="unsafe")
    # dy: strips 2·half wide (22, 20, M), bottom - 2·middle + top
    strips = np.subtract(corners[:, 2:], corners[:, :k], out=work("strips", (n, k, m)))  # same blocks as dx's
    steps = np.subtract(strips[1:], strips[:-1], out=work("steps", (n - 1, k, m)))
    np.copyto(out[:, 1], np.subtract(steps[1:], steps[:-1], out=second), casting="unsafe")
    return out


def gather_haar_responses(dx_img: np.ndarray, dy_img: np.ndarray, cols: np.ndarray, rows: np.ndarray,
                          out: np.ndarray, buffers: ScratchBuffers | None = None) -> np.ndarray:
    """Dense responses (see ``dense_haar_responses``) read at the samples (cols, rows (M, 20)) into ``out[:, 0]``
    (dx) and ``out[:, 1]`` (dy) of ``response_buffer(M)``; returns out."""
    m = len(cols)
    flat = scratch(buffers, "usurf_flat", (SAMPLES_PER_AXIS, SAMPLES_PER_AXIS, m), np.intp)
    np.add((rows * dx_img.shape[1]).T[:, None, :], cols.T[None, :, :], out=flat)  # sample [row, col] -> index
    for channel, image in enumerate((dx_img, dy_img)):
        gathered = np.take(image, flat, out=scratch(buffers, "usurf_gathered", flat.shape, image.dtype))
        np.copyto(out[:, channel], gathered, casting="unsafe")
    return out


@functools.lru_cache(maxsize=8)
def subregion_weights(scale: float) -> np.ndarray:
    """(4, 20) float32: row i holds the ``axis_weights`` of the 5 samples of subregion i along one axis, 0 elsewhere.

    The weight of sample (a, b) in subregion (i, j) is weights[i, a]·weights[j, b]: pooling is separable.
    """
    g = axis_weights(scale)
    weights = np.zeros((SUBREGIONS, SAMPLES_PER_AXIS), np.float32)
    samples = SAMPLES_PER_AXIS // SUBREGIONS
    for i in range(SUBREGIONS):
        weights[i, i * samples:(i + 1) * samples] = g[i * samples:(i + 1) * samples]
    weights.setflags(write=False)
    return weights


def pooled_sums(responses: np.ndarray, scale: float) -> np.ndarray:
    """Gaussian-weighted subregion sums (M, 64) float32 of the samples' responses.

    responses: (20, 4, 20, M) from ``response_buffer`` with dx, dy filled in (|dx|, |dy| are written here).
    Row-major subregions (i, j), each (Σdx, Σdy, Σ|dx|, Σ|dy|). The weights are separable, so the sums are two
    small matrix products (over sample rows, then columns) rather than one (400, 16) matrix of 15/16 zeros.
    """
    k, m = SAMPLES_PER_AXIS, responses.shape[3]
    np.abs(responses[:, :2], out=responses[:, 2:])  # the weights are positive, so Σ w·|dx| = Σ |w·dx|
    weights = subregion_weights(float(scale))
    rows_pooled = weights @ responses.reshape(k, -1)  # (4 i, 4 values · 20 columns · M)
    by_column = np.ascontiguousarray(rows_pooled.reshape(SUBREGIONS * 4, k, m).transpose(1, 0, 2)).reshape(k, -1)
    sums = weights @ by_column  # (4 j, 4 i · 4 values · M)
    return sums.reshape(SUBREGIONS, SUBREGIONS, 4, m).transpose(3, 1, 0, 2).reshape(m, DESCRIPTOR_SIZE)


def normalised(sums: np.ndarray, inside: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit descriptors (K, 64) float32 of the sums (M, 64) of the keypoints ``inside`` (N,) bool marks, and
    described (N,): inside and not perfectly flat (a zero vector has no direction)."""
    norms = np.linalg.norm(sums, axis=1)
    textured = norms > 0
    described = inside.copy()
    described[inside] = textured
    return (sums[textured] / norms[textured, None]).astype(np.float32), described


def pool_descriptors(responses: np.ndarray, inside: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """``normalised(pooled_sums(responses, scale), inside)``: (descriptors (K, 64) float32, described (N,))."""
    return normalised(pooled_sums(responses, scale), inside)


def usurf_from_haar(dx_img: np.ndarray, dy_img: np.ndarray, keypoints: np.ndarray, scale: float,
                    half: int, buffers: ScratchBuffers | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The descriptor core on precomputed dense Haar responses (see ``dense_haar_responses``)."""
    integral_shape = (dx_img.shape[0] + 2 * half, dx_img.shape[1] + 2 * half)
    cols, rows, inside = sample_corners(np.asarray(keypoints, np.float64).reshape(-1, 2), scale, half, integral_shape)
    responses = gather_haar_responses(dx_img, dy_img, cols, rows, response_buffer(len(cols), buffers), buffers)
    return pool_descriptors(responses, inside, scale)
