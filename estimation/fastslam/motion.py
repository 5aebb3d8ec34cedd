"""Odometry motion model: sampling (FastSLAM 1.0) and covariance propagation (FastSLAM 2.0)."""
from __future__ import annotations

import numpy as np

from ..geometry import compose, rot_z
from .config import FastSLAMConfig

TURN_CURVATURE_RAD_PER_M = 2.0   # an increment turning this much per metre (or more) is part of a turn
TURN_MIN_TRAVEL_M = 0.005        # ... if it moves at all: a spin on the spot has no forward travel to be wrong


def turning(delta: np.ndarray) -> np.ndarray:
    """(...,) bool: the increments (..., 3) that are part of a turn (an arc of ≥ TURN_CURVATURE_RAD_PER_M)."""
    delta = np.asarray(delta, float)
    trans = np.hypot(delta[..., 0], delta[..., 1])
    return (trans > TURN_MIN_TRAVEL_M) & (np.abs(delta[..., 2]) >= TURN_CURVATURE_RAD_PER_M * trans)


def turn_spans(mask: np.ndarray, min_increments: int) -> list[tuple[int, int]]:
    """(start, stop) of each run of ≥ ``min_increments`` consecutive True in ``mask`` (T,): the whole turns."""
    edges = np.flatnonzero(np.diff(np.r_[0, np.asarray(mask, int), 0]))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True) if b - a >= min_increments]


def increment_variance(delta: np.ndarray, config: FastSLAMConfig) -> np.ndarray:
    """Variances (..., 3) of (dx, dy, dθ) for odometry increments ``delta`` (..., 3) (random-walk model).

    ``config.odom_turn_xy_inflation`` multiplies the x/y variance of the increments of a turn (:func:`turning`):
    where a robot's forward travel in turns is wrong by an error that persists through the turn (MRCLAM's Creates
    cover 0.65-0.70 of the commanded distance in arcs), increments taken as independent understate it by the
    factor that the noise model fits as the turns' overdispersion (``estimate_noise(turn_variance=True)``), just as
    correlated sightings' variances are inflated (``RangeBearingNoise.variance_inflation``).
    """
    delta = np.asarray(delta, float)
    trans = np.hypot(delta[..., 0], delta[..., 1])
    var_xy = config.odom_xy_var_per_m * trans + config.odom_var_floor
    if config.odom_turn_xy_inflation != 1.0:
        var_xy = np.where(turning(delta), var_xy * config.odom_turn_xy_inflation, var_xy)
    var_theta = (config.odom_theta_var_per_rad * np.abs(delta[..., 2]) + config.odom_theta_var_per_m * trans
                 + config.odom_var_floor)
    return np.stack([var_xy, var_xy, var_theta], axis=-1)


def sample_motion(poses: np.ndarray, delta: np.ndarray, variance: np.ndarray,
                  rng: np.random.Generator) -> np.ndarray:
    """Poses (M, 3) each moved by its own noisy copy of ``delta`` (3,) drawn with ``variance`` (3,)."""
    noisy = delta + rng.standard_normal(poses.shape) * np.sqrt(variance)
    return compose(poses, noisy)


def propagate_covariance(poses: np.ndarray, cov: np.ndarray, delta: np.ndarray,
                         variance: np.ndarray) -> np.ndarray:
    """P ← J_a P J_aᵀ + J_b diag(variance) J_bᵀ for the composition poses ⊕ delta.

    poses (M, 3) before the motion, cov (M, 3, 3) -> (M, 3, 3); J_a, J_b the Jacobians of ⊕ by its arguments.
    """
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    ja = np.tile(np.eye(3), (len(poses), 1, 1))
    ja[:, 0, 2] = -s * delta[0] - c * delta[1]
    ja[:, 1, 2] = c * delta[0] - s * delta[1]
    jb = rot_z(poses[:, 2])
    return ja @ cov @ np.swapaxes(ja, 1, 2) + (jb * variance) @ np.swapaxes(jb, 1, 2)
