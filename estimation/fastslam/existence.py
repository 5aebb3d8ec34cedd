"""Landmark existence evidence in log-odds: what one detection and one miss are worth.

Two ways to set it (``FastSLAMConfig``):

- constants ``existence_hit`` / ``existence_miss`` (default +1 / −0.5), whatever the range;
- the sensor's own rates, when ``detection_probabilities`` is given: P_D per range band (band edges
  ``detection_range_edges``, metres from the sensor) and the false-alarm probability ``false_alarm_probability``
  P_FA. Then, the log-likelihood ratios of the sensor model (Thrun, Burgard & Fox, ch. 9 and 10),
  a detection at range r adds log(P_D(r) / P_FA) and a frame in which the landmark was well in view and not
  reported adds log(1 − P_D(r)); a new landmark starts at ``existence_initial`` (the prior) plus the worth of
  the detection that made it.

Why the rates: the constants break even at P_D = 1/3 (hit · P_D + miss · (1 − P_D) = 0), so a real landmark the
sensor reports less often than that (MRCLAM's camera: P_D = 0.12–0.34 beyond 5 m) loses existence on average
and is removed, then re-made at the drifted pose. With the rates, the expected change per frame of a real
landmark is P_D log(P_D/P_FA) + (1 − P_D) log(1 − P_D), which is > 0 whenever P_D > P_FA: a landmark the
sensor reports more often than it hallucinates is kept, however seldom.

Detections are not independent from frame to frame: a landmark hidden behind another robot, or whose barcode is
unreadable from where the robot stands, is missed for many frames in a row (MRCLAM: P(miss | missed in the
previous frame) = 0.78–0.93 against P(miss) = 0.47–0.72; lag-1 correlation ρ = 0.54–0.73). N such frames carry
the evidence of N (1 − ρ)/(1 + ρ) independent ones (the AR(1) argument the sensor variances' inflation uses), so
with ``detection_correlation`` = ρ every log-odds step is multiplied by (1 − ρ)/(1 + ρ). Without it, a run of
misses while a robot stands in front of a landmark removed landmarks seen dozens of times.

The constants +1 / −0.5 are the rates P_D ≈ 0.39, P_FA ≈ 0.145 (log(1 − 0.39) = −0.5, log(0.39/0.145) = 1):
the defaults for the simulated stereo camera, which has no measured rates.

Co-visibility of two landmarks (the duplicate test, ``exclusive_log_odds``): if two landmarks a, b are one
point, the sensor reports it once per frame, so when one of them is detected the other, although well in view,
is not. If they are two points, each detected with probability P_D, then P(only one | at least one) =
2 P_D (1 − P_D) / (1 − (1 − P_D)²) = 2 (1 − P_D) / (2 − P_D). A frame with one detected and the other missed in
view is thus worth log((2 − P_D) / (2 (1 − P_D))) for "one point" (discounted by the correlation like every
step), and a frame with both detected rules "one point" out (likelihood 0).
"""
from __future__ import annotations

import math

import numpy as np

from .config import FastSLAMConfig


def detection_probability(config: FastSLAMConfig, ranges: np.ndarray) -> np.ndarray:
    """P_D (N,) at sensor ranges (N,) m from the configured bands (needs ``detection_probabilities``)."""
    band = np.searchsorted(np.asarray(config.detection_range_edges, float), np.asarray(ranges, float), side="right")
    return np.asarray(config.detection_probabilities, float)[band]


def evidence_per_frame(config: FastSLAMConfig) -> float:
    """(1 − ρ)/(1 + ρ): the independent frames' worth of one correlated frame (ρ = ``detection_correlation``)."""
    rho = config.detection_correlation
    return (1.0 - rho) / (1.0 + rho)


def hit_log_odds(config: FastSLAMConfig, ranges: np.ndarray) -> np.ndarray | float:
    """Log-odds a detection at each range (N,) adds."""
    if not config.detection_probabilities:
        return config.existence_hit
    return evidence_per_frame(config) * np.log(detection_probability(config, ranges) / config.false_alarm_probability)


def miss_log_odds(config: FastSLAMConfig, ranges: np.ndarray) -> np.ndarray | float:
    """Log-odds a miss (well in view, not reported) at each range (N,) adds (≤ 0)."""
    if not config.detection_probabilities:
        return config.existence_miss
    return evidence_per_frame(config) * np.log1p(-detection_probability(config, ranges))


def detection_probability_or_constant(config: FastSLAMConfig, ranges: np.ndarray) -> np.ndarray:
    """P_D (N,) at ranges (N,): the configured bands, or the constants' own P_D = 1 − exp(existence_miss)."""
    ranges = np.asarray(ranges, float)
    if config.detection_probabilities:
        return detection_probability(config, ranges)
    return np.full(ranges.shape, -np.expm1(config.existence_miss))


def false_alarm_probability_or_constant(config: FastSLAMConfig, p_d: np.ndarray) -> np.ndarray:
    """P_FA (N,) beside P_D (N,): the configured rate, or the constants' own P_FA = P_D / exp(existence_hit)
    (a detection is worth log(P_D / P_FA) = existence_hit)."""
    if config.detection_probabilities:
        return np.full(np.shape(p_d), config.false_alarm_probability)
    return np.asarray(p_d, float) / math.exp(config.existence_hit)


def exclusive_log_odds(config: FastSLAMConfig, ranges: np.ndarray) -> np.ndarray:
    """Log-likelihood ratio "one point" : "two points" (N,) of a frame in which one landmark of a pair was
    detected and the other, predicted well in view at ``ranges`` (N,) m, was not (see the module docstring)."""
    p = np.clip(detection_probability_or_constant(config, ranges), 1e-6, 1.0 - 1e-6)
    return evidence_per_frame(config) * np.log((2.0 - p) / (2.0 * (1.0 - p)))
