"""The descriptor is a setting: U-SURF (ours), or OpenCV's SIFT or ORB at the same keypoints for comparison.

Every kind returns float32 rows so that one distance routine serves all: U-SURF and SIFT as unit vectors
compared by Euclidean distance; ORB as its 256 bits unpacked to 0/1, compared by Hamming distance (which
equals the squared Euclidean distance between bit vectors).
"""
from __future__ import annotations

from enum import StrEnum

import cv2
import numpy as np

from estimation.frontend.buffers import ScratchBuffers
from estimation.frontend.errors import FrontEndError
from estimation.frontend.usurf import usurf_descriptors, usurf_descriptors_of_images


class DescriptorKind(StrEnum):
    USURF = "usurf"
    SIFT = "sift"
    ORB = "orb"

    @property
    def is_binary(self) -> bool:
        return self is DescriptorKind.ORB


def descriptor_kind(kind: DescriptorKind | str) -> DescriptorKind:
    """The kind named by ``kind``; FrontEndError naming the choices otherwise."""
    try:
        return DescriptorKind(kind)
    except ValueError:
        raise FrontEndError(f"unknown descriptor {kind!r}; choose one of "
                            f"{', '.join(k.value for k in DescriptorKind)}") from None


def describe(image: np.ndarray, keypoints: np.ndarray, kind: DescriptorKind | str = DescriptorKind.USURF,
             scale: float = 2.0, buffers: ScratchBuffers | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Descriptors of keypoints (N, 2) (u, v) in a grey uint8 image (H, W).

    scale: the U-SURF s; SIFT gets a descriptor window of the same 20s side (OpenCV's SIFT window is 6 × the
    keypoint size), ORB its fixed 31 px patch. All upright (angle 0), like U-SURF.
    Returns (descriptors (M, D) float32, described (N,) bool); keypoints too near the border are dropped.
    """
    kind = descriptor_kind(kind)
    keypoints = np.asarray(keypoints, dtype=np.float64).reshape(-1, 2)
    if kind is DescriptorKind.USURF:
        return usurf_descriptors(image, keypoints, scale, buffers)
    if len(keypoints) == 0:
        size = 128 if kind is DescriptorKind.SIFT else 256
        return np.zeros((0, size), np.float32), np.zeros(0, bool)
    image = np.asarray(image)
    if image.dtype != np.uint8:
        raise FrontEndError(f"OpenCV {kind.value} needs an 8-bit image, got {image.dtype}")
    # class_id carries each keypoint's index through OpenCV, which may drop some (ORB near the border)
    size = 20.0 * scale / 6.0 if kind is DescriptorKind.SIFT else 31.0
    cv_keypoints = [cv2.KeyPoint(float(u), float(v), size, 0.0, 0, 0, i) for i, (u, v) in enumerate(keypoints)]
    extractor = cv2.SIFT_create() if kind is DescriptorKind.SIFT else cv2.ORB_create(edgeThreshold=31, patchSize=31)
    kept, descriptors = extractor.compute(image, cv_keypoints)
    described = np.zeros(len(keypoints), bool)
    if descriptors is None or len(kept) == 0:
        size = 128 if kind is DescriptorKind.SIFT else 256
        return np.zeros((0, size), np.float32), described
    index = np.array([k.class_id for k in kept])
    order = np.argsort(index)
    index, descriptors = index[order], descriptors[order]
    described[index] = True
    if kind is DescriptorKind.ORB:
        return np.unpackbits(descriptors, axis=1).astype(np.float32), described
    descriptors = descriptors.astype(np.float32)
    norms = np.linalg.norm(descriptors, axis=1, keepdims=True)
    return descriptors / np.maximum(norms, 1e-12), described


def describe_pair(left: np.ndarray, left_keypoints: np.ndarray, right: np.ndarray, right_keypoints: np.ndarray,
                  kind: DescriptorKind | str = DescriptorKind.USURF, scale: float = 2.0,
                  buffers: ScratchBuffers | None = None) -> tuple[tuple[np.ndarray, np.ndarray],
                                                                  tuple[np.ndarray, np.ndarray]]:
    """``describe`` of both images of a stereo pair: ((left descriptors, described), (right ...)).

    U-SURF describes both in one batch (one gather and one pooling); the others one image at a time.
    """
    if descriptor_kind(kind) is DescriptorKind.USURF:
        left_out, right_out = usurf_descriptors_of_images([left, right], [left_keypoints, right_keypoints], scale,
                                                          buffers)
        return left_out, right_out
    return describe(left, left_keypoints, kind, scale, buffers), describe(right, right_keypoints, kind, scale, buffers)


def distance_matrix(a: np.ndarray, b: np.ndarray, binary: bool = False, out: np.ndarray | None = None) -> np.ndarray:
    """Pairwise distances (N, M) float32 between descriptor rows a (N, D) and b (M, D), into ``out`` if given.

    Euclidean for real-valued descriptors; Hamming for 0/1 bit vectors (``binary``).
    """
    a = np.asarray(a, dtype=np.float32)
    b = np.asarray(b, dtype=np.float32)
    # |a - b|² = |a|² + |b|² - 2 a·b, which for bits is the Hamming distance
    squared = np.matmul(a, b.T, out=out)
    squared *= -2.0
    squared += (a * a).sum(axis=1)[:, None]
    squared += (b * b).sum(axis=1)[None, :]
    np.maximum(squared, 0.0, out=squared)
    return squared if binary else np.sqrt(squared, out=squared)
