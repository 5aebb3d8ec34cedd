"""Duplicates made after a drift: a merge gate widened by the pose's drift between the two landmarks' creations.

Why (docs/fastslam-history.md, "Session 10: unknown association" and "Session 11 (K)"): with the camera's range
calibrated the association gate is narrow, so an old landmark re-sighted after the pose drifted falls outside it in
every particle and is made again. The merge's plain test, (μ_a − μ_b)ᵀ(Σ_a + Σ_b)⁻¹(μ_a − μ_b) < ``merge_gate``, cannot
join the two: each Σ is the landmark's EKF covariance *given the particle's trajectory*, and the two estimates
differ by how far that trajectory drifted between their creations, which no Σ holds. Co-visibility's merge
(``merge_covisibility``) widens by the absolute drifts, Σ_a + Σ_b + C_a + C_b, but only after the old landmark was
missed in view again and again (``merge_log_odds``), and the absolute drifts also count the error the two share.

**The covariance to add.** The drift tracker (``drift.py``) keeps, per landmark l, the robot's start-frame pose
covariance D_l when it made l and where it stood, o_l. Let a be the older landmark, b the newer, both estimates of
one point p, and e_a, e_b the (x, y, θ) errors of the pose at their creations. A pose error e puts H(w) e on the
landmark it makes (w = p − o, the lever from the robot to the point; H(w) = [[1, 0, −w_y], [0, 1, w_x], [0, 0, 0]],
the map frame's Jacobian of t + R z by the pose). Along one chain of dead reckoning e_b = Φ e_a + ν, with
Φ = [[1, 0, −Δ_y], [0, 1, Δ_x], [0, 0, 1]] (Δ = o_b − o_a: a heading error at a carries the robot sideways by the
way it drove), and ν, the motion noise between, independent of e_a; the tracker's predict step builds exactly
D_b = Φ D_a Φᵀ + cov ν. Then the difference of the two estimates' drift errors is

    H(w_b) e_b − H(w_a) e_a = H(w_b) ν + (H(w_b) Φ − H(w_a)) e_a = H(w_b) ν,

since H(w_b) Φ = H(w_b + Δ) = H(w_a) for one point p (w_a = w_b + Δ). The error the two share (e_a, carried) cancels,
and what separates them is H(w_b) cov ν H(w_b)ᵀ = H(w_b) (D_b − Φ D_a Φᵀ) H(w_b)ᵀ: the drift *since* the older
landmark was made (the brief's D_r − D_l, taken at b's creation and with the older pose carried to where b was
made; without the carry the difference would count D_a's heading variance times |Δ|² as if it separated them,
metres after a long drive). So the merge's test becomes

    (μ_a − μ_b)ᵀ (Σ_a + Σ_b + H(w_b) (D_b − Φ D_a Φᵀ)⁺ H(w_b)ᵀ)⁻¹ (μ_a − μ_b) < merge_gate,

with ( )⁺ the positive semi-definite part: the tracker resets D_r to the mean of the matched landmarks' D_l when the
robot re-observes old ones, so D_b can be *below* Φ D_a Φᵀ (the robot re-anchored on landmarks older than a); the
difference then has no drift to add and the test is the plain one. (What it then misses: two branches from one
older anchor c separate a and b by (D_a − c's) + (D_b − c's), which the tracker, keeping no cross-covariances,
cannot tell from one chain. The test errs towards the narrower, i.e. towards a duplicate kept, not a wrong merge.)

**Two things stay two.** Geometry alone cannot tell one point from two neighbours within the widened gate
(MRCLAM: posts 0.7-1.9 m apart). Two landmarks ever detected in the same frame of the most probable particle are two
things (``FastSLAM._codetected``, kept with ``merge_covisibility``, which this option therefore needs), and are
never merged. A pair merged by this test keeps the older landmark's estimate (its frame is the one the map was
made in) and takes the newer one's sightings, as co-visibility's merges do.
"""
from __future__ import annotations

import numpy as np

from .drift import DriftTracker
from .id_gate import psd_part
from .linalg import pose_uncertainty, sym_components, sym_matrices


def carried(pose_covariance: np.ndarray, moved: np.ndarray) -> np.ndarray:
    """Φ D Φᵀ (L, 3, 3): pose covariances D (L, 3, 3) carried along a drive of ``moved`` (L, 2) metres in the start
    frame, Φ = [[1, 0, −Δ_y], [0, 1, Δ_x], [0, 0, 1]] (a heading error moves the robot sideways as it drives)."""
    phi = np.tile(np.eye(3), (len(moved), 1, 1))
    phi[:, 0, 2], phi[:, 1, 2] = -moved[:, 1], moved[:, 0]
    return phi @ pose_covariance @ np.swapaxes(phi, 1, 2)


