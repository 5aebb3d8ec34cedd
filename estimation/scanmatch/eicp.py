"""The extended ICP (eICP) of Armesto, Domenech & Tornero (ISR 2009), and its rigid-mesh variant.

The problem.  The reference scan defines a continuous curve C(λ): the polyline through its consecutive
points, broken at gaps and dropouts (:mod:`estimation.scanmatch.polyline`), with λ the arc length.  Each
point p_i of the current scan gets its own free curve parameter λ_i, and pose ξ = (x, y, θ) and λ are solved
together::

    J(ξ, λ) = Σ_i | R(θ) p_i + t − C(λ_i) |²            (over the kept correspondences)

Choices the paper's introduction leaves open, and what we chose:

* **The curve** is piecewise linear (the "continuous elements" of an indoor scene are mostly walls; a spline
  would overshoot at corners) and is parametrised by arc length, so that moving λ by δ moves the associated
  point by |δ| and the λ-block of the Hessian is the identity on every segment.
* **The solver** for the free-λ problem is Gauss-Newton on the joint (ξ, λ) with λ eliminated, i.e. variable
  projection.  For a fixed pose each λ_i has a closed-form optimum: the projection of the moved point on the
  curve (on each segment the cost is a convex quadratic in λ_i; the curve optimum is the best segment's).
  In the joint Gauss-Newton system the λ-block is diagonal (one λ per point, unit speed), so its Schur
  complement costs O(N) and leaves a 3×3 system in ξ whose rows are the Jacobians projected on the curve
  normal: n_iᵀ ∂(R p_i + t)/∂ξ.  At a curve end or a convex vertex (λ_i at a bound) the bound is active and
  the row uses the unit direction from the curve point to the moved point instead.  After each ξ step λ is
  reset to its exact optimum (the projection), and the step is halved while it does not lower the
  truncated cost Σ min(d_i, gate)² of the correspondences the step was computed for (the kept set may
  still change between iterations; :func:`common.iterate` stops on the resulting limit cycles).  We chose
  this over the alternating scheme (projection,
  then Procrustes on the projected points — also provided,
  ``eicp_solver="alternating"``) because alternating is linearly convergent and crawls along walls, where
  the curve lets points slide freely; Gauss-Newton on the eliminated problem converges quadratically near
  the solution and costs one projection per iteration.
* **Outliers and stopping** are the ones shared with ICP and PL-ICP (:mod:`estimation.scanmatch.common`):
  gated by the distance to the curve and trimmed.

Frame invariance.  J depends on the scans only through distances between moved points and curve points, so
applying one rigid motion G to both scans leaves J unchanged at the correspondingly conjugated pose
G ξ G⁻¹; and, unlike point-to-point ICP, J is zero at the true pose whatever the two scans' sampling of the
same walls, which is what removes the "closest point" bias.

The rigid-mesh variant ("eicp-mesh").  The paper's constrained solution keeps the distances between
consecutive associated points, like a rigid mesh.  We read it as: the associated points keep their mutual
arc-length spacing, λ_i = λ_i⁰ + s for one scalar shift s shared by all points (each clamped to its own
curve piece, since a point cannot jump over a gap).  λ⁰ is the projection at the current pose; for each s
the pose is the closed-form Procrustes solution onto the shifted curve points, so the inner problem is
one-dimensional and is solved by bounded Brent (golden section with parabolic steps) on
[−mesh_shift_bound, mesh_shift_bound]; then λ⁰ is re-projected and the loop repeats until the pose stops
changing.  Its fixed points are those of the alternating eICP (s = 0 there); the shift accelerates the
sliding direction that makes plain alternation slow.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar

from estimation.scanmatch.common import (
    MatchConfig,
    MatchResult,
    apply_pose,
    finish,
    iterate,
    pose_step_small,
    procrustes,
    rotate,
    select_correspondences,
    solve_normal_equations,
    truncated_cost,
)
from estimation.scanmatch.polyline import NearestVertexCache, Polyline
from estimation.scanmatch.scan import Scan2D

_MAX_HALVINGS = 6


def eicp_cost(reference: Scan2D, current: Scan2D, pose, config: MatchConfig | None = None) -> float:
    """J(ξ, λ*(ξ)): the eICP cost at pose (3,) with every λ at its optimum, over the kept correspondences."""
    config = config or MatchConfig()
    projection = Polyline(reference, config.gap).project(apply_pose(np.asarray(pose, float), current.points))
    keep = select_correspondences(projection.distance, config)
    return float(np.sum(projection.distance[keep] ** 2))


class _OnCurve:
    """The current scan's points projected on the reference curve at one pose, warm-started from the last pose.

    rotated: (N,) complex R(θ) p; distance: (N,) to the curve; offset: (N,) complex, moved point minus its curve
    point; flat: (N,) int, the chosen candidate segments (see :meth:`Polyline.project_complex`).  Points are
    complex x + iy throughout: fewer, bigger array operations, which is what an iteration costs.
    """

    def __init__(self, curve: Polyline, points: np.ndarray) -> None:
        self.curve = curve
        self.points = np.ascontiguousarray(points, dtype=float)   # (N, 2)
        self._jacobian = np.empty((self.points.shape[0], 3))     # scratch for rows()
        self.cache = NearestVertexCache()
        self.pose: tuple[float, float, float] | None = None

    def at(self, pose: np.ndarray) -> _OnCurve:
        """Project at pose (3,); the same pose twice in a row costs nothing (an accepted trial is the next start)."""
        key = tuple(pose.tolist())
        if key != self.pose:
            # The same arithmetic as apply_pose (a 2×2 matmul), so that results do not move by rounding.
            self.rotated = rotate(pose[2], self.points)                                     # (N, 2)
            self.moved = (self.rotated + pose[:2]).view(np.complex128)[:, 0]
            self.distance, self.offset, self.flat, self.along = self.curve.project_complex(self.moved, self.cache)
            self.pose = key
        return self

    def point(self) -> np.ndarray:
        """(N, 2) the curve points the moved points are associated with."""
        return (self.moved - self.offset).view(np.float64).reshape(-1, 2)

    def rows(self, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pose Jacobian (n, 3) with λ eliminated and residuals (n,) of the kept correspondences.

        Jacobian row i is u_iᵀ ∂(R p_i + t)/∂ξ = (u_x, u_y, u_y (R p_i)_x − u_x (R p_i)_y) with u_i the unit
        direction from the curve to the moved point (the curve normal inside a segment, the radial direction where
        λ_i sits at a bound); the residual is the distance, = u_iᵀ (R p_i + t − C(λ_i)).
        """
        # Every point's row into one buffer, then one compress: fewer array operations than on the kept subset.
        distance = self.distance
        residual = self.offset.view(np.float64).reshape(-1, 2)
        full = self._jacobian
        unit = full[:, :2]
        # Float division (not complex by real, which multiplies by the reciprocal): results stay bit-identical.
        if distance.min() > 1e-12:
            np.divide(residual, distance[:, None], out=unit)
        else:   # a point on the curve has no direction to it: the segment normal
            on_curve = distance <= 1e-12
            np.divide(residual, np.where(on_curve, 1.0, distance)[:, None], out=unit)
            normal = self.curve.candidate_normal(self.cache, self.flat[on_curve])
            unit[on_curve] = normal.view(np.float64).reshape(-1, 2)
        np.subtract(unit[:, 1] * self.rotated[:, 0], unit[:, 0] * self.rotated[:, 1], out=full[:, 2])
        return full.compress(keep, axis=0), distance.compress(keep)


