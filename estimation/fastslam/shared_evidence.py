"""Weights that select only where the readings can tell particles apart ("id" association).

Why. A landmark a particle made itself sits in that particle's own map frame: made from the particle's pose, it is
re-sighted from a pose that moved with it, so whatever heading or position error the particle's frame had when it
made the landmark, the re-sighting cannot see it. Two particles that made the same landmark separately (from
different poses) therefore differ in its re-sightings by noise only, and resampling on that noise is drift, not
selection: while only such landmarks are in view (the robot explores), the cloud loses the frame hypotheses it
will need at the next loop closure (MRCLAM robot 1, seed 2: the heading drifts 0.4 rad while new posts are made,
and the cloud that comes back to the old posts holds 0.07 rad of heading spread; docs/fastslam-history.md "Session 9").

The rule. Each (landmark, particle) carries a *creation token*: particles that made the landmark in one creation
share it (they had identical poses and maps when they made it, e.g. copies of one parent, or every particle in
the map's first frame), and resampling copies tokens with the particles. A reading of landmark L then moves
weight only *within* each group of particles that share L's token: each group's total weight is kept, and
within it the particles are reweighted by the reading's likelihood as usual. Particles that made L apart are not
compared by L at all. Landmarks made before the particles diverged (the first frame's, or a common parent's)
compare everyone, so the loop closure selects as before; frames with only the particles' own landmarks leave
the weights flat, the effective sample size stays high and the cloud is not resampled (the ESS rule is
unchanged).

Departure from the paper (Montemerlo et al., FastSLAM 2.0): the paper's weight is the full predictive
likelihood of every reading. Between particles that made a landmark apart, the reading cannot see the frame error
(the invariance above), but it does judge each particle's motion since it made the landmark, and that is dropped
too. Measured (docs/fastslam-history.md, "Session 10"): the rule keeps the frame hypotheses a slow heading drift needs
(MRCLAM robot 1 repaired on every seed) and loses the evidence a turn on the spot needs (robots 3 and 4 worse), so
it is an option, off by default.

Session 11: the weight relative to the landmark's creation, and why it is the paper's weight already. The
proposal after session 10 was to keep the motion evidence and drop only the frame's, by judging each particle on
its landmark expressed relative to its own pose when it made it. Write that likelihood. Particle m made landmark L
at pose c (its pose then, in its own map frame) from the reading z₀, so its estimate is μ = c ⊕ g(z₀) with
covariance Σ = J_c Σ₀ J_cᵀ (Σ₀ the reading's, J_c the rotation of c), later refined by readings taken from poses
that moved with the particle. Its pose now is x = c ⊕ Δ, Δ its own motion since c (odometry and its noise, FastSLAM
2.0's not yet sampled part with covariance P, propagated in the robot's frame). The relative-to-creation
likelihood of a reading z of L is

    p(z | Δ, ℓ) = N(z; h(Δ⁻¹ ⊕ ℓ), H_ℓ Σ_ℓ H_ℓᵀ + H_x P_Δ H_xᵀ + Q),   ℓ = c⁻¹ ⊕ μ,  Σ_ℓ = J_c⁻¹ Σ J_c⁻ᵀ,

with P_Δ the motion covariance in the creation frame. The filter's weight (Montemerlo et al., FastSLAM 2.0, eq. of
the importance weight; ``_gate``'s d² in the world frame) is N(z; h(x⁻¹ ⊕ μ), H_μ Σ H_μᵀ + H_x P H_xᵀ + Q). Every
term is the same: x⁻¹ ⊕ μ = (c ⊕ Δ)⁻¹ ⊕ (c ⊕ ℓ) = Δ⁻¹ ⊕ ℓ, and Σ, P are the creation frame's Σ_ℓ, P_Δ rotated by c
(P because the odometry's noise is drawn in the robot's frame), which the innovation covariance, read in the robot's
frame, undoes. So the paper's weight for a landmark a particle made itself never judged its frame: a rigid offset
of a particle's pose at creation, carried by the landmark it made then, leaves every later reading's weight equal
(tests/fastslam/test_relative_evidence.py: twins in an offset frame get equal weights to 1e-9 while the weights
spread by e^3 over their motions). What it does judge, and all it judges, is the motion since the creation; the
frame is judged only by landmarks made before the particles' frames diverged (by the first frame or a common
parent), as motion since *that* creation: the loop closure. The relative rule is ``weight_evidence="all"``; no
separate option is built for it. One exception in this code: a reading the gate rejected is judged again under the
drift tracker's covariance (``id_relative_drift``, id_gate.py), one covariance in the best particle's frame for all
particles, so for those readings only the weight is not exactly invariant to a particle's frame.

What session 10's rule dropped, then, was only motion evidence (the turn test: the heading a turn on the spot got
wrong stays wrong), and what it gained on MRCLAM robot 1 came from weights kept flat while only young posts were
in view, that is no resampling there, not from any frame evidence removed (seed 2, the first 140 s: 0 resamplings
against the plain weights' 31, the cloud's heading σ at 90-140 s 0.169 against 0.072 rad; over the whole run the
counts differ little, 718 against 777 of 4,159 frames; docs/fastslam-history.md "Session 11").
The plain cloud's loss of frame hypotheses is the selection's concentration of weight: the selection on each
particle's motion since creation is blind to its frame, but it picks a few particles and their frames come with
them (hitch-hike), whether resampling copies them or their weights alone dominate. Resampling less does not keep
the frames: with the plain weights and resample_threshold 0.25 / 0.1 (default 0.5), seed 2, robot 1 is at 0.66 /
1.49 m (1.02 at 0.5) and robot 3 at 0.68 / 0.83 m (0.11). Keeping the frame hypotheses without dropping evidence
needs each particle's frame since its last shared landmark carried apart from its motion (e.g. a Gaussian per
particle that a loop closure updates, so that selecting a motion does not select a frame); not built.
"""
from __future__ import annotations

