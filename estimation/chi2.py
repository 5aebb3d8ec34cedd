"""The χ² distribution's cdf, sf, logsf, ppf and isf, without importing ``scipy.stats``.

``scipy.stats.chi2`` costs about 0.5 s to import (scipy.stats loads every distribution), and the code here used it
for four functions that scipy.stats itself computes with ``scipy.special`` (``chdtr``, ``chdtrc``, ``chdtri`` and
``gammaincinv``). These are the same calls with the same edge rules as ``scipy.stats.chi2`` (probabilities 0 and 1
give the support's ends, anything outside [0, 1], a NaN or a degrees-of-freedom count ≤ 0 gives NaN), so they return
bit for bit what ``scipy.stats.chi2`` returns (tests/estimation/test_chi2.py checks it against scipy.stats).

``logsf`` is scipy.stats.chi2.logsf's computation (log of ``sf`` above the median, log1p of −``cdf`` below), bit for
bit where that is finite; where ``sf`` underflows (x beyond ≈ 1500 for few degrees of freedom) scipy's is −inf and
this one is the log of the upper incomplete gamma function's continued fraction, finite and right (session 27:
``estimation.constellation.guard_batches`` ranks χ² shares far in the tail by it).

Arguments broadcast as numpy arrays; a scalar call returns a numpy float64 scalar, as scipy.stats does.
"""
from __future__ import annotations

import numpy as np
from scipy.special import chdtr, chdtrc, chdtri, gammaincinv, gammaln

__all__ = ["cdf", "isf", "logsf", "ppf", "sf"]

_CF_TERMS = 300           # the continued fraction's terms: it is used for x/2 > 700 only, where a few dozen do


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


def logsf(x, df):
    """log P(X > x) for X ~ χ²(df), finite however far in the tail (module docstring)."""
    x, df = np.asarray(x, dtype=np.float64), np.asarray(df)
    with np.errstate(invalid="ignore", divide="ignore"):
        valid = df > 0
        inside = valid & (0 < x) & (x < np.inf)
        out = np.where(valid & (x <= 0), 0.0, -np.inf)
        out = np.where(~valid | np.isnan(x), np.nan, out)
        median = 2 * gammaincinv(df / 2, 0.5)
        upper = x > median
        value = np.where(upper, np.log(chdtrc(df, x)), np.log1p(-chdtr(df, x)))
        tail = inside & upper & np.isneginf(value)
        if np.any(tail):
            x_b, df_b = np.broadcast_arrays(x, df)
            value = np.array(np.broadcast_to(value, tail.shape), dtype=np.float64)
            value[tail] = _log_upper_gamma_regularised(df_b[tail] / 2.0, x_b[tail] / 2.0)
        return _result(np.where(inside, value, out))


def _log_upper_gamma_regularised(a: np.ndarray, x: np.ndarray) -> np.ndarray:
    """log Q(a, x) = log Γ(a, x)/Γ(a) for x > a + 1 by the continued fraction of Γ(a, x) (modified Lentz; Numerical
    Recipes' gcf), in logs: −x + a log x − log Γ(a) + log CF."""
    a, x = np.asarray(a, np.float64), np.asarray(x, np.float64)
    tiny = 1e-300
    b = x + 1.0 - a
    c = np.full_like(b, 1.0 / tiny)
    d = 1.0 / b
    h = d.copy()
    for i in range(1, _CF_TERMS + 1):
        an = -i * (i - a)
        b = b + 2.0
        d = an * d + b
        d = np.where(np.abs(d) < tiny, tiny, d)
        c = b + an / c
        c = np.where(np.abs(c) < tiny, tiny, c)
        d = 1.0 / d
        delta = d * c
        h = h * delta
        if np.all(np.abs(delta - 1.0) < 1e-16):
            break
    return -x + a * np.log(x) - gammaln(a) + np.log(h)
