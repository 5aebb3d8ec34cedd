"""Sparse stereo correspondence on a rectified pair: corners on the same row, matched by descriptor.

For each left corner the candidates are the right corners within ``row_tolerance`` px of its row and with
a disparity u_left - u_right of at least min_disparity anywhere along the row (``search="full_row"``, the default
since session 52: the front end then refuses a match beyond max_disparity, so the range is a validity test and not a
window that makes up a wrong match for a corner whose true one lies beyond it, e.g. a wall nearer than
fx·B / max_disparity), or only in [min_disparity, max_disparity] (``search="window"``, the default before). The
nearest candidate by descriptor distance
is kept if it passes the ratio test against the second nearest and the left-right check (the left corner
is also the nearest of that right corner's candidates). The disparity is then refined to sub-pixel by a
parabola through a zero-mean SSD profile along the row (or taken from the corners' sub-pixel u).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from estimation.frontend.buffers import ScratchBuffers, scratch
from estimation.frontend.descriptors import distance_matrix
from estimation.frontend.errors import FrontEndError

NEAR_SCENE_SHARE = 0.3   # a frame's refused share beyond it: a scene too near. Not fitted: on the rendered demo's
#                          3,900 frames the share is 0.33–0.80 in every frame that faces a wall nearer than the head
#                          measures and ≤ 0.22 in every other (0.2 drops the same frames); a textured surface too near
#                          gives it, whatever the renderer


@dataclass(frozen=True)
class StereoMatchConfig:
    """Settings of the matcher.

    row_tolerance:     |v_left - v_right| allowed, px (rectified pairs: ~1)
    min_disparity, max_disparity: search range of u_left - u_right, px
    ratio:             keep the best match only if best < ratio × second best distance
    max_distance:      and best ≤ this share of the largest possible descriptor distance (2 for unit vectors,
                       D for D-bit binary descriptors); None: no limit
    subpixel:          "ssd": parabola through a zero-mean SSD profile along the row; "corner": u_l - u_r
    ssd_half_window:   the SSD patch is (2·h + 1)² px
    search:            "full_row" (default): every disparity ≥ min_disparity is a candidate (the ratio test and
                       the left-right check see the whole row), and ``run_frontend`` refuses the matches beyond
                       max_disparity, counting them (``StereoMatches.beyond_range``); "window": candidates only within
                       [min_disparity, max_disparity] (the default before session 52)
    near_scene_share:  a frame whose refused matches are more than this share of all its matches gives no match
                       (``StereoMatches.near_scene``): the scene is nearer than the head can measure and its in-range
                       matches are mostly false too; None: no such rule. Under "window" nothing is refused, so it
                       never acts. Default NEAR_SCENE_SHARE.

    Session 52 (helper C's diagnosis, benchmarks/demo_frame_loss.py): on the rendered demo a robot turning on the spot
    0.3 m from a wall, nearer than fx·B / max_disparity = 0.487 m, got the window's best wrong match for every corner
    (0.63 m off, 97 % beyond χ²₃ 99 % of their covariance) and FastSLAM lost its heading (seed 4's robot 1). Over 20
    robots × 3 filter draws the whole-row search with the frame rule took the alarms 14 → 3 and the robots that stay
    lost 7 → 0; on the real pairs (Middlebury cones, tsukuba) it keeps the same matches, and where max_disparity is set
    below the scene's (cones at 48 px) it refuses 21–28 true near matches instead of keeping wrong ones (within 1 px
    83.0 → 84.5 %, U-SURF), at no extra front-end time (2.8–3.0 ms a 640 × 480 demo frame either way).
    """

    row_tolerance: float = 1.0
    min_disparity: float = 0.0
    max_disparity: float = 96.0
    ratio: float = 0.8
    max_distance: float | None = 0.25
    subpixel: str = "ssd"
    ssd_half_window: int = 3
    search: str = "full_row"
    near_scene_share: float | None = NEAR_SCENE_SHARE

    def __post_init__(self) -> None:
        if self.subpixel not in ("ssd", "corner"):
            raise FrontEndError(f"subpixel must be 'ssd' or 'corner', got {self.subpixel!r}")
        if not 0.0 < self.ratio <= 1.0:
            raise FrontEndError(f"ratio must be in (0, 1], got {self.ratio}")
        if self.max_disparity <= self.min_disparity:
            raise FrontEndError(f"empty disparity range [{self.min_disparity}, {self.max_disparity}]")
        if self.search not in ("window", "full_row"):
            raise FrontEndError(f"search must be 'window' or 'full_row', got {self.search!r}")
        if self.near_scene_share is not None:
            share = self.near_scene_share
            if isinstance(share, bool) or not isinstance(share, (int, float)) or not 0.0 <= share < 1.0:
                raise FrontEndError(f"near_scene_share must be in [0, 1) or None, got {self.near_scene_share!r}")


def admissible_pairs(left_pixels: np.ndarray, right_pixels: np.ndarray,
                     config: StereoMatchConfig = StereoMatchConfig(),
                     buffers: ScratchBuffers | None = None) -> np.ndarray:
    """(N, M) bool: right corner j is a candidate for left corner i (same row within the tolerance, disparity
    within range, or only ≥ min_disparity with ``search="full_row"``); left (N, 2) and right (M, 2) pixels (u, v),
    compared in float32."""
    n, m = len(left_pixels), len(right_pixels)
    left_px = np.asarray(left_pixels, np.float32)
    right_px = np.asarray(right_pixels, np.float32)
    work = scratch(buffers, "match_work", (n, m), np.float32)
    admissible = scratch(buffers, "match_admissible", (n, m), bool)
    test = scratch(buffers, "match_test", (n, m), bool)
    # disparity u_l - u_r within range
    np.subtract(left_px[:, 0:1], right_px[None, :, 0], out=work)
    np.greater_equal(work, config.min_disparity, out=admissible)
    if config.search == "window":
        admissible &= np.less_equal(work, config.max_disparity, out=test)
    # same row within tolerance
    np.subtract(left_px[:, 1:2], right_px[None, :, 1], out=work)
    admissible &= np.less_equal(np.abs(work, out=work), config.row_tolerance, out=test)
    return admissible


def with_candidates(left_pixels: np.ndarray, right_pixels: np.ndarray,
                    config: StereoMatchConfig = StereoMatchConfig()) -> tuple[np.ndarray, np.ndarray]:
    """Masks (N,), (M,) of the left and right corners that have at least one candidate on the other side.

    A corner without any can never be matched, and removing it changes no other corner's nearest, second
    nearest or left-right check (its row or column of the distance matrix is all excluded), so the front end
    describes only these: ``match_rows`` on the subsets gives the same matches.
    """
    admissible = admissible_pairs(left_pixels, right_pixels, config)
    return admissible.any(axis=1), admissible.any(axis=0)


def match_rows(left_pixels: np.ndarray, left_descriptors: np.ndarray, right_pixels: np.ndarray,
               right_descriptors: np.ndarray, config: StereoMatchConfig = StereoMatchConfig(),
               binary: bool = False,
               buffers: ScratchBuffers | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Descriptor matches between left corners (N, 2) and right corners (M, 2) of a rectified pair.

    Returns (left_index (K,), right_index (K,), distance (K,)). The (N, M) work arrays come from ``buffers``.
    """
    n, m = len(left_pixels), len(right_pixels)
    if n == 0 or m == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32)
    admissible = admissible_pairs(left_pixels, right_pixels, config, buffers)
    work = scratch(buffers, "match_work", (n, m), np.float32)
    test = scratch(buffers, "match_test", (n, m), bool)
    distance = distance_matrix(left_descriptors, right_descriptors, binary, out=work)
    np.logical_not(admissible, out=test)
    distance[test] = np.inf
    rows = np.arange(n)
    best_right = np.argmin(distance, axis=1)
    best = distance[rows, best_right]
    best_left_of_right = np.argmin(distance, axis=0)
    distance[rows, best_right] = np.inf  # the second best is the row minimum without the best
    second = distance.min(axis=1)
    keep = np.isfinite(best) & (best < config.ratio * second) & (best_left_of_right[best_right] == rows)
    if config.max_distance is not None:
        largest = left_descriptors.shape[1] if binary else 2.0
        keep &= best <= config.max_distance * largest
    return rows[keep], best_right[keep], best[keep]


