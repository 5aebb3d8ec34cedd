"""How bent a map can be, from its own file: each landmark's covariance about the map's rigid placement.

A FastSLAM map's exported covariance of landmark l (``mixture+drift``) is the particle cloud's (local, millimetres on
MRCLAM) plus C_l = H_l D_l H_lᵀ, the effect of the frame's drift D_l (the robot's pose covariance relative to the
start frame when it made l, ``estimation.fastslam.drift``).  Most of that drift is *shared*: landmarks made from one
stretch of the route carry one pose error, which moves them together, and an alignment removes it.  What a merge
must weigh is the rest, the map's bend.  The map file keeps D_l and where the robot was when it made l (o_l,
``LandmarkMap.drift_origins``), which is enough to say which landmarks share their drift.

Model (the drift tracker's chain, first order): the pose error at the making of the landmark with the smaller drift,
e, is carried on along the route to the other, so two landmarks a, b share

    Cov(e_a, e_b) = H(x_a, o_e) D_e H(x_b, o_e)ᵀ,   e = a or b, whichever has the smaller tr D,
    H(x, o) = [[1, 0, −(x_y − o_y)], [0, 1, x_x − o_x]]      (∂ landmark / ∂ pose at o)

and each its own local part (the file's covariance minus C_l).  The landmarks' covariance about the map's best rigid
placement is the joint covariance K projected off the rigid motions: (I − A A⁺) K (I − A A⁺)ᵀ, A (2N, 3) the
motions of the plane about the landmarks' centroid.  Only its (2, 2) diagonal blocks are returned (computed without
forming K when N is large: K's diagonal blocks are the file's covariances, and A⁺ K needs one pass over the pairs).

Where this departs from the paper: the paper weighs each landmark by its EKF covariance and takes the maps as
independent; FastSLAM's EKF covariance is conditional on the particle's trajectory and forgets the frame's drift,
while the drift as exported (``mixture+drift``) is mostly rigid, so neither is the error that merging averages.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import minimize

from estimation.landmark_map import LandmarkMap


def _lever(points: np.ndarray, origins: np.ndarray) -> np.ndarray:
    """H (..., 2, 3) of points (..., 2) about origins (..., 2)."""
    w = points - origins
    h = np.zeros(w.shape[:-1] + (2, 3))
    h[..., 0, 0] = h[..., 1, 1] = 1.0
    h[..., 0, 2], h[..., 1, 2] = -w[..., 1], w[..., 0]
    return h


def rigid_motions(points: np.ndarray) -> np.ndarray:
    """A (N, 2, 3): each point's displacement per unit translation (x, y) and rotation about the centroid."""
    points = np.asarray(points, float)[:, :2]
    return _lever(points, points.mean(axis=0))


def shape_covariances(landmark_map: LandmarkMap, floor: float = 1e-8) -> np.ndarray | None:
    """(N, 2, 2) planar covariance of each landmark about the map's best rigid placement (module docstring), in the
    map's frame; None when the file keeps no drift (``drift_covariances``) or the map has fewer than 3 landmarks.
    Eigenvalues are floored at ``floor`` m² (the chain model's cross terms need not make an exactly PSD K)."""
    terms = _projection(landmark_map)
    if terms is None:
        return None
    total, A, G, F = terms
    AG = np.einsum("nki,inj->nkj", A, G)                                 # (A A⁺ K)_ll
    shape = total - AG - np.swapaxes(AG, 1, 2) + A @ F @ np.swapaxes(A, 1, 2)
    return _psd(shape, floor)


def rigid_covariance(landmark_map: LandmarkMap) -> np.ndarray | None:
    """(3, 3) covariance of the map's rigid placement error the file claims (A⁺ K A⁺ᵀ): translation at the landmarks'
    centroid (x, y) and rotation about it; what an alignment removes.  None as :func:`shape_covariances`."""
    terms = _projection(landmark_map)
    return None if terms is None else _psd(terms[3], 0.0)


