"""Batched small-matrix helpers (closed forms beat LAPACK's per-call overhead for thousands of 3×3s)."""
from __future__ import annotations

import numpy as np


def inv3(a: np.ndarray) -> np.ndarray:
    """Inverses (..., 3, 3) of (..., 3, 3) matrices by the adjugate (callers pass well-conditioned SPD)."""
    a00, a01, a02 = a[..., 0, 0], a[..., 0, 1], a[..., 0, 2]
    a10, a11, a12 = a[..., 1, 0], a[..., 1, 1], a[..., 1, 2]
    a20, a21, a22 = a[..., 2, 0], a[..., 2, 1], a[..., 2, 2]
    c00 = a11 * a22 - a12 * a21
    c01 = a02 * a21 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    c10 = a12 * a20 - a10 * a22
    c11 = a00 * a22 - a02 * a20
    c12 = a02 * a10 - a00 * a12
    c20 = a10 * a21 - a11 * a20
    c21 = a01 * a20 - a00 * a21
    c22 = a00 * a11 - a01 * a10
    det = a00 * c00 + a01 * c10 + a02 * c20
    out = np.stack([np.stack([c00, c01, c02], -1), np.stack([c10, c11, c12], -1),
                    np.stack([c20, c21, c22], -1)], -2)
    return out / det[..., None, None]


def symmetrise(a: np.ndarray) -> np.ndarray:
    """(A + Aᵀ)/2 over the last two axes: keeps covariances symmetric against round-off."""
    return 0.5 * (a + np.swapaxes(a, -1, -2))


def quadratic_form(v: np.ndarray, a_inv: np.ndarray) -> np.ndarray:
    """vᵀ A⁻¹ v for v (..., 3) and A⁻¹ (..., 3, 3) -> (...)."""
    return np.einsum("...i,...ij,...j->...", v, a_inv, v)
