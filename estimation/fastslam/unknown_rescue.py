"""Unknown association: old landmarks re-sighted after a drift, re-associated when one pose correction explains two.

Why (docs/fastslam-history.md, "Session 7: unknown association"): the gate's S holds the landmark's EKF covariance, the
sensor noise and the pose's uncertainty since the last frame; the resampled particle cloud forgets how far the
pose has drifted relative to landmarks made long ago (Bailey, Nieto & Nebot 2006; ``id_gate.py``). When such a
landmark comes back into view every particle rejects its reading and makes a *new* landmark there: a duplicate,
and the map after the drift is never tied back to the map before it. In "id" association the identity says
which landmark to judge again (``id_gate.py``); here nothing does, and a gate widened by the drift admits other,
nearby landmarks too (MRCLAM: 15 alike posts 0.7-1.9 m apart). So a re-association needs more than passing a
wider gate (``FastSLAMConfig.unknown_relative_drift = "consistent"``, FastSLAM 2.0, "unknown" association):

1. a reading no landmark of the particle passes under the plain gate is judged again against the particle's
   landmarks in view (with descriptors: only those whose descriptor agrees, as the plain association requires)
   under S + H (D_r − D_l)⁺ Hᵀ, D_l the robot's start-frame pose covariance when l was made and D_r now
   (``drift.py``): the drift accumulated since l was made;
2. it must have exactly one such candidate, and that landmark must be claimed by no other reading of the frame
   (a unique candidate: a widened gate holding two landmarks says "one of these", which is no association);
3. at least two different landmarks must be re-associated in the particle in one frame, *jointly*: their
   stacked innovations must pass the χ² gate of their stacked covariance, in which the drift is one pose error
   shared by both readings (the cross term H_a (D_r − D_y)⁺ H_bᵀ, D_y the younger landmark's: in a chain the
   drift since the younger one is common to both). Two readings that each fit their landmark under some
   correction, but not under one and the same rigid correction, fail; the largest jointly compatible set is
   kept (greedily from the best pair; Neira & Tardós 2001's joint compatibility, on the rejected readings only).
   Why two: one planar reading fixes two of the pose's three degrees of freedom (``id_gate.py``), and a drifted
   pose makes every old landmark in view fail consistently while a look-alike fits one.

The accepted readings then anchor the particle's proposal on the oldest of them exactly as ``id_gate`` does
(:meth:`id_gate.RelativeGate.anchor`), and cost ½ [d̃² + log(det S̃ / det S)], at most ½ gate, in the weight.
No constant beyond the filter's own: the same gate probability (χ²₃ at ``mahalanobis_gate``), carried to 3n
degrees of freedom for n stacked readings, and the drift tracker's covariances.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import chi2
from .drift import DriftTracker
from .id_gate import RelativeGate, psd_part
from .linalg import pose_uncertainty, sym_adjugate, sym_components, sym_matrices, sym_quadratic


@dataclass
class Rescued:
    """Readings re-associated in one frame (arrays over R pairs): ``rows`` into the frame's candidate list (one
    landmark of one particle each), ``j`` the observation; the landmarks' ``mean`` (3, R), ``cov`` (6, R); the
    ``innovation`` (3, R) = R z + t − μ and ``s_obs`` (6, R) = Σ + R Q Rᵀ at the predicted pose; ``cost`` (R,)
    the weight's d² (see the module docstring)."""

    rows: np.ndarray
    j: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    innovation: np.ndarray
    s_obs: np.ndarray
    cost: np.ndarray

    def relative_gate(self, tracker: DriftTracker, lids: np.ndarray, d2: np.ndarray, gated: np.ndarray,
                      gate: float) -> RelativeGate:
        """The frame's pairs as ``id_gate`` describes them, for :meth:`RelativeGate.anchor`: ``lids`` (P + R,)
        the landmark of every pair, the plain pairs first (``d2``, ``gated`` (P,)), then these R."""
        n_plain = len(d2)
        rescued = np.concatenate([np.zeros(n_plain, bool), np.ones(len(self.rows), bool)])
        return RelativeGate("consistent", np.concatenate([d2, np.minimum(self.cost, gate)]),
                            np.concatenate([gated, np.ones(len(self.rows), bool)]), rescued.copy(), rescued,
                            tracker.landmark_pose_covariances(lids), np.asarray(tracker.robot, float))


