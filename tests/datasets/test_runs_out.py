"""benchmarks/mrclam_constellation --runs-out: a run of one post's sightings under another post's name is
taken out of that name, and the naming gives it back to its own post. MRCLAM robot 2's first 300 s with the barcodes
as names stand for a tight final map; the barcodes only score."""
from __future__ import annotations

import argparse

import numpy as np

from .test_constellation import _robot2
from .test_name_unnamed import _state


def test_a_visit_of_one_post_under_its_neighbour_s_name_is_taken_out_and_named_again_by_its_own_post():
    from benchmarks.mrclam_constellation import leave_out_flagged_runs, name_unnamed
    log, noise, config, drift = _robot2(until=300.0)
    honest = np.asarray(log.landmark_ids, np.int64)
    args = argparse.Namespace(path_step=0.25, honest_names=0.01)
    _, nothing = leave_out_flagged_runs(log, _state(log, honest, noise, config, drift), noise, config, drift, args)
    assert nothing["runs"] == []                           # the barcodes' map: no run flagged
    t = log.sighting_times - log.sighting_times[0]
    moved = np.flatnonzero((honest == 17) & (t > 220.0) & (t < 232.0))     # a visit of post 17, 1.5 m from 16
    names = honest.copy()
    names[moved] = 16
    state = _state(log, names, noise, config, drift)
    used = state.named.sightings[state.solution.inliers]
    fitted = moved[np.isin(moved, used)]                   # the smoother kept most: the map bends to fit them
    assert len(fitted) >= 20
    left, record = leave_out_flagged_runs(log, state, noise, config, drift, args)
    assert any(r["name"] == 16 and r["wrong"] == r["sightings"] == len(fitted) for r in record["runs"])
    taken = np.flatnonzero((left.names < 0) & (names >= 0))
    assert np.isin(fitted, taken).all()                    # (the ones it dropped keep their name, unused)
    right = np.setdiff1d(taken, moved)                     # right runs the bent map flagged too
    named, _ = name_unnamed(log, left, noise, config, drift, args)
    used = named.named.sightings[named.solution.inliers]
    assert not np.any(np.isin(moved, used) & (named.names[moved] == 16))
    assert np.mean(named.names[fitted] == 17) >= 0.9       # measured: all
    assert np.mean(named.names[right] == honest[right]) >= 0.9


def test_runs_out_without_the_screen_or_the_naming_is_refused(capsys):
    import pytest

    from benchmarks.mrclam_constellation import main
    for argv in (["--runs-out", "--name-unnamed"], ["--runs-out", "--honest-names", "0.01"]):
        with pytest.raises(SystemExit):
            main(argv)
        assert "--runs-out needs --honest-names ALPHA and --name-unnamed" in capsys.readouterr().err
