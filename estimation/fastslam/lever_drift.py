"""The map frame's drift with the heading's lever arm: a robot pinned to old landmarks is as far off as they are,
plus the heading error times the distance it has moved since they were made.

Why (measured on the rendered building, ``benchmarks/rendered_covariance_diagnosis.py``, docs/fastslam-history.md
"Session 8"): :class:`~estimation.fastslam.drift.DriftTracker` sets the robot's pose covariance, after a frame
that matched landmarks, to the mean of their creation-time covariances plus the local one,
D_r ← mean_l D_l + P_local. That says "the robot is exactly as uncertain as the pose that made those landmarks",
which holds for the heading but not for the position: the landmarks were made at another place, and a heading
error δθ there puts the whole neighbourhood of the map turned about that place, so a robot that has moved by
Δ = t_r − t_l since is off by δθ × Δ more. On robot1 seed 0 the heading σ was honest (0.019 rad against an
error locked in at −0.018 rad) while the position σ stayed 2–4 cm against errors growing to 0.27 m: the
predict step propagates that lever (the motion model's Jacobian), and every update threw it away.

The correction is the Jacobian of "pose of the creation frame ⊕ the robot's motion relative to it" by the
creation pose, G_l = [[1, 0, −Δ_y], [0, 1, Δ_x], [0, 0, 1]] with Δ = t_r − t_l (start frame):

    D_r ← mean_l G_l D_l G_lᵀ + P_local,

with t_l the robot's position when it made landmark l. Optionally (``drift_translation_per_m`` = q > 0) the
position also takes a random walk from the pose that made the landmarks: + q · mean_l |Δ_l| on x and y. The
landmark-relative pose errors do not average out over the ~50 landmarks a frame matches (their errors are
correlated), so the proposal's few-mm P_local misses it; q comes from data with ground truth
(``benchmarks/rendered_covariance_diagnosis.py`` prints the rate of the position error's increments that the
heading's lever does not explain). Everything else is as in ``drift.py`` (creation: D_l = D_r,
C_l = H D_r Hᵀ; export Σ + C_l). With Δ = 0 it is the old rule. Only what the tracker claims changes: on the
stereo path (no drift-widened gates) the particles and maps are the same, so the stereo fingerprint is too.
"""
from __future__ import annotations

import numpy as np

from .drift import DriftTracker
from .linalg import sym_matrices


class LeverDriftTracker(DriftTracker):
    """:class:`DriftTracker` whose update carries each matched landmark's D_l from where it was made to where the
    robot is (the lever arm above). ``remeasured`` (known-ID anchoring) keeps the landmark's creation position,
    so the lever from there is counted again: wider, never narrower."""

    def __init__(self, translation_per_m: float = 0.0) -> None:
        super().__init__()
        self._origin = np.zeros((0, 2))               # t_l: the robot's position when it made landmark l
        self.translation_per_m = float(translation_per_m)   # q: m² per axis per metre from the landmarks' makers

    def update(self, matched_ids: np.ndarray, new_ids: np.ndarray, new_positions: np.ndarray,
               robot_pose: np.ndarray, local_covariance: np.ndarray, n_ids: int) -> None:
        """As :meth:`DriftTracker.update`, with D_r ← mean_l G_l D_l G_lᵀ + P_local after matches."""
        self._ensure(n_ids)
        if len(self._origin) < len(self._pose):
            self._origin = np.vstack([self._origin, np.zeros((len(self._pose) - len(self._origin), 2))])
        matched_ids = np.asarray(matched_ids, np.int64)
        robot_pose = np.asarray(robot_pose, float)
        if len(matched_ids):
            moved = robot_pose[:2] - self._origin[matched_ids]
            self.robot = lever_mean(sym_matrices(self._pose[matched_ids].T), moved) + local_covariance
            if self.translation_per_m > 0:   # pinned to landmarks made |Δ| ago: a random walk of the position
                walk = self.translation_per_m * float(np.mean(np.hypot(moved[:, 0], moved[:, 1])))
                self.robot[[0, 1], [0, 1]] += walk
        super().update(np.zeros(0, np.int64), new_ids, new_positions, robot_pose, local_covariance, n_ids)
        self._origin[np.asarray(new_ids, np.int64)] = robot_pose[:2]


def lever_mean(pose_covariances: np.ndarray, moved: np.ndarray) -> np.ndarray:
    """mean_l G_l D_l G_lᵀ (3, 3) for creation-pose covariances D_l (L, 3, 3) and the robot's displacement since
    each creation Δ_l (L, 2), G_l = [[1, 0, −Δ_y], [0, 1, Δ_x], [0, 0, 1]] (the lever of the heading error)."""
    g = shears(moved)
    return (g @ pose_covariances @ np.swapaxes(g, 1, 2)).mean(axis=0)


