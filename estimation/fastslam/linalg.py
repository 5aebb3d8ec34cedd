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


# -- symmetric 3×3 matrices as six component arrays --------------------------------------------------------
# A stack of P symmetric matrices is a (6, P) array of its upper triangle (xx, xy, xz, yy, yz, zz): every
# operation below is a few dozen elementwise operations on length-P rows, ~100× faster than stacked matmul
# or LAPACK calls on (P, 3, 3) (numpy's batched matmul has a large per-matrix overhead for 3×3 blocks).
UPPER = (0, 1, 2, 4, 5, 8)                                   # positions of the six components in a flat 3×3
_SYM = ((0, 1, 2), (1, 3, 4), (2, 4, 5))                     # _SYM[i][k]: component index of element (i, k)


def sym_components(a: np.ndarray) -> np.ndarray:
    """(6, P) components of symmetric matrices given as (P, 3, 3) or flattened (P, 9)."""
    return np.ascontiguousarray(np.asarray(a).reshape(-1, 9)[:, UPPER].T)


def sym_matrices(s: np.ndarray) -> np.ndarray:
    """(P, 3, 3) matrices from (6, P) components (inverse of :func:`sym_components`)."""
    return s[[0, 1, 2, 1, 3, 4, 2, 4, 5]].T.reshape(-1, 3, 3)


