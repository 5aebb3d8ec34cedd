"""Unknown association: which gated landmark a reading takes, beyond "the nearest" (``unknown_association_rule``).

Measured on MRCLAM (docs/fastslam-history.md, "Session 8: unknown association"): 7–27 % of the most probable particle's
matches go to a landmark of another post under the plain gate, and in most of those frames no particle made the
right association: with maximum likelihood every particle near one pose makes the same choice. Two rules, each an
option (the default stays "nearest", maximum likelihood):

- ``"sampled"`` (:func:`sample_associations`): per-particle association (Montemerlo et al. 2003, FastSLAM 2.0,
  sec. 4; Nieto, Guivant, Nebot & Thrun 2003, "Real time data association for FastSLAM"). Each particle draws its
  association from the posterior over the landmarks inside the gate, weight exp(−d²/2), and a new landmark, weight
  exp(−gate/2): the filter's own p₀, the likelihood its weights already give a reading no landmark explains (so
  with d² at the gate a match and a new landmark are equally likely). Some particles then carry the rarer
  hypotheses and later readings decide between them.
- ``"unambiguous"`` (:func:`unambiguous_associations`): a reading whose nearest gated landmark is not at least as
  probable as the gate itself demands (its posterior among the gated landmarks, 1 − α with α the gate's own
  tail, χ²₃ 99 %: 0.99) is left unused in that particle: neither matched nor a new landmark. A confidently wrong
  map is worse than a reading not used.

In both, a particle's weight for a reading is its largest term, exp(−½ min(d², gate)) (the filter's weight under
the nearest association), whatever was drawn or left: a draw in proportion to the terms already counts them, so
weighting by the drawn term would count its likelihood twice; and the sum of the terms (the exact marginal) would
reward a particle for holding two landmarks at one place, each adding a term, since the filter does not charge the
second one's missing detection in the weight.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

GATE_PROBABILITY = 0.99   # the χ²₃ 99 % gate's (mahalanobis_gate = 11.345): the confidence "unambiguous" asks for


@dataclass(frozen=True)
class AssociationChoice:
    """One frame's choice. gated (P,) bool: the pairs left to the filter's mutual exclusion, at most one per
    (particle, reading), none for a reading that takes a new landmark or is left unused; log_lik (M,): each
    particle's log-weight increment, −½ Σ over readings of min(d², gate); new (M·N,) bool: (particle, reading) that
    drew a new landmark although a landmark was inside the gate; unused (M·N,) bool: left unused as ambiguous."""

    gated: np.ndarray
    log_lik: np.ndarray
    new: np.ndarray
    unused: np.ndarray


@dataclass(frozen=True)
class CandidateGate:
    """The plain gate over every (particle, reading, landmark near the particle's view) triple of a frame, all
    arrays over the P triples (:meth:`FastSLAM.candidate_gate`): m, j, lid (P,) particle, reading, landmark id;
    innovation (3, P) ν = R z + t − μ and covariance (6, P) S = Σ + R Q Rᵀ (+ H_x P H_xᵀ under FastSLAM 2.0;
    symmetric components, world frame, at the predicted pose), the gate's own; lever (2, P) the landmark's
    planar offset from the particle, H_x's lever; d2 (P,) νᵀS⁻¹ν; log_det (P,) log |S|."""

    m: np.ndarray
    j: np.ndarray
    lid: np.ndarray
    innovation: np.ndarray
    covariance: np.ndarray
    lever: np.ndarray
    d2: np.ndarray
    log_det: np.ndarray


def _largest_terms(keys: np.ndarray, d2: np.ndarray, n_particles: int, n_obs: int, gate: float):
    """(M·N,) the smallest d² per key (gate where none), and the log-weight increments (M,)."""
    best = np.full(n_particles * n_obs, float(gate))
    np.minimum.at(best, keys, d2)
    return best, -0.5 * best.reshape(n_particles, n_obs).sum(axis=1) if n_obs else np.zeros(n_particles)


def sample_associations(key: np.ndarray, d2: np.ndarray, gated: np.ndarray, n_particles: int, n_obs: int,
                        gate: float, rng: np.random.Generator) -> AssociationChoice:
    """Draw every (particle, reading)'s association among its gated pairs and a new landmark.

    key (P,): m·N + j of each (particle, landmark, reading) pair; d2 (P,): its squared Mahalanobis distance;
    gated (P,) bool: d² under the gate. One uniform number is drawn per (particle, reading), in key order, so a
    run is reproducible from the generator alone.
    """
    n_keys = n_particles * n_obs
    idx = np.flatnonzero(gated)
    u = rng.random(n_keys)
    keys = key[idx]
    term = np.exp(-0.5 * (d2[idx] - gate))                       # relative to a new landmark's exp(−gate/2): ≥ 1
    total = 1.0 + np.bincount(keys, term, minlength=n_keys)     # a new landmark + every gated landmark
    order = np.argsort(keys, kind="stable")
    sorted_keys, sorted_term = keys[order], term[order]
    upto = np.cumsum(sorted_term)                                # running sum, restarted per key below
    starts = np.flatnonzero(np.r_[True, sorted_keys[1:] != sorted_keys[:-1]]) if len(keys) else np.zeros(0, int)
    before_key = np.zeros(n_keys)
    before_key[sorted_keys[starts]] = upto[starts] - sorted_term[starts]
    high = upto - before_key[sorted_keys]                        # the pair's upper edge within its key
    draw = (u * total)[sorted_keys]
    chosen = (draw >= high - sorted_term) & (draw < high)
    kept = np.zeros(len(gated), bool)
    kept[idx[order[chosen]]] = True
    had, took = np.zeros(n_keys, bool), np.zeros(n_keys, bool)
    had[keys] = True
    took[keys[order[chosen]]] = True
    _, log_lik = _largest_terms(keys, d2[idx], n_particles, n_obs, gate)
    return AssociationChoice(kept, log_lik, had & ~took, np.zeros(n_keys, bool))


def unambiguous_associations(key: np.ndarray, d2: np.ndarray, gated: np.ndarray, n_particles: int, n_obs: int,
                             gate: float) -> AssociationChoice:
    """Keep each (particle, reading)'s nearest gated landmark only where its posterior among the gated landmarks,
    exp(−d²_min/2) / Σ exp(−d²_k/2), is at least ``GATE_PROBABILITY``; elsewhere the reading is left unused in that
    particle. Arguments as :func:`sample_associations`."""
    n_keys = n_particles * n_obs
    idx = np.flatnonzero(gated)
    keys = key[idx]
    best, log_lik = _largest_terms(keys, d2[idx], n_particles, n_obs, gate)
    # Σ_k exp(−(d²_k − d²_min)/2) ≥ 1; the nearest's posterior is its inverse
    spread = np.bincount(keys, np.exp(-0.5 * (d2[idx] - best[keys])), minlength=n_keys)
    had = np.zeros(n_keys, bool)
    had[keys] = True
    unused = had & (spread * GATE_PROBABILITY > 1.0)
    kept = np.zeros(len(gated), bool)
    kept[idx] = ~unused[keys]
    return AssociationChoice(kept, log_lik, np.zeros(n_keys, bool), unused)