def shears(moved: np.ndarray) -> np.ndarray:
    """G(Δ) (L, 3, 3) = [[1, 0, −Δ_y], [0, 1, Δ_x], [0, 0, 1]] for displacements Δ (L, 2): the Jacobian of "pose ⊕ a
    motion that moved it by Δ" by the pose (the lever of a heading error)."""
    moved = np.asarray(moved, float).reshape(-1, 2)
    g = np.zeros((len(moved), 3, 3))                  # the identity filled in: cheaper than tiling np.eye(3)
    g[:, 0, 0] = g[:, 1, 1] = g[:, 2, 2] = 1.0
    g[:, 0, 2], g[:, 1, 2] = -moved[:, 1], moved[:, 0]
    return g


def correlated_mean_factor(n_observations: np.ndarray, correlation: float) -> np.ndarray:
    """How much an EKF that took n observations as independent understates the variance of their mean when
    successive errors are an AR(1) process with lag-1 correlation ρ (the Bartlett variance inflation):
    var(mean) = σ²/n · f, f(n, ρ) = 1 + 2 Σ_{k=1}^{n−1} (1 − k/n) ρ^k. f(1) = 1 (one observation is what it
    claims), f(2) = 1 + ρ, and f → (1 + ρ)/(1 − ρ) as n grows (the effective number of independent
    observations n (1 − ρ)/(1 + ρ)). Closed form of the sum; ``n_observations`` (L,) ≥ 1 -> (L,)."""
    n = np.maximum(np.asarray(n_observations, float), 1.0)
    rho = float(correlation)
    if rho == 0.0:
        return np.ones_like(n)
    # Σ_{k=1}^{n−1} ρ^k = ρ (1 − ρ^{n−1}) / (1 − ρ);  Σ_{k=1}^{n−1} k ρ^k = ρ (1 − n ρ^{n−1} + (n − 1) ρ^n) / (1 − ρ)²
    geometric = rho * (1.0 - rho ** (n - 1.0)) / (1.0 - rho)
    weighted = rho * (1.0 - n * rho ** (n - 1.0) + (n - 1.0) * rho ** n) / (1.0 - rho) ** 2
    return 1.0 + 2.0 * (geometric - weighted / n)


def empirical_local_position(residuals_xy: np.ndarray) -> np.ndarray:
    """(2, 2) variance of the mean position error measured from the frame's own residuals (L, 2) (observation in
    the start frame minus its landmark, the most probable particle's matches): Σ_l r_l r_lᵀ / L², the sandwich
    estimate of a mean's variance. It needs no error model: the proposal's P_local assumes the front end's Q,
    whose bulk is over-claimed while ~4 % of the readings are gross (docs/fastslam-history.md "Session 8"), and a mean
    of L readings is as good as their real spread, not the claimed one. Zeros with fewer than 2 residuals."""
    r = np.asarray(residuals_xy, float).reshape(-1, 2)
    if len(r) < 2:
        return np.zeros((2, 2))
    return r.T @ r / len(r) ** 2


def with_empirical_position(local_covariance: np.ndarray, residuals_xy: np.ndarray,
                            sightings: np.ndarray | None = None, correlation: float = 0.0) -> np.ndarray:
    """P_local (3, 3) plus the empirical position covariance where that is larger (trace) than P_local's own:
    the translation the robot's pose carries from one generation of landmarks to the next, measured online
    (``FastSLAMConfig.drift_local_empirical``) rather than fitted per run (``drift_translation_per_m``). Added, not
    substituted for the position block: a block replaced under the proposal's position-heading cross terms need not
    leave a positive semi-definite matrix (a demo's fusion refused such a landmark covariance).

    ``sightings`` (L,), the matched landmarks' sighting counts, and ``correlation`` ρ: a landmark made now takes
    this frame's pose error, but its EKF then averages the pose errors of the n frames that see it, which are
    AR(1)-correlated like the readings, so what a generation hands on is that error × f(n, ρ)/n
    (:func:`correlated_mean_factor`; mean over the matched landmarks, whose counts stand for the new ones').
    Without them (or ρ = 0 and n = 1) the frame's error is handed on whole."""
    local = np.array(local_covariance, float)
    empirical = empirical_local_position(residuals_xy)
    if sightings is not None and len(sightings):
        n = np.maximum(np.asarray(sightings, float), 1.0)
        empirical = empirical * float(np.mean(correlated_mean_factor(n, correlation) / n))
    if np.trace(empirical) > np.trace(local[:2, :2]):
        local[:2, :2] += empirical
    return local
