"""Map merging: one map from two aligned maps (Section 4 of the ISR 2009 paper, formulas made right).

Common landmarks are found by

* Method 1 — the RANSAC supports of the alignment (close in position *and* similar in descriptor);
* Method 2 — after alignment, mutual nearest neighbours in position within a gate (Euclidean th2 in the
  paper preset, a 3-D Mahalanobis gate in the robust one), hence one-to-one.

Each common pair is fused by the stationary Kalman update (vectorised over landmarks; ``rule="kalman"``, the
default):

    K = P1 (P1 + P2)⁻¹          (eq. 6)
    x = x1 + K (x2 − x1)        (eq. 7 — the text has (x1 − x2), which moves the mean *away* from map 2)
    P = (I − K) P1, symmetrised (eq. 8 — the text multiplies the coordinates C1 instead of the covariance)

where x2, P2 are map 2's estimate expressed in map 1's frame: x2 = R x2' + t and P2 = R P2' Rᵀ (the text
forgets to rotate the covariance), plus, when the alignment carries a covariance Σ (robust preset),
J Σ Jᵀ with J = ∂(R x2' + t)/∂(tx, ty, θ), so that an uncertain alignment weighs map 2 less.  The Kalman update
takes the two maps' errors as independent; when they are not (robots that share sensors and landmarks, FastSLAM maps
on MRCLAM) ``rule="intersection"`` fuses by covariance intersection (``fusion.intersection``), whose covariance holds
for any correlation (docs/fusion-history.md, "Session 7: merging").  The fused
descriptor is the mean of the two, renormalised to unit length.  Landmarks seen by one robot only are
kept as they are (map 2's transformed into map 1's frame), and ``seen_by`` records which robots saw
each landmark.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from estimation.geometry import rot_z, transform_points
from estimation.landmark_map import LandmarkMap
from estimation.name_vote import VOTE_KEY

from .alignment import Alignment
from .alignment_config import PRESETS
from .errors import IncompatibleMapsError
from .intersection import covariance_intersection
from .pose_covariance import point_jacobians
from .provenance import source_metadata
from .ransac import CHI2_999, identity_pairs, landmark_identities


def kalman_fuse(x1: np.ndarray, P1: np.ndarray, x2: np.ndarray, P2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fuse two estimates of the same points.  x1, x2 (N, 3); P1, P2 (N, 3, 3) -> x (N, 3), P (N, 3, 3)."""
    S = P1 + P2 + 1e-12 * np.eye(3)                                # innovation covariance (ε: exact maps)
    # K = P1 S⁻¹; S and P1 symmetric, so K = (S⁻¹ P1)ᵀ
    K = np.swapaxes(np.linalg.solve(S, P1), -1, -2)
    x = x1 + np.einsum("nij,nj->ni", K, x2 - x1)                   # eq. 7, toward map 2
    P = P1 - K @ P1                                                # eq. 8, (I − K) P1
    return x, 0.5 * (P + np.swapaxes(P, -1, -2))


# How a landmark both maps hold is fused (docs/fusion-history.md, "Session 7: merging"): "kalman" is the paper's
# stationary Kalman update (eqs. 6–8, independent maps), the default: on maps whose errors are mostly their own
# (MRCLAM sightings) it makes the merged map better than the best single one.  "intersection" is covariance
# intersection (fusion.intersection), which holds for any correlation between the maps' errors: honest on FastSLAM
# maps that share their errors, but it gives up the averaging gain of independent ones.
MERGE_RULES = {"kalman": kalman_fuse, "intersection": covariance_intersection}
DEFAULT_MERGE_RULE = "kalman"


def check_merge_rule(rule: str) -> None:
    """Raise :class:`IncompatibleMapsError` naming the known rules when ``rule`` is not one of them."""
    if rule not in MERGE_RULES:
        raise IncompatibleMapsError(f"unknown merge rule {rule!r} (one of: {', '.join(MERGE_RULES)})")


