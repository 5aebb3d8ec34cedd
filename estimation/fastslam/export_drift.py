"""The drift's heading lever in the exported covariance only: the gate keeps the plain tracker, the map file the lever.

Why (docs/fastslam-history.md, "Session 13 ... (N)"; ``benchmarks/mrclam_nees_diagnosis.py``): on MRCLAM known-ID maps
the landmarks outside the χ²₂ 95 % bound are outside by the map frame's error, and that error is the heading's lever.
The plain tracker (:class:`~estimation.fastslam.drift.DriftTracker`, what ``range_bearing_config`` uses) resets the
robot after every matched frame to D_r ← mean_l D_l + P_local: the robot as uncertain as the poses that made the
landmarks it sees, *where they were*. Its heading σ covers the creation poses' heading errors, but a heading error
δθ turns the map about where it was locked in, so the robot, metres away, is off by δθ × that distance, which the
reset throws away at every frame (the predict step carries it, the update drops it). The lever tracker
(``lever_drift.LeverDriftTracker``, ``drift_lever``, the stereo default) carries it, but on the range-bearing path the
tracker's D_l and D_r also feed the known-ID gate (``id_gate.judge``), so turning it on there changes the estimates.

:class:`ExportLeverDriftTracker` keeps both: the plain tracker's D_r and D_l (``robot``,
``landmark_pose_covariances``: what the gate reads, so the particles and the maps' estimates are those of the
plain tracker, to the digit) and, beside them, the lever tracker's, whose C_l = H D_l Hᵀ is what
``landmark_covariances`` returns (the export's term, ``best_map(covariance="mixture+drift")``). In "id" association
``landmark_covariances`` is read by the export only; in "unknown" association co-visibility counting and merges
read it too, so there it would change estimates (not measured, not meant for it).

The lever D_r is not propagated separately: the filter propagates ``robot`` itself (J D Jᵀ + Q, J the motion's
Jacobian by the pose, which for a displacement Δ in the start frame is the shear G(Δ) = [[1, 0, −Δ_y], [0, 1, Δ_x],
[0, 0, 1]]; shears compose by adding their Δ), and the propagation is linear in D with the same Q for both, so
between two updates the lever D_r is the plain one plus G(Δ) (S − P) G(Δ)ᵀ, S − P the difference right after the
last update and Δ the best particle's displacement since (its positions at the two updates; the proposal's shift
of a few cm within a frame is the approximation). ``remeasured`` (known-ID anchoring, ``id_drift_inherit``) lowers
the plain D_l only; the export's stays as made (wider, never narrower, as ``remeasured`` leaves C_l).

``relative=True`` (``drift_export="lever+heading+relative"``, docs/fastslam-history.md "Session 14 ... (J)"): the
landmark's shape part. C_l counts the creation pose's error; a landmark's EKF then averages its readings placed from the
poses that re-sighted it, and each of those poses drifted relative to the creation pose, which the EKF (conditional on
one path) does not count. With e_k = G_k e_c + δ_k (the pose at sighting k, G_k = G(t_k − t_c) the lever from the
creation position t_c), the reading placed from it is off by H_k e_k = H_c e_c + H_k δ_k (H_k G_k = H_c: the lever
composes), so beyond C_l = H_c D_l H_cᵀ sighting k adds H_k R_k H_kᵀ with R_k = (D_r,k − G_k D_l G_kᵀ)⁺ (the PSD
part, as ``id_gate`` takes D_r − D_l; D_r,k the lever D_r right after frame k's update, the pose the EKF placed the
reading from; H_k's lever w = p_l − t_k, p_l where l was made). The landmark is a weighted mean of its n readings
(the creation one with R = 0), so its error carries Σ a_k H_k δ_k, whose covariance is at most Σ a_k H_k R_k H_kᵀ
(the weighted variance of the vectors is ⪰ 0) and equal to it when the δ_k are fully correlated and alike, as
successive sightings' drifts are (one chain): the mean, not the sum (the n sightings share one drift) and not 1/n of
it (they are not independent). Weights: equal, the EKF's own for a static point whose readings have equal noise (gain
1/k at the k-th reading); the tracker sees frames, not the readings' noise. Export: C_l + mean_k H_k R_k H_kᵀ.
"""
from __future__ import annotations

import numpy as np

from .drift import DriftTracker, _components, made_position_covariances
from .id_gate import psd_part
from .lever_drift import lever_mean, shears
from .linalg import sym_components, sym_matrices