def _jacobians(lever: np.ndarray) -> np.ndarray:
    """World-frame pose Jacobians (L, 3, 3) H = [[−1, 0, w_y], [0, −1, −w_x], [0, 0, 0]] for levers w (2, L)."""
    h = np.zeros((lever.shape[1], 3, 3))
    h[:, 0, 0] = h[:, 1, 1] = -1.0
    h[:, 0, 2], h[:, 1, 2] = lever[1], -lever[0]
    return h


def joint_d2(innovation: np.ndarray, s_obs: np.ndarray, lever: np.ndarray, drift: np.ndarray, robot: np.ndarray,
             motion: np.ndarray) -> float:
    """d² of n readings of one particle stacked (3n): ``innovation`` (3, n), S without the pose (6, n) (landmark
    and sensor: independent per reading), levers (2, n), their landmarks' D_l (n, 3, 3), D_r (3, 3) and the
    particle's motion covariance since the last frame (3, 3). The pose errors are shared: this frame's motion by
    every reading, the drift since the younger of two landmarks (larger tr D) by both (a chain of relative
    estimates)."""
    n = innovation.shape[1]
    h = _jacobians(lever)
    age = np.trace(drift, axis1=1, axis2=2)
    younger = np.where(age[:, None] >= age[None, :], np.arange(n)[:, None], np.arange(n)[None, :])
    shared = psd_part(robot[None] - drift) + motion[None]                          # (n, 3, 3): D_r − D_l + P
    big = np.zeros((3 * n, 3 * n))
    own = sym_matrices(s_obs)
    for a in range(n):
        for b in range(n):
            block = h[a] @ shared[younger[a, b]] @ h[b].T
            if a == b:
                block = block + own[a]
            big[3 * a:3 * a + 3, 3 * b:3 * b + 3] = block
    nu = innovation.T.reshape(-1)
    try:
        return float(nu @ np.linalg.solve(big, nu))
    except np.linalg.LinAlgError:
        return np.inf


