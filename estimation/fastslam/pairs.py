"""The (particle, observation, landmark) triples one update works on, and step 3's mutual exclusion over them.

:class:`Pairs` holds the triples as arrays of one length (``filter.py`` builds them from the candidate blocks, or by
identity); :func:`exclusive_matches` picks, per (particle, observation), the nearest gated landmark and, per landmark,
the nearest of the observations that claimed it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .arrays import first_minimum


@dataclass
class Pairs:
    """(particle, observation, candidate) triples, all arrays of one length P."""

    m: np.ndarray     # particle index
    j: np.ndarray     # observation index
    k: np.ndarray     # table position of the landmark's block in the particle's block table
    g: np.ndarray     # flat slot of the landmark (block * block_size + slot)
    c: np.ndarray     # index in the frame's candidate list (unique per particle and landmark)

    def take(self, index) -> Pairs:
        return Pairs(self.m[index], self.j[index], self.k[index], self.g[index], self.c[index])


def no_pairs() -> Pairs:
    return Pairs(*(np.zeros(0, np.int64) for _ in range(5)))


def exclusive_matches(pairs: Pairs, d2: np.ndarray, gated: np.ndarray, n_particles: int, n_obs: int,
                       n_candidates: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the winning pairs, ascending (each observation takes its nearest gated landmark; a landmark
    claimed by several observations of a particle keeps the nearest; exact ties go to the first pair), and an
    (M·N,) bool, indexed m·N + j, telling which (particle, observation) had any gated candidate.

    No sorting: per-key minima by ``np.minimum.at`` over dense keys m·N + j and the candidate index ``c``.
    """
    idx = np.flatnonzero(gated)
    key = pairs.m[idx] * n_obs + pairs.j[idx]
    had_candidate = np.zeros(n_particles * n_obs, bool)
    had_candidate[key] = True
    if len(idx) == 0:
        return idx, had_candidate
    choice = first_minimum(key, d2[idx], n_particles * n_obs, np.arange(len(idx)))    # one per (m, j)
    claimed = pairs.c[idx[choice]]
    keep = first_minimum(claimed, d2[idx[choice]], n_candidates, key[choice])         # one per landmark
    won = np.zeros(len(d2), bool)   # ascending through a mask: distinct positions, no sort
    won[idx[choice[keep]]] = True
    return np.flatnonzero(won), had_candidate