class ExportLeverDriftTracker(DriftTracker):
    """:class:`DriftTracker` for the gate, with the heading's lever carried for the export (module docstring)."""

    def __init__(self, one_landmark_heading: bool = False, relative: bool = False) -> None:
        super().__init__()
        self.one_landmark_heading = bool(one_landmark_heading)   # see :meth:`update`
        self.relative = bool(relative)                 # export the shape part too (module docstring)
        self._relative_sum = np.zeros((0, 6))          # Σ_k H_k R_k H_kᵀ over l's re-sightings (components)
        self._sightings = np.zeros(0)                  # n: l's sightings, its creation included
        self._made_at = np.zeros((0, 2))               # each landmark's position when it was made (start frame)
        self._lever_pose = np.zeros((0, 6))            # the lever tracker's D_l per landmark id
        self._lever_position = np.zeros((0, 6))        # its C_l = H D_l Hᵀ: the export's term
        self._difference = np.zeros((3, 3))            # lever D_r − plain D_r right after the last update
        self._last_position = np.zeros(2)              # the robot's position at the last update

    def _ensure(self, n_ids: int) -> None:
        super()._ensure(n_ids)
        grow = len(self._pose) - len(self._lever_pose)
        if grow > 0:
            self._lever_pose = np.vstack([self._lever_pose, np.zeros((grow, 6))])
            self._lever_position = np.vstack([self._lever_position, np.zeros((grow, 6))])
            self._made_at = np.vstack([self._made_at, np.zeros((grow, 2))])
            self._relative_sum = np.vstack([self._relative_sum, np.zeros((grow, 6))])
            self._sightings = np.concatenate([self._sightings, np.zeros(grow)])

    @property
    def lever_robot(self) -> np.ndarray:
        """The lever tracker's D_r now (3, 3), before this frame's update (the plain D_r plus the carried difference;
        exact at the last update's position)."""
        return self.robot + self._difference

    def update(self, matched_ids: np.ndarray, new_ids: np.ndarray, new_positions: np.ndarray,
               robot_pose: np.ndarray, local_covariance: np.ndarray, n_ids: int) -> None:
        """As :meth:`DriftTracker.update` for the gate's D_r and D_l; beside them the lever tracker's
        D_r ← mean_l G_l D_l G_lᵀ + P_local (``lever_drift.lever_mean``) and its D_l, C_l for new landmarks.

        ``one_landmark_heading``: a frame that matched one landmark only pins the two degrees of freedom its reading
        observes (where the landmark is in the robot's frame), not the robot's rotation about the landmark: then
        D_r ← M + max(0, D⁻_θθ − M_θθ) g gᵀ, M the rule above, D⁻ the predicted D_r and g = (−Δ_y, Δ_x, 1) the
        rotation about the landmark (Δ = t_r − p_l, p_l where it was made): the heading uncertainty the prediction
        carried beyond the landmark's stays, as a turn about it. Two or more landmarks observe the heading too
        (the rule above)."""
        robot_pose = np.asarray(robot_pose, float)
        g = shears(robot_pose[:2] - self._last_position)[0]
        lever = self.robot + g @ self._difference @ g.T                 # carried from the last update to here
        super().update(matched_ids, new_ids, new_positions, robot_pose, local_covariance, n_ids)
        matched_ids = np.asarray(matched_ids, np.int64)
        if len(matched_ids):
            moved = robot_pose[:2] - self._origin[matched_ids]
            predicted = lever
            lever = lever_mean(sym_matrices(self._lever_pose[matched_ids].T), moved) + local_covariance
            if self.one_landmark_heading and len(matched_ids) == 1:
                arm = robot_pose[:2] - self._made_at[matched_ids[0]]
                g = np.array([-arm[1], arm[0], 1.0])
                lever = lever + max(0.0, predicted[2, 2] - lever[2, 2]) * np.outer(g, g)
            if self.relative:
                self._accumulate(matched_ids, lever, robot_pose, moved)
        new_ids = np.asarray(new_ids, np.int64)
        if len(new_ids):
            self._lever_pose[new_ids] = sym_components(lever[None])[:, 0]
            self._lever_position[new_ids] = made_position_covariances(lever, robot_pose, new_positions)
            self._made_at[new_ids] = np.asarray(new_positions, float)[:, :2]
            self._relative_sum[new_ids] = 0.0
            self._sightings[new_ids] = 1.0
        self._difference = lever - self.robot
        self._last_position = robot_pose[:2].copy()

    def _accumulate(self, ids: np.ndarray, robot: np.ndarray, robot_pose: np.ndarray, moved: np.ndarray) -> None:
        """Σ_k += H_k (D_r − G_k D_l G_kᵀ)⁺ H_kᵀ and n += 1 for re-sighted landmarks ``ids`` (K,), D_r = ``robot``
        (3, 3) the lever D_r after this frame's update, ``moved`` (K, 2) = t_k − t_c (module docstring)."""
        g = shears(moved)
        relative = psd_part(robot[None] - g @ sym_matrices(self._lever_pose[ids].T) @ np.swapaxes(g, 1, 2))
        self._relative_sum[ids] += made_position_covariances(relative, robot_pose, self._made_at[ids])
        self._sightings[ids] += 1.0

    def relative_covariances(self, ids: np.ndarray) -> np.ndarray:
        """The shape part mean_k H_k R_k H_kᵀ (L, 3, 3) of landmarks ``ids`` (L,) (module docstring; zeros for ids
        never seen, never re-sighted, or without ``relative``, which accumulates nothing)."""
        total = _components(self._relative_sum, ids)
        n = _components(np.repeat(self._sightings[:, None], 6, axis=1), ids)
        return sym_matrices(total / np.maximum(n, 1.0))

    def landmark_covariances(self, ids: np.ndarray) -> np.ndarray:
        """C_l (L, 3, 3) of the lever tracker (the export's term; zeros for ids never seen by the tracker); with
        ``relative``, plus the shape part (:meth:`relative_covariances`)."""
        made = sym_matrices(_components(self._lever_position, ids))
        return made + self.relative_covariances(ids) if self.relative else made

    def export_pose_covariances(self, ids: np.ndarray) -> np.ndarray:
        """The lever tracker's D_l (6, L) components (the gate reads the plain ones, ``landmark_pose_covariances``)."""
        return _components(self._lever_pose, ids)
