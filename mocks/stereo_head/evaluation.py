"""Ground-truth checks of rendered stereo pairs (for tests and benchmarks)."""
from __future__ import annotations

import cv2
import numpy as np

from mocks.stereo_head.renderer import StereoRenderer


def project_rectified(renderer: StereoRenderer, pose: np.ndarray, points: np.ndarray, camera: str,
                      size: tuple[int, int] = (640, 480)) -> tuple[np.ndarray, np.ndarray]:
    """World points (N, 3) -> rectified pixels (N, 2) of ``camera`` and depth (N,) in the rectified left frame."""
    calib = renderer.calibration.scaled(*size)
    world_to_left = np.linalg.inv(renderer.camera_pose_world(pose, "left", size, rectified=True))
    p = points @ world_to_left[:3, :3].T + world_to_left[:3, 3]
    P = calib.P1 if camera == "left" else calib.P2
    h = np.column_stack([p, np.ones(len(p))]) @ P.T
    return h[:, :2] / h[:, 2:3], p[:, 2]


def window_alignment(renderer: StereoRenderer, pose: np.ndarray, left: np.ndarray, right: np.ndarray,
                     half: int = 16, step: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """Where each textured (2 half)^2 window of the rectified left image really is in the rectified right one.

    For every window without a depth edge, the true 3-D points (``true_points``) predict its disparity; phase
    correlation measures the remaining shift. Returns (vertical, horizontal) residuals in pixels, (M,) each:
    vertical is the epipolar error, horizontal the disparity error.
    """
    height, width = left.shape[:2]
    left, right = left.astype(np.float32), right.astype(np.float32)
    window = cv2.createHanningWindow((2 * half, 2 * half), cv2.CV_32F)
    offsets = np.array([[-half, -half], [half, -half], [-half, half], [half, half], [0, 0]], float)
    vertical, horizontal = [], []
    for vc in range(half + 24, height - half - 24, step):
        for uc in range(half + 24, width - half - 24, step):
            pixels = offsets + (uc, vc)
            points = renderer.true_points(pose, pixels, "left", (width, height), rectified=True)
            predicted, _ = project_rectified(renderer, pose, points, "right", (width, height))
            disparity = pixels[:, 0] - predicted[:, 0]
            if not np.all(np.isfinite(disparity)) or np.ptp(disparity) > 1.5:
                continue  # a depth edge inside the window
            patch = left[vc - half:vc + half, uc - half:uc + half]
            shift = int(round(disparity[-1]))
            if patch.std() < 8 or uc - shift - half < 0:
                continue
            target = right[vc - half:vc + half, uc - shift - half:uc - shift + half]
            (dx, dy), response = cv2.phaseCorrelate(patch, target, window)
            if response < 0.3:
                continue
            vertical.append(dy)
            horizontal.append(dx + (disparity[-1] - shift))
    return np.asarray(vertical), np.asarray(horizontal)
