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
    """vᵀ A⁻¹ v for v (..., n) and A⁻¹ (..., n, n) -> (...)."""
    return np.sum(v * matvec(a_inv, v), axis=-1)


def matvec(a: np.ndarray, v: np.ndarray) -> np.ndarray:
    """A v for stacks A (..., n, n), v (..., n) -> (..., n) (matmul: faster than einsum for small blocks)."""
    return (a @ v[..., None])[..., 0]


def transpose(a: np.ndarray) -> np.ndarray:
    """Aᵀ over the last two axes."""
    return np.swapaxes(a, -1, -2)


def sandwich(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """A B Aᵀ for stacks (..., n, n)."""
    return a @ b @ np.swapaxes(a, -1, -2)


def group_sum(index: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Sums of ``values`` (P, ...) grouped by ``index`` (P,) in [0, n) -> (n, ...) (bincount per element,
    much faster than ``np.add.at``)."""
    flat = values.reshape(len(values), int(np.prod(values.shape[1:])))
    out = np.stack([np.bincount(index, flat[:, c], minlength=n) for c in range(flat.shape[1])], axis=1)
    return out.reshape((n,) + values.shape[1:])