def sym_adjugate(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Adjugate (6, P) and determinant (P,) of symmetric matrices (6, P): S⁻¹ = adj / det."""
    a, b, c, d, e, f = s
    adj = np.empty_like(s)
    np.subtract(d * f, e * e, out=adj[0])
    np.subtract(c * e, b * f, out=adj[1])
    np.subtract(b * e, c * d, out=adj[2])
    np.subtract(a * f, c * c, out=adj[3])
    np.subtract(b * c, a * e, out=adj[4])
    np.subtract(a * d, b * b, out=adj[5])
    det = a * adj[0] + b * adj[1] + c * adj[2]
    return adj, det


def sym_inverse(s: np.ndarray) -> np.ndarray:
    """(6, P) inverses of symmetric positive-definite matrices (6, P)."""
    adj, det = sym_adjugate(s)
    return adj / det


def sym_matvec(s: np.ndarray, v: np.ndarray) -> np.ndarray:
    """S v (3, P) for symmetric S (6, P) and vectors v (3, P)."""
    return np.stack([s[_SYM[i][0]] * v[0] + s[_SYM[i][1]] * v[1] + s[_SYM[i][2]] * v[2] for i in range(3)])


def sym_quadratic(s: np.ndarray, v: np.ndarray) -> np.ndarray:
    """vᵀ S v (P,) for symmetric S (6, P) and v (3, P)."""
    x, y, z = v
    return (s[0] * x * x + s[3] * y * y + s[5] * z * z
            + 2.0 * (s[1] * x * y + s[2] * x * z + s[4] * y * z))


def sym_product(a: np.ndarray, b: np.ndarray) -> list[list[np.ndarray]]:
    """A B as nested lists [i][j] of (P,) rows (a full, generally unsymmetric matrix) for symmetric A, B (6, P)
    (lists, not a stacked array: callers only index it, and stacking would copy)."""
    return [[a[_SYM[i][0]] * b[_SYM[0][j]] + a[_SYM[i][1]] * b[_SYM[1][j]] + a[_SYM[i][2]] * b[_SYM[2][j]]
             for j in range(3)] for i in range(3)]


def sym_rotate_z(c: np.ndarray, s: np.ndarray, q: np.ndarray) -> np.ndarray:
    """R Q Rᵀ (6, ...) for R = R_z(θ) given c = cos θ, s = sin θ (broadcastable) and symmetric Q (6, ...)."""
    xx, xy, xz, yy, yz, zz = q
    cc, ss, cs = c * c, s * s, c * s
    out = np.empty((6,) + np.broadcast_shapes(np.shape(c), np.shape(xx)))
    cs_xy = 2.0 * cs * xy
    out[0] = cc * xx - cs_xy + ss * yy
    out[1] = cs * (xx - yy) + (cc - ss) * xy
    out[2] = c * xz - s * yz
    out[3] = ss * xx + cs_xy + cc * yy
    out[4] = s * xz + c * yz
    out[5] = zz
    return out


_UPPER_PAIRS = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def full_sym_product(k, s: np.ndarray) -> list[list[np.ndarray]]:
    """K S as nested lists [i][j] of (P,) rows for a full K ([i][j] of (P,) rows) and symmetric S (6, P)."""
    return [[k[i][0] * s[_SYM[0][j]] + k[i][1] * s[_SYM[1][j]] + k[i][2] * s[_SYM[2][j]] for j in range(3)]
            for i in range(3)]


def joseph_update(s: np.ndarray, k, r: np.ndarray) -> np.ndarray:
    """(I − K) S (I − K)ᵀ + K R Kᵀ (6, P) for symmetric S, R (6, P) and a gain K ([i][j] of (P,) rows; any K, not
    only the optimal one), as S − KS − (KS)ᵀ + K (S + R) Kᵀ on the upper triangle, so the result is symmetric."""
    ks = full_sym_product(k, s)
    kb = full_sym_product(k, s + r)
    out = np.empty_like(s)
    for n, (i, j) in enumerate(_UPPER_PAIRS):
        out[n] = s[_SYM[i][j]] - ks[i][j] - ks[j][i] + kb[i][0] * k[j][0] + kb[i][1] * k[j][1] + kb[i][2] * k[j][2]
    return out


def sym_cholesky(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lower Cholesky factors (6, P) of symmetric S (6, P), packed (l00, l10, l20, l11, l21, l22), and an (P,)
    bool telling which S are numerically positive definite (every pivot finite and > 0). Where not, the
    factor's entries are meaningless (zeros); callers decide what to do with those columns."""
    a, b, c, d, e, f = s
    with np.errstate(invalid="ignore", divide="ignore"):
        l00 = np.sqrt(a)
        l10, l20 = b / l00, c / l00
        p11 = d - l10 * l10
        l11 = np.sqrt(p11)
        l21 = (e - l20 * l10) / l11
        p22 = f - l20 * l20 - l21 * l21
        l22 = np.sqrt(p22)
        out = np.stack([l00, l10, l20, l11, l21, l22])
    ok = (a > 0) & (p11 > 0) & (p22 > 0) & np.all(np.isfinite(out), axis=0)
    out[:, ~ok] = 0.0
    return out, ok


def lower_matvec(l6: np.ndarray, v: np.ndarray) -> np.ndarray:
    """L v (3, P) for packed lower-triangular L (6, P) (see :func:`sym_cholesky`) and v (3, P)."""
    l00, l10, l20, l11, l21, l22 = l6
    return np.stack([l00 * v[0], l10 * v[0] + l11 * v[1], l20 * v[0] + l21 * v[1] + l22 * v[2]])


def pose_uncertainty(p6: np.ndarray, lever: np.ndarray) -> np.ndarray:
    """H P Hᵀ (6, P) in the world frame for pose covariances P (6, P) and landmark offsets w = μ − t (2, P):
    H = [[−1, 0, w_y], [0, −1, −w_x], [0, 0, 0]], the filter's world-frame pose Jacobian (its gate, and the
    known-ID gate's drift terms in id_gate.py)."""
    a, b = lever[1], -lever[0]
    out = np.zeros_like(p6)
    out[0] = p6[0] - 2.0 * a * p6[2] + a * a * p6[5]
    out[1] = p6[1] - b * p6[2] - a * p6[4] + a * b * p6[5]
    out[3] = p6[3] - 2.0 * b * p6[4] + b * b * p6[5]
    return out
