"""benchmarks.mrclam_frame_nees on a saved chain state (MRCLAM robot 2's first 120 s, the barcodes as names with some
sightings left unnamed): the state is re-smoothed with its run's sighting offsets and named again by a smoother of its
own, passed to each step, so the benchmark's wrappers it calls are left as they were (until session 37 a module-level
setting of mrclam_constellation carried the offsets, and a later mrclam_constellation.name_unnamed in the same
process smoothed with them)."""
from __future__ import annotations

import argparse

import numpy as np

from .test_constellation import _robot2


def _saved_state(directory, log, noise, config, drift):
    """A final state (every 9th sighting unnamed) and its round-0 state (the offsets' groups: the names, every 4th
    sighting's a name of its own) as mrclam_constellation --state-dir keeps them; the final state's path."""
    from benchmarks import mrclam_constellation as chain
    from estimation.named_smoothing import MergeRound, smooth_named

    names = np.asarray(log.landmark_ids, np.int64).copy()
    names[::9] = -1
    round0 = names.copy()
    round0[1::4] += 1000
    named, solution = smooth_named(log, names, noise, config, heading_drift=drift, path_step_s=0.25)
    meta = {"robot": log.name, "seed": 0, "drift": chain._drift_meta(drift), "path_step_s": 0.25, "round": 9,
            "scores": {}, "sighting_offset_m": 0.03}
    for tag, tag_names in (("final", names), ("round0", round0)):
        chain.save_state(chain.state_path(directory, log, 0, tag), MergeRound(
            [], 0.0, 0.0, True, tag_names, named, solution), meta)
    return chain.state_path(directory, log, 0, "final"), names, round0


def test_a_state_re_smoothed_with_offsets_by_its_own_smoother_leaves_the_benchmark_s_naming_as_it_was(tmp_path,
                                                                                                      monkeypatch):
    import benchmarks.mrclam_constellation as mc
    import benchmarks.mrclam_frame_nees as fn
    from estimation import datasets, unnamed_sightings
    from estimation.landmark_smoother import SightingOffset
    from estimation.name_chain import with_offsets
    from estimation.name_merging import NamedSmoother

    from .conftest import MRCLAM2

    log, noise, config, drift = _robot2(until=120.0)
    path, names, round0 = _saved_state(tmp_path, log, noise, config, drift)
    monkeypatch.setattr(datasets, "read_mrclam", lambda data, robot: log)       # frame_nees reads the robot's log
    state, _ = mc.load_saved_state(path, log, noise, config)
    options = argparse.Namespace(path_step=0.25)
    alone, alone_record = mc.name_unnamed(log, state, noise, config, drift, options)
    assert alone_record["proposed"] > 0

    problem, solution, posts, truth, record = fn.chain_map(path, MRCLAM2, 0.03, True)
    # what the module docstring says it does: the offsets grouped by the round-0 names, then the last naming step
    smoother = NamedSmoother(log, noise, config, drift, 0.25, SightingOffset(0.03), round0)
    expected = unnamed_sightings.name_unnamed(smoother, with_offsets(smoother, state))[0]
    assert np.array_equal(solution.landmarks, expected.solution.landmarks)
    assert np.array_equal(solution.poses, expected.solution.poses)
    assert record["named_again"]["proposed"] > 0
    assert not np.allclose(solution.landmarks[:len(alone.solution.landmarks)], alone.solution.landmarks, atol=1e-9)

    after, after_record = mc.name_unnamed(log, state, noise, config, drift, options)     # as before chain_map ran
    assert after_record == alone_record
    for key in ("landmarks", "poses", "landmark_covariances"):
        assert np.array_equal(getattr(after.solution, key), getattr(alone.solution, key)), key
    assert np.array_equal(after.names, alone.names)


def test_a_state_whose_run_s_noise_file_is_gone_is_refused_in_one_line(tmp_path, monkeypatch, capsys):
    """A state made with ``--noise FILE`` is re-smoothed with that file's model (its meta records it); without the
    file frame_nees says so in one line instead of fitting another model."""
    import json

    import benchmarks.mrclam_frame_nees as fn
    from benchmarks import mrclam_constellation as chain
    from estimation import datasets

    from .conftest import MRCLAM2

    log, noise, config, drift = _robot2(until=60.0)
    path, _, _ = _saved_state(tmp_path, log, noise, config, drift)
    with np.load(path, allow_pickle=False) as data:
        arrays = dict(data)
    meta = json.loads(str(arrays.pop("meta")))
    names = arrays.pop("names")
    missing = tmp_path / "gone.toml"
    np.savez(path, names=names, meta=np.array(json.dumps({**meta, "noise": str(missing)})), **arrays)
    assert chain.saved_meta(path)["noise"] == str(missing)
    monkeypatch.setattr(datasets, "read_mrclam", lambda data, robot: log)
    assert fn.main([str(path), "--data", str(MRCLAM2)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(missing) in err and "no such noise-model file" in err, err
