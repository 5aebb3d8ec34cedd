"""The map frame's drift: the uncertainty FastSLAM's particles forget, kept beside them (an honest export).

Why: every particle's landmark EKF is conditional on that particle's trajectory, and the spread of the
particles would carry the trajectory's own uncertainty, but resampling nearly every frame makes all particles
descend from one recent ancestor (Bailey, Nieto & Nebot 2006): the cloud keeps the pose's uncertainty relative
to the landmarks in view (~1 cm) and loses how far that whole neighbourhood of the map has drifted from the
start frame. Maps exported with the EKF (or even the particle-mixture) covariances were therefore overconfident
by one to two orders of magnitude in NEES (docs/fastslam.md).

Model (a chain of relative estimates, as in visual odometry): each landmark l carries the pose covariance D_l
the robot had, relative to the start frame, when it created l, and the position covariance C_l = H D_l Hᵀ
that this pose error puts on l (H = ∂(t + R z)/∂(x, y, θ) = [[1, 0, −w_y], [0, 1, w_x], [0, 0, 0]], w = μ − t).
The robot carries D_r:

- predict: D_r ← J D_r Jᵀ + G V Gᵀ (the motion model, like dead reckoning);
- update with matches: the pose is pinned to the matched landmarks, so its absolute uncertainty is theirs plus
  the local one, D_r ← mean_l D_l + P_local (P_local: the particle cloud's pose covariance this frame); with
  no match D_r keeps growing with the motion;
- a landmark created now gets D_l = D_r and C_l = H D_r Hᵀ;
- a landmark re-placed from a pose pinned to an older landmark a (known-ID, ``id_gate.py``) gets
  D_l ← D_a + P_local where that is smaller (:meth:`DriftTracker.remeasured`), C_l unchanged;
- export: Σ_l ← Σ_l + C_l.

Without loops, D_r grows by P_local once per generation of landmarks (not once per frame, as landmarks are
seen over many frames); revisiting old landmarks brings D_r back to their level. The mean over matched
landmarks (not an information sum) is deliberate: their drifts are nearly fully correlated (one chain), so
seeing many of them does not make the frame more certain.
"""
from __future__ import annotations

import numpy as np

from .linalg import sym_components, sym_matrices


class DriftTracker:
    """Map-frame drift per landmark id (see the module docstring). Covariances are (6,) symmetric components."""

    def __init__(self) -> None:
        self.robot = np.zeros((3, 3))                 # D_r, the robot's pose covariance relative to the start
        self._pose = np.zeros((0, 6))                 # D_l per landmark id
        self._position = np.zeros((0, 6))             # C_l per landmark id
        self._origin = np.zeros((0, 2))               # where the robot was when it made l (exported beside D_l)

    def _ensure(self, n_ids: int) -> None:
        if n_ids > len(self._pose):
            grow = max(n_ids, 2 * len(self._pose)) - len(self._pose)
            self._pose = np.vstack([self._pose, np.zeros((grow, 6))])
            self._position = np.vstack([self._position, np.zeros((grow, 6))])
            self._origin = np.vstack([self._origin, np.zeros((grow, 2))])

    def predict(self, jacobian_pose: np.ndarray, motion_noise: np.ndarray) -> None:
        """D_r ← J D_r Jᵀ + Q_motion (both (3, 3), Q_motion already in the start frame)."""
        self.robot = jacobian_pose @ self.robot @ jacobian_pose.T + motion_noise

    def update(self, matched_ids: np.ndarray, new_ids: np.ndarray, new_positions: np.ndarray,
               robot_pose: np.ndarray, local_covariance: np.ndarray, n_ids: int) -> None:
        """After a frame: ``matched_ids`` (K,) landmark ids the robot re-observed, ``new_ids`` (L,) ids it created
        with their positions (L, 3) in the start frame, ``robot_pose`` (3,), ``local_covariance`` (3, 3)."""
        self._ensure(n_ids)
        matched_ids = np.asarray(matched_ids, np.int64)
        if len(matched_ids):
            self.robot = sym_matrices(self._pose[matched_ids].mean(axis=0)[:, None])[0] + local_covariance
        if len(new_ids):
            d = sym_components(self.robot[None])[:, 0]
            self._pose[new_ids] = d
            self._origin[new_ids] = np.asarray(robot_pose, float)[:2]
            self._position[new_ids] = made_position_covariances(self.robot, robot_pose, new_positions)

    def remeasured(self, ids: np.ndarray, pose_covariance: np.ndarray) -> np.ndarray:
        """Landmarks ``ids`` (L,) were re-placed from a pose whose covariance relative to the start frame is
        ``pose_covariance`` (3, 3) (id_gate.py: a frame anchored on an older landmark): D_l ← that covariance
        where it is smaller (trace) than D_l, so that the chain is shortened as at a loop closure. C_l, the
        export's term, is left as made (wider, never narrower; see id_gate.RelativeGate.inherit). Returns the
        ids lowered."""
        ids = np.asarray(ids, np.int64)
        ids = ids[ids < len(self._pose)]
        d = sym_components(np.asarray(pose_covariance, float)[None])[:, 0]
        lowered = ids[self._pose[ids][:, [0, 3, 5]].sum(axis=1) > d[[0, 3, 5]].sum()]
        self._pose[lowered] = d
        return lowered

    def landmark_pose_covariances(self, ids: np.ndarray) -> np.ndarray:
        """D_l (6, L) components for landmark ids (L,) (zeros for ids never seen by the tracker)."""
        return _components(self._pose, ids)

    def landmark_origins(self, ids: np.ndarray) -> np.ndarray:
        """(L, 2) the robot's position when it made landmarks ``ids`` (L,) (zeros for ids never seen by the tracker):
        with D_l, what a map file exports so that fusion can tell which landmarks share a drift
        (``LandmarkMap.drift_origins``)."""
        ids = np.asarray(ids, np.int64)
        out = np.zeros((len(ids), 2))
        inside = ids < len(self._origin)
        out[inside] = self._origin[ids[inside]]
        return out

    def landmark_covariances(self, ids: np.ndarray) -> np.ndarray:
        """C_l (L, 3, 3) for landmark ids (L,) (zeros for ids never seen by the tracker)."""
        return sym_matrices(_components(self._position, ids))


def _components(table: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """Rows of a per-landmark table (n, 6) for ids (L,) as (6, L) components; zeros for ids beyond it."""
    ids = np.asarray(ids, np.int64)
    out = np.zeros((len(ids), 6))
    inside = ids < len(table)
    out[inside] = table[ids[inside]]
    return out.T


def made_position_covariances(pose_covariance: np.ndarray, robot_pose: np.ndarray, positions: np.ndarray
                              ) -> np.ndarray:
    """C_l = H D Hᵀ (L, 6 components) of landmarks made at ``positions`` (L, ≥2) from a robot at ``robot_pose`` whose
    pose covariance is D (3, 3), or one D per landmark (L, 3, 3): H = [[1, 0, −w_y], [0, 1, w_x], [0, 0, 0]], w the
    landmark's offset from the robot."""
    w = np.asarray(positions, float)[:, :2] - np.asarray(robot_pose, float)[:2]
    h = np.zeros((len(w), 3, 3))
    h[:, 0, 0] = h[:, 1, 1] = 1.0
    h[:, 0, 2], h[:, 1, 2] = -w[:, 1], w[:, 0]
    return sym_components(h @ pose_covariance @ np.swapaxes(h, 1, 2)).T
