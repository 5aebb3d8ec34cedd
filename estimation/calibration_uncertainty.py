"""How uncertain is a self-calibrated camera when its residuals are not independent? Time-clustered sandwich
(HAC) covariances of :func:`~estimation.camera_calibration.self_calibrate`'s calibration.

The calibration's printed covariance is the Laplace one, the inverse information: it holds if every residual's error
is independent with the model's σ. On MRCLAM they are not (a post seen in consecutive frames, the odometry's slow
errors), and the printed errors missed the calibration against each robot's truth fit by up to 7 of them
(docs/fastslam-history.md, "Session 47: robot 1's long ranges ... (U)"). The sandwich replaces the model's claim
about the errors by the residuals themselves, summed over blocks of time, so errors correlated within a block count
as one: at the joint solution the calibration moves by δc = A Jᵀ δe for a change δe of the whitened residuals
(A = H⁻¹'s calibration rows, H = JᵀJ), so residual row i's influence on the calibration is u_i = A J_iᵀ e_i
(Σ_i u_i = 0 at the optimum), and

- :func:`clustered_covariance`: Σ_b (Σ_{i∈b} u_i)(Σ_{i∈b} u_i)ᵀ · G/(G − 1) over blocks b of ``length`` seconds (G of
  them; length 0: each row its own block, White's HC0);
- :func:`newey_west_covariance`: the influences summed per second, their long-run covariance with Bartlett weights
  out to a bandwidth; :func:`andrews_bandwidth` the bandwidth from the series' own lag-1 correlation (Andrews 1991,
  AR(1) plug-in), a rule that reads no truth;
- the known distances' rows are the model's (JᵀJ's share: one residual cannot measure its own spread), added to
  each.

The residuals at the solution are smaller than the errors: the poses (one per frame) and the landmarks take part of
them. :func:`null_draws` measures by how much for each estimator: under the model's own errors (independent, unit)
the residuals are (I − P)ε, P = J H⁻¹ Jᵀ; the estimator's mean over draws, against the Laplace covariance, is its
factor κ (0.6-0.9 for the range terms on MRCLAM, 0.2-0.3 for the bearing offset with one row a block), and
:func:`corrected` divides it out.

Simulated (a 12-minute log, sightings AR(1) with ρ 0.9 along each pass, the model not told): the RMS of the range
offset's error/σ is 3.4 with the Laplace σ, 1.4 with Newey–West at Andrews' bandwidth; with the model's own errors
both are 1.0-1.1. On MRCLAM (benchmarks/mrclam_calibration_uncertainty.py; docs/fastslam-history.md, "Session 48:
... (A)"), at Andrews' bandwidth (9-14 s) the range offset's σ is 0.7-1.5× the Laplace one (2.4× at most with blocks
of 240 s), not the 3-5× its miss against the truth fit needs: the miss is an error shared by the whole log, which no
within-log estimate sees.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse.linalg as spla

from .camera_calibration import CameraCalibration
from .datasets import RangeBearingLog
from .landmark_smoother import _residuals


@dataclass(frozen=True, eq=False)
class Influences:
    """Each residual row's influence on the calibration's estimated terms (``free``: indices into the solve's c, in
    :data:`~estimation.camera_calibration.ESTIMATED` order, the odometry's scale 5): ``rows`` (N, k) u_i, ``times``
    (N,) its time (an odometry row: its increment's end; a sighting's: its own; a known distance's: NaN), ``laplace``
    (k, k) the inverse information's block (the printed covariance), ``lengths`` (k, k) the known distances' share
    of the sandwich (the model's), ``null`` (D, N, k) the influences of D draws of the model's own errors (see
    :func:`null_draws`), ``values`` the solve's c (the MAP)."""

    free: np.ndarray
    rows: np.ndarray
    times: np.ndarray
    laplace: np.ndarray
    lengths: np.ndarray
    null: np.ndarray
    values: np.ndarray


def influences(log: RangeBearingLog, calibration: CameraCalibration, draws: int = 20,
               seed: int = 0) -> Influences:
    """The influences of ``log``'s residuals on ``calibration`` (made by ``self_calibrate(log, ...,
    keep_solution=True)``), with ``draws`` null draws (:func:`null_draws`) from ``seed``."""
    solution = calibration.solution
    if solution is None:
        raise ValueError("the calibration keeps no solution: make it with self_calibrate(..., keep_solution=True)")
    p, shape, poses, landmarks, c = solution.problem, solution.shape, solution.poses, solution.landmarks, \
        solution.values
    t, n, k = p.n_poses, len(landmarks), len(shape.free)
    weights = solution.inliers.astype(float)
    jac = shape.jacobian(p, poses, landmarks, c, weights).tocsc()
    odometry, sightings = _residuals(shape.applied(p, c), poses, landmarks)
    e = np.concatenate([odometry, sightings * np.repeat(weights, 2), shape.residuals(landmarks, c)])
    free = np.ones(jac.shape[1], bool)
    free[3 * t:3 * t + 2 * n] = np.repeat(solution.seen, 2)
    jac = jac[:, free]
    information = (jac.T @ jac).tocsc()
    m = information.shape[0]
    select = np.zeros((m, k))
    select[m - k + np.arange(k), np.arange(k)] = 1.0
    factor = spla.splu(information)
    columns = factor.solve(select)                # H⁻¹'s calibration columns (m, k)
    along = np.asarray(jac @ columns)             # (J H⁻¹)[:, c]: row i's influence per unit residual
    sighting_rows = 3 * t + 2 * len(p.ranges)
    times = np.concatenate([np.repeat(solution.frame_times, 3), np.repeat(log.sighting_times, 2),
                            np.full(jac.shape[0] - sighting_rows, np.nan)])
    tape = along[sighting_rows:]
    live = np.asarray(abs(jac).sum(axis=1)).ravel() > 0   # an outlier's rows are 0: no error of its own counts
    rng = np.random.default_rng(seed)
    null = np.empty((draws, jac.shape[0], k), np.float32)
    for d in range(draws):
        eps = rng.standard_normal(jac.shape[0]) * live
        residual = eps - jac @ factor.solve(np.asarray(jac.T @ eps).ravel())
        null[d] = along * residual[:, None]
    return Influences(np.asarray(shape.free), along * e[:, None], times, columns[m - k:], tape.T @ tape, null,
                      np.asarray(c[shape.free], float))


def _block_sums(rows: np.ndarray, times: np.ndarray, length: float) -> np.ndarray:
    keep = np.isfinite(times)
    if length <= 0:
        return rows[keep]
    label = np.floor((times[keep] - np.min(times[keep])) / length).astype(np.int64)
    _, index = np.unique(label, return_inverse=True)
    sums = np.zeros((int(index.max()) + 1, rows.shape[1]))
    np.add.at(sums, index, rows[keep])
    return sums


def clustered_covariance(found: Influences, length: float, rows: np.ndarray | None = None) -> np.ndarray:
    """The calibration's covariance from its influences summed over blocks of ``length`` s (0: each row its own),
    the known distances' share added (``rows``: other influences than ``found.rows``, e.g. a null draw)."""
    sums = _block_sums(found.rows if rows is None else np.asarray(rows, float), found.times, length)
    g = len(sums)
    return sums.T @ sums * (g / (g - 1) if length > 0 and g > 1 else 1.0) + found.lengths


def per_second(found: Influences, rows: np.ndarray | None = None) -> np.ndarray:
    """(seconds, k) the influences summed per second of the log, a second without a row 0 (lags are seconds)."""
    rows = found.rows if rows is None else np.asarray(rows, float)
    keep = np.isfinite(found.times)
    second = np.floor(found.times[keep] - np.min(found.times[keep])).astype(np.int64)
    out = np.zeros((int(second.max()) + 1, rows.shape[1]))
    np.add.at(out, second, rows[keep])
    return out


def andrews_bandwidth(series: np.ndarray) -> float:
    """Andrews' (1991) AR(1) plug-in bandwidth for the Bartlett kernel of one series (T,): 1.1447 (α T)^⅓,
    α = 4ρ²/((1 − ρ)²(1 + ρ)²), ρ its lag-1 correlation (clipped to ±0.97)."""
    x = np.asarray(series, float) - np.mean(series)
    denominator = float(np.dot(x[:-1], x[:-1]))
    rho = float(np.clip(np.dot(x[1:], x[:-1]) / denominator, -0.97, 0.97)) if denominator > 0 else 0.0
    alpha = 4 * rho ** 2 / ((1 - rho) ** 2 * (1 + rho) ** 2)
    return 1.1447 * (alpha * len(x)) ** (1 / 3)


def newey_west_covariance(found: Influences, bandwidth: float, rows: np.ndarray | None = None) -> np.ndarray:
    """The long-run covariance of the per-second influences (Bartlett weights 1 − j/(bandwidth + 1) out to
    ⌊bandwidth⌋ s), the known distances' share added."""
    x = per_second(found, rows)
    x = x - x.mean(axis=0)
    out = x.T @ x
    for j in range(1, int(np.floor(bandwidth)) + 1):
        lagged = x[j:].T @ x[:-j]
        out += (1 - j / (bandwidth + 1)) * (lagged + lagged.T)
    return out + found.lengths


def null_draws(found: Influences, estimator) -> np.ndarray:
    """κ (k,): ``estimator(rows)``'s diagonal averaged over the null draws (the model's own errors, independent and
    unit, through the solution's (I − P)), against the Laplace covariance's: the estimator's bias from what the
    poses and landmarks take of the errors."""
    mean = np.mean([estimator(draw) for draw in found.null], axis=0)
    return np.diag(mean) / np.diag(found.laplace)


def corrected(covariance: np.ndarray, kappa: np.ndarray) -> np.ndarray:
    """``covariance`` with each term's κ divided out (its correlations kept)."""
    root = np.sqrt(np.asarray(kappa, float))
    return covariance / np.outer(root, root)
