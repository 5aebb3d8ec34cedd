"""Known-ID association: readings judged with the pose's drift relative to the landmark seen, not only its last step.

Why (docs/fastslam-history.md, "Session 6"): in "id" association the barcode names the landmark and the Mahalanobis
gate only has to reject outliers. Its S holds the landmark's EKF covariance (conditional on the particle's
trajectory), the sensor noise and the pose's uncertainty *since the last frame*: the particle cloud's spread
is supposed to carry the rest, but after resampling nearly every frame it keeps only the pose's uncertainty
relative to the landmarks seen lately (Bailey, Nieto & Nebot 2006). When an old landmark comes back into view
after a stretch mapped only with newer landmarks (MRCLAM robot 3: a 2.2 rad turn on the spot ended 0.24 rad
off), every particle is off by the same drift and the gate rejects the correct reading in every particle.

The drift tracker (``drift.py``) knows how uncertain the pose is relative to each landmark: the landmarks and
the robot form a chain of relative estimates, D_l the robot's map-frame covariance when it created l, D_r the
robot's now, so D_r − D_l is the drift accumulated since l was made (and D_i − D_a that between two landmarks).
``FastSLAMConfig.id_relative_drift`` chooses how it is used (FastSLAM 2.0, "id" association only):

- ``"rescue"``: a reading rejected under S is accepted if it passes the same χ² gate under
  S + H (D_r − D_l)⁺ Hᵀ (a spike outlier fails both; a recent landmark, D_l ≈ D_r, gains nothing). In a particle
  that accepted such a reading, the oldest of them (smallest tr D) anchors the frame: the pose's prior becomes
  P + (D_r − D_a)⁺ and every matched landmark i takes Σ_i + H (D_i − D_a)⁺ Hᵀ in the proposal and its EKF update,
  so the landmarks made since the anchor (which drifted *with* the pose) cannot hold the pose where the drift
  put it, and move onto the anchor's frame instead. (Session 5 widened the prior alone, and the newest
  landmarks pulled the pose: robot 3 0.49 → 1.69 m.) With ``id_drift_inherit`` (off by default), those the most
  probable particle re-measured so take the drift of the pose they were re-measured from, D_a + P_local
  (:meth:`RelativeGate.inherit`); without it their D_i stays the drift at creation and they are widened and
  re-placed again at every later rescue (the map's shape: docs/fastslam-history.md "Session 7").
- ``"consistent"``: as ``"rescue"``, but a particle's rescue needs two or more *different* landmarks rejected
  by the plain gate and accepted by the widened one in the same frame. Why: one range-bearing reading fixes
  only two of the pose's three degrees of freedom, so a correction from one landmark under a wide prior slides
  along the unobserved one (the cloud spreads: a variant that put every frame relative to its oldest landmark
  did exactly that, robot 3 1.10 → 1.70 m, docs); and a misread barcode or a reflection fails for one landmark,
  while a drifted pose fails for every old landmark in view, consistently. Two independent gross outliers in
  one frame have probability ~P_FA², one has P_FA.

Weights: a reading judged under a widened S̃ costs ½ [d̃² + log(det S̃ / det S)] (the Gaussian's log-likelihood
with its normaliser, which only matters where S differs between particles, as here), at most ½ gate.
The drift terms are taken as independent where they are one chain: the approximation errs towards wider.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .drift import DriftTracker
from .linalg import pose_uncertainty, sym_adjugate, sym_components, sym_matrices, sym_quadratic


def psd_part(d: np.ndarray) -> np.ndarray:
    """The positive semi-definite part of symmetric matrices d (L, 3, 3) (negative eigenvalues set to 0)."""
    w, v = np.linalg.eigh(0.5 * (d + np.swapaxes(d, 1, 2)))
    return np.einsum("lij,lj,lkj->lik", v, np.clip(w, 0.0, None), v)


@dataclass
class RelativeGate:
    """The outcome of :func:`judge` for one frame's (particle, observation) pairs (arrays over pairs P).

    d2: the squared distance the weight uses (where rescued: d̃² plus the log-determinant ratio, at most the
    gate); gated: accepted; widened: judged under the drift-widened S (the plain S rejected it); rescued:
    accepted only thanks to the widening (and, "consistent", with another landmark of the frame);
    drift6 (6, P): D_l per pair, components; robot (3, 3): D_r.
    """

    mode: str
    d2: np.ndarray
    gated: np.ndarray
    widened: np.ndarray
    rescued: np.ndarray
    drift6: np.ndarray
    robot: np.ndarray
    anchored: np.ndarray | None = None        # after :meth:`anchor`: particles (A,) with an anchor, ascending
    anchor_drift: np.ndarray | None = None    # and their anchors' D_a (A, 3, 3)

    def anchor(self, win: np.ndarray, m: np.ndarray, cov: np.ndarray, lever: np.ndarray, motion_cov: np.ndarray):
        """The frame relative to each particle's anchor (see the module docstring), for the winning pairs ``win``
        (W,) of particles ``m`` (W,): their landmark covariances ``cov`` (6, W) with H (D_i − D_a)⁺ Hᵀ added
        (``lever`` (2, W): μ − t at the predicted pose), and the particles' motion covariances ``motion_cov``
        (M, 3, 3) with (D_r − D_a)⁺ added where anchored. Returns (cov, motion_cov), copies."""
        candidates = self.widened[win] & self.gated[win]
        if not candidates.any():
            return cov, motion_cov
        n = len(motion_cov)
        size = self.drift6[0, win] + self.drift6[3, win] + self.drift6[5, win]       # tr D_i: the chain's "age"
        oldest = np.full(n, np.inf)
        np.minimum.at(oldest, m[candidates], size[candidates])
        anchored = np.isfinite(oldest)
        is_anchor = candidates & (size == oldest[m])
        anchor_of = np.full(n, -1, np.int64)
        anchor_of[m[is_anchor][::-1]] = np.flatnonzero(is_anchor)[::-1]             # the first on ties
        d_anchor = sym_matrices(self.drift6[:, win][:, anchor_of[anchored]])          # (A, 3, 3)
        self.anchored, self.anchor_drift = np.flatnonzero(anchored), d_anchor
        motion_cov = motion_cov.copy()
        motion_cov[anchored] += psd_part(self.robot[None] - d_anchor)
        inside = np.flatnonzero(anchored[m])
        d_pair = sym_matrices(self.drift6[:, win][:, inside])
        d_a = sym_matrices(self.drift6[:, win][:, anchor_of[m[inside]]])
        cov = cov.copy()
        cov[:, inside] += pose_uncertainty(sym_components(psd_part(d_pair - d_a)), lever[:, inside])
        return cov, motion_cov


    def inherit(self, tracker: DriftTracker, particle: int, lids: np.ndarray, local: np.ndarray) -> np.ndarray:
        """The landmarks ``lids`` (L,) that ``particle`` (the most probable) matched, when its frame was anchored on
        an older landmark a: D_i ← D_a + P_local where that is smaller than D_i (``local`` (3, 3): P_local, the
        frame's pose covariance relative to the map, as ``DriftTracker.update`` takes it). Returns the ids lowered.

        Why D_a + P_local (and not D_a): in the anchored frame the pose is x = x_a ⊕ δ, x_a the pose that made a
        (start-frame error e_a, covariance D_a) and δ the pose relative to it, fixed by this frame's readings
        (proposal covariance P_local; with a's reading and the loosened younger ones it is about as large as D_a
        itself on MRCLAM: mean tr_xy 0.015 vs 0.018 m², heading 0.0022 vs 0.0077 rad², robot 5 seed 0). The
        widened update places i from that pose: i's start-frame error is H (e_a + e_δ) + its EKF error relative
        to the pose (Σ_i, kept by the EKF), so its pose term is D_a + P_local, exactly what a landmark *created*
        in this frame gets (D_r = D_a + P_local). D_a alone drops e_δ, and the next landmarks pinned to i inherit
        the loss: session 6's D_i ← D_a lowered the landmarks within the NEES bound on 8 of 15 MRCLAM runs
        (robot 5 seed 0: 64 → 13 %). Only lowered, never raised: the widened prior Σ_i + H (D_i − D_a) Hᵀ lets the
        reading place i wherever D_i − D_a is large, and where it is small little changes. C_i (the export's
        term) is left as made: it is the wider of the two, so the export errs wide, not narrow.
        """
        if self.anchored is None or len(lids) == 0:
            return np.zeros(0, np.int64)
        row = int(np.searchsorted(self.anchored, particle))
        if row >= len(self.anchored) or self.anchored[row] != particle:
            return np.zeros(0, np.int64)
        return tracker.remeasured(lids, self.anchor_drift[row] + local)


def judge(mode: str, tracker: DriftTracker, particles: np.ndarray, lids: np.ndarray, d2: np.ndarray,
          s_gate: np.ndarray, innovation: np.ndarray, lever: np.ndarray, gate: float) -> RelativeGate:
    """Gate pairs (P) with the pose's drift relative to their landmarks (see the module docstring).
    ``particles``, ``lids`` (P,): each pair's particle and landmark id; ``d2`` (P,): d² under ``s_gate``
    (6, P); ``innovation`` (3, P); ``lever`` (2, P): μ − t at the predicted pose."""
    drift6 = tracker.landmark_pose_covariances(lids)                                  # (6, P) D_l
    robot = np.asarray(tracker.robot, float)
    plain = d2 < gate
    look = np.flatnonzero(~plain)
    out, gated, widened = d2.copy(), plain.copy(), np.zeros(len(d2), bool)
    if len(look):
        uniq, inverse = np.unique(lids[look], return_inverse=True)
        relative = robot[None] - sym_matrices(tracker.landmark_pose_covariances(uniq))
        wide = s_gate[:, look] + pose_uncertainty(sym_components(psd_part(relative))[:, inverse], lever[:, look])
        adj, det_wide = sym_adjugate(wide)
        d2_wide = sym_quadratic(adj, innovation[:, look]) / det_wide
        det_plain = sym_adjugate(s_gate[:, look])[1]
        cost = d2_wide + np.log(np.maximum(det_wide, 1e-300) / np.maximum(det_plain, 1e-300))
        ok = d2_wide < gate
        if mode == "consistent":   # two different landmarks or none (one observation per landmark and frame)
            ok &= np.bincount(particles[look][ok], minlength=int(particles.max()) + 1)[particles[look]] >= 2
        gated[look] = ok
        widened[look] = True
        out[look] = np.where(ok, np.minimum(cost, gate), np.maximum(d2_wide, gate))
    return RelativeGate(mode, out, gated, widened, gated & ~plain, drift6, robot)
