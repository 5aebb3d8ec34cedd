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


def increment_variance(delta: np.ndarray, config: FastSLAMConfig, seconds=None) -> np.ndarray:
    """Variances (..., 3) of (dx, dy, dθ) for odometry increments ``delta`` (..., 3) (random-walk model).

    ``seconds`` (...,) (or a scalar): each increment's duration, which ``config.odom_theta_var_per_s`` multiplies
    (a heading that wanders with time, the robot moving or not: bumps, pushes, slip; the noise model fits it,
    ``estimate_noise(time_variance=True)``). Needed when that term is non-zero (a ValueError without it: dropping it
    would make a stopped increment as certain as before); ignored when it is 0.

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
    per_s = config.odom_theta_var_per_s
    if per_s != 0.0:
        if seconds is None:
            raise ValueError("increment_variance: odom_theta_var_per_s is set, so each increment's duration "
                             "(seconds) is needed")
        seconds = np.asarray(seconds, float)
        if np.any(~np.isfinite(seconds)) or np.any(seconds < 0):
            raise ValueError("increment_variance: increments' durations must be finite and ≥ 0")
        var_theta = var_theta + per_s * seconds
    return np.stack([var_xy, var_xy, var_theta], axis=-1)


def sample_motion(poses: np.ndarray, delta: np.ndarray, variance: np.ndarray,
                  rng: np.random.Generator) -> np.ndarray:
    """Poses (M, 3) each moved by its own noisy copy of ``delta`` (3,) (or its own delta, (M, 3)) drawn with
    ``variance`` (3,)."""
    noisy = delta + rng.standard_normal(poses.shape) * np.sqrt(variance)
    return compose(poses, noisy)


def motion_jacobians(poses: np.ndarray, delta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """J_a, J_b (M, 3, 3): the Jacobians of the composition poses ⊕ delta by the poses (M, 3) and by ``delta`` (3,)."""
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    # the identity filled in, not tiled: the filter builds these twice a frame, for 1 and for M poses
    ja = np.zeros((len(poses), 3, 3))
    ja[:, 0, 0] = ja[:, 1, 1] = ja[:, 2, 2] = 1.0
    ja[:, 0, 2] = -s * delta[0] - c * delta[1]
    ja[:, 1, 2] = c * delta[0] - s * delta[1]
    return ja, rot_z(poses[:, 2])


def propagate_covariance(poses: np.ndarray, cov: np.ndarray, delta: np.ndarray,
                         variance: np.ndarray) -> np.ndarray:
    """P ← J_a P J_aᵀ + J_b diag(variance) J_bᵀ for the composition poses ⊕ delta.

    poses (M, 3) before the motion, cov (M, 3, 3) -> (M, 3, 3); J_a, J_b the Jacobians of ⊕ by its arguments
    (:func:`motion_jacobians`).
    """
    return _propagated(*motion_jacobians(poses, delta), cov, variance)


def _propagated(ja: np.ndarray, jb: np.ndarray, cov: np.ndarray, variance: np.ndarray) -> np.ndarray:
    return ja @ cov @ np.swapaxes(ja, 1, 2) + (jb * variance) @ np.swapaxes(jb, 1, 2)


# -- a drifting heading bias per metre (docs/fastslam.md "Noise models"; history: Session 23 (D)) ----------------
def heading_drift_decay(dt: float, tau: float) -> float:
    """e^(−Δt/τ): how much of a Gauss–Markov heading bias survives ``dt`` seconds (a negative Δt counts as 0)."""
    return float(np.exp(-max(float(dt), 0.0) / tau))


def walk_heading_bias(bias: np.ndarray, decay: float, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """b ← e^(−Δt/τ) b + σ_b √(1 − e^(−2Δt/τ)) ε per particle (M,): the first-order Gauss–Markov process whose
    stationary standard deviation is σ_b (``decay`` = :func:`heading_drift_decay`). Draws M normals."""
    return decay * bias + sigma * np.sqrt(1.0 - decay * decay) * rng.standard_normal(bias.shape)


def with_heading_bias(delta: np.ndarray, bias: np.ndarray) -> np.ndarray:
    """(M, 3) the increment ``delta`` (3,) of each particle, its heading turned by that particle's bias (M,) rad per
    metre times the increment's distance (its chord, as the noise model's heading bias per metre)."""
    out = np.tile(np.asarray(delta, float), (len(bias), 1))
    out[:, 2] += bias * float(np.hypot(delta[0], delta[1]))
    return out


def propagate_with_heading_drift(pose: np.ndarray, cov: np.ndarray, cross: np.ndarray, delta: np.ndarray,
                                 variance: np.ndarray, sigma: float, decay: float) -> tuple[np.ndarray, np.ndarray]:
    """The pose covariance (3, 3) and its cross-covariance with the heading bias b (3,) after ``delta`` (3,) from
    ``pose`` (3,): the 4-state [pose, b] propagation of ``odometry_consistency.dead_reckoned_windows`` with
    Var(b) = σ_b² (stationary), ∂θ'/∂b = the increment's distance d, b' = e^(−Δt/τ) b + noise:

        P' = J P Jᵀ + d (J c e_θᵀ + e_θ cᵀ Jᵀ) + d² σ_b² e_θ e_θᵀ + G V Gᵀ,   c' = e^(−Δt/τ) (J c + d σ_b² e_θ).
    """
    d = float(np.hypot(delta[0], delta[1]))
    ja, jb = motion_jacobians(pose[None], delta)   # built once, for the pose block and the cross term
    jc = ja[0] @ cross
    out = _propagated(ja, jb, cov[None], variance)[0]
    out[:, 2] += d * jc
    out[2, :] += d * jc
    out[2, 2] += d * d * sigma * sigma
    jc[2] += d * sigma * sigma
    return out, decay * jc
