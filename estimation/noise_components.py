"""Variance components of a least-squares problem: each group's noise level estimated from its own residuals.

Why: a noise model fitted on other robots carries their sensors' σ's; a robot's own log, without ground truth, still
says how large its sightings' errors are, by how far they disagree with the solution that all of them and the
odometry give (:mod:`estimation.camera_calibration` uses this beside the camera's calibration).

The estimator (Helmert's; Förstner 1979, Koch 1986): the observations fall in groups g (the odometry's increments,
the sightings' ranges, their bearings), each with its covariance k_g Σ_g (Σ_g the model's, k_g an unknown factor).
At the weighted least-squares solution (weights Σ_g⁻¹), E[v_gᵀ Σ_g⁻¹ v_g] = k_g r_g, with r_g = n_g − tr(H⁻¹ H_g) the
group's redundancy: its n_g rows less the share of the unknowns they determine (H = JᵀJ the information of all the
unknowns, H_g = J_gᵀJ_g its group's part; Σ_g tr(H⁻¹ H_g) = p, the number of unknowns). So k_g ← χ²_g / r_g, the
weights rescaled, the problem solved again, to the fixed point: the restricted (REML) likelihood's estimating
equations for the factors. Each group's r_g is the trace d/dε log det(H + ε H_g) at ε = 0, a central difference of
two log-determinants (:meth:`~estimation.landmark_smoother.NormalFactor.log_determinant`, which follows the
smoothing problem's structure; the error is ε² tr((H⁻¹H_g)³)/3 ≤ ε²/3 of the trace).

Its standard error: k̂_g is a χ²_{r_g} / r_g, so ± k_g √(2 / r_g), a σ's ± σ / √(2 r_g) (for independent rows; an
AR(1) series of correlation ρ has (1 + ρ²)/(1 − ρ²) times that variance).

Rows cut as outliers (χ²₂ beyond a threshold c on a sighting's two residuals) leave the kept ones' χ² short: for two
standard normal errors E[e² | e_r² + e_φ² ≤ c] = (2 − c e^{−c/2} / (1 − e^{−c/2})) / 2 (0.954 at χ²₂ 99 %). But a
residual is not its error: its variance is 1 − h (h its row's leverage, on average 1 − r_g/n_g: 0.16 for the
simulated ranges, 0.34 for the bearings), so the cut takes less of it; :func:`truncated_means` gives the mean for
two unequal variances, the caller the variances r_g/n_g (a first order: the leverages differ from row to row).
Dividing by the errors' 0.954 instead took the simulated σ_φ 2 % high (six seeds: +1.4 standard errors on average).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .landmark_smoother import NormalFactor

EPSILON = 1e-3          # the log-determinants' step: ε H_g beside H


def information_shares(jac: sp.spmatrix, groups: Sequence[np.ndarray], t: int, free: np.ndarray) -> np.ndarray:
    """tr(H⁻¹ H_g) (G,) for the row groups ``groups`` (each an array of row indices of ``jac``): H = JᵀJ over the
    columns ``free`` (bool), its first 3t the poses' (x, y, θ) in :class:`NormalFactor`'s band, the rest dense."""
    jac = sp.csr_matrix(jac)[:, np.flatnonzero(free)]
    normal = (jac.T @ jac).tocsc()

    def log_det(matrix) -> float:
        return NormalFactor(matrix.tocsc(), t, 3).log_determinant()

    out = np.zeros(len(groups))
    for g, rows in enumerate(groups):
        part = jac[np.asarray(rows, int)]
        own = (part.T @ part).tocsc()
        out[g] = (log_det(normal + EPSILON * own) - log_det(normal - EPSILON * own)) / (2.0 * EPSILON)
    return out


def variance_factors(jac: sp.spmatrix, residuals: np.ndarray, groups: Sequence[np.ndarray], t: int,
                     free: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One step: (χ²_g (G,), r_g (G,)): each group's sum of squared normalised ``residuals`` (one per row of
    ``jac``) and its redundancy; the factor is χ²_g / r_g, over the expected square of a kept row where rows beyond a
    cut were dropped (:func:`truncated_means`)."""
    shares = information_shares(jac, groups, t, free)
    redundancy = np.array([len(rows) for rows in groups], float) - shares
    chi2 = np.array([float(np.sum(residuals[np.asarray(rows, int)] ** 2)) for rows in groups])
    return chi2, redundancy