def transform_landmarks(positions: np.ndarray, covariances: np.ndarray, pose, pose_covariance=None
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Map-2 landmarks in map 1's frame.  positions (N, 3), covariances (N, 3, 3), pose (3,).

    x = R x' + t;  P = R P' Rᵀ (+ J Σ Jᵀ when the pose covariance Σ (3, 3) is given).
    """
    R = rot_z(pose[2])
    x = transform_points(pose, positions)
    P = R @ covariances @ R.T
    if pose_covariance is not None:
        J = point_jacobians(pose, positions)
        P = P + J @ np.asarray(pose_covariance, float) @ np.swapaxes(J, -1, -2)
    return x, P


def _normalised_mean(d1: np.ndarray, d2: np.ndarray) -> np.ndarray:
    mean = 0.5 * (d1.astype(np.float64) + d2.astype(np.float64))
    norm = np.linalg.norm(mean, axis=1, keepdims=True)
    return (mean / np.where(norm > 0, norm, 1.0)).astype(np.float32)


def position_correspondences(x1: np.ndarray, P1: np.ndarray, x2: np.ndarray, P2: np.ndarray,
                             euclidean_gate: float | None = None, floor: float = 0.02) -> np.ndarray:
    """Method 2: mutual nearest neighbours in position, within a gate -> pairs (K, 2) int64 (one-to-one).

    x1 (N1, 3), x2 (N2, 3) in the same frame; P1, P2 their covariances.  With ``euclidean_gate`` (metres)
    a pair is kept when its distance is below it; otherwise when its Mahalanobis distance under
    P1 + P2 + floor² I is within the 99.9 % χ²(3) quantile.
    """
    if len(x1) == 0 or len(x2) == 0:
        return np.zeros((0, 2), np.int64)
    _, j_of_i = cKDTree(x2).query(x1, k=1)
    _, i_of_j = cKDTree(x1).query(x2, k=1)
    i = np.flatnonzero(i_of_j[j_of_i] == np.arange(len(x1)))
    j = j_of_i[i]
    r = x1[i] - x2[j]
    if euclidean_gate is not None:
        keep = np.einsum("ki,ki->k", r, r) < euclidean_gate ** 2
    else:
        S = P1[i] + P2[j] + floor ** 2 * np.eye(3)
        keep = np.einsum("ki,ki->k", r, np.linalg.solve(S, r[..., None])[..., 0]) < CHI2_999[3]
    return np.stack([i[keep], j[keep]], axis=1).astype(np.int64)


@dataclass(frozen=True)
class MergeResult:
    """The merged map and where every input landmark went.

    rows1 (N1,): row of each map-1 landmark in ``map`` (map 1 keeps its rows: rows1 = arange(N1));
    rows2 (N2,): row of each map-2 landmark (a map-1 row when it was fused, or when it was withheld: the map-1 row
    that keeps its identity); pairs (K, 2) the fused pairs; withheld (W, 2) the (map-1 row, map-2 row) pairs of
    one identity that were neither fused nor added (the maps disagree about it beyond their covariances).
    """

    map: LandmarkMap
    rows1: np.ndarray
    rows2: np.ndarray
    pairs: np.ndarray
    withheld: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))


def check_covariances(landmark_map: LandmarkMap, name: str = "map") -> None:
    """Raise :class:`IncompatibleMapsError` naming the first landmark whose covariance (3, 3) is not symmetric
    positive semi-definite (relative tolerance 1e-9): the Kalman update of such a landmark is meaningless."""
    P = landmark_map.covariances
    if len(P) == 0:
        return
    scale = np.maximum(np.abs(P).max(axis=(1, 2)), np.finfo(float).tiny)
    asym = np.abs(P - np.swapaxes(P, -1, -2)).max(axis=(1, 2)) / scale
    low = np.linalg.eigvalsh(0.5 * (P + np.swapaxes(P, -1, -2)))[:, 0] / scale
    bad = np.flatnonzero((asym > 1e-9) | (low < -1e-9) | ~np.isfinite(asym) | ~np.isfinite(low))
    if len(bad):
        k = int(bad[0])
        what = "not symmetric" if asym[k] > 1e-9 else f"not positive semi-definite (eigenvalue {low[k] * scale[k]:.3g})"
        raise IncompatibleMapsError(f"{name} ({landmark_map.robot}): covariance of landmark row {k} (id "
                                    f"{int(landmark_map.ids[k])}) is {what}; {len(bad)} such landmarks")


def _merged_identities(map1: LandmarkMap, map2: LandmarkMap, only2: np.ndarray) -> list[int] | None:
    """External identities of the merged rows when both maps carry them (map 1's, then map 2's own)."""
    ids1, ids2 = landmark_identities(map1), landmark_identities(map2)
    if ids1 is None or ids2 is None:
        return None
    return [int(v) for v in np.concatenate([ids1, ids2[only2]])]


def merge_pairs(map1: LandmarkMap, map2: LandmarkMap, pose, pairs, pose_covariance=None,
                metadata: dict | None = None, withheld=None, conflicts: list[dict] | None = None,
                rule: str = DEFAULT_MERGE_RULE) -> MergeResult:
    """Merge map 2 (aligned by ``pose`` (3,), optionally uncertain by ``pose_covariance`` (3, 3)) into map 1,
    fusing the landmark ``pairs`` (K, 2) rows (i in map 1, j in map 2), which must be one-to-one.

    ``withheld`` (W, 2) rows (i in map 1, j in map 2): one identity held by both maps at places the gate refused
    to fuse; map 2's landmark j is not added (one identity is one landmark: adding it would put the same post
    in the map twice), map 1's i is kept unchanged, and ``conflicts`` (one dict per withheld pair, saying how far
    apart they were) are appended to the merged map's ``metadata["identity_conflicts"]``.

    ``rule`` fuses each pair: "kalman" (the paper's eqs. 6–8, maps taken as independent) or "intersection"
    (covariance intersection, no independence assumed; :data:`MERGE_RULES`).

    Raises :class:`IncompatibleMapsError` when a map's covariances are not symmetric positive semi-definite, or for an
    unknown ``rule``."""
    check_merge_rule(rule)
    if len(map1) and len(map2) and map1.descriptor_size != map2.descriptor_size:
        raise IncompatibleMapsError(f"descriptor sizes differ: {map1.descriptor_size} vs {map2.descriptor_size}")
    check_covariances(map1, "map 1")
    check_covariances(map2, "map 2")
    pairs = np.asarray(pairs, np.int64).reshape(-1, 2)
    if len(np.unique(pairs[:, 0])) != len(pairs) or len(np.unique(pairs[:, 1])) != len(pairs):
        raise IncompatibleMapsError("common landmarks must be one-to-one between the maps")
    x2, P2 = transform_landmarks(map2.positions, map2.covariances, pose, pose_covariance)
    i, j = pairs[:, 0], pairs[:, 1]

    positions = map1.positions.copy()
    covariances = map1.covariances.copy()
    descriptors = map1.descriptors.copy() if len(map1) else np.zeros((0, map2.descriptor_size), np.float32)
    counts = map1.counts.copy()
    positions[i], covariances[i] = MERGE_RULES[rule](map1.positions[i], map1.covariances[i], x2[j], P2[j])
    descriptors[i] = _normalised_mean(map1.descriptors[i], map2.descriptors[j])
    counts[i] += map2.counts[j]

    robots = list(map1.robots) + [r for r in map2.robots if r not in map1.robots]
    col2 = np.array([robots.index(r) for r in map2.robots], np.int64)
    seen = np.zeros((len(map1), len(robots)), bool)
    seen[:, : len(map1.robots)] = map1.seen_by
    seen[i[:, None], col2[None, :]] |= map2.seen_by[j]

    withheld = np.zeros((0, 2), np.int64) if withheld is None else np.asarray(withheld, np.int64).reshape(-1, 2)
    only2 = np.ones(len(map2), bool)
    only2[j] = False
    only2[withheld[:, 1]] = False
    seen2 = np.zeros((int(only2.sum()), len(robots)), bool)
    seen2[:, col2] = map2.seen_by[only2]
    next_id = int(map1.ids.max()) + 1 if len(map1) else 0

    meta = {**map1.metadata, **(metadata or {})}
    meta.pop("external_ids", None)
    meta.pop(VOTE_KEY, None)      # a vote's per-landmark record describes the voted map's rows, not the merged map's
    identities = _merged_identities(map1, map2, only2)
    if identities is not None:
        meta["external_ids"] = identities
    if conflicts:
        meta["identity_conflicts"] = list(map1.metadata.get("identity_conflicts", [])) + list(conflicts)
    rows2 = np.empty(len(map2), np.int64)
    rows2[j] = i
    rows2[withheld[:, 1]] = withheld[:, 0]
    rows2[only2] = len(map1) + np.arange(int(only2.sum()))
    merged = LandmarkMap(
        positions=np.vstack([positions, x2[only2]]),
        covariances=np.concatenate([covariances, P2[only2]]),
        descriptors=np.vstack([descriptors, map2.descriptors[only2].astype(descriptors.dtype)]),
        ids=np.concatenate([map1.ids, next_id + np.arange(int(only2.sum()))]),
        counts=np.concatenate([counts, map2.counts[only2]]),
        robot="+".join(robots), frame=map1.frame, robots=robots,
        seen_by=np.vstack([seen, seen2]),
        trajectory=map1.trajectory.copy(),
        metadata=meta,
    )
    return MergeResult(merged, np.arange(len(map1)), rows2, pairs, withheld)


def common_landmarks(map1: LandmarkMap, map2: LandmarkMap, alignment: Alignment, method: int = 1,
                     gate: float | None = None) -> np.ndarray:
    """Pairs (K, 2) of landmarks both maps hold: Method 1 (RANSAC supports) or Method 2 (position).

    Method 2's gate: ``gate`` metres (Euclidean) if given, else th2 for the paper preset and the Mahalanobis
    gate otherwise.  Method 1's supports are made one-to-one (the paper's matching lets two map-1
    landmarks share a map-2 landmark; the nearer in position keeps it).
    """
    alignment.require()
    if method == 1:
        return one_to_one_supports(map1, map2, alignment)
    if method == 2:
        x2, P2 = transform_landmarks(map2.positions, map2.covariances, alignment.pose, alignment.covariance)
        if gate is None and alignment.preset == "paper":
            gate = PRESETS["paper"].support_threshold
        return position_correspondences(map1.positions, map1.covariances, x2, P2, gate)
    raise IncompatibleMapsError(f"unknown common-landmark method {method!r} (1: RANSAC supports, 2: position)")


def one_to_one_supports(map1: LandmarkMap, map2: LandmarkMap, alignment: Alignment) -> np.ndarray:
    """The alignment's supports (K, 2) with each landmark used once (greedily, nearest in position first)."""
    sup = alignment.supports
    if len(sup) == 0:
        return sup.reshape(0, 2)
    x2, _ = transform_landmarks(map2.positions[sup[:, 1]], map2.covariances[sup[:, 1]], alignment.pose)
    dist = np.linalg.norm(map1.positions[sup[:, 0]] - x2, axis=1)
    order = np.argsort(dist, kind="stable")
    keep = np.zeros(len(sup), bool)
    used1, used2 = set(), set()
    for k in order:
        a, b = int(sup[k, 0]), int(sup[k, 1])
        if a not in used1 and b not in used2:
            keep[k] = True
            used1.add(a)
            used2.add(b)
    return sup[keep]


