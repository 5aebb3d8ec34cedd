"""What eICP, ICP and PL-ICP share: configuration, outlier handling, stopping rule, result and covariance.

Outliers.  A correspondence is kept when the distance between the point and its partner is at most
``max_distance`` (the gate) and its residual is not among the worst ``trim_fraction`` of the gated ones
(trimmed least squares, so a fixed share of points seen by only one of the scans cannot drag the pose).
For ICP and eICP the residual is that distance; for PL-ICP it is the distance to the line.

Stopping.  Iterate until the pose update is below ``tolerance_translation`` (m) and ``tolerance_rotation``
(rad), or ``max_iterations`` is reached, or the kept set cycles (see :func:`iterate`).  ``converged`` means
the tolerance was met with at least ``min_correspondences`` correspondences left.

Covariance.  With the final correspondences held fixed, the cost is J(ξ) = Σ_i r_i(ξ)², ξ = (x, y, θ).  Its
Gauss-Newton Hessian is 2 AᵀA (A: stacked residual Jacobians, m×3) and the residual variance is
σ² = Σ r_i² / (m − 3), so cov(ξ) = σ² (AᵀA)⁻¹ — the usual least-squares estimate.  It ignores the
uncertainty of the associations themselves, so it is optimistic (Censi 2007 gives the full form).  In a
degenerate scene (a corridor) AᵀA is (nearly) singular; its eigenvalues are floored at 1e-12 of the largest,
so the unconstrained direction gets a huge but finite variance instead of the zero a pseudo-inverse would
give.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from estimation.geometry import wrap_angle
from estimation.scanmatch.errors import ScanMatchError


@dataclass(frozen=True)
class MatchConfig:
    """Settings shared by every method (metres, radians)."""

    max_iterations: int = 50
    tolerance_translation: float = 1e-4
    tolerance_rotation: float = 1e-4
    max_distance: float = 1.0          # correspondence gate
    trim_fraction: float = 0.1         # share of the gated correspondences dropped as the worst
    min_correspondences: int = 10
    gap: float = 0.5                   # curve break between consecutive reference points farther apart
    mesh_shift_bound: float = 0.5      # eICP-mesh: search the arc-length shift in [-bound, bound]
    eicp_solver: str = "gauss-newton"  # or "alternating" (projection + Procrustes)
    # eICP's Gauss-Newton converges quadratically: a step below 10× the tolerances leaves an error far below
    # them, so it stops there (the linearly converging methods use the tolerances as they are).
    gauss_newton_tolerance_scale: float = 5.0

    def __post_init__(self) -> None:
        if self.max_iterations < 1:
            raise ScanMatchError(f"max_iterations must be >= 1, got {self.max_iterations}")
        if not 0.0 <= self.trim_fraction < 1.0:
            raise ScanMatchError(f"trim_fraction must be in [0, 1), got {self.trim_fraction}")
        if self.max_distance <= 0.0 or self.gap <= 0.0:
            raise ScanMatchError("max_distance and gap must be positive")
        if self.gauss_newton_tolerance_scale < 1.0:
            raise ScanMatchError(f"gauss_newton_tolerance_scale must be >= 1, got {self.gauss_newton_tolerance_scale}")
        if self.eicp_solver not in ("gauss-newton", "alternating"):
            raise ScanMatchError(f"eicp_solver must be 'gauss-newton' or 'alternating', got {self.eicp_solver!r}")

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class MatchResult:
    """The pose of the current scan in the reference scan's frame, and how it was found.

    pose:              (3,) x, y (m), θ (rad): current-scan points p map to R(θ) p + (x, y) in the reference
    covariance:        (3, 3) of pose (see the module docstring)
    iterations:        iterations run
    residual:          RMS of the final residuals (m)
    converged:         the stopping tolerance was met with enough correspondences
    n_correspondences: correspondences used in the last iteration
    """

    pose: np.ndarray
    covariance: np.ndarray
    iterations: int
    residual: float
    converged: bool
    n_correspondences: int
    method: str = field(default="")

    def to_dict(self) -> dict:
        return {"pose": self.pose.tolist(), "covariance": self.covariance.tolist(), "iterations": self.iterations,
                "residual": self.residual, "converged": self.converged,
                "n_correspondences": self.n_correspondences, "method": self.method}


def select_correspondences(distance: np.ndarray, config: MatchConfig, residual: np.ndarray | None = None
                           ) -> np.ndarray:
    """Boolean mask (N,) of the correspondences kept.

    Gated by the distance (N,) between the point and what it is paired with, then the worst ``trim_fraction``
    of the gated ones trimmed by the residual the method minimises (N,) (default: the same distance; PL-ICP
    passes its point-to-line residual).
    """
    keep = distance <= config.max_distance
    n_keep = int(np.count_nonzero(keep))
    n_trim = int(config.trim_fraction * n_keep)
    if n_trim > 0:
        # The gated-out points score ∞, so the last N − n_keep + n_trim of the partition are exactly they and the
        # n_trim worst gated ones (one partition of the whole array: fewer small-array steps than a subset's).
        score = distance if residual is None else np.abs(residual)
        score = np.where(keep, score, np.inf)
        keep[score.argpartition(n_keep - n_trim)[n_keep - n_trim:]] = False
    return keep


def truncated_cost(distance: np.ndarray, config: MatchConfig) -> float:
    """Σ min(d_i, gate)² over the distances (N,) given."""
    clipped = np.minimum(distance, config.max_distance)
    return float(clipped @ clipped)


def pose_step_small(step: np.ndarray, config: MatchConfig, scale: float = 1.0) -> bool:
    """The stopping rule: the last pose update (3,) is below both tolerances (times ``scale``)."""
    return (math.hypot(float(step[0]), float(step[1])) < scale * config.tolerance_translation
            and abs(float(step[2])) < scale * config.tolerance_rotation)


def rotate(theta: float, points: np.ndarray) -> np.ndarray:
    """R(θ) p for points (N, 2)."""
    c, s = math.cos(theta), math.sin(theta)
    return points @ np.array([[c, s], [-s, c]])   # one small matmul: fewer temporaries than per-column


def apply_pose(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """R(θ) p + t for points (N, 2)."""
    return rotate(pose[2], points) + pose[:2]


def pose_jacobian(rotated: np.ndarray) -> np.ndarray:
    """∂(R(θ) p + t)/∂(x, y, θ) for rotated points R(θ)p (N, 2): (N, 2, 3)."""
    n = rotated.shape[0]
    jac = np.zeros((n, 2, 3))
    jac[:, 0, 0] = 1.0
    jac[:, 1, 1] = 1.0
    jac[:, 0, 2] = -rotated[:, 1]
    jac[:, 1, 2] = rotated[:, 0]
    return jac


def _solve_symmetric_3x3(normal: list, rhs: list) -> np.ndarray | None:
    """x (3,) with normal x = rhs for a symmetric positive semi-definite 3×3 given as nested lists of floats,
    or None when it is ill-conditioned.  Python floats: np.linalg.solve/det cost ~20 µs on a 3×3."""
    (a, b, c), (_, d, e), (_, _, f) = normal   # symmetric
    trace = a + d + f
    # Cofactors of the symmetric matrix; the solve is adjugate · rhs / det (well conditioned past the test).
    ca, cb, cc = d * f - e * e, c * e - b * f, b * e - c * d
    det = a * ca + b * cb + c * cc
    # cond ≤ trace³ / det for a symmetric positive semi-definite 3×3: a cheap test before the plain solve.
    if det > 1e-10 * trace ** 3:
        cd, ce, cf = a * f - c * c, b * c - a * e, a * d - b * b
        r0, r1, r2 = rhs
        return np.array([ca * r0 + cb * r1 + cc * r2, cb * r0 + cd * r1 + ce * r2, cc * r0 + ce * r1 + cf * r2]) / det
    return None


def solve_normal_equations(jacobian: np.ndarray, residuals: np.ndarray) -> np.ndarray:
    """The least-squares x (3,) of jacobian (m, 3) · x ≈ residuals (m,); pseudo-inverse when ill-conditioned."""
    solution = _solve_symmetric_3x3((jacobian.T @ jacobian).tolist(), (jacobian.T @ residuals).tolist())
    return np.linalg.lstsq(jacobian, residuals, rcond=None)[0] if solution is None else solution


def least_squares_covariance(jacobian: np.ndarray, residuals: np.ndarray) -> np.ndarray:
    """σ² (AᵀA)⁻¹ for stacked residual Jacobians A (m, 3) and residuals (m,) (eigenvalues floored); NaN if m <= 3."""
    m = residuals.shape[0]
    if m <= 3:
        return np.full((3, 3), np.nan)
    sigma2 = float(residuals @ residuals) / (m - 3)
    eigval, eigvec = np.linalg.eigh(jacobian.T @ jacobian)
    floor = max(float(eigval[-1]), 1e-300) * 1e-12
    cov = sigma2 * (eigvec / np.maximum(eigval, floor)) @ eigvec.T
    return 0.5 * (cov + cov.T)


def procrustes(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The pose (3,) minimising Σ |R(θ) source_i + t − target_i|², closed form.  source, target: (N, 2)."""
    n = source.shape[0]
    if n < 2:
        raise ScanMatchError("Procrustes needs at least 2 point pairs")
    ms, mt = source.sum(axis=0) / n, target.sum(axis=0) / n
    # Cross-covariance terms of the centred sets: Σ a·b and Σ a×b give cos and sin of θ.
    dot = float(np.einsum("ij,ij->", source, target)) - n * float(ms @ mt)
    cross = float(np.einsum("i,i->", source[:, 0], target[:, 1]) - np.einsum("i,i->", source[:, 1], target[:, 0]))
    cross -= n * float(ms[0] * mt[1] - ms[1] * mt[0])
    theta = float(np.arctan2(cross, dot))
    c, s = np.cos(theta), np.sin(theta)
    return np.array([mt[0] - (c * ms[0] - s * ms[1]), mt[1] - (s * ms[0] + c * ms[1]), theta])


