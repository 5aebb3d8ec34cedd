"""Scan-to-scan odometry over a laser log and its error against the log's reference poses.

The pipeline apart from the matchers (kiss-icp keeps ``pipeline.py`` apart from the algorithm the same way):
pair scans k apart, pick an initial guess, match, compare with the reference relative pose.
"""
from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from estimation.geometry import between, compose, wrap_angle
from estimation.scanmatch.common import MatchConfig, MatchResult
from estimation.scanmatch.errors import ScanMatchError
from estimation.scanmatch.match import match_scans
from estimation.scanmatch.scan import Scan2D

#: A match is a success when it is within both of these of the reference relative pose.
SUCCESS_TRANSLATION = 0.10   # metres
SUCCESS_ROTATION = np.radians(2.0)

GUESSES = ("identity", "constant-velocity", "reference")


def pose_error(estimate, reference) -> tuple[np.ndarray, np.ndarray]:
    """Translation (m) and absolute rotation (rad) errors of estimated poses (..., 3) against reference (..., 3)."""
    difference = between(np.asarray(reference, float), np.asarray(estimate, float))
    return np.hypot(difference[..., 0], difference[..., 1]), np.abs(wrap_angle(difference[..., 2]))


def is_success(translation_error, rotation_error) -> np.ndarray:
    return (np.asarray(translation_error) < SUCCESS_TRANSLATION) & (np.asarray(rotation_error) < SUCCESS_ROTATION)


def perturbations(count: int, translation: float, rotation: float, rng: np.random.Generator) -> np.ndarray:
    """(count, 3) pose errors of fixed size: ``translation`` m in a uniform direction, ±``rotation`` rad."""
    direction = rng.uniform(0.0, 2.0 * np.pi, count)
    sign = rng.choice([-1.0, 1.0], count)
    return np.column_stack([translation * np.cos(direction), translation * np.sin(direction), sign * rotation])


def perturbed_guesses(poses: np.ndarray, pairs: Sequence[tuple[int, int]], translation: float, rotation: float,
                      rng: np.random.Generator) -> np.ndarray:
    """(P, 3) initial guesses: each pair's reference relative pose composed with a fixed-size perturbation."""
    first, second = np.array(pairs, dtype=int).T
    return compose(between(poses[first], poses[second]), perturbations(len(pairs), translation, rotation, rng))


@dataclass(frozen=True)
class PairOutcome:
    """One match of scan j against scan i, with its errors against the reference relative pose."""

    i: int
    j: int
    result: MatchResult
    reference: np.ndarray          # (3,) reference pose of j in i's frame
    translation_error: float       # m
    rotation_error: float          # rad
    seconds: float

    @property
    def success(self) -> bool:
        return bool(is_success(self.translation_error, self.rotation_error))


def match_pairs(scans: Sequence[Scan2D], poses: np.ndarray, pairs: Sequence[tuple[int, int]], method: str,
                initial_guesses: np.ndarray, config: MatchConfig | None = None,
                clock: Callable[[], float] = time.perf_counter) -> list[PairOutcome]:
    """Match every pair (i, j) (scan j against reference scan i) from the given initial guesses (P, 3)."""
    outcomes = []
    for (i, j), initial in zip(pairs, initial_guesses, strict=True):
        reference = between(poses[i], poses[j])
        start = clock()
        result = match_scans(scans[i], scans[j], method, initial=initial, config=config)
        seconds = clock() - start
        t_err, r_err = pose_error(result.pose, reference)
        outcomes.append(PairOutcome(i, j, result, reference, float(t_err), float(r_err), seconds))
    return outcomes


@dataclass(frozen=True)
class Odometry:
    """Scan-to-scan odometry over a log.

    indices:    (K,) scan indices chained (0, step, 2·step, …)
    trajectory: (K, 3) estimated poses, starting at the reference pose of the first scan
    outcomes:   one PairOutcome per link
    """

    indices: np.ndarray
    trajectory: np.ndarray
    outcomes: list[PairOutcome]

    def summary(self, reference_poses: np.ndarray) -> dict:
        """Per-link and end-point errors against the reference poses (N, 3) of the whole log."""
        t_err = np.array([o.translation_error for o in self.outcomes])
        r_err = np.array([o.rotation_error for o in self.outcomes])
        end_t, end_r = pose_error(self.trajectory[-1], reference_poses[self.indices[-1]])
        path = np.sum(np.hypot(*np.diff(reference_poses[self.indices, :2], axis=0).T))
        return {
            "links": len(self.outcomes),
            "converged_share": float(np.mean([o.result.converged for o in self.outcomes])),
            "success_share": float(np.mean(is_success(t_err, r_err))),
            "median_translation_error_m": float(np.median(t_err)),
            "median_rotation_error_deg": float(np.degrees(np.median(r_err))),
            "mean_iterations": float(np.mean([o.result.iterations for o in self.outcomes])),
            "mean_time_ms": float(1e3 * np.mean([o.seconds for o in self.outcomes])),
            "path_length_m": float(path),
            "end_translation_error_m": float(end_t),
            "end_rotation_error_deg": float(np.degrees(end_r)),
        }


def scan_odometry(scans: Sequence[Scan2D], reference_poses: np.ndarray, method: str = "eicp", step: int = 1,
                  guess: str = "constant-velocity", config: MatchConfig | None = None,
                  clock: Callable[[], float] = time.perf_counter) -> Odometry:
    """Chain matches of scan i+step against scan i over the log.

    guess: "identity"; "constant-velocity" (the previous link's estimate, identity for the first); or
    "reference" (the reference relative pose itself — isolates the matcher's accuracy from its basin).
    The reference poses are used only for that guess, for the starting pose and for the reported errors.
    """
    if guess not in GUESSES:
        raise ScanMatchError(f"unknown initial guess {guess!r}; choose one of {', '.join(GUESSES)}")
    if step < 1:
        raise ScanMatchError(f"step must be >= 1, got {step}")
    indices = np.arange(0, len(scans), step)
    if indices.size < 2:
        raise ScanMatchError(f"the log has {len(scans)} scans: too few for step {step}")
    reference_poses = np.asarray(reference_poses, dtype=float)
    trajectory = [reference_poses[indices[0]]]
    outcomes: list[PairOutcome] = []
    previous = np.zeros(3)
    for i, j in zip(indices[:-1], indices[1:], strict=True):
        if guess == "identity":
            initial = np.zeros(3)
        elif guess == "constant-velocity":
            initial = previous
        else:
            initial = between(reference_poses[i], reference_poses[j])
        outcome = match_pairs(scans, reference_poses, [(int(i), int(j))], method, initial[None, :], config, clock)[0]
        outcomes.append(outcome)
        previous = outcome.result.pose
        trajectory.append(compose(trajectory[-1], outcome.result.pose))
    return Odometry(indices, np.array(trajectory), outcomes)
