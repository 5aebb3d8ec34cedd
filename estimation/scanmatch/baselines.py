"""The baselines eICP is measured against: point-to-point ICP (Besl & McKay 1992) and PL-ICP (Censi 2008).

Both share :mod:`estimation.scanmatch.common`'s gate, trimming, stopping rule and covariance with eICP.

ICP pairs each current point with the nearest reference point and solves the pose by Procrustes.
PL-ICP pairs it with the nearest reference point j₁ and the closer of its scan neighbours j₂ (when the
segment j₁–j₂ is part of the reference curve, i.e. not across a gap or a dropout), and minimises the
distance to the *infinite* line through them, in closed form (:func:`common.point_to_line_pose`).
"""
from __future__ import annotations

import numpy as np

from estimation.geometry import compose
from estimation.scanmatch.common import (
    MatchConfig,
    MatchResult,
    apply_pose,
    finish,
    iterate,
    point_to_line_pose,
    pose_jacobian,
    procrustes,
    rotate,
    select_correspondences,
)
from estimation.scanmatch.nearest import NearestPoint
from estimation.scanmatch.polyline import Polyline
from estimation.scanmatch.scan import Scan2D


def match_icp(reference: Scan2D, current: Scan2D, initial: np.ndarray, config: MatchConfig) -> MatchResult:
    """Point-to-point ICP: the pose (3,) of ``current`` in ``reference``'s frame, starting from ``initial``."""
    target = reference.points
    source = current.points
    nearest_vertex = NearestPoint(target)

    def correspond(pose):
        moved = apply_pose(pose, source)
        distance, nearest = nearest_vertex(moved)
        return moved, nearest, select_correspondences(distance, config)

    def update(pose):
        _, nearest, keep = correspond(pose)
        if np.count_nonzero(keep) < max(config.min_correspondences, 3):
            return None
        return procrustes(source.compress(keep, axis=0), target[nearest.compress(keep)])

    pose, iterations, tolerance_met = iterate(update, initial, config)
    moved, nearest, keep = correspond(pose)
    residual_rows = (moved[keep] - target[nearest[keep]]).reshape(-1)          # (2n,)
    jacobian_rows = pose_jacobian(rotate(pose[2], source[keep])).reshape(-1, 3)  # (2n, 3)
    return finish("icp", pose, iterations, tolerance_met, jacobian_rows, residual_rows,
                  int(np.count_nonzero(keep)), config)


def match_plicp(reference: Scan2D, current: Scan2D, initial: np.ndarray, config: MatchConfig) -> MatchResult:
    """PL-ICP: the pose (3,) of ``current`` in ``reference``'s frame, starting from ``initial``."""
    curve = Polyline(reference, config.gap)
    vertices = curve.vertices
    source = current.points
    nearest_vertex = NearestPoint(vertices)
    # Per vertex v, looked up by the nearest vertex of each point (gathers instead of per-iteration clips):
    # whether the segment to v-1 / v+1 is part of the curve, and those neighbours (clamped at the ends).
    m = len(vertices)
    has_before = np.zeros(m, dtype=bool)
    has_before[1:] = curve.segment_valid
    has_after = np.zeros(m, dtype=bool)
    has_after[:-1] = curve.segment_valid
    has_either = has_before | has_after
    vertex_before = vertices[np.maximum(np.arange(m) - 1, 0)]
    vertex_after = vertices[np.minimum(np.arange(m) + 1, m - 1)]

    def correspond(pose):
        moved = apply_pose(pose, source)
        distance, first = nearest_vertex(moved)
        before_ok, after_ok, either_ok = has_before[first], has_after[first], has_either[first]
        before, after = vertex_before[first], vertex_after[first]
        d_before = np.where(before_ok, np.sum((moved - before) ** 2, axis=1), np.inf)
        d_after = np.where(after_ok, np.sum((moved - after) ** 2, axis=1), np.inf)
        second = np.where((d_before <= d_after)[:, None], before, after)
        anchor = vertices[first]
        direction = second - anchor
        direction /= np.maximum(np.hypot(direction[:, 0], direction[:, 1]), 1e-12)[:, None]
        normal = np.empty_like(direction)
        np.negative(direction[:, 1], out=normal[:, 0])
        normal[:, 1] = direction[:, 0]
        line_residual = np.where(either_ok, np.sum(normal * (moved - anchor), axis=1), np.inf)
        keep = select_correspondences(distance, config, line_residual) & either_ok
        return moved, anchor, normal, keep

    def update(pose):
        moved, anchor, normal, keep = correspond(pose)
        if np.count_nonzero(keep) < max(config.min_correspondences, 3):
            return None
        # Solve for the increment applied after the current estimate, so a direction the scene leaves free
        # (a corridor) keeps its current value instead of jumping to the minimum-norm solution.
        increment = point_to_line_pose(moved.compress(keep, axis=0), anchor.compress(keep, axis=0),
                                       normal.compress(keep, axis=0))
        return compose(increment, pose)

    pose, iterations, tolerance_met = iterate(update, initial, config)
    moved, anchor, normal, keep = correspond(pose)
    residuals = np.sum(normal[keep] * (moved[keep] - anchor[keep]), axis=1)
    jacobian = np.einsum("nj,njk->nk", normal[keep], pose_jacobian(rotate(pose[2], source[keep])))
    return finish("plicp", pose, iterations, tolerance_met, jacobian, residuals, int(np.count_nonzero(keep)), config)
