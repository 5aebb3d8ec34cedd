"""First-order covariance propagation through the planar pose operations of ``estimation.geometry``."""
from __future__ import annotations

import numpy as np

from estimation.geometry import compose, inverse


def inverse_with_covariance(pose, covariance) -> tuple[np.ndarray, np.ndarray]:
    """⊖pose and its covariance J Σ Jᵀ, J = ∂(⊖pose)/∂pose.  pose (3,), covariance (3, 3)."""
    x, y, theta = np.asarray(pose, float)
    c, s = np.cos(theta), np.sin(theta)
    J = np.array([[-c, -s, s * x - c * y],
                  [s, -c, c * x + s * y],
                  [0.0, 0.0, -1.0]])
    return inverse(pose), J @ np.asarray(covariance, float) @ J.T


def compose_with_covariance(a, cov_a, b, cov_b) -> tuple[np.ndarray, np.ndarray]:
    """a ⊕ b and its covariance for independent a, b.  a, b (3,), cov_a, cov_b (3, 3)."""
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    c, s = np.cos(a[2]), np.sin(a[2])
    J_a = np.array([[1.0, 0.0, -s * b[0] - c * b[1]],
                    [0.0, 1.0, c * b[0] - s * b[1]],
                    [0.0, 0.0, 1.0]])
    J_b = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return compose(a, b), J_a @ np.asarray(cov_a, float) @ J_a.T + J_b @ np.asarray(cov_b, float) @ J_b.T


def point_jacobians(pose, points) -> np.ndarray:
    """∂(R(θ) p + t)/∂(tx, ty, θ) for points p (N, 3) given in the frame of ``pose`` -> (N, 3, 3)."""
    theta = float(np.asarray(pose, float)[2])
    c, s = np.cos(theta), np.sin(theta)
    points = np.asarray(points, float).reshape(-1, 3)
    rx = c * points[:, 0] - s * points[:, 1]
    ry = s * points[:, 0] + c * points[:, 1]
    J = np.zeros((len(points), 3, 3))
    J[:, 0, 0] = 1.0
    J[:, 1, 1] = 1.0
    J[:, 0, 2] = -ry
    J[:, 1, 2] = rx
    return J
