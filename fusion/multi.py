"""Fusion of more than two maps: every pair aligned, the strongest alignments chosen, all merged in one frame.

The pairwise alignments form a graph weighted by their support counts; its maximum spanning tree holds the
strongest alignments that connect every map that can be connected.  Each map's pose in the reference
frame (map ``reference``'s) is the composition of the alignments along the tree path, with its covariance
propagated to first order; the maps are merged one by one in breadth-first order from the reference,
each with its tree parent's common landmarks (Method 1: that alignment's supports; Method 2: nearest
neighbours in position against everything merged so far).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import nnls
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import breadth_first_order, minimum_spanning_tree

from estimation.geometry import transform_points
from estimation.landmark_map import LandmarkMap

from .alignment import Alignment, align
from .alignment_config import PRESETS, AlignmentConfig
from .cache import AlignmentCache
from .errors import IncompatibleMapsError, NoOverlapError
from .merging import (
    DEFAULT_MERGE_RULE,
    check_merge_rule,
    identity_matches,
    merge_pairs,
    one_to_one_supports,
    position_correspondences,
    transform_landmarks,
)
from .placement import shape_placement
from .pose_covariance import compose_with_covariance
from .provenance import source_metadata
from .shape_covariance import shape_calibrated, shape_covariances, shape_levels, sighting_variances, spread_level


@dataclass
class MultiFusion:
    """Result of :func:`fuse_all`.

    map: the merged map in the reference map's frame (only the maps connected to the reference);
    poses[k]: (3,) pose of map k's frame in the reference frame, None if map k is not connected;
    covariances[k]: (3, 3) or None; start_covariances[k]: (3, 3) or None, against the true start frames
    (``Alignment.start_covariance`` composed along the tree); alignments[(i, j)] (i < j): the pairwise
    alignment of map j to map i;
    tree: (parent, child) edges used, in merge order; unconnected: indices of maps left out;
    rows[k]: (N_k,) row in ``map`` of each landmark of map k (None if not connected);
    covariance_scales[k]: the factor map k's covariances were scaled by before merging, None if not calibrated
    (the merged map's covariances then describe its landmarks about the reference map's frame, not that frame's
    own error against the reference robot's true start, which ``start_covariances`` and the maps' metadata keep);
    placements[k], placement_covariances[k]: where map k's landmarks were put in the merged map (``poses[k]`` when
    the maps were not calibrated; with calibrated maps each tree edge refitted on its supports under the calibrated
    covariances, ``fusion.placement.shape_placement``: ``poses`` answers where robot k started, ``placements``
    where its map's shape fits the others').
    """

    map: LandmarkMap
    reference: int
    poses: list[np.ndarray | None]
    covariances: list[np.ndarray | None]
    alignments: dict[tuple[int, int], Alignment]
    tree: list[tuple[int, int]]
    unconnected: list[int] = field(default_factory=list)
    rows: list[np.ndarray | None] = field(default_factory=list)
    start_covariances: list[np.ndarray | None] = field(default_factory=list)
    covariance_scales: list[float] | None = None   # per map, applied before merging (covariance_scales), or None
    placements: list[np.ndarray | None] = field(default_factory=list)
    placement_covariances: list[np.ndarray | None] = field(default_factory=list)


def pairwise_alignments(maps: list[LandmarkMap], preset: str | AlignmentConfig = "robust",
                        rng: np.random.Generator | None = None, cache: AlignmentCache | None = None,
                        priors: dict | None = None) -> dict[tuple[int, int], Alignment]:
    """align(maps[j] to maps[i]) for every i < j; each pair gets its own child generator of ``rng``.
    With ``cache`` a pair of unchanged maps is not aligned again (:class:`fusion.cache.AlignmentCache`).
    ``priors`` {(i, j): fusion.prior.StartPrior}: a rough relative start for some pairs (fusion.prior.pair_priors)."""
    rng = np.random.default_rng(0) if rng is None else rng
    keys = [(i, j) for i in range(len(maps)) for j in range(i + 1, len(maps))]
    children = rng.spawn(len(keys)) if keys else []
    run = align if cache is None else cache.align
    priors = priors or {}
    return {key: run(maps[key[0]], maps[key[1]], preset, child, prior=priors.get(key))
            for key, child in zip(keys, children, strict=True)}


def spanning_tree(n: int, alignments: dict[tuple[int, int], Alignment], reference: int = 0
                  ) -> tuple[list[tuple[int, int]], list[int]]:
    """Maximum spanning tree over support counts: (parent, child) edges in BFS order from ``reference``,
    and the maps not connected to it."""
    weights = np.zeros((n, n))
    top = max((len(a.supports) for a in alignments.values() if a.found), default=0)
    for (i, j), a in alignments.items():
        if a.found:
            weights[i, j] = top + 1 - len(a.supports)       # > 0: more supports -> lighter edge
    tree = minimum_spanning_tree(csr_matrix(weights))
    tree = tree + tree.T
    order, predecessors = breadth_first_order(tree, reference, directed=False, return_predecessors=True)
    edges = [(int(predecessors[k]), int(k)) for k in order[1:]]
    connected = set(int(k) for k in order)
    return edges, [k for k in range(n) if k not in connected]


def covariance_scales(maps: list[LandmarkMap], alignments: dict[tuple[int, int], Alignment],
                      floor: float = 0.02, standard_errors: float = 1.0) -> np.ndarray | None:
    """Per map, the factor (N,) by which its landmark covariances must be scaled to explain how far its landmarks
    lie from the other maps' once aligned, or None when the found alignments cannot tell the maps apart.

    Each found pair (i, j) gives the residuals r of its supports after its alignment:
    v_ij = Σ|r|² / (2S − 3) (per axis, 3 pose parameters fitted) estimates σ_i² + σ_j², the two maps' landmark
    variances about a rigid placement (the "three-cornered hat": pairwise differences of independent estimates
    determine each one's variance once the pairs form an odd cycle).  Non-negative weighted least squares gives σ_k²,
    each v_ij weighted by its own variance 2 (σ_i² + σ_j²)² / (2S − 3) (a sample variance of 2S − 3 degrees of
    freedom; from the fitted values, iterated), plus ``standard_errors`` of its standard error (at least ``floor``²);
    the factor is σ_k² over the median per-axis variance the map claims.  Why the standard error: the most accurate
    map's σ_k² is a small difference of large pair variances (its pairs are dominated by the other maps' scatter), the
    least certain estimate, and an underestimate is what the merge trusts most — on the session-5 MRCLAM maps plain
    least squares put robot 1 at the 0.02 m floor against 0.068 m real, and the merged landmarks' NEES against Vicon
    had median 21.5 (docs/fusion-history.md, "Session 7: merging").  Why: a map's
    covariances can carry an error that an alignment removes (FastSLAM's ``mixture+drift`` export adds the frame's
    drift, which moves the overlap as a whole) and say nothing of how bent the map is: on MRCLAM the most accurate
    map (0.068 m per axis about its best rigid fit) claimed σ 0.40 m, the second worst (0.175 m) 0.14 m, and
    weighting by those claims made the merged map worse than most single maps (docs/fusion-history.md).
    """
    n = len(maps)
    rows, rhs, dof = [], [], []
    for (i, j), a in alignments.items():
        if not a.found or len(a.supports) < 2:
            continue
        x1 = maps[i].positions[a.supports[:, 0], :2]
        x2 = transform_points(a.pose, maps[j].positions[a.supports[:, 1]])[:, :2]
        rows.append(np.bincount([i, j], minlength=n).astype(float))
        dof.append(2 * len(x1) - 3)
        rhs.append(float(np.sum((x1 - x2) ** 2)) / dof[-1])
    if not rows:
        return None
    design = np.array(rows)
    involved = design.any(axis=0)
    if np.linalg.matrix_rank(design[:, involved]) < int(involved.sum()):
        return None                       # e.g. two maps, or a chain: only the sums σ_i² + σ_j² are known
    variance = np.full(n, np.nan)
    variance[involved] = np.maximum(_hat_variances(design[:, involved], np.array(rhs), np.array(dof, float), floor,
                                                   standard_errors), floor ** 2)
    claimed = np.array([claimed_variance(m) for m in maps])
    scales = variance / np.maximum(claimed, 1e-12)
    return np.where(np.isfinite(scales), scales, 1.0)


def _hat_variances(design: np.ndarray, v: np.ndarray, dof: np.ndarray, floor: float, standard_errors: float,
                   iterations: int = 20) -> np.ndarray:
    """σ² (K,) from v (P,) ≈ design (P, K) σ² by non-negative least squares weighted by var(v_p) = 2 (design σ²)² /
    dof_p (iterated from the unweighted solution), plus ``standard_errors`` × the standard error of each σ²."""
    variance = nnls(design, v)[0]
    for _ in range(iterations):
        fitted = np.maximum(design @ variance, 2 * floor ** 2)   # a pair's variance is at least both maps' floors
        w = np.sqrt(dof / (2 * fitted ** 2))
        new = nnls(design * w[:, None], v * w)[0]
        done = np.allclose(new, variance, rtol=1e-9, atol=1e-15)
        variance = new
        if done:
            break
    fitted = np.maximum(design @ variance, 2 * floor ** 2)
    information = design.T @ ((dof / (2 * fitted ** 2))[:, None] * design)
    return variance + standard_errors * np.sqrt(np.maximum(np.diag(np.linalg.inv(information)), 0.0))


def claimed_variance(landmark_map: LandmarkMap) -> float:
    """The per-axis planar variance (m²) a map claims for its landmarks: the median of tr Σ_xy / 2 (NaN for an
    empty map); :func:`covariance_scales` gives factors of it."""
    if not len(landmark_map):
        return float("nan")
    return float(np.median(np.trace(landmark_map.covariances[:, :2, :2], axis1=1, axis2=2)) / 2)


CALIBRATIONS = ("isotropic", "scaled", "drift", "sightings")


def calibrated_map(landmark_map: LandmarkMap, scale: float, calibration: str = "isotropic") -> LandmarkMap:
    """``landmark_map`` with its covariances calibrated by the factor ``scale`` of :func:`covariance_scales`.

    "scaled": every covariance × scale (the claimed per-landmark structure kept, its level calibrated).
    "isotropic": every landmark's planar block becomes σ² I₂ with σ² = scale × the claimed median per-axis variance
    (the map's scatter about a rigid placement, as the pairwise residuals measure it), the xy–z terms 0, z's variance
    scaled.  Why: a FastSLAM map's claimed structure is the pose drift when each landmark was made (landmarks made
    near the start claim least), an error the alignment removes; it does not say which landmarks are bent.  On the
    session-6 MRCLAM maps the merged landmarks' NEES against Vicon falls from median 7.3 (6 of 15 above the χ²(2)
    99 % bound) to 3.4 (3 of 15) and their error from 0.136 to 0.121 m (docs/fusion-history.md, "Session 7:
    merging")."""
    P = landmark_map.covariances * scale
    if calibration == "isotropic" and len(P):   # P is already a new array
        P[:, :2, :2] = scale * claimed_variance(landmark_map) * np.eye(2)
        P[:, :2, 2] = P[:, 2, :2] = 0.0
    return LandmarkMap(landmark_map.positions, P, landmark_map.descriptors,
                       landmark_map.ids, landmark_map.counts, landmark_map.robot, landmark_map.frame,
                       list(landmark_map.robots), landmark_map.seen_by, landmark_map.trajectory,
                       dict(landmark_map.metadata))


def drift_calibrated(maps: list[LandmarkMap], alignments: dict[tuple[int, int], Alignment]
                     ) -> tuple[list[LandmarkMap], np.ndarray] | None:
    """Every map with its landmarks' planar covariance (a + b s_k²) I, s_k² the mean per-axis variance of map k's
    landmarks about its rigid placement from the drift its file keeps (``fusion.shape_covariance``), (a, b) one pair for
    all maps from the found pairs' residuals (``shape_levels``); and per map the
    factor its median claimed variance was scaled by (for the report).  None when a map keeps no drift or no pair
    was found (two maps suffice: one level is fitted, not one per map)."""
    shapes = [shape_covariances(m) for m in maps]
    if any(s is None for s in shapes):
        return None
    # one isotropic variance per map, its landmarks' mean about the rigid placement: the files rank the maps (MRCLAM,
    # 20 maps: Spearman +0.59 with the real σ, the hat's +0.29), but their per-landmark blocks are nearly singular
    # across the bend (the local part is millimetres), and merging by them was worse on 3 of 4 sets
    # (docs/fusion-history.md)
    shapes = [np.tile(np.eye(2) * float(np.mean(np.trace(s, axis1=1, axis2=2))) / 2, (len(s), 1, 1)) for s in shapes]
    levels = shape_levels(maps, shapes, alignments)
    if levels is None:
        return None
    a, b = levels
    factors = np.array([(a + b * float(np.median(np.trace(s, axis1=1, axis2=2))) / 2) / max(claimed_variance(m), 1e-12)
                        for m, s in zip(maps, shapes, strict=True)])
    return [shape_calibrated(m, s, levels) for m, s in zip(maps, shapes, strict=True)], factors


def sighting_calibrated(maps: list[LandmarkMap], alignments: dict[tuple[int, int], Alignment], per: str = "sighting",
                        pooled: bool = False, floor: bool = False) -> tuple[list[LandmarkMap], np.ndarray] | None:
    """Every map with each landmark's planar covariance b v_l I, v_l the variance its file's sightings' spread gives it
    (``fusion.shape_covariance.sighting_variances``: how well the map agrees with itself at the landmark), b one factor
    for all maps from the found pairs' residuals (``spread_level``: the spread of single sightings says which landmark
    and which map is worse, not by how much its estimate errs), so the merge's weights are the files' own ratios.
    Measured alternatives (docs/fusion-history.md, session 11): ``pooled``, v_l replaced by its map's mean (one variance
    per map, as "drift"); ``floor``, (a + b v_l) I with (a, b) by ``shape_levels``.  And per map the factor its median
    claimed variance was scaled by (for the report).  None when a map keeps no sightings or no pair was found."""
    spreads = [sighting_variances(m, per) for m in maps]
    if any(v is None for v in spreads):
        return None
    if pooled:
        spreads = [np.full(len(v), float(np.mean(v))) for v in spreads]
    shapes = [v[:, None, None] * np.eye(2) for v in spreads]
    if floor:
        levels = shape_levels(maps, shapes, alignments)
    else:
        b = spread_level(maps, spreads, alignments)
        levels = None if b is None else (0.0, b)
    if levels is None:
        return None
    a, b = levels
    factors = np.array([(a + b * float(np.median(v))) / max(claimed_variance(m), 1e-12)
                        for m, v in zip(maps, spreads, strict=True)])
    return [shape_calibrated(m, s, levels) for m, s in zip(maps, shapes, strict=True)], factors


def _edge(alignments: dict[tuple[int, int], Alignment], parent: int, child: int) -> Alignment:
    """The alignment of ``child`` to ``parent`` (inverting the stored one when needed)."""
    if (parent, child) in alignments:
        return alignments[(parent, child)]
    return alignments[(child, parent)].inverse()


def fuse_all(maps: list[LandmarkMap], preset: str | AlignmentConfig = "robust", method: int = 1,
             rng: np.random.Generator | None = None, reference: int = 0,
             alignments: dict[tuple[int, int], Alignment] | None = None,
             cache: AlignmentCache | None = None, calibrate: bool = True, merge_rule: str = DEFAULT_MERGE_RULE,
             calibration: str = "isotropic") -> MultiFusion:
    """Fuse every map connected to ``maps[reference]`` into its frame (see the module docstring).

    ``alignments`` may be given (keys (i, j), i < j) to skip the pairwise alignment; ``cache`` keeps the
    alignments of unchanged maps from one call to the next (:class:`fusion.cache.AlignmentCache`).  With
    ``calibrate`` (and three or more maps whose found alignments determine it) each map's covariances are scaled
    by :func:`covariance_scales` before merging, so that the merge weighs each map by how well its landmarks
    agree with the others' (``MultiFusion.covariance_scales``): ``calibration`` "isotropic" gives every landmark of
    map k the per-axis variance σ_k² in the plane (:func:`calibrated_map`), "scaled" multiplies its claimed
    covariances by the factor (session 5), "drift" gives map k's landmarks the variance its file's drift implies about
    its rigid placement, at one level for all maps (:func:`drift_calibrated`; session 10; maps without the drift fall
    back to "isotropic"), "sightings" gives each landmark the variance the spread of its map's own sightings of it
    implies, at one level for all maps (:func:`sighting_calibrated`; session 11; maps without
    ``sighting_covariances`` fall back to "isotropic").  ``merge_rule`` fuses the common landmarks
    (``fusion.merging.MERGE_RULES``: "kalman", the paper's update, or "intersection", covariance intersection).  Raises
    :class:`NoOverlapError` only when no map at all connects to the reference (with two or more maps).
    """
    if not maps:
        raise IncompatibleMapsError("no maps to fuse")
    if not 0 <= reference < len(maps):
        raise IncompatibleMapsError(f"reference {reference} is not one of the {len(maps)} maps")
    if method not in (1, 2):
        raise IncompatibleMapsError(f"unknown common-landmark method {method!r} (1: RANSAC supports, 2: position)")
    check_merge_rule(merge_rule)
    if calibration not in CALIBRATIONS:
        raise IncompatibleMapsError(f"unknown calibration {calibration!r} (one of: {', '.join(CALIBRATIONS)})")
    n = len(maps)
    if alignments is None:
        alignments = pairwise_alignments(maps, preset, rng, cache)
    edges, unconnected = spanning_tree(n, alignments, reference)
    if n > 1 and not edges:
        raise NoOverlapError("none of the maps overlaps the reference map "
                             f"{maps[reference].robot!r}: nothing to fuse")
    # which maps the fused map holds, by content as given (before any calibration scales their covariances)
    sources = source_metadata(maps, [k for k in range(n) if k not in unconnected])
    shaped = None
    if calibrate and calibration == "drift":
        shaped = drift_calibrated(maps, alignments)
    elif calibrate and calibration == "sightings":
        shaped = sighting_calibrated(maps, alignments)
    if shaped is not None:
        maps, scales = shaped
    else:       # "drift" or "sightings" without the field in every file falls back to the default
        calibration = "isotropic" if calibration in ("drift", "sightings") else calibration
        scales = covariance_scales(maps, alignments) if calibrate and n > 2 else None
    if scales is not None and shaped is None:
        maps = [calibrated_map(m, float(c), calibration) for m, c in zip(maps, scales, strict=True)]
    poses: list[np.ndarray | None] = [None] * n
    covs: list[np.ndarray | None] = [None] * n
    start_covs: list[np.ndarray | None] = [None] * n
    rows: list[np.ndarray | None] = [None] * n
    placed: list[np.ndarray | None] = [None] * n
    placed_covs: list[np.ndarray | None] = [None] * n
    poses[reference], covs[reference], start_covs[reference] = np.zeros(3), np.zeros((3, 3)), np.zeros((3, 3))
    placed[reference], placed_covs[reference] = np.zeros(3), np.zeros((3, 3))
    rows[reference] = np.arange(len(maps[reference]))
    fused = maps[reference]
    for parent, child in edges:
        a = _edge(alignments, parent, child)
        edge_cov = a.covariance if a.covariance is not None else np.zeros((3, 3))
        poses[child], covs[child] = compose_with_covariance(poses[parent], covs[parent], a.pose, edge_cov)
        if a.start_covariance is not None and start_covs[parent] is not None:
            start_covs[child] = compose_with_covariance(poses[parent], start_covs[parent], a.pose,
                                                        a.start_covariance)[1]
        # the supports made one-to-one: Method 1's common landmarks, and what a calibrated placement is fitted on
        sup = one_to_one_supports(maps[parent], maps[child], a) if method == 1 or scales is not None else None
        if scales is None:     # the merge weighs the maps by their claims, under which the alignment is the fit
            edge_pose, edge_place_cov = a.pose, edge_cov
        else:
            edge_pose, edge_place_cov = shape_placement(maps[parent], maps[child], sup, a.pose)
        placed[child], placed_covs[child] = compose_with_covariance(placed[parent], placed_covs[parent], edge_pose,
                                                                    edge_place_cov)
        pose_cov = placed_covs[child] if a.covariance is not None else None
        if method == 1:
            pairs = np.column_stack([rows[parent][sup[:, 0]], sup[:, 1]])
            # two parent landmarks may already be one fused landmark: keep the first pair of each row
            _, first = np.unique(pairs[:, 0], return_index=True)
            pairs, withheld, conflicts = identity_matches(fused, maps[child], placed[child], pose_cov,
                                                          pairs[np.sort(first)])
        else:
            withheld, conflicts = None, None
            x2, P2 = transform_landmarks(maps[child].positions, maps[child].covariances, placed[child], pose_cov)
            gate = PRESETS["paper"].support_threshold if a.preset == "paper" else None
            pairs = position_correspondences(fused.positions, fused.covariances, x2, P2, gate)
        info = {"fusion": {"maps": [m.robot for m in maps], **sources, "method": int(method),
                           "reference": int(reference), "tree": [list(e) for e in edges],
                           "covariance_scales": None if scales is None else [float(c) for c in scales],
                           "merge_rule": merge_rule, "calibration": None if scales is None else calibration}}
        result = merge_pairs(fused, maps[child], placed[child], pairs, pose_cov, info, withheld, conflicts, merge_rule)
        fused, rows[child] = result.map, result.rows2
    return MultiFusion(fused, reference, poses, covs, alignments, edges, unconnected, rows, start_covs,
                       None if scales is None else [float(c) for c in scales], placed, placed_covs)