def _projection(m: LandmarkMap) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """K's diagonal blocks (N, 2, 2), A (N, 2, 3), G = A⁺ K (3, N, 2) and F = A⁺ K A⁺ᵀ (3, 3)."""
    if m.drift_covariances is None or len(m) < 3:
        return None
    x = m.positions[:, :2]
    D, o = m.drift_covariances, m.drift_origins
    # K's diagonal blocks: C_l at the landmark's present position plus the local part, the file's covariance less
    # that C_l (clipped at zero: the file's C_l was taken where the landmark was made, which it has moved from)
    C = _lever(x, o) @ D @ np.swapaxes(_lever(x, o), 1, 2)
    total = C + _psd(m.covariances[:, :2, :2] - C, 0.0)
    A = rigid_motions(x)                              # (N, 2, 3)
    information = np.einsum("nki,nkj->ij", A, A)
    tr = np.trace(D, axis1=1, axis2=2)
    AtK = np.zeros((3, len(m), 2))                    # Aᵀ K, column block b
    for b in range(len(m)):
        e = np.where(tr <= tr[b], np.arange(len(m)), b)                  # the pair's smaller drift
        Ha = _lever(x, o[e])                                             # (N, 2, 3)
        Hb = _lever(x[b][None], o[e])                                    # (N, 2, 3)
        block = Ha @ D[e] @ np.swapaxes(Hb, 1, 2)                        # K_ab (N, 2, 2)
        block[b] = total[b]
        AtK[:, b] = np.einsum("nki,nkj->ij", A, block)
    G = np.linalg.solve(information, AtK.reshape(3, -1)).reshape(3, len(m), 2)   # A⁺ K
    GA = np.einsum("ink,nkj->ij", G, A)
    F = np.linalg.solve(information, GA.T).T                             # A⁺ K A⁺ᵀ = G A (AᵀA)⁻¹
    return total, A, G, 0.5 * (F + F.T)


def _psd(P: np.ndarray, floor: float) -> np.ndarray:
    """(..., n, n) symmetrised, eigenvalues raised to ``floor``."""
    w, v = np.linalg.eigh(0.5 * (P + np.swapaxes(P, -1, -2)))
    return v @ (np.maximum(w, floor)[..., None] * np.swapaxes(v, -1, -2))


def shape_levels(maps: list[LandmarkMap], shapes: list[np.ndarray], alignments) -> tuple[float, float] | None:
    """(a, b): every landmark of every map takes the planar covariance a I + b S_l (S_l its shape covariance,
    :func:`shape_covariances`), a and b one pair for all maps, by maximum likelihood on the found pairs' supports: the
    residual r of a support after its alignment ~ N(0, 2 a I + b (S_i + R S_j Rᵀ)), the likelihood of each pair scaled
    by (2 S − 3) / 2 S (3 pose parameters fitted).  None without a found pair of two or more supports.

    Why a floor a: the file's local part (the particle cloud's covariance) is millimetres on MRCLAM, so the projected
    S_l can be nearly singular across the direction the drift bends a landmark, while the landmarks also err a few
    centimetres on their own (the sensor).  Why b: the files say which map and which landmark is bent how much
    relative to the others, but their level rests on the filter's own chain of mean drifts, which is pessimistic
    (MRCLAM: about 4x the real scatter, docs/fusion-history.md "Session 10").  Two numbers for all maps are well
    determined by all pairs together, where a level per map (the three-cornered hat, ``fusion.multi.covariance_scales``)
    is a small difference of large pair variances."""
    residuals, covs, weights = [], [], []
    for i, j, p, c, R, r, w in _support_residuals(maps, alignments):
        residuals.append(r)
        covs.append(shapes[i][p] + R @ shapes[j][c] @ R.T)
        weights.append(np.full(len(p), w))
    if not residuals:
        return None
    r, S, w = np.concatenate(residuals), np.concatenate(covs), np.concatenate(weights)

    def cost(log_ab: np.ndarray) -> float:
        a, b = np.exp(log_ab)
        total = 2 * a * np.eye(2) + b * S
        _, logdet = np.linalg.slogdet(total)
        return float(np.sum(w * (logdet + np.einsum("ki,ki->k", r, np.linalg.solve(total, r[..., None])[..., 0]))))

    start = np.log([max(float(np.mean(r ** 2)) / 4, 1e-8), 1.0])
    best = minimize(cost, start, method="Nelder-Mead", options={"xatol": 1e-4, "fatol": 1e-6, "maxiter": 2000})
    a, b = np.exp(best.x)
    return float(a), float(b)


