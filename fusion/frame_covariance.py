"""How far an alignment can be from the true relative pose of the two robots' start frames.

The weighted least-squares fit (``alignment.refine_pose``) reports the alignment's own precision, (JᵀWJ)⁻¹,
which treats every support's landmark error as independent: with 40 supports it is ~6× smaller in σ than
one landmark's.  That is the right uncertainty for placing one map on the other, but not against the truth
of the start frames.  A map's landmarks near one another share most of their error — the drift of the
robot's pose when it mapped them (``estimation.fastslam.drift``: the exported covariance is the particle
mixture plus that drift) — so the whole overlap of a map can be off its start frame by about one landmark's
σ, and no number of supports averages that away (docs/fusion.md: the demo's and MRCLAM's "frame error").

Worst case for any correlation inside a map.  The fitted pose is linear in the landmark errors,
δpose = Σ_k A_k δr_k with A_k = (JᵀWJ)⁻¹ J_kᵀ W_k.  In any direction u the standard deviation of a sum is
at most the sum of the standard deviations (Minkowski), whatever the correlations:

    σ_u ≤ Σ_k sqrt(uᵀ A_k P_k A_kᵀ u)

with equality when the errors move together, as a drifted frame moves every landmark of the overlap
rigidly.  The two maps are independent of each other (their sums add in quadrature) and the position floor is
independent per landmark.  The covariance reported is each map's independent-error covariance Σ_k A_k P_k A_kᵀ
scaled by the largest ratio of that bound to it over a fixed set of directions (between 1 and the number of
supports), then by the supports' reduced χ² when their residuals show the covariances too small.  It covers
the truth when the maps' covariances cover their landmarks' errors; it cannot when they do not (a map warped
by time-shifted observations whose covariances say centimetres), which is the map's error to fix.
"""
from __future__ import annotations

import numpy as np


def _unit_directions() -> np.ndarray:
    """13 directions in 3-D: the axes, the face diagonals and the body diagonals (one of each ± pair)."""
    dirs = []
    for v in np.ndindex(3, 3, 3):
        d = np.array(v, float) - 1.0
        if np.any(d) and tuple(-d) not in {tuple(x) for x in dirs}:
            dirs.append(d)
    out = np.array(dirs)
    return out / np.linalg.norm(out, axis=1, keepdims=True)


_DIRECTIONS = _unit_directions()


def _correlation_scale(terms: np.ndarray, total: np.ndarray) -> float:
    """max over directions of (Σ_k σ_k(u))² / σ²_independent(u), in [1, K]: how much fully correlated errors
    (terms (K, 3, 3), their sum ``total``) can add over independent ones.  Directions are taken in the
    coordinates that whiten ``total`` (plus its eigenvectors), so no axis or unit dominates."""
    try:
        L = np.linalg.cholesky(total)
    except np.linalg.LinAlgError:
        return float(len(terms))
    u = np.linalg.solve(L.T, _DIRECTIONS.T).T                    # uᵀ total u = 1 for each direction
    _, vecs = np.linalg.eigh(total)
    u = np.vstack([u, vecs.T / np.sqrt(np.einsum("di,ij,dj->d", vecs.T, total, vecs.T))[:, None]])
    sigma = np.sqrt(np.maximum(np.einsum("di,kij,dj->dk", u, terms, u), 0.0))   # (D, K)
    # min(max(·, 1), K) as np.clip does it (NaN through), without its call overhead on one number
    return float(min(max(float(np.max(np.sum(sigma, axis=1) ** 2)), 1.0), float(len(terms))))


def start_frame_covariance(p1: np.ndarray, P1: np.ndarray, p2: np.ndarray, P2: np.ndarray, pose,
                           floor: float = 0.02) -> np.ndarray:
    """Covariance (3, 3) of an alignment ``pose`` (tx, ty, θ) fitted on supports p1 (K, 3) in map 1 and p2 (K, 3)
    in map 2 with covariances P1, P2 (K, 3, 3), as an estimate of the true relative pose of the start frames:
    each map's landmark errors taken as possibly fully correlated (see the module docstring), the position
    floor independent, scaled by the reduced χ² of the residuals when above 1."""
    p1, p2 = np.asarray(p1, float), np.asarray(p2, float)
    theta = float(np.asarray(pose, float)[2])
    c, s = np.cos(theta), np.sin(theta)
    R = np.array([[c, -s], [s, c]])
    q = p2[:, :2] @ R.T
    r = p1[:, :2] - (q + np.asarray(pose, float)[:2])
    P1xy = P1[:, :2, :2]
    P2xy = R @ P2[:, :2, :2] @ R.T
    S = P1xy + P2xy + floor ** 2 * np.eye(2)
    W = np.linalg.inv(S)
    J = np.zeros((len(q), 2, 3))
    J[:, 0, 0] = J[:, 1, 1] = 1.0
    J[:, 0, 2], J[:, 1, 2] = -q[:, 1], q[:, 0]
    H = np.einsum("kji,kjl,klm->im", J, W, J)
    A = np.einsum("im,kml->kil", np.linalg.inv(H), np.einsum("kji,kjl->kil", J, W))   # (K, 3, 2)
    terms1 = A @ P1xy @ np.swapaxes(A, 1, 2)                       # (K, 3, 3) map 1's share per support
    terms2 = A @ P2xy @ np.swapaxes(A, 1, 2)
    independent = floor ** 2 * np.einsum("kij,klj->il", A, A)
    cov = independent.copy()
    for terms in (terms1, terms2):
        total = terms.sum(axis=0)
        cov += _correlation_scale(terms, total) * total
    dof = 2 * len(q) - 3
    if dof > 0:
        chi2 = float(np.einsum("ki,kij,kj->", r, W, r))
        cov *= max(1.0, chi2 / dof)
    return 0.5 * (cov + cov.T)