def rescue(tracker: DriftTracker, rejected: np.ndarray, cand_m: np.ndarray, cand_lids: np.ndarray,
           cand_g: np.ndarray, flat_state: np.ndarray, world: np.ndarray, noise: np.ndarray, motion_cov: np.ndarray,
           poses: np.ndarray, gate: float, obs_desc: np.ndarray | None = None,
           lid_desc: np.ndarray | None = None, desc_threshold: float = 0.5) -> Rescued | None:
    """Readings to re-associate this frame (see the module docstring), or None.

    ``rejected`` (M·N,) bool, indexed m·N + j: (particle, observation) with no landmark inside the plain gate;
    the frame's candidate landmarks: ``cand_m`` (C,) particle, ``cand_lids`` (C,) id, ``cand_g`` (C,) slot in the
    store's ``flat_state`` (slots, 9: mean and covariance components); ``world`` (3, M·N) R z + t and ``noise``
    (6, M·N) R Q Rᵀ at the predicted ``poses`` (M, 3); ``motion_cov`` (M, 3, 3) the motion not yet sampled;
    ``obs_desc`` (N, D) and ``lid_desc`` (ids, D) unit descriptors (D = 0 or None: position alone) compared at
    ``desc_threshold`` (the first descriptor of each landmark, as the plain association without bands).
    """
    n_particles = len(poses)
    n_obs = len(rejected) // max(n_particles, 1)
    if n_obs == 0 or len(cand_m) == 0 or not rejected.any():
        return None
    # 1. pairs (rejected reading, landmark of the same particle), descriptor-agreeing where there are descriptors
    order = np.argsort(cand_m, kind="stable")
    counts = np.bincount(cand_m, minlength=n_particles)
    starts = np.cumsum(counts) - counts
    key = np.flatnonzero(rejected)
    m_r, j_r = np.divmod(key, n_obs)
    reps = counts[m_r]
    first = np.repeat(starts[m_r], reps)
    within = np.arange(int(reps.sum())) - np.repeat(np.cumsum(reps) - reps, reps)
    rows = order[first + within]
    m, j = np.repeat(m_r, reps), np.repeat(j_r, reps)
    lids = cand_lids[rows]
    if obs_desc is not None and lid_desc is not None and obs_desc.shape[1] > 0 and len(rows):
        diff = obs_desc[j] - lid_desc[lids]
        agree = np.einsum("ij,ij->i", diff, diff) < desc_threshold ** 2
        rows, m, j, lids = rows[agree], m[agree], j[agree], lids[agree]
    if len(rows) == 0:
        return None
    # 2. the widened gate, a unique candidate per reading, a landmark claimed by one reading only
    state = np.take(flat_state, cand_g[rows], axis=0).T
    mean, cov = np.ascontiguousarray(state[:3]), np.ascontiguousarray(state[3:])
    mj = m * n_obs + j
    innovation = world[:, mj] - mean
    s_obs = cov + noise[:, mj]
    lever = mean[:2] - poses[m, :2].T
    s_plain = s_obs + pose_uncertainty(sym_components(motion_cov[m]), lever)
    drift = sym_matrices(tracker.landmark_pose_covariances(lids))
    robot = np.asarray(tracker.robot, float)
    s_wide = s_plain + pose_uncertainty(sym_components(psd_part(robot[None] - drift)), lever)
    adj, det_wide = sym_adjugate(s_wide)
    d2_wide = sym_quadratic(adj, innovation) / det_wide
    ok = np.flatnonzero(d2_wide < gate)
    ok = ok[np.bincount(mj[ok], minlength=n_particles * n_obs)[mj[ok]] == 1]              # one per reading
    landmark_key = rows[ok]                                                                  # (particle, id)
    ok = ok[np.bincount(landmark_key, minlength=len(cand_m))[landmark_key] == 1]          # one reading each
    ok = ok[np.bincount(m[ok], minlength=n_particles)[m[ok]] >= 2]                         # two landmarks
    if len(ok) == 0:
        return None
    # 3. joint compatibility per particle: one rigid correction explains the readings kept
    p_gate = chi2.cdf(gate, 3)
    kept = []
    for particle in np.unique(m[ok]):
        mine = ok[m[ok] == particle]
        mine = mine[np.argsort(d2_wide[mine], kind="stable")]
        chosen = _compatible(mine, innovation, s_obs, lever, drift, robot, motion_cov[particle], p_gate)
        kept.extend(chosen)
    if not kept:
        return None
    kept = np.sort(np.array(kept, np.int64))
    det_plain = sym_adjugate(s_plain[:, kept])[1]
    cost = d2_wide[kept] + np.log(np.maximum(det_wide[kept], 1e-300) / np.maximum(det_plain, 1e-300))
    return Rescued(rows[kept], j[kept], mean[:, kept], cov[:, kept], innovation[:, kept], s_obs[:, kept],
                   np.minimum(cost, gate))


def _compatible(candidates: np.ndarray, innovation, s_obs, lever, drift, robot, motion, p_gate: float) -> list[int]:
    """The largest jointly compatible subset (≥ 2) of one particle's candidate pairs (sorted by widened d²):
    all of them if they pass together, else greedily from the most compatible pair; [] if no pair passes."""
    def passes(idx) -> tuple[bool, float]:
        d2 = joint_d2(innovation[:, idx], s_obs[:, idx], lever[:, idx], drift[idx], robot, motion)
        return d2 < chi2.ppf(p_gate, 3 * len(idx)), d2

    if passes(candidates)[0]:
        return candidates.tolist()
    best, best_d2 = None, np.inf
    for a in range(len(candidates)):
        for b in range(a + 1, len(candidates)):
            ok, d2 = passes(candidates[[a, b]])
            if ok and d2 < best_d2:
                best, best_d2 = [candidates[a], candidates[b]], d2
    if best is None:
        return []
    for c in candidates:
        if c not in best and passes(np.array(best + [c]))[0]:
            best.append(c)
    return [int(c) for c in best]
