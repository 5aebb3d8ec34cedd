"""The χ² distribution's cdf, sf, ppf and isf, without importing ``scipy.stats``.

``scipy.stats.chi2`` costs about 0.5 s to import (scipy.stats loads every distribution), and the code here used it
for four functions that scipy.stats itself computes with ``scipy.special`` (``chdtr``, ``chdtrc``, ``chdtri`` and
``gammaincinv``). These are the same calls with the same edge rules as ``scipy.stats.chi2`` (probabilities 0 and 1
give the support's ends, anything outside [0, 1], a NaN or a degrees-of-freedom count ≤ 0 gives NaN), so they return
bit for bit what ``scipy.stats.chi2`` returns (tests/estimation/test_chi2.py checks it against scipy.stats).

Arguments broadcast as numpy arrays; a scalar call returns a numpy float64 scalar, as scipy.stats does.
"""
from __future__ import annotations

import numpy as np
from scipy.special import chdtr, chdtrc, chdtri, gammaincinv

__all__ = ["cdf", "isf", "ppf", "sf"]


def _result(out: np.ndarray):
    return out[()] if out.ndim == 0 else out


def cdf(x, df):
    """P(X ≤ x) for X ~ χ²(df)."""
    x, df = np.asarray(x, dtype=np.float64), np.asarray(df)
    with np.errstate(invalid="ignore"):
        valid = df > 0
        inside = valid & (0 < x) & (x < np.inf)
        out = np.where(valid & (x >= np.inf), 1.0, 0.0)
        out = np.where(~valid | np.isnan(x), np.nan, out)
        return _result(np.where(inside, chdtr(df, x), out))


def sf(x, df):
    """P(X > x) for X ~ χ²(df)."""
    x, df = np.asarray(x, dtype=np.float64), np.asarray(df)
    with np.errstate(invalid="ignore"):
        valid = df > 0
        inside = valid & (0 < x) & (x < np.inf)
        out = np.where(valid & (x <= 0), 1.0, 0.0)
        out = np.where(~valid | np.isnan(x), np.nan, out)
        return _result(np.where(inside, chdtrc(df, x), out))


def ppf(q, df):
    """The x with P(X ≤ x) = q for X ~ χ²(df) (the inverse of ``cdf``)."""
    q, df = np.asarray(q), np.asarray(df)
    with np.errstate(invalid="ignore"):
        valid = df > 0
        inside = valid & (0 < q) & (q < 1)
        out = np.where(valid & (q == 1), np.inf, np.where(valid & (q == 0), 0.0, np.nan))
        return _result(np.where(inside, 2 * gammaincinv(df / 2, q), out))


def isf(q, df):
    """The x with P(X > x) = q for X ~ χ²(df) (the inverse of ``sf``)."""
    q, df = np.asarray(q), np.asarray(df)
    with np.errstate(invalid="ignore"):
        valid = df > 0
        inside = valid & (0 < q) & (q < 1)
        out = np.where(valid & (q == 0), np.inf, np.where(valid & (q == 1), 0.0, np.nan))
        return _result(np.where(inside, chdtri(df, q), out))
