"""estimation/unnamed_sightings: the visits that group late-named sightings (hypothesis), and the naming of unnamed
sightings with sighting offsets on a real map (MRCLAM robot 2's first 300 s with the barcodes as names standing for
a tight final map; skipped without the data): the named sightings get offset groups of their own visits, and the
smoother returned carries them."""
from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from estimation.landmark_smoother import SightingOffset
from estimation.name_merging import NamedSmoother
from estimation.unnamed_sightings import VISIT_GAP_S, name_unnamed, visits
from tests.datasets.test_name_unnamed import post_16_unnamed


@given(st.lists(st.tuples(st.integers(0, 3), st.floats(0.0, 60.0, allow_nan=False)), min_size=1, max_size=40))
def test_visits_order_rows_by_name_then_time_and_start_a_visit_at_a_new_name_or_a_gap(sightings):
    names = np.array([n for n, _ in sightings])
    times = np.array([t for _, t in sightings])
    rows = np.arange(len(sightings))
    order, visit = visits(rows, names, times)
    assert sorted(order.tolist()) == rows.tolist()
    keys = list(zip(names[order], times[order], strict=True))
    assert keys == sorted(keys)
    assert visit[0] == 1 and np.all(np.diff(visit) >= 0) and np.all(np.diff(visit) <= 1)
    for a, b, step in zip(order[:-1], order[1:], np.diff(visit), strict=True):
        assert step == int(names[a] != names[b] or times[b] - times[a] > VISIT_GAP_S)


def test_named_sightings_get_offset_groups_of_their_own_visits_and_the_smoother_keeps_them():
    log, noise, config, drift, honest, _, names, state = post_16_unnamed()
    groups = names.copy()
    smoother = NamedSmoother(log, noise, config, drift, 0.25, SightingOffset(0.03), groups)
    named, proposed, after = name_unnamed(smoother, state)
    assert len(proposed) >= 15 and all(honest[r] == x for r, x in proposed.items())
    rows = np.array(sorted(proposed))
    assert np.array_equal(after.offset_names[names >= 0], groups[names >= 0])     # the others' groups stay
    assert after.offset_names[rows].min() > groups.max()                         # new groups, none shared
    _, visit = visits(rows, named.names, log.sighting_times)
    assert len(np.unique(after.offset_names[rows])) == visit.max()
    assert np.array_equal(smoother.offset_names, groups)                         # the smoother given is unchanged
    # a map with nothing left to name is returned as it is, with the smoother given
    left = np.flatnonzero(named.names < 0)
    assert not set(left.tolist()) & set(proposed)
    again, nothing, same = name_unnamed(after, named)
    assert nothing == {} and again is named and same is after
