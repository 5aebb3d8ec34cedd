"""Particle weights and resampling: small pure functions."""
from __future__ import annotations

import numpy as np


def normalise_log_weights(log_weights: np.ndarray) -> np.ndarray:
    """Normalised weights (M,) from log-weights (M,), computed stably (max subtracted)."""
    log_weights = np.asarray(log_weights, dtype=float)
    w = np.exp(log_weights - np.max(log_weights))
    return w / w.sum()


def effective_sample_size(weights: np.ndarray) -> float:
    """N_eff = 1 / Σ w², for normalised weights (M,)."""
    weights = np.asarray(weights, dtype=float)
    return float(1.0 / np.sum(weights * weights))


def low_variance_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Indices (M,) drawn by systematic (low-variance) resampling from normalised weights (M,).

    One uniform offset r ∈ [0, 1/M) and the comb r + k/M: each particle is copied ⌊M·w⌋ or ⌈M·w⌉ times.
    """
    weights = np.asarray(weights, dtype=float)
    m = len(weights)
    positions = (rng.random() + np.arange(m)) / m
    cumulative = np.cumsum(weights)
    cumulative[-1] = 1.0  # guard against round-off leaving the last comb tooth outside
    return np.searchsorted(cumulative, positions, side="right").astype(np.intp)