def match_eicp(reference: Scan2D, current: Scan2D, initial: np.ndarray, config: MatchConfig) -> MatchResult:
    """eICP with free curve parameters: the pose (3,) of ``current`` in ``reference``'s frame."""
    curve = Polyline(reference, config.gap)
    source = current.points
    minimum = max(config.min_correspondences, 3)
    on_curve = _OnCurve(curve, source)

    def gauss_newton(pose):
        here = on_curve.at(pose)
        keep = select_correspondences(here.distance, config)
        if np.count_nonzero(keep) < minimum:
            return None
        jacobian, residuals = here.rows(keep)
        step = -solve_normal_equations(jacobian, residuals)
        if pose_step_small(step, config, scale):
            return pose + step   # below the tolerance: the stopping rule ends here, no line search needed
        # Accept the step when it lowers the truncated cost of the correspondences it was computed for.  The kept
        # distances are within the gate, so their truncated cost is their plain sum of squares.
        cost = float(residuals @ residuals)
        for _ in range(_MAX_HALVINGS):
            trial = pose + step
            if truncated_cost(on_curve.at(trial).distance.compress(keep), config) <= cost:
                return trial
            step = step / 2.0
        return pose   # no descent along the Gauss-Newton direction: a minimum of the truncated cost

    def alternating(pose):
        here = on_curve.at(pose)
        keep = select_correspondences(here.distance, config)
        if np.count_nonzero(keep) < minimum:
            return None
        return procrustes(source[keep], here.point()[keep])

    newton = config.eicp_solver == "gauss-newton"
    scale = config.gauss_newton_tolerance_scale if newton else 1.0
    pose, iterations, tolerance_met = iterate(gauss_newton if newton else alternating, initial, config, scale)
    return _finish_on_curve("eicp", on_curve, pose, iterations, tolerance_met, config)


def match_eicp_mesh(reference: Scan2D, current: Scan2D, initial: np.ndarray, config: MatchConfig) -> MatchResult:
    """eICP constrained to a rigid mesh (one arc-length shift for all points): pose (3,) of ``current``."""
    curve = Polyline(reference, config.gap)
    source = current.points
    minimum = max(config.min_correspondences, 3)
    bound = config.mesh_shift_bound
    # Warm-started like eICP's; its first tree query asks for 2 vertices, as this matcher's cold projections did.
    warm_start = NearestVertexCache(first_query=2)

    def update(pose):
        projection = curve.project(apply_pose(pose, source), warm_start)
        keep = select_correspondences(projection.distance, config)
        if np.count_nonzero(keep) < minimum:
            return None
        points = source[keep]
        arc0 = projection.arc[keep]
        piece = curve.piece_at(arc0)

        def targets(shift):
            return curve.evaluate(curve.clamp_to_piece(arc0 + shift, piece))

        def residual_of_shift(shift):
            target = targets(shift)
            fitted = procrustes(points, target)
            return float(np.sum((apply_pose(fitted, points) - target) ** 2))

        found = minimize_scalar(residual_of_shift, bounds=(-bound, bound), method="bounded",
                                options={"xatol": config.tolerance_translation})
        shift = found.x if found.fun < residual_of_shift(0.0) else 0.0
        return procrustes(points, targets(shift))

    pose, iterations, tolerance_met = iterate(update, initial, config)
    return _finish_on_curve("eicp-mesh", _OnCurve(curve, source), pose, iterations, tolerance_met, config)


def _finish_on_curve(method, on_curve: _OnCurve, pose, iterations, tolerance_met, config) -> MatchResult:
    keep = select_correspondences(on_curve.at(pose).distance, config)
    jacobian, residuals = on_curve.rows(keep)
    return finish(method, pose, iterations, tolerance_met, jacobian, residuals, int(np.count_nonzero(keep)), config)