def identity_matches(fused: LandmarkMap, child: LandmarkMap, pose, pose_cov, pairs: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, list[dict]]:
    """Known-ID maps: the child's landmarks outside ``pairs`` (K, 2) (the tree parent lacked them, or the alignment
    left them out) that ``fused`` holds under the same identity, kept when inside the Mahalanobis gate of Method 2;
    appended to ``pairs``.

    Returns (pairs (K, 2), withheld (W, 2), conflicts): a child landmark whose identity the fused map holds but
    which lies outside the gate is withheld (fused row, child row) — one identity is one post, so it is neither
    fused (the maps disagree beyond their covariances) nor added as a second landmark — and each conflict says
    which identity, how far apart and by what Mahalanobis distance (``merge_pairs`` records them)."""
    empty = np.zeros((0, 2), np.int64)
    ids_f, ids_c = landmark_identities(fused), landmark_identities(child)
    if ids_f is None or ids_c is None:
        return pairs, empty, []
    free_f = np.ones(len(fused), bool)
    free_f[pairs[:, 0]] = False
    free_c = np.ones(len(child), bool)
    free_c[pairs[:, 1]] = False
    cand = identity_pairs(np.where(free_f, ids_f, -1), np.where(free_c, ids_c, -1))
    if len(cand) == 0:
        return pairs, empty, []
    x2, P2 = transform_landmarks(child.positions[cand[:, 1]], child.covariances[cand[:, 1]], pose, pose_cov)
    r = fused.positions[cand[:, 0]] - x2
    S = fused.covariances[cand[:, 0]] + P2 + PRESETS["robust"].position_floor ** 2 * np.eye(3)
    d2 = np.einsum("ki,ki->k", r, np.linalg.solve(S, r[..., None])[..., 0])
    inside = d2 < CHI2_999[3]
    kept = cand[inside]
    _, first = np.unique(kept[:, 0], return_index=True)          # a duplicated identity: one pair per row
    kept = kept[np.sort(first)]
    _, first = np.unique(kept[:, 1], return_index=True)
    kept = kept[np.sort(first)]
    refused = ~inside & ~np.isin(cand[:, 1], kept[:, 1])
    order = np.flatnonzero(refused)[np.argsort(d2[refused], kind="stable")]
    _, first = np.unique(cand[order, 1], return_index=True)     # per child row, its nearest same-identity row
    order = np.sort(order[first])
    withheld = cand[order]
    conflicts = [{"identity": int(ids_c[c]), "robot": child.robot, "kept_row": int(f),
                  "distance_m": float(np.linalg.norm(r[k, :2])), "mahalanobis_d2": float(d2[k]),
                  "gate_d2": float(CHI2_999[3])} for k, (f, c) in zip(order, withheld, strict=True)]
    return np.vstack([pairs, kept]), withheld, conflicts


