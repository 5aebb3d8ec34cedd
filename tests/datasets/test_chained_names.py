"""benchmarks/mrclam_chained_names: names chained through overlapping windows by the sightings they share.

The chaining links two windows' landmarks only on a mutual clear majority of their shared sightings and names each
sighting by its core window; a merge of names is tested on the smoother's joint covariance. Synthetic windows (no
filter) check the chaining rule sighting by sighting; the real data (skipped without ../shared/data) check that a
stretch of robot 2's log is chained with few wrong sightings and that the loops it closes join names of one post.
"""
from __future__ import annotations

import numpy as np
import pytest

from benchmarks.mrclam_chained_names import (
    Window,
    chain_windows,
    close_loops,
    majority,
    naming_scores,
    run_windows,
)
from estimation.datasets import read_mrclam
from estimation.fastslam import range_bearing_config
from estimation.noise_model import DATASET_CALIBRATIONS, estimate_noise

from .conftest import MRCLAM2


def _window(start, seconds, sightings, times, labels):
    return Window(start, seconds, np.asarray(sightings), np.asarray(times, float), np.asarray(labels),
                  map=_Rows(max(labels) + 1))


class _Rows(list):
    """A stand-in for a window map: chain_windows needs only its length."""

    def __init__(self, n):
        super().__init__(range(n))


def test_mutual_majority_links_and_a_minority_does_not():
    # window 0 covers sightings 0-7 (t 0-7 s), window 1 sightings 4-11 (t 4-11 s): the overlap is 4-7
    times = np.arange(12.0)
    w0 = _window(0.0, 8.0, range(0, 8), times[0:8], [0, 0, 1, 1, 0, 0, 1, 1])
    # in window 1, landmark 0 takes sightings 4, 5 (window 0's landmark 0: linked); landmark 1 takes one of
    # landmark 1's two overlap sightings (6) and landmark 2 the other (7): no clear majority, neither is linked
    w1 = _window(4.0, 8.0, range(4, 12), times[4:12], [0, 0, 1, 2, 0, 1, 2, 2])
    chained = chain_windows([w0, w1], 12)
    assert chained.links == 1
    assert chained.unlinked == 2
    assert chained.window_names[1][0] == chained.window_names[0][0]
    assert len({*chained.window_names[0].tolist(), *chained.window_names[1].tolist()}) == 4
    # the core window names each sighting: window 0's middle is 4 s, window 1's 8 s; sightings 0-5 are window 0's,
    # 6 is equidistant (window 0's, named first), 7-11 are window 1's
    names = chained.names
    n0, n1 = chained.window_names
    assert names[:7].tolist() == [n0[0], n0[0], n0[1], n0[1], n0[0], n0[0], n0[1]]
    assert names[7:].tolist() == [n1[2], n1[0], n1[1], n1[2], n1[2]]


def test_a_sighting_its_core_window_leaves_unnamed_takes_the_other_windows_name():
    times = np.arange(8.0)
    w0 = _window(0.0, 6.0, range(0, 6), times[0:6], [0, 0, 0, 0, 0, 0])
    w1 = _window(2.0, 6.0, range(2, 8), times[2:8], [0, 0, 0, -1, 0, 0])   # sighting 5 is unnamed in window 1
    chained = chain_windows([w0, w1], 8)
    assert chained.links == 1
    assert np.all(chained.names == chained.window_names[0][0])


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
    windows = run_windows(log, 40.0, config, noise, seed=0)
    chained = chain_windows(windows, len(log))
    scores = naming_scores(chained.names, log.landmark_ids)
    assert scores["wrong_fraction"] < 0.02
    assert chained.links > len(windows)
    owner = majority(chained.names, log.landmark_ids)
    closure = close_loops(log, chained.names, noise, config, max_rounds=5)
    merged = [pair for r in closure.rounds if r.accepted for pair in r.merged]
    assert merged                                       # 400 s: the drift is small enough for names to merge
    assert all(owner[a] == owner[b] for a, b in merged)
