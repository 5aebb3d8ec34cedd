"""The two standard consistency tests of a Kalman filter's innovations, for one landmark's sequence of updates.

A consistent filter's innovations ν_i (the reading minus its prediction) with the covariance S_i it claims for them
are zero-mean, have E[νᵀ S⁻¹ ν] = dof (the normalised innovation squared, NIS, is χ²_dof), and are white: successive
ones are uncorrelated (Bar-Shalom, Li & Kirubarajan, *Estimation with Applications to Tracking and Navigation*,
2001, §5.4.2, "the NIS test" and "the test of whiteness"; Mehra 1970). Both are checked here on the whitened
innovations w_i = L_i⁻¹ ν_i (S_i = L_i L_iᵀ), whose components are i.i.d. N(0, 1) when the filter is consistent.

- :func:`normalised_innovations`: w_i and the NIS w_iᵀ w_i.
- :func:`variance_factor`: the a-posteriori variance factor Σ NIS / (dof · n), 1 for a consistent filter; > 1 says
  the innovations are larger than claimed (the covariance-matching rule would scale S by it).
- :func:`lag1_correlation`: ρ = Σ w_i · w_{i+1} / Σ w_i · w_i, 0 for white innovations.
- :func:`block_variance_ratio`: the variance of a sum of ``block`` successive w over ``block`` times the variance of
  one (1 if white): how much less sure a mean of ``block`` readings is than independent readings would make it.
  Unlike the AR(1) (Bartlett) factor of ρ (:func:`estimation.fastslam.lever_drift.correlated_mean_factor`) it
  assumes no model of the correlation.

docs/fastslam-history.md, "Session 14: ... (I)": on MRCLAM known-ID maps the landmarks' NIS is far below χ²₂'s mean (the
innovations do not see the landmarks' shape error) while their innovations are correlated.
"""
from __future__ import annotations

import numpy as np


def normalised_innovations(innovations, covariances) -> tuple[np.ndarray, np.ndarray]:
    """Innovations (N, d) with their claimed covariances (N, d, d) -> (the whitened innovations L⁻¹ ν (N, d), the
    NIS νᵀ S⁻¹ ν (N,)). Raises numpy's LinAlgError if a covariance is not positive definite."""
    nu = np.asarray(innovations, float)
    s = np.asarray(covariances, float)
    if nu.ndim != 2 or s.shape != (*nu.shape, nu.shape[1]):
        raise ValueError(f"innovations (N, d) and covariances (N, d, d) expected, not {nu.shape} and {s.shape}")
    w = np.linalg.solve(np.linalg.cholesky(s), nu[..., None])[..., 0] if len(nu) else np.zeros_like(nu)
    return w, np.einsum("ni,ni->n", w, w)


def variance_factor(nis, dof: int) -> float:
    """The a-posteriori variance factor Σ NIS / (dof · n) of n updates (nan for none)."""
    nis = np.asarray(nis, float).reshape(-1)
    return float(np.sum(nis) / (dof * len(nis))) if len(nis) else float("nan")


def lag1_correlation(whitened) -> float:
    """ρ = Σ w_i · w_{i+1} / Σ w_i · w_i of whitened innovations (N, d) in time order (nan under two)."""
    w = np.asarray(whitened, float)
    w = w.reshape(len(w), -1)
    total = float(np.sum(w * w))
    if len(w) < 2 or total <= 0.0:
        return float("nan")
    return float(np.sum(w[1:] * w[:-1]) / total)


def block_variance_ratio(whitened, block: int) -> float:
    """The mean squared norm of sums of ``block`` successive whitened innovations (N, d) (consecutive, disjoint
    blocks; a remainder is dropped) over ``block`` times the mean squared norm of one: 1 if white, the variance
    inflation of a mean of ``block`` readings otherwise (nan when N < block)."""
    if block < 1:
        raise ValueError(f"block must be ≥ 1, not {block}")
    w = np.asarray(whitened, float)
    w = w.reshape(len(w), -1)
    n = len(w) // block
    if n == 0:
        return float("nan")
    w = w[:n * block]
    one = float(np.mean(np.sum(w * w, axis=1)))
    if one <= 0.0:
        return float("nan")
    sums = w.reshape(n, block, -1).sum(axis=1)
    return float(np.mean(np.sum(sums * sums, axis=1)) / (block * one))
