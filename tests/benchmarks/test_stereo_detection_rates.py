"""benchmarks/stereo_detection_rates.py: the range bands and the lag-1 correlation the existence model's rates use."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from benchmarks import stereo_detection_rates as sdr
from estimation.fastslam import FastSLAMConfig
from estimation.fastslam.existence import detection_probability
from estimation.noise_model import DETECTION_BANDS


@settings(max_examples=100)
@given(st.lists(st.floats(0.0, 30.0), min_size=1, max_size=20))
def test_the_bands_are_the_existence_models_bands(ranges):
    """A range's band here is the band existence.detection_probability reads for it (edges from DETECTION_BANDS)."""
    config = FastSLAMConfig(detection_probabilities=tuple(0.1 * (k + 1) for k in range(len(DETECTION_BANDS))),
                            detection_range_edges=tuple(edge for _, edge in DETECTION_BANDS[:-1]))
    r = np.array(ranges)
    assert np.allclose(0.1 * (sdr.band_of(r) + 1), detection_probability(config, r))


def test_runs_of_misses_are_correlated_and_alternation_is_not():
    runs = [np.repeat(np.array([1, 0] * 5), 20)]    # 20 frames detected, 20 missed, ...: ρ = 1 − 2/20
    alternating = [np.array([1, 0] * 30)]
    assert abs(sdr.lag1_correlation(runs) - 0.9) < 0.02
    assert sdr.lag1_correlation(alternating) < -0.9
    assert sdr.lag1_correlation([np.ones(50, int)]) == 0.0           # undefined: no variation
    assert sdr.lag1_correlation([np.array([1, 0]), np.array([0, 1])]) == 0.0   # too few pairs


@settings(max_examples=30)
@given(st.integers(0, 2**32 - 1), st.floats(0.05, 0.95))
def test_independent_frames_have_no_correlation(seed, p):
    """Detections drawn independently per frame: the pooled lag-1 correlation is near 0 (many sequences, never
    joined across sequences)."""
    rng = np.random.default_rng(seed)
    sequences = [(rng.random(40) < p).astype(int) for _ in range(200)]
    assert abs(sdr.lag1_correlation(sequences)) < 0.1