import numpy as np


class CreationTokens:
    """Creation tokens (lids, M) for "id" association (landmark ids common to all particles); -1: none."""

    def __init__(self, n_particles: int) -> None:
        self.tokens = np.full((0, n_particles), -1, np.int64)
        self._next = 0

    def made(self, lids: np.ndarray, particles: np.ndarray, poses: np.ndarray) -> None:
        """Record landmarks ``lids`` (K,) just made by ``particles`` (K,) at ``poses`` (M, 3): one token per
        landmark and distinct pose (identical poses: one creation, e.g. the map's first frame)."""
        if len(lids) == 0:
            return
        top = int(lids.max()) + 1
        if top > len(self.tokens):
            grown = np.full((max(top, 2 * len(self.tokens)), self.tokens.shape[1]), -1, np.int64)
            grown[:len(self.tokens)] = self.tokens
            self.tokens = grown
        keys = np.column_stack([lids.astype(float), poses[particles]])
        _, group = np.unique(keys, axis=0, return_inverse=True)
        group = group.ravel()
        self.tokens[lids, particles] = self._next + group
        self._next += int(group.max()) + 1

    def resampled(self, parents: np.ndarray) -> None:
        """The particles were replaced by copies of ``parents`` (M,)."""
        self.tokens = self.tokens[:, parents]

    def log_likelihood(self, log_weights: np.ndarray, terms: np.ndarray, lids: np.ndarray,
                       holds: np.ndarray) -> np.ndarray:
        """The frame's log-likelihood (M,) with each reading's term moving weight only within creation groups.

        ``log_weights`` (M,): the weights before this frame; ``terms`` (M, N): each reading's log-likelihood
        term per particle; ``lids`` (N,): the landmark each reading names (-1: none yet); ``holds`` (M, N): the
        particle holds that landmark. Particles that do not hold it form one more group; a landmark with no
        token (a prior map's) is one group. Readings are taken in
        order, each against the weights the earlier ones left.
        """
        n_particles, n_obs = terms.shape
        log_w = np.asarray(log_weights, float) - np.max(log_weights)
        total = np.zeros(n_particles)
        for j in range(n_obs):
            lid = int(lids[j])
            if lid < 0:   # a landmark no particle holds yet: the same term for all
                continue
            # a landmark the filter did not make (a prior map's, -1) is one creation shared by every holder
            made_as = self.tokens[lid] if lid < len(self.tokens) else np.full(n_particles, -1, np.int64)
            group = np.where(holds[:, j], made_as, -2)
            _, group = np.unique(group, return_inverse=True)
            group = group.ravel()
            # minus the log of each group's weighted mean likelihood: the group's total weight is kept
            term = terms[:, j] - (_group_logsumexp(log_w + terms[:, j], group)
                                  - _group_logsumexp(log_w, group))[group]
            total += term
            log_w = log_w + term
            log_w -= np.max(log_w)
        return total


def _group_logsumexp(values: np.ndarray, group: np.ndarray) -> np.ndarray:
    """log Σ exp(values) per group (G,), for group indices 0..G-1 (M,), without underflow."""
    n = int(group.max()) + 1
    top = np.full(n, -np.inf)
    np.maximum.at(top, group, values)
    return top + np.log(np.bincount(group, np.exp(values - top[group]), minlength=n))