@functools.lru_cache(maxsize=8)
def _patch_offsets(width: int, half_window: int) -> tuple[np.ndarray, np.ndarray]:
    """Flat offsets in an image ``width`` px wide of a (2h+1)² patch around a pixel, (W, W), and of the five right
    patches at disparity steps -2..2 from it, (5, W, W) (step s moves the patch s px left)."""
    window = np.arange(-half_window, half_window + 1)
    patch = window[:, None] * width + window[None, :]
    steps = np.arange(-2, 3)
    right = patch[None] - steps[:, None, None]
    patch.setflags(write=False)
    right.setflags(write=False)
    return patch, right


def refine_disparity_ssd(left: np.ndarray, right: np.ndarray, left_pixels: np.ndarray, disparities: np.ndarray,
                         half_window: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel disparities at the integer left pixels nearest ``left_pixels`` (K, 2).

    Evaluates the zero-mean SSD between (2h+1)² patches for the integer disparities round(d) - 2 .. round(d) + 2,
    takes the minimum among the middle three and the vertex of the parabola through it and its neighbours.
    Returns (disparity (K,) float64, refined (K,) bool); where the patch leaves the image or the profile has
    no interior minimum the input disparity is returned with refined = False.
    """
    left, right = np.asarray(left), np.asarray(right)  # patches are gathered first, then made float
    if left.shape != right.shape:
        raise FrontEndError(f"left {left.shape} and right {right.shape} images differ in size")
    k = len(left_pixels)
    result = np.asarray(disparities, dtype=np.float64).copy()
    refined = np.zeros(k, bool)
    if k == 0:
        return result, refined
    h = half_window
    x0 = np.rint(left_pixels[:, 0]).astype(np.int64)
    y0 = np.rint(left_pixels[:, 1]).astype(np.int64)
    d0 = np.rint(result).astype(np.int64)
    steps = np.arange(-2, 3)
    width = left.shape[1]
    inside = ((y0 - h >= 0) & (y0 + h < left.shape[0]) & (x0 - h >= 0) & (x0 + h < width)
              & (x0 - d0 - 2 - h >= 0) & (x0 - d0 + 2 + h < width))
    idx = np.flatnonzero(inside)
    if len(idx) == 0:
        return result, refined
    # patches as flat offsets from each match's pixel: one gather per image, (K, W, W) left, (K, 5, W, W) right
    left_offsets, right_offsets = _patch_offsets(width, h)
    left_patch = np.take(left.reshape(-1), (y0[idx] * width + x0[idx])[:, None, None] + left_offsets)
    right_patch = np.take(right.reshape(-1), (y0[idx] * width + x0[idx] - d0[idx])[:, None, None, None] + right_offsets)
    left_patch, right_patch = left_patch.astype(np.float32), right_patch.astype(np.float32)
    left_patch = left_patch - left_patch.mean(axis=(1, 2), keepdims=True)
    right_patch = right_patch - right_patch.mean(axis=(2, 3), keepdims=True)
    cost = ((right_patch - left_patch[:, None]) ** 2).sum(axis=(2, 3))  # (K, 5) over steps -2..2
    b = 1 + np.argmin(cost[:, 1:4], axis=1)
    j = np.arange(len(idx))
    before, centre, after = cost[j, b - 1], cost[j, b], cost[j, b + 1]
    curvature = before - 2.0 * centre + after
    good = curvature > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        vertex = np.where(good, 0.5 * (before - after) / curvature, 0.0)
    result[idx[good]] = d0[idx[good]] + steps[b[good]] + np.clip(vertex[good], -0.5, 0.5)
    refined[idx[good]] = True
    return result, refined
