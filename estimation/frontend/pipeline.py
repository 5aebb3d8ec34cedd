"""One stereo frame in, one observation set out: detect, describe, match, refine, triangulate.

``run_frontend`` is the pure functional core (arrays in, ``StereoMatches`` out); ``FrontEnd`` holds the
configuration (and optional rectification maps) and turns each pair into the ``StereoObservations`` that
FastSLAM consumes.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import cv2
import numpy as np

from estimation.frontend.buffers import ScratchBuffers, scratch
from estimation.frontend.caching import once_per_value
from estimation.frontend.descriptors import DescriptorKind, describe_pair, descriptor_kind
from estimation.frontend.errors import FrontEndError
from estimation.frontend.harris import HarrisConfig, detect_corners
from estimation.frontend.stereo import StereoMatchConfig, match_rows, refine_disparity_ssd, with_candidates
from estimation.frontend.triangulation import (
    StereoGeometry,
    TriangulationNoise,
    camera_to_base,
    keep_triangulable,
    triangulate,
    triangulation_covariances,
)
from estimation.frontend.usurf import haar_half_size
from estimation.observations import StereoObservations


@dataclass(frozen=True)
class FrontEndConfig:
    """Everything the front end needs; ``to_dict()`` dumps it (e.g. to JSON next to a run's output).

    descriptor: "usurf" (default, 64-D), "sift" (128-D) or "orb" (256 bits as 0/1 floats, Hamming distance)
    scale:      the fixed U-SURF scale s, px (window 20s); SIFT/ORB patches get the same side
    """

    harris: HarrisConfig = field(default_factory=HarrisConfig)
    descriptor: DescriptorKind = DescriptorKind.USURF
    scale: float = 2.0
    matching: StereoMatchConfig = field(default_factory=StereoMatchConfig)
    geometry: StereoGeometry = field(default_factory=StereoGeometry)
    noise: TriangulationNoise = field(default_factory=TriangulationNoise)

    def __post_init__(self) -> None:
        object.__setattr__(self, "descriptor", descriptor_kind(self.descriptor))
        if self.scale <= 0:
            raise FrontEndError(f"scale must be positive, got {self.scale}")

    def to_dict(self) -> dict:
        out = dataclasses.asdict(self)
        out["descriptor"] = self.descriptor.value
        return out


@dataclass(frozen=True)
class RectificationMaps:
    """Per-camera ``cv2.remap`` tables from rectified to raw pixels: (map1, map2) as float32 x and y (H, W), or
    OpenCV's fixed-point pair (CV_16SC2, CV_16UC1) from ``cv2.initUndistortRectifyMap``."""

    left_map1: np.ndarray
    left_map2: np.ndarray
    right_map1: np.ndarray
    right_map2: np.ndarray


@dataclass(frozen=True)
class StereoMatches:
    """Every stereo match of one rectified pair that survived triangulation's limits (K matches).

    left_pixels, right_pixels: (K, 2) (u, v) px;  disparities: (K,) px
    points_camera, covariances_camera: (K, 3), (K, 3, 3) in the left optical frame (m, m²)
    points_base, covariances_base: the same in base_link
    descriptors: (K, D) float32 of the left corners;  descriptor_distances: (K,)
    beyond_range: with ``StereoMatchConfig(search="full_row")``, the matches (found along the whole row, refined,
                  triangulable) refused because their disparity is beyond max_disparity, not among the K; 0 under
                  "window"
    near_scene:   the frame was dropped as nearer than the head can measure (beyond_range more than
                  ``near_scene_share`` of all its matches): K = 0, and the filter only predicts
    """

    left_pixels: np.ndarray
    right_pixels: np.ndarray
    disparities: np.ndarray
    points_camera: np.ndarray
    covariances_camera: np.ndarray
    points_base: np.ndarray
    covariances_base: np.ndarray
    descriptors: np.ndarray
    descriptor_distances: np.ndarray
    beyond_range: int = 0
    near_scene: bool = False

    def __len__(self) -> int:
        return len(self.disparities)

    def to_observations(self, timestamp: float) -> StereoObservations:
        return StereoObservations(self.points_base, self.covariances_base, self.descriptors,
                                  self.left_pixels, float(timestamp))


def rectify_pair(left: np.ndarray, right: np.ndarray, maps: RectificationMaps,
                 buffers: ScratchBuffers | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Remap a raw pair to the rectified geometry (bilinear); the maps' (H, W) is the output size."""
    out = []
    for name, image, map1, map2 in (("left", left, maps.left_map1, maps.left_map2),
                                    ("right", right, maps.right_map1, maps.right_map2)):
        image = np.asarray(image)
        dst = scratch(buffers, "rectified_" + name, map1.shape[:2] + image.shape[2:], image.dtype)
        out.append(cv2.remap(image, map1, map2, cv2.INTER_LINEAR, dst=dst))
    return out[0], out[1]


def _grey(image: np.ndarray, name: str) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim == 3 and image.shape[2] == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if image.ndim != 2:
        raise FrontEndError(f"{name} image must be grey (H, W) or BGR (H, W, 3), got shape {image.shape}")
    if image.dtype != np.uint8:
        if not np.issubdtype(image.dtype, np.number):
            raise FrontEndError(f"{name} image has non-numeric dtype {image.dtype}")
        image = np.clip(np.rint(image), 0, 255).astype(np.uint8)
    return image


def detection_margin(config: FrontEndConfig) -> int:
    """Border (px) inside which a corner can be described: the 20s window plus the Haar half side."""
    return max(config.harris.margin, int(np.ceil(10.0 * config.scale)) + haar_half_size(config.scale) + 1)


@once_per_value
def _detection_settings(config: FrontEndConfig) -> HarrisConfig:
    """The Harris settings with the margin raised to where a descriptor window fits (once per configuration)."""
    return dataclasses.replace(config.harris, margin=detection_margin(config))


def run_frontend(left: np.ndarray, right: np.ndarray, config: FrontEndConfig = FrontEndConfig(),
                 buffers: ScratchBuffers | None = None) -> StereoMatches:
    """The front end on a rectified pair of grey (H, W) images (uint8, or numbers rounded to 0..255).

    buffers: scratch arrays reused from frame to frame (``FrontEnd`` keeps one); None allocates afresh.
    """
    left, right = _grey(left, "left"), _grey(right, "right")
    if left.shape != right.shape:
        raise FrontEndError(f"left {left.shape} and right {right.shape} images differ in size")
    # 1. corners, kept where a descriptor window fits
    harris = _detection_settings(config)
    left_corners, _ = detect_corners(left, harris, buffers)
    right_corners, _ = detect_corners(right, harris, buffers)
    # 2. descriptors, of the corners that have a candidate on the other side (no other can be matched)
    left_candidate, right_candidate = with_candidates(left_corners, right_corners, config.matching)
    left_corners, right_corners = left_corners[left_candidate], right_corners[right_candidate]
    (left_desc, left_ok), (right_desc, right_ok) = describe_pair(left, left_corners, right, right_corners,
                                                                 config.descriptor, config.scale, buffers)
    left_corners, right_corners = left_corners[left_ok], right_corners[right_ok]
    # 3. row-constrained matching with ratio test and left-right check
    li, ri, dist = match_rows(left_corners, left_desc, right_corners, right_desc, config.matching,
                              binary=config.descriptor.is_binary, buffers=buffers)
    left_px = left_corners[li]
    disparity = left_px[:, 0] - right_corners[ri, 0]
    # 4. sub-pixel disparity
    if config.matching.subpixel == "ssd":
        disparity, _ = refine_disparity_ssd(left, right, left_px, disparity, config.matching.ssd_half_window)
    # 5. triangulation, dropping points too far away
    keep = keep_triangulable(disparity, config.geometry, config.noise)
    beyond_range, near_scene = 0, False
    if config.matching.search == "full_row":   # the range is a validity test: refuse (and count) what lies beyond
        beyond = keep & (disparity > config.matching.max_disparity)
        beyond_range = int(np.count_nonzero(beyond))
        keep &= ~beyond
        share = config.matching.near_scene_share
        if share is not None and beyond_range > share * (beyond_range + np.count_nonzero(keep)):
            keep[:], near_scene = False, True   # a scene nearer than the head can measure: no reading at all
    left_px, disparity, desc, dist = left_px[keep], disparity[keep], left_desc[li[keep]], dist[keep]
    points = triangulate(left_px, disparity, config.geometry)
    covariances = triangulation_covariances(left_px, disparity, config.geometry, config.noise)
    points_base, covariances_base = camera_to_base(points, covariances, config.geometry)
    right_px = np.stack([left_px[:, 0] - disparity, left_px[:, 1]], axis=1)
    return StereoMatches(left_px, right_px, disparity, points, covariances, points_base, covariances_base,
                         desc, dist, beyond_range, near_scene)


class FrontEnd:
    """The visual front end of one stereo head.

    ``FrontEnd(FrontEndConfig(geometry=StereoGeometry(fx=..., baseline=...)))``; ``process(left, right, t)``
    takes a rectified pair (or a raw pair when built with ``rectification`` maps) and returns the frame's
    ``StereoObservations`` in base_link. ``last_matches`` keeps the full detail of the last frame.
    """

    def __init__(self, config: FrontEndConfig = FrontEndConfig(), rectification: RectificationMaps | None = None):
        self.config = config
        self.rectification = rectification
        self.last_matches: StereoMatches | None = None
        self._buffers = ScratchBuffers()  # image-sized scratch arrays reused from frame to frame

    def match(self, left: np.ndarray, right: np.ndarray) -> StereoMatches:
        if self.rectification is not None:
            left, right = rectify_pair(left, right, self.rectification, self._buffers)
        self.last_matches = run_frontend(left, right, self.config, self._buffers)
        return self.last_matches

    def process(self, left: np.ndarray, right: np.ndarray, timestamp: float) -> StereoObservations:
        return self.match(left, right).to_observations(timestamp)
