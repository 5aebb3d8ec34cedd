"""The ground truth's heading, aligned with the robot's direction of travel.

A motion-capture system reports the body frame its markers define. A wheeled robot cannot move sideways, so its x
axis (REP-103 ``base_link``) is the direction it drives in. Markers set a little askew give a heading that is off that
axis by a constant; a marker set tracked badly gives one that wanders. Either way the truth's start frame, and every
figure scored in it, carries the error.

:func:`travel_heading_offset` measures the offset from the truth alone: the truth's heading minus the direction of
the truth's own displacement, over steps where the robot drives forward and barely turns. (A tracked centre ``d`` ahead
of the axle adds ``d`` × the step's curvature: at most 5 mrad for 5 cm on the steps kept, and it cancels between left
and right turns; it is not fitted, because on a drive of one curvature it cannot be told from the offset.) The
offset is smoothed over time by a Gaussian kernel whose width is chosen by leaving out one block of time at a time
(the widest width within one standard error of the one that best predicts the held-out steps), so a constant offset
and a wandering one are both followed as far as the data show them, and no width is set by hand.
:func:`align_truth_heading` subtracts it.

On MRCLAM dataset 2 (Vicon) the offsets are −0.014 (mean), +0.0136, −0.0094, +0.0027 and +0.0168 rad (robots 1–5);
robot 1's wanders (smoothed over 20 s, spread 0.018 rad), and that wander is Vicon's: robot 1's slow bearing residuals
against Vicon follow it (correlation 0.87 over 20 s windows). The constant offsets are the robots' build: each
camera is turned with the markers, so a camera calibrated against Vicon makes its map in the markers' frame and one
calibrated without truth in the wheels' (score each against its own: docs/fastslam.md, *The truth's heading*).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..geometry import wrap_angle
from .errors import DatasetError
from .landmark_log import RangeBearingLog

STEP_S = 1.0                # displacement step: at 0.06 m/s it spans ~60 mm against the mocap's ~1 mm noise
MIN_STEP_M = 0.03           # a shorter step's direction is too noisy (> ~0.03 rad from 1 mm of position noise)
MAX_CURVATURE = 0.1         # rad/m over a step: nearly straight, so a lever arm of the tracked centre adds little
FORWARD_COS = np.cos(0.3)   # heading and displacement within 0.3 rad: driving forward, not reversing or sliding
MIN_STEPS = 30              # fewer forward steps cannot place an offset
BLOCK_S = 10.0              # blocks of time left out in turn when the width is chosen (longer than the 1–2 steps that
                            # share a position, shorter than the wander the smoothing should follow)
WIDTHS_S = (5.0, 10.0, 20.0, 40.0, 80.0, 160.0, 320.0, 640.0, np.inf)


@dataclass(frozen=True)
class TravelHeadingOffset:
    """The truth's heading minus its direction of travel.

    times, offsets: (K,) s and rad, on a grid over the truth's span (interpolate between, hold at the ends)
    width_s:        the Gaussian smoothing width chosen (inf: one constant offset)
    steps:          forward steps used; residual_sd: their spread about the smoothed offset (rad)
    """

    times: np.ndarray
    offsets: np.ndarray
    width_s: float
    steps: int
    residual_sd: float

    def at(self, times) -> np.ndarray:
        return np.interp(np.asarray(times, float), self.times, self.offsets)

    def summary(self) -> str:
        width = "constant" if np.isinf(self.width_s) else f"smoothed over {self.width_s:g} s"
        return (f"the ground truth's heading aligned with its direction of travel: offset mean "
                f"{np.mean(self.offsets):+.4f} rad, spread {np.std(self.offsets):.4f} rad ({width}, {self.steps} "
                "forward steps)")


def travel_heading_offset(ground_truth: np.ndarray, name: str = "ground truth") -> TravelHeadingOffset:
    """The offset of ``ground_truth`` (G, 4) rows (t, x, y, θ) from its direction of travel (module docstring).

    Raises DatasetError when fewer than MIN_STEPS steps drive forward in a nearly straight line.
    """
    rows = np.asarray(ground_truth, float)
    if len(rows) < 2 or rows[-1, 0] - rows[0, 0] < STEP_S:
        raise DatasetError(f"{name}: the ground truth spans less than {STEP_S:g} s; its direction of travel is unknown")
    grid = np.arange(rows[0, 0], rows[-1, 0], STEP_S)
    x, y = np.interp(grid, rows[:, 0], rows[:, 1]), np.interp(grid, rows[:, 0], rows[:, 2])
    heading = np.interp(grid, rows[:, 0], np.unwrap(rows[:, 3]))
    dx, dy, turn = np.diff(x), np.diff(y), np.diff(heading)
    length = np.hypot(dx, dy)
    difference = wrap_angle(0.5 * (heading[1:] + heading[:-1]) - np.arctan2(dy, dx))
    curvature = turn / np.maximum(length, 1e-12)
    keep = (length >= MIN_STEP_M) & (np.abs(curvature) <= MAX_CURVATURE) & (np.cos(difference) >= FORWARD_COS)
    if keep.sum() < MIN_STEPS:
        raise DatasetError(f"{name}: the ground truth drives forward in a nearly straight line on {int(keep.sum())} "
                           f"steps of {STEP_S:g} s (at least {MIN_STEPS} needed to find its direction of travel)")
    times = 0.5 * (grid[1:] + grid[:-1])[keep]
    samples = difference[keep]
    width = _chosen_width(times, samples)
    smoothed = _kernel_mean(times, samples, grid, width)
    residual = samples - np.interp(times, grid, smoothed)
    return TravelHeadingOffset(grid, smoothed, width, int(len(times)), float(np.std(residual)))


def align_truth_heading(log: RangeBearingLog) -> tuple[RangeBearingLog, TravelHeadingOffset]:
    """``log`` with its ground truth's heading turned onto the direction of travel, and the offset removed (the
    summary is added to the log's notes). Raises DatasetError when the log has no ground truth or too little
    straight driving."""
    if not log.has_ground_truth:
        raise DatasetError(f"{log.name}: the log has no ground truth to align")
    offset = travel_heading_offset(log.ground_truth, log.name)
    truth = log.ground_truth.copy()
    truth[:, 3] = wrap_angle(truth[:, 3] - offset.at(truth[:, 0]))
    return replace(log, ground_truth=truth, notes=(*log.notes, offset.summary()), truth_heading="travel"), offset


def _kernel_mean(times: np.ndarray, values: np.ndarray, at: np.ndarray, width: float) -> np.ndarray:
    if np.isinf(width):
        return np.full(len(at), np.mean(values))
    out = np.empty(len(at))
    for start in range(0, len(at), 512):     # bounded memory: 512 × steps weights at a time
        block = at[start:start + 512, None]
        weights = np.exp(-0.5 * ((block - times[None, :]) / width) ** 2)
        total = weights.sum(axis=1)
        nearest = values[np.abs(block - times[None, :]).argmin(axis=1)]
        out[start:start + 512] = np.where(total > 1e-9, (weights @ values) / np.maximum(total, 1e-300), nearest)
    return out


def _chosen_width(times: np.ndarray, values: np.ndarray) -> float:
    """The widest width among WIDTHS_S whose error in predicting each left-out BLOCK_S block from the others is within
    one standard error of the best width's (the usual one-standard-error rule: no more wander than the data show)."""
    blocks = ((times - times[0]) // BLOCK_S).astype(int)
    labels = np.unique(blocks)
    if len(labels) < 3:
        return np.inf
    errors = np.empty((len(WIDTHS_S), len(labels)))   # squared error per width and left-out block
    for i, width in enumerate(WIDTHS_S):
        for j, block in enumerate(labels):
            out = blocks == block
            predicted = _kernel_mean(times[~out], values[~out], times[out], width)
            errors[i, j] = float(np.sum((values[out] - predicted) ** 2))
    mean = errors.mean(axis=1)
    best = int(np.argmin(mean))
    standard_error = errors[best].std(ddof=1) / np.sqrt(len(labels))
    return float(max(w for w, m in zip(WIDTHS_S, mean, strict=True) if m <= mean[best] + standard_error))
