"""One point, one landmark in the exported map: coincident landmarks merged at export, the filter untouched.

A rendered run's map holds ~23 % duplicates (docs/fastslam-history.md, "Session 17: coincident landmarks merged at
export"): the front end reports two corners of one texture blob, and U-SURF's look changes with the range, so the
filter makes a point again where its descriptor no longer matches. Merging them inside the filter cost ATE
(sessions 9-11): a reading that makes or joins a merged landmark stops localizing the robot. Merging them in the
*exported* map costs the filter nothing.

The test is the map's own: two landmarks of the exported particle are one point when their positions coincide
under that particle's own covariances (conditional on its trajectory, where the two share every pose error:
d² < χ²₃ at ``level`` under Σ_a + Σ_b), and no descriptor test: on the rendered runs the descriptors of one point
are 0.5-0.8 apart across ranges, and a descriptor test at 0.8 halved the merges without lowering the share of
wrong ones (measured). Each landmark merges at most once a round, the closest pairs first (not the smallest d²: a
young landmark with a wide covariance would otherwise take a farther partner first); the rounds repeat until no
pair passes, so a point made three times becomes one landmark.

The merged landmark is the moment-matched mixture of the two exported Gaussians, weighted by their sighting
counts: mean the weighted mean, covariance the weighted covariances plus the spread of the two means. If the two
were two close points (> 10 cm apart for 6-12 % of the merges on the rendered runs, median 0.12-0.16 m: below
the stereo's depth resolution at range), the covariance still covers both: the
map loses a point it could not resolve, and does not claim a wrong one. The older landmark (lower id) keeps its id,
descriptor and frame drift; counts add; ``metadata["merged_at_export"]`` lists (kept id, merged id).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..landmark_map import LandmarkMap

CHI2_3_95 = 7.815


def coincident_pairs(positions: np.ndarray, covariances: np.ndarray, level: float = CHI2_3_95) -> np.ndarray:
    """(M, 2) index pairs (i < j) of points (N, 3) that coincide under covariances (N, 3, 3): d² < ``level``
    under Σ_i + Σ_j, each index in at most one pair, the closest pairs first."""
    positions = np.asarray(positions, float).reshape(-1, 3)
    covariances = np.asarray(covariances, float).reshape(-1, 3, 3)
    n = len(positions)
    if n < 2:
        return np.zeros((0, 2), np.int64)
    largest = np.linalg.eigvalsh(covariances)[:, -1]
    # |d|² ≤ d² λ_max(Σ_i + Σ_j) ≤ level (λ_i + λ_max): no pair beyond this radius can pass
    radius = np.sqrt(level * (np.maximum(largest, 0.0) + largest.max()))
    near = cKDTree(positions).query_ball_point(positions, radius)
    i = np.repeat(np.arange(n), [len(b) for b in near])
    j = np.concatenate([np.asarray(b, np.int64) for b in near])
    keep = i < j
    i, j = i[keep], j[keep]
    if len(i) == 0:
        return np.zeros((0, 2), np.int64)
    d = positions[i] - positions[j]
    d2 = np.einsum("ni,ni->n", d, np.linalg.solve(covariances[i] + covariances[j], d[..., None])[..., 0])
    passing = np.flatnonzero(d2 < level)
    used = np.zeros(n, bool)
    pairs = []
    for k in passing[np.argsort(np.einsum("ni,ni->n", d, d)[passing], kind="stable")]:
        a, b = i[k], j[k]
        if not (used[a] or used[b]):
            used[a] = used[b] = True
            pairs.append((a, b))
    return np.array(pairs, np.int64).reshape(-1, 2)


def merge_coincident(landmark_map: LandmarkMap, conditional_covariances: np.ndarray,
                     level: float = CHI2_3_95) -> LandmarkMap:
    """``landmark_map`` with its coincident landmarks merged (module docstring); ``conditional_covariances``
    (N, 3, 3): each landmark's covariance given the exported particle's trajectory, the test's (a merged
    landmark's is the same mixture of the two, so the next round judges it with its spread)."""
    ids = landmark_map.ids.copy()
    positions = landmark_map.positions.copy()
    covariances = landmark_map.covariances.copy()
    conditional = np.asarray(conditional_covariances, float).reshape(-1, 3, 3).copy()
    counts = landmark_map.counts.copy()
    seen_by = landmark_map.seen_by.copy()
    rows = np.arange(len(ids))             # each kept landmark's row in the input map
    merged: list[tuple[int, int]] = []
    while len(pairs := coincident_pairs(positions, conditional, level)):
        older = np.where(ids[pairs[:, 0]] <= ids[pairs[:, 1]], pairs[:, 0], pairs[:, 1])
        newer = pairs.sum(axis=1) - older
        wa = counts[older] / np.maximum(counts[older] + counts[newer], 1)
        wb = 1.0 - wa
        spread = positions[older] - positions[newer]
        outer = (wa * wb)[:, None, None] * np.einsum("ni,nj->nij", spread, spread)
        for matrices in (covariances, conditional):
            matrices[older] = wa[:, None, None] * matrices[older] + wb[:, None, None] * matrices[newer] + outer
        positions[older] = wa[:, None] * positions[older] + wb[:, None] * positions[newer]
        counts[older] += counts[newer]
        seen_by[older] |= seen_by[newer]
        merged += zip(ids[older].tolist(), ids[newer].tolist(), strict=True)
        kept = np.ones(len(ids), bool)
        kept[newer] = False
        ids, positions, covariances, conditional = ids[kept], positions[kept], covariances[kept], conditional[kept]
        counts, seen_by, rows = counts[kept], seen_by[kept], rows[kept]
    if not merged:
        return landmark_map
    metadata = dict(landmark_map.metadata)
    metadata["merged_at_export"] = [list(pair) for pair in merged]

    def kept_rows(array):
        return None if array is None else array[rows]

    return LandmarkMap(
        positions, covariances, landmark_map.descriptors[rows], ids, counts,
        robot=landmark_map.robot, frame=landmark_map.frame, robots=landmark_map.robots, seen_by=seen_by,
        trajectory=landmark_map.trajectory, metadata=metadata,
        drift_covariances=kept_rows(landmark_map.drift_covariances),
        drift_origins=kept_rows(landmark_map.drift_origins),
        sighting_covariances=kept_rows(landmark_map.sighting_covariances))
