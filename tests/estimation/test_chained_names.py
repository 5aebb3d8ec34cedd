"""estimation/chained_names.py: a log's sightings named through overlapping windows, without barcodes.

Synthetic windows (no filter) check the chaining rule sighting by sighting: two windows' landmarks are linked only on
a mutual clear majority of their shared sightings, and each sighting takes its core window's name. The real-data
chain (run_windows' filter) is tested in tests/datasets/test_chained_names.py.
"""
from __future__ import annotations

import numpy as np

from estimation.chained_names import Window, chain_windows


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