def truncated_means(cut: float, variances: Sequence[float], points: int = 801) -> np.ndarray:
    """(2,) E[e_j² | e_1² + e_2² ≤ cut] / v_j for two independent normal residuals e_j of variances ``variances``
    (v_1, v_2) in the cut's units (equal ones: (2 − c e^{−c/2} / (1 − e^{−c/2})) / 2); by quadrature over e_1."""
    if not math.isfinite(cut):
        return np.ones(2)
    v1, v2 = (float(v) for v in variances)
    angle = np.linspace(-math.pi / 2, math.pi / 2, points)              # e_1 = √c sin θ: smooth at the cut's edge
    x, room = math.sqrt(cut) * np.sin(angle), math.sqrt(cut) * np.cos(angle)   # |e_2| ≤ room
    z = room / math.sqrt(2.0 * v2)
    inside = np.array([math.erf(float(u)) for u in z])                  # P(|e_2| ≤ room)
    # E[e_2² 1{|e_2| ≤ room}] = v_2 (P − 2 room φ(room/√v_2)/√v_2)
    second = v2 * inside - 2.0 * room * np.sqrt(v2) * np.exp(-room ** 2 / (2.0 * v2)) / math.sqrt(2.0 * math.pi)
    density = np.exp(-x ** 2 / (2.0 * v1)) / math.sqrt(2.0 * math.pi * v1) * room   # dx = √c cos θ dθ
    mass = np.trapezoid(density * inside, angle)
    return np.array([np.trapezoid(density * x ** 2 * inside, angle) / mass / v1,
                     np.trapezoid(density * second, angle) / mass / v2])


GROUPS = ("odometry", "range", "bearing")
MIN_FACTOR = 1e-6        # a variance factor below this (σ a thousandth of the model's): residuals of exact data
MIN_REDUNDANCY = 8.0     # a factor from fewer redundant rows is known to no better than ± 50 % (its σ ± 25 %)


@dataclass(frozen=True)
class NoiseComponents:
    """The noise's level found in a log: ``factors`` (3,) on the given model's variances of the odometry's increments,
    the sightings' ranges (σ_r² = (a + b r)², its shape kept) and bearings (σ_φ²), 1 for a group not ``estimated``;
    each group's ``redundancies`` r_g and kept ``rows`` n_g, the given correlations ``correlations`` (3,) (ρ of
    consecutive rows, 0 for the odometry's) that widen the standard errors, and how the fixed point was reached."""

    estimated: tuple[str, ...]
    factors: np.ndarray
    redundancies: np.ndarray
    rows: np.ndarray
    correlations: np.ndarray
    rounds: int
    converged: bool

    @property
    def standard_errors(self) -> np.ndarray:
        """(3,) of the factors: k √(2 / r) √((1 + ρ²)/(1 − ρ²)); 0 where not estimated."""
        rho2 = np.asarray(self.correlations, float) ** 2
        with np.errstate(divide="ignore", invalid="ignore"):
            se = self.factors * np.sqrt(2.0 / self.redundancies * (1.0 + rho2) / (1.0 - rho2))
        return np.where([g in self.estimated for g in GROUPS], se, 0.0)

    @property
    def sigma_factors(self) -> np.ndarray:
        """(3,) √factors: on the σ's."""
        return np.sqrt(self.factors)

    @property
    def sigma_relative_errors(self) -> np.ndarray:
        """(3,) the σ's standard errors over the σ's: ½ of the factors' relative ones (0 where not estimated)."""
        return 0.5 * self.standard_errors / self.factors

    def problem(self) -> str | None:
        """Why the estimate is not to be used, in one sentence (None: it is determined)."""
        for g, name in enumerate(GROUPS):
            if name not in self.estimated:
                continue
            if not (np.isfinite(self.factors[g]) and self.factors[g] >= MIN_FACTOR):
                return (f"the {name} noise's variance factor came out {self.factors[g]:g}: not determined (its "
                        "residuals are no noise the model's σ could describe; exact data?)")
            if not self.redundancies[g] >= MIN_REDUNDANCY:
                return (f"the {name} noise is not determined: its {int(self.rows[g])} rows have a redundancy of "
                        f"{self.redundancies[g]:.1f} (at least {MIN_REDUNDANCY:g} needed)")
        if not self.converged:
            return (f"the noise's variance components did not reach their fixed point in {self.rounds} rounds (or "
                    "its solves did not converge)")
        return None