def _support_residuals(maps: list[LandmarkMap], alignments):
    """Per found pair (i, j) of two or more supports: (i, j, its supports' rows p in map i and c in map j, the planar
    rotation R (2, 2) of its pose, the supports' planar residuals x_i − (R x_j + t) (S, 2), and the pair's weight
    (2 S − 3) / 2 S: S supports, 3 pose parameters fitted to them).  What :func:`shape_levels` and
    :func:`spread_level` fit their levels on."""
    for (i, j), a in alignments.items():
        if not a.found or len(a.supports) < 2:
            continue
        R = np.array([[np.cos(a.pose[2]), -np.sin(a.pose[2])], [np.sin(a.pose[2]), np.cos(a.pose[2])]])
        p, c = a.supports[:, 0], a.supports[:, 1]
        r = maps[i].positions[p, :2] - (maps[j].positions[c, :2] @ R.T + np.asarray(a.pose[:2], float))
        yield i, j, p, c, R, r, (2 * len(p) - 3) / (2 * len(p))


def shape_calibrated(landmark_map: LandmarkMap, shape: np.ndarray, levels: tuple[float, float]) -> LandmarkMap:
    """``landmark_map`` whose planar covariances are a I + b × ``shape`` (N, 2, 2), (a, b) = ``levels`` (xy–z terms 0,
    z kept): what
    ``fusion.multi.fuse_all(calibration="drift")`` merges.  The drift fields are dropped (they described the claims
    this replaces)."""
    P = landmark_map.covariances.copy()
    P[:, :2, :2] = levels[0] * np.eye(2) + levels[1] * shape
    P[:, :2, 2] = P[:, 2, :2] = 0.0
    m = landmark_map
    return LandmarkMap(m.positions, P, m.descriptors, m.ids, m.counts, m.robot, m.frame, list(m.robots), m.seen_by,
                       m.trajectory, dict(m.metadata))


def sighting_variances(landmark_map: LandmarkMap, per: str = "sighting") -> np.ndarray | None:
    """(N,) per-axis planar variance of each landmark from its file's sightings' spread (``sighting_covariances``,
    ``estimation.sighting_spread``), or None when the file keeps none.

    per="sighting": tr S_l,xy / 2 × n/(n − 1), the spread of one sighting about the landmark (n = its count; the
    factor because the estimate is nearly the sightings' mean); per="mean": that over n, the error of the mean were the
    sightings independent.  A landmark with fewer than 2 sightings (nothing known of its spread) takes the map's
    largest value: a landmark the map cannot check against itself is trusted least."""
    S = landmark_map.sighting_covariances
    if S is None:
        return None
    if per not in ("sighting", "mean"):
        raise ValueError(f"per must be 'sighting' or 'mean', not {per!r}")
    n = landmark_map.counts.astype(float)
    known = n >= 2
    v = np.trace(S[:, :2, :2], axis1=1, axis2=2) / 2 * np.where(known, n / np.maximum(n - 1, 1), 1.0)
    if per == "mean":
        v = v / np.maximum(n, 1)
    known &= v > 0
    if not known.any():
        return None
    return np.where(known, v, v[known].max())


def spread_level(maps: list[LandmarkMap], spreads: list[np.ndarray], alignments) -> float | None:
    """b: every landmark of every map takes the planar covariance b v_l I (v_l its per-axis variance from its map's
    sightings, :func:`sighting_variances`), b one number for all maps, by maximum likelihood on the found pairs'
    supports: r ~ N(0, b (v_i + v_j) I₂), so b = Σ w |r|² / (v_i + v_j) / (2 Σ w), w = (2S − 3) / 2S per pair of S
    supports (3 pose parameters fitted).  None without a found pair of two or more supports.

    Why one factor and no floor (unlike :func:`shape_levels`): the sightings' spread is never near singular (it holds
    the sensor's noise), and with one factor the merge's weights are the files' own ratios — two maps determine it,
    where a floor and a factor are not told apart by one pair."""
    num, den = 0.0, 0.0
    for i, j, p, c, _, r, w in _support_residuals(maps, alignments):
        num += w * float(np.sum(np.sum(r ** 2, axis=1) / (spreads[i][p] + spreads[j][c])))
        den += 2 * w * len(p)
    return None if den == 0 else num / den