def drift_since(tracker: DriftTracker, older: np.ndarray, newer: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(D_b − Φ D_a Φᵀ)⁺ (L, 3, 3), the pose's drift between the creations of landmarks ``older`` and ``newer`` (L,)
    with the older pose carried to where the newer was made (module docstring), and the newer's origins o_b (L, 2)."""
    o_a, o_b = tracker.landmark_origins(older), tracker.landmark_origins(newer)
    d_a = sym_matrices(tracker.landmark_pose_covariances(older))
    d_b = sym_matrices(tracker.landmark_pose_covariances(newer))
    return psd_part(d_b - carried(d_a, o_b - o_a)), o_b


def relative_drift(tracker: DriftTracker, older: np.ndarray, newer: np.ndarray, point: np.ndarray) -> np.ndarray:
    """H(w_b) (D_b − Φ D_a Φᵀ)⁺ H(w_b)ᵀ (6, L), the drift that separates landmark ``newer`` (L,) from landmark
    ``older`` (L,) made at one point ``point`` (L, 3 or 2) (see the module docstring): w_b = point − o_b."""
    older, newer = np.asarray(older, np.int64), np.asarray(newer, np.int64)
    key, first, at = np.unique(np.stack([older, newer]), axis=1, return_index=True, return_inverse=True)
    since, o_b = drift_since(tracker, *key)
    since = sym_components(since)                                                   # (6, pairs)
    at = np.ravel(at)
    lever = (np.asarray(point, float)[:, :2] - o_b[at]).T
    return pose_uncertainty(since[:, at], lever)


def mutually_unique(particles: np.ndarray, older: np.ndarray, newer: np.ndarray) -> np.ndarray:
    """(P,) bool over pairs that passed the widened test, rows (particle, older id, newer id): True where neither
    landmark is in another passing pair of that particle. A widened gate that holds two landmarks for one says "one
    of these", which is no association (as in ``unknown_rescue``): neither is merged."""
    particles = np.asarray(particles, np.int64) << 32
    keys = np.concatenate([particles | np.asarray(older, np.int64), particles | np.asarray(newer, np.int64)])
    _, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
    once = counts[np.ravel(inverse)] == 1
    return once[:len(particles)] & once[len(particles):]


def candidate_pairs(tracker: DriftTracker, ids: np.ndarray, rows_of: np.ndarray, states: np.ndarray,
                    touched: np.ndarray, codetected: set[int], gate: float,
                    shift: int) -> tuple[np.ndarray, np.ndarray]:
    """Id pairs (a older < b newer) that may pass the drift-widened merge test in some particle: one of them in
    ``touched``, never detected in one frame (key ``a << shift | b`` not in ``codetected``), and not excluded by an
    exact bound. ``ids`` (U,) the landmark ids near some particle's view, ``rows_of`` (R,) the index into ``ids``
    of each candidate row and ``states`` (R, 9) its landmark's state (μ, Σ components) in that row's particle.

    The bound: d² ≥ |μ_a − μ_b|² / tr(Σ_a + Σ_b + W) in any particle, |μ_a − μ_b| ≥ |ref_a − ref_b| − spread_a −
    spread_b (ref: one row's mean, spread: the farthest row from it), tr Σ at most its largest over the rows, and
    tr W ≤ (√(D_xx + D_yy) + |w| √D_θθ)² for W = H(w) D Hᵀ(w), |w| at most |ref_b − o_b| + spread_b (the position
    error is e_t + e_θ w⊥: Cauchy-Schwarz on the two terms)."""
    none = np.zeros(0, np.int64), np.zeros(0, np.int64)
    ids = np.asarray(ids, np.int64)
    t = np.flatnonzero(np.isin(ids, touched))
    if len(t) == 0 or len(ids) < 2:
        return none
    _, first = np.unique(rows_of, return_index=True)     # every id has a row
    ref = states[first, :3]
    spread2, trace = np.zeros(len(ids)), np.zeros(len(ids))
    np.maximum.at(spread2, rows_of, np.sum((states[:, :3] - ref[rows_of]) ** 2, axis=1))
    np.maximum.at(trace, rows_of, states[:, 3] + states[:, 6] + states[:, 8])
    spread = np.sqrt(spread2)
    ti, ui = np.nonzero(ids[t][:, None] != ids[None, :])
    a, b = np.minimum(ids[t[ti]], ids[ui]), np.maximum(ids[t[ti]], ids[ui])
    ia = np.where(ids[t[ti]] == a, t[ti], ui)              # index into ids of the older, the newer
    ib = np.where(ids[t[ti]] == a, ui, t[ti])
    key = (a << shift) | b
    key, at = np.unique(key, return_index=True)
    a, b, ia, ib = a[at], b[at], ia[at], ib[at]
    if codetected:
        keep = np.array([k not in codetected for k in key.tolist()], bool)
        a, b, ia, ib = a[keep], b[keep], ia[keep], ib[keep]
    if len(a) == 0:
        return none
    since, o_b = drift_since(tracker, a, b)
    lever = np.linalg.norm(ref[ib, :2] - o_b, axis=1) + spread[ib]
    widen = (np.sqrt(np.maximum(since[:, 0, 0] + since[:, 1, 1], 0.0))
             + lever * np.sqrt(np.maximum(since[:, 2, 2], 0.0))) ** 2
    gap = np.linalg.norm(ref[ia] - ref[ib], axis=1) - spread[ia] - spread[ib]
    close = np.maximum(gap, 0.0) ** 2 < gate * (trace[ia] + trace[ib] + widen)
    return a[close], b[close]
