"""The detection term of a particle's weight: what its map says the sensor should have reported.

The filter's weight per frame is the readings' robust Gaussian terms, −½ min(d², gate) each
(``filter.py``, "Importance weights"). It says nothing about the landmarks a particle's map holds in view that the
sensor did *not* report, so a particle that keeps two landmarks for one post, or one that took a new post's first
reading into a neighbour's landmark, pays nothing for what its map predicts. The full measurement likelihood of
a frame has that term (negative information: a landmark in view that the sensor does not report is evidence
too; the detection model whose log-likelihood ratios ``existence.py`` adds to each landmark's existence):

- a landmark detected (a reading matched to it) at range r: P_D(r);
- a landmark predicted well inside the view (``miss_fov_margin`` of the field of view and range) and not
  detected: 1 − P_D(r).

With ``FastSLAMConfig.detection_in_weight`` (unknown association only; off by default and in
``range_bearing_config``: measured on MRCLAM in docs/fastslam-history.md, "Session 9") each particle's log-weight gains

    w · [Σ_detected log P_D(r) + miss_weight · Σ_missed log(1 − P_D(r))],   w = (1 − ρ)/(1 + ρ),

P_D per range band as configured (``detection_probabilities``, fitted by ``p3at slam noise``), or the
constants' own P_D = 1 − exp(existence_miss); ρ the lag-1 correlation of a landmark's detected / missed frames
(``detection_correlation``): N correlated frames are the evidence of N w independent ones, as for the existence
steps. ``miss_weight`` is the share of a capped frame's readings that were kept (``max_observations``).

Where this departs from the textbook likelihood: the reading that makes a new landmark keeps the filter's p₀ =
exp(−gate/2) (no P_D: the robust weight's constant already stands for "a reading no landmark explains"), and the
association itself is unchanged: "nearest" still picks by d², "sampled" still draws by exp(−d²/2) against p₀; the
term only reweights the particles for the maps they hold after the frame's association.
"""
from __future__ import annotations

import numpy as np

from .config import FastSLAMConfig
from .existence import detection_probability_or_constant, evidence_per_frame

_P_D_CLIP = 1e-6   # keeps log P_D and log(1 − P_D) finite for configured rates at the ends of (0, 1)


def detection_log_likelihood(config: FastSLAMConfig, n_particles: int, detected_particle: np.ndarray,
                             detected_range: np.ndarray, missed_particle: np.ndarray, missed_range: np.ndarray,
                             miss_weight: float = 1.0) -> np.ndarray:
    """Each particle's log-weight increment (M,) from its landmarks detected and missed in one frame.

    detected_particle, detected_range (D,): the particle of each matched (particle, reading) pair and the
    reading's range from the sensor (m); missed_particle, missed_range (K,): the particle of each landmark
    predicted well in view and not detected, and its predicted range (m).
    """
    p_hit = np.clip(detection_probability_or_constant(config, detected_range), _P_D_CLIP, 1.0 - _P_D_CLIP)
    p_miss = np.clip(detection_probability_or_constant(config, missed_range), _P_D_CLIP, 1.0 - _P_D_CLIP)
    hits = np.bincount(np.asarray(detected_particle, np.int64), np.log(p_hit), minlength=n_particles)
    misses = np.bincount(np.asarray(missed_particle, np.int64), np.log1p(-p_miss), minlength=n_particles)
    return evidence_per_frame(config) * (hits + miss_weight * misses)
