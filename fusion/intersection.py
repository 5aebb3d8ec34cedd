"""Covariance intersection: fusing two estimates of the same points whose errors may be correlated.

The paper's stationary Kalman update (``fusion.merging.kalman_fuse``, eqs. 6–8) takes the two maps' estimates of a
landmark as independent, so the fused covariance is (P1⁻¹ + P2⁻¹)⁻¹ — half of either when they are equal.  Maps of
one place made by robots that share sensors, landmarks and a placement into one frame are not independent: on
MRCLAM the two best maps' errors correlate +0.59 and the Kalman merge of five maps claims about 1/√5 of their σ
(docs/fusion-history.md, "Session 7: merging").  Covariance intersection (Julier & Uhlmann 1997) needs no
cross-covariance:

    P⁻¹ = ω P1⁻¹ + (1 − ω) P2⁻¹,    x = P (ω P1⁻¹ x1 + (1 − ω) P2⁻¹ x2),    ω ∈ [0, 1]

is consistent (P ⪰ the true error covariance of x) for *every* correlation between the two errors whenever P1 and P2
are consistent for theirs.  ω is chosen per landmark to minimise tr P (the fused mean squared error bound); tr P is
convex in ω, so a golden-section search finds it; the end points (keep one estimate) are candidates too, so tr P ≤
min(tr P1, tr P2).  Fusing an estimate with itself returns it unchanged (the Kalman update would halve P).  What CI
cannot do is make the result better than the best input when the inputs share their errors — nothing can without
knowing the correlation.
"""
from __future__ import annotations

import numpy as np

_GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0
_EPS = 1e-12          # as kalman_fuse: a zero covariance (an exact map) stays invertible


def _information(P: np.ndarray) -> np.ndarray:
    info = np.linalg.inv(P + _EPS * np.eye(P.shape[-1]))
    return 0.5 * (info + np.swapaxes(info, -1, -2))


def _trace_of_inverse(info1: np.ndarray, info2: np.ndarray, omega: np.ndarray) -> np.ndarray:
    w = omega[:, None, None]
    return np.trace(np.linalg.inv(w * info1 + (1.0 - w) * info2), axis1=1, axis2=2)


def intersection_weights(P1: np.ndarray, P2: np.ndarray, iterations: int = 60) -> np.ndarray:
    """ω (N,) minimising tr P of the covariance intersection of P1, P2 (N, 3, 3), per landmark."""
    info1, info2 = _information(P1), _information(P2)
    lo, hi = np.zeros(len(P1)), np.ones(len(P1))
    a, b = hi - _GOLDEN * (hi - lo), lo + _GOLDEN * (hi - lo)
    fa, fb = _trace_of_inverse(info1, info2, a), _trace_of_inverse(info1, info2, b)
    for _ in range(iterations):                              # golden section: the interval shrinks by 0.618
        left = fa < fb                                       # the minimum lies in [lo, b], else in [a, hi]
        hi, lo = np.where(left, b, hi), np.where(left, lo, a)
        new = np.where(left, hi - _GOLDEN * (hi - lo), lo + _GOLDEN * (hi - lo))
        f_new = _trace_of_inverse(info1, info2, new)
        a, fa, b, fb = (np.where(left, new, b), np.where(left, f_new, fb),
                        np.where(left, a, new), np.where(left, fa, f_new))
    omega = 0.5 * (lo + hi)
    # candidates: ½ first (an equal pair: tr P is flat in ω, and the plain average is the symmetric choice), the
    # search's ω, and the end points (keep one input); the first within rounding of the least tr P is taken.
    # Rounding of tr P grows with the inputs' condition number (a near-singular pair: 1e-12 relative at κ ~ 3e4,
    # where a fixed 1e-12 let the order of two equal inputs pick ω = 0.16 or 0.84)
    candidates = np.stack([np.full_like(omega, 0.5), omega, np.zeros_like(omega), np.ones_like(omega)])
    cost = np.stack([_trace_of_inverse(info1, info2, c) for c in candidates])
    rounding = 1e-12 + 100 * np.finfo(float).eps * np.maximum(np.linalg.cond(P1), np.linalg.cond(P2))
    best = np.argmax(cost <= cost.min(axis=0) * (1 + rounding), axis=0)
    return candidates[best, np.arange(len(omega))]


def covariance_intersection(x1: np.ndarray, P1: np.ndarray, x2: np.ndarray, P2: np.ndarray
                            ) -> tuple[np.ndarray, np.ndarray]:
    """Fuse two estimates of the same points without assuming their errors independent (module docstring).
    x1, x2 (N, 3); P1, P2 (N, 3, 3) -> x (N, 3), P (N, 3, 3)."""
    x1, x2 = np.asarray(x1, float), np.asarray(x2, float)
    P1, P2 = np.asarray(P1, float), np.asarray(P2, float)
    if len(x1) == 0:
        return x1.copy(), P1.copy()
    # the input of smaller trace first, so that the result does not depend on the order of the two
    swap = (np.trace(P2, axis1=1, axis2=2) < np.trace(P1, axis1=1, axis2=2))[:, None]
    x1, x2 = np.where(swap, x2, x1), np.where(swap, x1, x2)
    P1, P2 = np.where(swap[..., None], P2, P1), np.where(swap[..., None], P1, P2)
    omega = intersection_weights(P1, P2)[:, None, None]
    info1, info2 = omega * _information(P1), (1.0 - omega) * _information(P2)
    P = np.linalg.inv(info1 + info2)
    x = np.einsum("nij,nj->ni", P, np.einsum("nij,nj->ni", info1, x1) + np.einsum("nij,nj->ni", info2, x2))
    return x, 0.5 * (P + np.swapaxes(P, -1, -2))
