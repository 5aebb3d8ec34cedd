"""Measures of the front end's quality against ground truth (pure functions; the scripts in
``benchmarks/`` and the tests share them).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .. import chi2


@dataclass(frozen=True)
class DisparityScore:
    """Sparse disparities against a ground-truth map: n with known truth, share within 1 px, median |error|."""

    evaluated: int
    within_1px: float
    median_error: float

    def as_dict(self) -> dict:
        return {"evaluated": self.evaluated, "within_1px": self.within_1px, "median_error_px": self.median_error}


def truth_at(pixels: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Ground-truth disparity (N,) at the nearest integer pixel of each (u, v) in pixels (N, 2); NaN off the map."""
    pixels = np.asarray(pixels, dtype=float).reshape(-1, 2)
    cols = np.rint(pixels[:, 0]).astype(np.int64)
    rows = np.rint(pixels[:, 1]).astype(np.int64)
    inside = (rows >= 0) & (rows < truth.shape[0]) & (cols >= 0) & (cols < truth.shape[1])
    out = np.full(len(pixels), np.nan)
    out[inside] = truth[rows[inside], cols[inside]]
    return out


def score_disparities(pixels: np.ndarray, disparities: np.ndarray, truth: np.ndarray,
                      unknown: float = 0.0) -> DisparityScore:
    """Score disparities (N,) at pixels (N, 2) against a truth map (H, W) in px where ``unknown`` marks no truth."""
    reference = truth_at(pixels, truth)
    known = np.isfinite(reference) & (reference != unknown) & np.isfinite(disparities)
    errors = np.abs(np.asarray(disparities, dtype=float)[known] - reference[known])
    if len(errors) == 0:
        return DisparityScore(0, float("nan"), float("nan"))
    return DisparityScore(int(len(errors)), float(np.mean(errors <= 1.0)), float(np.median(errors)))


def middlebury_truth(disp_pgm: np.ndarray, scale: float = 4.0) -> np.ndarray:
    """Middlebury 2003 ground truth (stored as disparity × scale, 0 = unknown) -> disparity px (H, W), 0 unknown."""
    return np.asarray(disp_pgm, dtype=np.float64) / scale


def sgbm_disparity(left: np.ndarray, right: np.ndarray, max_disparity: int = 64, block_size: int = 5) -> np.ndarray:
    """OpenCV StereoSGBM dense disparity (H, W) px of a rectified grey pair; NaN where it gives none."""
    num = int(np.ceil(max_disparity / 16.0)) * 16
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=num, blockSize=block_size,
                                 P1=8 * block_size**2, P2=32 * block_size**2, uniquenessRatio=10,
                                 speckleWindowSize=100, speckleRange=2, disp12MaxDiff=1,
                                 mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    fixed = sgbm.compute(left, right).astype(np.float64) / 16.0  # StereoSGBM returns disparity × 16
    fixed[fixed < 0] = np.nan
    return fixed


def nees(errors: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """Normalised estimation error squared eᵀ C⁻¹ e of each error (N, 3) with covariance (N, 3, 3) -> (N,)."""
    errors = np.asarray(errors, dtype=float)
    solved = np.linalg.solve(covariances, errors[..., None])[..., 0]
    return np.einsum("ni,ni->n", errors, solved)


def chi2_interval(dof: int = 3, probability: float = 0.95) -> tuple[float, float]:
    """Two-sided chi-square bounds that hold a single NEES value with the given probability."""
    tail = (1.0 - probability) / 2.0
    return float(chi2.ppf(tail, dof)), float(chi2.ppf(1.0 - tail, dof))
