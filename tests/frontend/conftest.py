"""Shared fixtures of the front-end tests: the real stereo pairs (skipped when absent) and synthetic texture."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "stereo"


def read_pair(folder: str, left: str, right: str) -> tuple[np.ndarray, np.ndarray]:
    paths = [DATA / folder / left, DATA / folder / right]
    if not all(p.is_file() for p in paths):
        pytest.skip(f"real stereo data absent: {paths[0].parent} (see ../shared/data/README.md)")
    return tuple(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in paths)


@pytest.fixture(scope="session")
def cones():
    """(left, right, truth disparity px with 0 = unknown) of Middlebury cones."""
    left, right = read_pair("middlebury-cones", "im2.png", "im6.png")
    truth = cv2.imread(str(DATA / "middlebury-cones" / "disp2.pgm"), cv2.IMREAD_UNCHANGED)
    if truth is None:
        pytest.skip("real stereo data absent: middlebury-cones/disp2.pgm")
    return left, right, truth.astype(np.float64) / 4.0


@pytest.fixture(scope="session")
def tsukuba():
    return read_pair("tsukuba", "tsukuba_l.png", "tsukuba_r.png")


def texture(shape: tuple[int, int], seed: int, blur: float = 1.5) -> np.ndarray:
    """Smoothed random texture (H, W) float64 in 0..255: corners everywhere, unambiguous matches."""
    rng = np.random.default_rng(seed)
    noise = rng.uniform(0, 255, shape)
    smooth = cv2.GaussianBlur(noise, (0, 0), blur)
    smooth = (smooth - smooth.min()) / (smooth.max() - smooth.min())
    return smooth * 235 + 10


def shifted_pair(shape: tuple[int, int], disparity: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A rectified uint8 pair of one fronto-parallel textured plane: right(u) = left(u + disparity)."""
    big = texture((shape[0], shape[1] + 64), seed)
    warp = np.float32([[1, 0, disparity], [0, 1, 0]])
    right = cv2.warpAffine(big, warp, (big.shape[1], big.shape[0]), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP)
    return (np.clip(np.rint(big[:, :shape[1]]), 0, 255).astype(np.uint8),
            np.clip(np.rint(right[:, :shape[1]]), 0, 255).astype(np.uint8))
