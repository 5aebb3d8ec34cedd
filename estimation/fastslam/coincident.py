"""Readings of one frame that are one point by their own covariances (``FastSLAMConfig.coincident_readings``;
"all", the default, uses every reading as before).

Why (measured on the rendered building, ``benchmarks/rendered_duplicates.py``, docs/fastslam-history.md "Session 9"):
a Harris detector with non-maximum suppression over 5 px reports two corners on one texture blob 2-6 cm apart
at 3-6 m. On robot1 seed 0, 35 % of the exported map's duplicate pairs were made that way: the newer landmark
came from a reading of the very frame in which the best particle detected the older one, 4.7 cm away (median)
but with another look (descriptor distance 0.77), so it had no candidate and became a landmark.

Two rules:

- ``"no_twin_landmark"`` (:func:`twins_of_matched`): every reading is associated as before, but one that no
  landmark took and that coincides with a reading a landmark took in the same particle makes no new landmark
  (it is left unused): the twin of a detected point is that point again. Matched readings are never dropped,
  so the rule acts only where a duplicate would be made.
- ``"one_per_point"`` (:func:`one_per_point`): before association, a greedy non-maximum suppression in 3-D
  with each reading's covariance as its radius, the most precise first (smallest trace, as ``selection.py``'s
  "nearest"). It also drops readings a landmark would have taken: on robot1 seed 0, 35 % of the readings
  coincide with another of their frame, and only 20 % of those pairs are one 5 cm cluster.

"Coincide": d² = (z_i − z_j)ᵀ (Q_i + Q_j)⁻¹ (z_i − z_j) < χ²₃ 95 % (the merge's test), Q the filter's, with
the observation floor (the corner's own slide along the texture, which the triangulation does not model).
"""
from __future__ import annotations

import numpy as np

GATE = 7.815   # χ²₃ 95 %: the merge's test of "one point"
RULES = ("all", "one_per_point", "no_twin_landmark")


def coincident_pairs(points: np.ndarray, covariances: np.ndarray, gate: float = GATE) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i, j), i < j, of readings (N, 3) with covariances (N, 3, 3) that coincide: d² < gate under
    Q_i + Q_j."""
    points = np.asarray(points, float).reshape(-1, 3)
    covariances = np.asarray(covariances, float).reshape(-1, 3, 3)
    i, j = np.triu_indices(len(points), 1)
    if len(i) == 0:
        return i, j
    diff = points[i] - points[j]
    d2 = np.einsum("pi,pi->p", diff, np.linalg.solve(covariances[i] + covariances[j], diff[..., None])[..., 0])
    close = d2 < gate
    return i[close], j[close]


def twins_of_matched(points: np.ndarray, covariances: np.ndarray, matched_m: np.ndarray, matched_j: np.ndarray,
                     n_particles: int) -> np.ndarray:
    """(M·N,) bool, indexed m·N + j: reading j coincides with a reading that particle m matched to a landmark
    (``matched_m``, ``matched_j`` (K,)), so in particle m it is that point again and makes no new landmark."""
    n = len(np.asarray(points).reshape(-1, 3))
    out = np.zeros(n_particles * n, bool)
    i, j = coincident_pairs(points, covariances)
    if len(i) == 0 or len(matched_m) == 0:
        return out
    a, b = np.concatenate([i, j]), np.concatenate([j, i])        # both directions: a matched, b its twin
    order = np.argsort(a, kind="stable")
    a, b = a[order], b[order]
    lo, hi = np.searchsorted(a, matched_j, "left"), np.searchsorted(a, matched_j, "right")
    count = hi - lo
    if not count.any():
        return out
    m = np.repeat(np.asarray(matched_m, np.int64), count)
    starts = np.repeat(lo, count) + (np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count))
    out[m * n + b[starts]] = True
    return out


def one_per_point(points: np.ndarray, covariances: np.ndarray, gate: float = GATE) -> np.ndarray:
    """Mask (N,) of the readings to keep from points (N, 3) and their covariances (N, 3, 3): every dropped
    reading coincides (d² < ``gate`` under Q_i + Q_j) with a kept one that is at least as precise, and no two
    kept ones coincide."""
    points = np.asarray(points, float).reshape(-1, 3)
    covariances = np.asarray(covariances, float).reshape(-1, 3, 3)
    n = len(points)
    keep = np.ones(n, bool)
    if n < 2 or gate <= 0:
        return keep
    i, j = coincident_pairs(points, covariances, gate)
    if len(i) == 0:
        return keep
    neighbours: dict[int, list[int]] = {}
    for a, b in zip(i.tolist(), j.tolist(), strict=True):
        neighbours.setdefault(a, []).append(b)
        neighbours.setdefault(b, []).append(a)
    order = np.argsort(np.trace(covariances, axis1=1, axis2=2), kind="stable")
    for k in order.tolist():
        if keep[k] and k in neighbours:
            for other in neighbours[k]:
                if keep[other] and other != k:
                    # k is the more precise of the two (taken first): the other is the same point again
                    keep[other] = False
    return keep