def merge(map1: LandmarkMap, map2: LandmarkMap, alignment: Alignment, method: int = 1,
          gate: float | None = None, use_alignment_covariance: bool = True, rule: str = DEFAULT_MERGE_RULE
          ) -> LandmarkMap:
    """The fused map in map 1's frame (see the module docstring), common landmarks fused by ``rule``
    (:func:`merge_pairs`).

    Raises :class:`~fusion.errors.NoOverlapError` when ``alignment`` was not found.  The alignment's
    covariance (robust preset) is added to map 2's landmarks unless ``use_alignment_covariance`` is False.
    """
    pairs = common_landmarks(map1, map2, alignment, method, gate)
    pose_cov = alignment.covariance if use_alignment_covariance else None
    withheld, conflicts = None, None
    if method == 1:              # known-ID maps: one landmark per identity (a no-op without identities)
        pairs, withheld, conflicts = identity_matches(map1, map2, alignment.pose, pose_cov, pairs)
    info = {"fusion": {"maps": [map1.robot, map2.robot], **source_metadata([map1, map2]), "method": int(method),
                       "preset": alignment.preset,
                       "pose": [float(v) for v in alignment.pose], "common_landmarks": int(len(pairs)),
                       "merge_rule": rule}}
    return merge_pairs(map1, map2, alignment.pose, pairs, pose_cov, info, withheld, conflicts, rule).map