def _inverse_2x2(a: np.ndarray) -> np.ndarray:
    """Inverse of a symmetric 2×2, the pseudo-inverse when it is (near) singular."""
    det = a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]
    if abs(det) <= 1e-12 * max(1.0, float(np.abs(a).max()) ** 2):
        return np.linalg.pinv(a)
    return np.array([[a[1, 1], -a[0, 1]], [-a[1, 0], a[0, 0]]]) / det


def point_to_line_pose(source: np.ndarray, anchor: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """The pose (3,) minimising Σ (n_iᵀ (R(θ) p_i + t − q_i))², in closed form (Censi, ICRA 2008).

    source p: (N, 2); anchor q: (N, 2) a point of each line; normal n: (N, 2) unit.

    With x = (t_x, t_y, cos θ, sin θ) the cost is a quadratic xᵀMx + gᵀx + k under the constraint
    cos² + sin² = 1.  Eliminating t (linear) leaves uᵀSu + hᵀu on the unit circle u = (cos θ, sin θ); the
    Lagrange condition (S + λI)u = −h/2 with |u| = 1 is a quartic in λ whose largest real root gives the
    global minimum.  Degenerate translation (all normals parallel) is handled with a pseudo-inverse.
    """
    if source.shape[0] < 3:
        raise ScanMatchError("point-to-line alignment needs at least 3 correspondences")
    # Rows of M_i: R p + t = M_i x with M_i = [[1, 0, px, -py], [0, 1, py, px]]; residual n_iᵀ M_i x − n_iᵀ q_i.
    nx, ny, px, py = normal[:, 0], normal[:, 1], source[:, 0], source[:, 1]
    row = np.column_stack([nx, ny, nx * px + ny * py, ny * px - nx * py])   # (N, 4)
    rhs = nx * anchor[:, 0] + ny * anchor[:, 1]                              # (N,)
    M = row.T @ row
    g = -2.0 * (row.T @ rhs)
    A, B, D = M[:2, :2], M[:2, 2:], M[2:, 2:]
    A_inv = _inverse_2x2(A)
    S = D - B.T @ A_inv @ B
    h = g[2:] - B.T @ (A_inv @ g[:2])
    # Eigen-decomposition of the symmetric 2×2 S, in closed form.
    mean, half_diff = 0.5 * (S[0, 0] + S[1, 1]), 0.5 * (S[0, 0] - S[1, 1])
    radius = float(np.hypot(half_diff, S[0, 1]))
    eigval = np.array([mean - radius, mean + radius])
    phi = 0.5 * np.arctan2(2.0 * S[0, 1], S[0, 0] - S[1, 1])          # angle of the larger eigenvector
    eigvec = np.array([[-np.sin(phi), np.cos(phi)], [np.cos(phi), np.sin(phi)]])  # columns: small, large
    hp = eigvec.T @ h / 2.0
    e1, e2 = eigval
    # (e1+λ)²(e2+λ)² − hp1²(e2+λ)² − hp2²(e1+λ)² = 0
    p1 = np.array([1.0, 2.0 * e1, e1 * e1])
    p2 = np.array([1.0, 2.0 * e2, e2 * e2])
    poly = np.convolve(p1, p2)
    poly[2:] -= hp[0] ** 2 * p2 + hp[1] ** 2 * p1
    roots = np.roots(poly)
    real = roots[np.abs(roots.imag) <= 1e-7 * max(1.0, float(np.max(np.abs(roots))))].real
    lam = float(np.max(real)) if real.size else -e1
    lam = max(lam, -e1)   # the global minimum has S + λI positive semi-definite
    denom = eigval + lam
    weak = int(np.argmin(np.abs(denom)))
    u = eigvec @ (-hp / denom) if abs(denom[weak]) >= 1e-12 else np.full(2, np.nan)
    norm = float(np.hypot(u[0], u[1]))
    if not np.isfinite(norm) or abs(norm - 1.0) > 1e-3:
        # The trust-region "hard case": h has (almost) no component on the weak eigenvector, λ = −e_weak and
        # u takes what the strong component leaves of the unit length along the weak eigenvector.
        comp = np.zeros(2)
        comp[1] = -hp[1] / denom[1] if abs(denom[1]) >= 1e-12 else 0.0
        comp[1] = float(np.clip(comp[1], -1.0, 1.0))
        comp[0] = np.sqrt(max(0.0, 1.0 - comp[1] ** 2)) * (-1.0 if hp[0] > 0 else 1.0)
        u = eigvec @ comp
        norm = float(np.hypot(u[0], u[1]))
    u = u / norm
    t = -A_inv @ (B @ u + g[:2] / 2.0)
    return np.array([t[0], t[1], np.arctan2(u[1], u[0])])


def iterate(update, initial: np.ndarray, config: MatchConfig, tolerance_scale: float = 1.0
            ) -> tuple[np.ndarray, int, bool]:
    """Run ``update(pose) -> new pose | None`` until the stopping rule holds (tolerances × ``tolerance_scale``).

    Returns (pose (3,), iterations, tolerance_met).  ``None`` from ``update`` (too few correspondences) or a
    non-finite pose stops at once without convergence, keeping the last good pose.  So does a limit cycle:
    when the kept correspondence set flips between a few states the poses repeat with a period of 2-4
    iterations and never meet the tolerance, so returning to a pose of 2-4 iterations back (to rounding
    error: the same kept set gives the same solve) stops the run, not converged, instead of spinning to
    ``max_iterations``.
    """
    pose = np.asarray(initial, dtype=float).copy()
    tolerance_translation = tolerance_scale * config.tolerance_translation
    tolerance_rotation = tolerance_scale * config.tolerance_rotation
    history: list[tuple[float, float, float]] = []
    here = tuple(pose.tolist())
    for iteration in range(1, config.max_iterations + 1):
        new = update(pose)
        if new is None:   # too few correspondences
            return pose, iteration, False
        x, y, theta = new.tolist()   # Python floats: a handful of scalar steps cost less than array ones
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(theta)):   # a degenerate solve
            return pose, iteration, False
        step = (x - here[0], y - here[1], (theta - here[2] + math.pi) % (2.0 * math.pi) - math.pi)
        pose, here = new, (x, y, theta)
        if math.hypot(step[0], step[1]) < tolerance_translation and abs(step[2]) < tolerance_rotation:
            return pose, iteration, True
        # The same kept set gives the same solve: a cycle returns to an earlier pose to rounding error.
        # (A converging run also comes back near earlier poses, but with steps that have become tiny.)
        if max(abs(step[0]), abs(step[1]), abs(step[2])) > 1e-6 and any(
                max(abs(a - b) for a, b in zip(here, earlier, strict=True)) < 1e-9 for earlier in history[-4:-1]):
            return pose, iteration, False
        history.append(here)
    return pose, config.max_iterations, False


def finish(method: str, pose: np.ndarray, iterations: int, tolerance_met: bool, jacobian: np.ndarray,
           residuals: np.ndarray, n_correspondences: int, config: MatchConfig) -> MatchResult:
    """The MatchResult of a run, from the residual rows (m,) and their Jacobian (m, 3) at the final pose."""
    rms = float(np.sqrt(np.mean(residuals ** 2))) if residuals.size else float("nan")
    pose = np.array([pose[0], pose[1], wrap_angle(pose[2])])
    return MatchResult(pose=pose, covariance=least_squares_covariance(jacobian, residuals), iterations=iterations,
                       residual=rms, converged=bool(tolerance_met and n_correspondences >= config.min_correspondences),
                       n_correspondences=int(n_correspondences), method=method)
