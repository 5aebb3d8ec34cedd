"""What the tests of a smoothed map's frame share (tests/estimation/test_frame_reliability*.py,
tests/datasets/test_anchor_frame.py): MRCLAM-like odometry and sighting noise for their synthetic logs, the ring of
eight landmarks those logs see, and the frame's covariance read from the landmarks' joint covariance (the reference
estimation.frame_reliability's own is checked against)."""
from __future__ import annotations

import numpy as np

from estimation.geometry import dead_reckoning, wrap_angle
from estimation.landmark_scores import rigid_functional
from estimation.landmark_smoother import (
    LandmarkLogProblem,
    Smoothed,
    joint_landmark_covariance,
    landmarks_from_first_sightings,
    smooth,
)

THETA_VAR_PER_RAD, XY_VAR_PER_M, FLOOR = 0.0087, 0.003, 1e-8   # MRCLAM-like odometry (rad²/rad, m²/m)
RANGE_SIGMA, BEARING_SIGMA = 0.03, 0.017
ANGLES = np.linspace(0, 2 * np.pi, 8, endpoint=False)
LANDMARKS = np.column_stack([3.0 * np.cos(ANGLES), 1.5 + 3.0 * np.sin(ANGLES)])


def turn_and_lap(turn_frames: int) -> np.ndarray:
    """(1 + turn_frames + 80, 3) the true increments of a robot that stays at the origin for its first frame (increment
    0: the origin to the first frame, the map's pose 0), turns on the spot 0.1 rad a frame for ``turn_frames`` frames,
    then drives a lap of a 1.5 m circle about (0, 1.5) (the ring's centre) in 80."""
    turn = np.tile([0.0, 0.0, 0.1], (turn_frames, 1))
    lap = np.tile([2 * np.pi * 1.5 / 80, 0.0, 2 * np.pi / 80], (80, 1))
    return np.vstack([np.zeros((1, 3)), turn, lap])


def unicycle(v: np.ndarray, w: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x, y, θ) (T,) each, θ unwrapped, of a robot starting at the origin driven by forward speeds ``v`` and turn rates
    ``w`` (T,) held over steps of ``dt`` s (Euler: each step moves along the heading it starts with)."""
    theta = np.concatenate([[0.0], np.cumsum(w[:-1] * dt)])
    x = np.concatenate([[0.0], np.cumsum(v[:-1] * np.cos(theta[:-1]) * dt)])
    y = np.concatenate([[0.0], np.cumsum(v[:-1] * np.sin(theta[:-1]) * dt)])
    return x, y, theta


def seen_from(points: np.ndarray, x: float, y: float, theta: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact (ranges, bearings) (N,) of ``points`` (N, 2) from the pose (x, y, θ)."""
    d = points - [x, y]
    return np.hypot(d[:, 0], d[:, 1]), wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - theta)


def odometry_variances(increments: np.ndarray, xy_floor: float = FLOOR) -> np.ndarray:
    """(T, 3) MRCLAM-like variances of ``increments`` (T, 3): x and y XY_VAR_PER_M per metre travelled + ``xy_floor``,
    θ THETA_VAR_PER_RAD per radian turned + FLOOR."""
    xy = XY_VAR_PER_M * np.hypot(increments[:, 0], increments[:, 1]) + xy_floor
    return np.column_stack([xy, xy, THETA_VAR_PER_RAD * np.abs(increments[:, 2]) + FLOOR])


def seen_joint_covariance(problem: LandmarkLogProblem, solution: Smoothed) -> tuple[np.ndarray, np.ndarray]:
    """The landmarks with a kept sighting (K,) (index order) and their joint covariance (2K, 2K):
    :func:`~estimation.landmark_smoother.joint_landmark_covariance`'s rows and columns of those (the others' are
    inf)."""
    joint = joint_landmark_covariance(problem, solution)
    seen = np.flatnonzero(np.isfinite(np.diag(joint)[0::2]))
    columns = np.column_stack([2 * seen, 2 * seen + 1]).ravel()
    return seen, joint[np.ix_(columns, columns)]


def joint_frame_covariance(problem: LandmarkLogProblem, solution: Smoothed) -> np.ndarray:
    """(3, 3) the covariance of the frame's (dx, dy, dθ), the seen landmarks' rigid motion about pose 0 at their
    estimated positions, from their joint covariance: g C gᵀ."""
    seen, covariance = seen_joint_covariance(problem, solution)
    functional = rigid_functional(solution.landmarks[seen])
    return functional @ covariance @ functional.T


TURN_FRAMES = 30


def glimpses_then_lap(rng, glimpses_at_start: int, lone_glimpses: bool = True, per_glimpse: int = 1,
                      shared_bearing_error: float = 0.0, turn_frames: int = TURN_FRAMES,
                      noise: float = 1.0) -> LandmarkLogProblem:
    """A robot at the origin sees ``glimpses_at_start`` landmarks from its first pose, turns on the spot by 3 rad in
    30 frames seeing (``lone_glimpses``) the ``per_glimpse`` landmarks nearest its heading every fifth frame, then
    drives a lap of a 1.5 m circle seeing every landmark ahead (MRCLAM robot 1's start: one glimpse at a time while
    it turns, each the lone tie of its own pose). Noisy odometry and sightings (MRCLAM-like σ's); the turn's images
    after the first add ``shared_bearing_error`` (rad) to all their bearings (a stale image's time stamp).
    ``turn_frames`` 0: no turn, the lap straight after the first pose. ``noise`` 0: exact data (the same draws)."""
    true_increments = turn_and_lap(turn_frames)
    truth = dead_reckoning(true_increments)
    variance = odometry_variances(true_increments, xy_floor=1e-6)
    measured = true_increments + noise * rng.standard_normal(variance.shape) * np.sqrt(variance)
    pose_index, landmark_index, ranges, bearings = [], [], [], []
    for k in range(1, len(truth)):
        r, b = seen_from(LANDMARKS, *truth[k])
        if k == 1:
            visible = np.argsort(np.abs(b))[:glimpses_at_start]
        elif k <= turn_frames + 1:
            visible = np.argsort(np.abs(b))[:per_glimpse] if lone_glimpses and k % 5 == 0 else np.zeros(0, int)
            b = b + shared_bearing_error
        else:
            visible = np.flatnonzero((np.abs(b) < 0.6) & (r < 6.0))
        pose_index += [k] * len(visible)
        landmark_index += list(visible)
        ranges += list(r[visible] + noise * RANGE_SIGMA * rng.standard_normal(len(visible)))
        bearings += list(b[visible] + noise * BEARING_SIGMA * rng.standard_normal(len(visible)))
    s = len(ranges)
    return LandmarkLogProblem(measured, variance, np.array(pose_index), np.array(landmark_index), np.array(ranges),
                              np.array(bearings), np.full(s, RANGE_SIGMA), np.full(s, BEARING_SIGMA))


def solved(problem: LandmarkLogProblem) -> Smoothed:
    """The smoother's solution from dead reckoning and each landmark's first sighting."""
    poses = dead_reckoning(problem.increments)
    return smooth(problem, poses, landmarks_from_first_sightings(problem, poses))
