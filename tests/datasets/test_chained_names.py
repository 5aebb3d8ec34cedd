"""benchmarks/mrclam_chained_names: the chained names scored by the barcodes, and their loops closed, on real data.

The chaining rule itself (estimation/chained_names.py) and the smoothing on a naming (estimation/named_smoothing.py)
are tested on synthetic windows and problems in tests/estimation. Here: the benchmark's scoring of a naming by the
barcodes, and (skipped without ../shared/data) a stretch of robot 2's log chained with few wrong sightings whose
loops the benchmark's test closes join names of one post.
"""
from __future__ import annotations

import numpy as np
import pytest

from benchmarks.mrclam_chained_names import close_loops, majority, naming_scores
from estimation.chained_names import chain_log
from estimation.datasets import read_mrclam
from estimation.fastslam import range_bearing_config
from estimation.noise_estimation import DATASET_CALIBRATIONS, estimate_noise

from .conftest import MRCLAM2


def test_naming_scores_count_sightings_of_another_barcode():
    names = np.array([0, 0, 0, 1, 1, -1, 2, 2, 2, 2, 2])
    barcodes = np.array([6, 6, 7, 7, 7, 6, 6, 6, 6, 6, 6])
    assert majority(names, barcodes) == {0: 6, 1: 7, 2: 6}
    scores = naming_scores(names, barcodes)
    assert scores["wrong"] == 1 and scores["unnamed"] == 1 and scores["names"] == 3
    assert scores["names_min_sightings"] == 1 and scores["posts"] == 1      # names of fewer than 5 sightings: glimpses


@pytest.mark.slow
def test_mrclam_stretch_is_chained_nearly_right_and_its_loops_close_right():
    if not MRCLAM2.is_dir():
        pytest.skip("MRCLAM data set 2 is not in ../shared/data")
    log = read_mrclam(MRCLAM2, 2, until=400.0)
    noise = estimate_noise([read_mrclam(MRCLAM2, 2)], **DATASET_CALIBRATIONS).model
    config = range_bearing_config(n_particles=50)
    chained = chain_log(log, noise, config, seconds=40.0, seed=0)
    scores = naming_scores(chained.names, log.landmark_ids)
    assert scores["wrong_fraction"] < 0.02
    assert chained.links > len(chained.windows)
    owner = majority(chained.names, log.landmark_ids)
    closure = close_loops(log, chained.names, noise, config, max_rounds=5)
    merged = [pair for r in closure.rounds if r.accepted for pair in r.merged]
    assert merged                                       # 400 s: the drift is small enough for names to merge
    assert all(owner[a] == owner[b] for a, b in merged)
