"""benchmarks/mrclam_seed_vote: the names several chain runs agree on, smoothed into one map.

The helpers are checked against brute force; the whole vote on MRCLAM robot 2's first 300 s, with the barcodes as one
run's names and two runs that each make one mistake (a wrong merge, a duplicate). The barcodes only score.
"""
from __future__ import annotations

import inspect
import itertools
import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from benchmarks.mrclam_seed_vote import offset_groups, pairs_apart
from estimation.geometry import between
from estimation.landmark_map import LandmarkMap

from .test_constellation import _robot2

namings = st.lists(st.tuples(st.integers(-1, 4), st.integers(-1, 4)), min_size=1, max_size=30).map(
    lambda rows: np.array(rows, np.int64).T)


@given(namings)
def test_pairs_apart_counts_the_pairs_one_naming_joins_and_the_other_does_not(pair):
    a, b = pair
    brute = sum((a[i] == a[j]) != (b[i] == b[j]) for i, j in itertools.combinations(range(len(a)), 2)
                if min(a[i], a[j], b[i], b[j]) >= 0)
    assert pairs_apart(a, b) == brute
    assert pairs_apart(a, a) == 0


@given(st.lists(st.tuples(st.integers(-1, 3), st.integers(-1, 3), st.integers(-1, 4)), min_size=1, max_size=30))
def test_offset_groups_are_the_chains_common_names_and_the_rest_by_visit(rows):
    rows = np.array(rows, np.int64)
    round0, names = rows[:, :2].T, rows[:, 2]
    times = np.arange(len(names)) * 3.0          # 3 s apart: a visit ends where a sighting of another kind comes
    groups = offset_groups(round0, names, times)
    loose = (round0 < 0).all(axis=0) & (names >= 0)          # named, but by no run's chain
    for i, j in itertools.combinations(range(len(names)), 2):
        if not loose[i] and not loose[j]:       # the runs' chains: one group exactly when every chain agrees
            assert (groups[i] == groups[j]) == bool(np.array_equal(round0[:, i], round0[:, j])), (i, j)
        elif loose[i] and loose[j]:             # one visit: one name, nothing else between
            one_visit = bool(np.all(loose[i:j + 1] & (names[i:j + 1] == names[i])))
            assert (groups[i] == groups[j]) == one_visit, (i, j)
        else:
            assert groups[i] != groups[j], (i, j)


def test_one_wrong_merge_and_one_duplicate_each_made_by_one_run_of_three_are_voted_out(tmp_path, monkeypatch):
    from benchmarks import mrclam_constellation as chain
    from benchmarks import mrclam_seed_vote
    from estimation.landmark_smoother import HeadingDrift
    from estimation.named_smoothing import MergeRound, smooth_named

    log, noise, config, _ = _robot2(until=300.0)
    drift = HeadingDrift(0.16, 10.0, sigma_per_rad=0.3)          # the chain's, with session 30's slip
    truth = np.asarray(log.landmark_ids, np.int64)
    posts, counts = np.unique(truth, return_counts=True)
    a, b, c = posts[np.argsort(-counts)[:3]]
    wrong = np.where(truth == b, a, truth)                  # two posts under one name
    wrong[::50] = -1                                        # and sightings the run left unnamed
    duplicate = truth.copy()                                # a post's later sightings under a second name
    rows = np.flatnonzero(truth == c)
    duplicate[rows[len(rows) // 2:]] = 1000
    chained = np.where(np.arange(len(truth)) % 7 == 0, -1, truth)   # round 0: some sightings no chain named
    for seed, names in enumerate((truth, wrong, duplicate)):
        named, solution = smooth_named(log, names, noise, config, heading_drift=drift, path_step_s=0.25)
        state = MergeRound([], 0.0, 0.0, True, names, named, solution)
        meta = {"robot": log.name, "seed": seed, "drift": chain._drift_meta(drift), "path_step_s": 0.25,
                "round": 9, "scores": {}, "sighting_offset_m": 0.03}
        chain.save_state(chain.state_path(tmp_path, log, seed, "final"), state, meta)
        chain.save_state(chain.state_path(tmp_path, log, seed, "round0"), MergeRound(
            [], 0.0, 0.0, True, chained, named, solution), meta)
    maps = tmp_path / "maps"
    maps.mkdir()
    row = mrclam_seed_vote.vote_robot(log, [str(tmp_path)], [0, 1, 2], out_maps=str(maps))
    final = row["final"]
    assert final["names"] == len(posts)
    assert final["duplicate_fraction"] == 0.0
    assert final["wrong_sightings_kept"] == 0
    apart = [r["pairs_apart_from_vote"] for r in row["runs"]]
    assert apart[0] == 0 and apart[1] > 0 and apart[2] > 0
    assert row["vote"]["started_from_seed"] == 0
    assert row["vote"]["unnamed_by_majority"] == 0 and row["vote"]["fragments"] == 0
    # run 1's name for a and b is a's by mutual majority (a is the larger), so b alone is contested; run 2 still
    # holds c by its later half (55 of c's 109 sightings)
    assert [(x["sightings"], x["held_by"]) for x in row["vote"]["contested"]] == [(int(np.sum(truth == b)), 2)]
    assert sorted(row["vote"]["held_by"]) == [2] + [3] * (len(posts) - 1)
    voted_map = LandmarkMap.load(row["map"])                # the map records the seeds and each landmark's support
    assert len(voted_map.positions) == len(posts)
    record = voted_map.metadata["vote"]
    assert record["seeds"] == [0, 1, 2] and sorted(record["held_by"]) == [2] + [3] * (len(posts) - 1)
    post_b = between(np.asarray(voted_map.metadata["true_start_pose"]), np.append(log.true_landmarks()[int(b)], 0.0))
    nearest_b = int(np.argmin(np.linalg.norm(voted_map.positions[:, :2] - post_b[:2], axis=1)))
    assert record["held_by"][nearest_b] == 2                 # the contested landmark is post b's, not another's
    assert final["ate_m"] < 0.1

    def broken(*args, **kwargs):
        raise RuntimeError("the smoother stopped")
    from estimation import seed_vote  # where the vote's last step runs (moved from the benchmark, session 36)
    monkeypatch.setattr(seed_vote, "name_unnamed", broken)
    with pytest.raises(RuntimeError):
        mrclam_seed_vote.vote_robot(log, [str(tmp_path)], [0, 1, 2])


def test_runs_of_different_commands_are_not_voted(tmp_path):
    from benchmarks import mrclam_constellation as chain
    from benchmarks.mrclam_seed_vote import vote_robot
    from estimation.named_smoothing import MergeRound, smooth_named

    log, noise, config, drift = _robot2(until=120.0)
    names = np.asarray(log.landmark_ids, np.int64)
    named, solution = smooth_named(log, names, noise, config, heading_drift=drift, path_step_s=0.25)
    for seed in (0, 1, 2):
        meta = {"robot": log.name, "seed": seed, "drift": chain._drift_meta(drift), "path_step_s": 0.25,
                "round": 9, "scores": {}, "sighting_offset_m": 0.03, "command": {"pairwise": 6 if seed else 0}}
        for tag in ("final", "round0"):
            chain.save_state(chain.state_path(tmp_path, log, seed, tag), MergeRound(
                [], 0.0, 0.0, True, names, named, solution), meta)
    with pytest.raises(SystemExit, match="one command"):
        vote_robot(log, [str(tmp_path)], [0, 1, 2])



def _runs_given(directory, log, noise, config, drift, command: dict | None) -> None:
    """Three seeds' final and round-0 states of ``log`` (the barcodes as names, smoothed with ``noise``) whose meta
    records ``command`` as mrclam_constellation's final state does (None: no command, as the states before it)."""
    from benchmarks import mrclam_constellation as chain
    from estimation.named_smoothing import MergeRound, smooth_named

    names = np.asarray(log.landmark_ids, np.int64)
    named, solution = smooth_named(log, names, noise, config, heading_drift=drift, path_step_s=0.25)
    for seed in (0, 1, 2):
        meta = {"robot": log.name, "seed": seed, "drift": chain._drift_meta(drift), "path_step_s": 0.25,
                "round": 9, "scores": {}, "sighting_offset_m": 0.03, **({"command": command} if command else {})}
        for tag in ("final", "round0"):
            chain.save_state(chain.state_path(directory, log, seed, tag), MergeRound(
                [], 0.0, 0.0, True, names, named, solution), meta)


def test_a_vote_of_runs_given_a_noise_file_smooths_with_the_file_s_model_and_fits_none(tmp_path, monkeypatch):
    """Runs made with ``mrclam_constellation --noise FILE`` record the file in their command: the vote loads their
    states and smooths the voted names with that file's model, and fits none from the log (session 37)."""
    from benchmarks import mrclam_constellation as chain
    from benchmarks import mrclam_seed_vote
    from estimation import noise_estimation
    from estimation.noise_estimation import DATASET_CALIBRATIONS, estimate_noise
    from estimation.noise_model import NoiseModel

    log, in_sample, config, drift = _robot2(until=120.0)
    path = tmp_path / "model.toml"
    estimate_noise([_robot2(until=400.0)[0]], **DATASET_CALIBRATIONS).model.save(path)   # another stretch's
    model = NoiseModel.load(path)
    assert model != in_sample
    _runs_given(tmp_path, log, model, config, drift, {"noise": str(path)})

    def no_fit(*args, **kwargs):
        raise AssertionError("the vote fitted a noise model from the log")

    for owner in (noise_estimation, chain, mrclam_seed_vote):
        if hasattr(owner, "estimate_noise"):
            monkeypatch.setattr(owner, "estimate_noise", no_fit)
    given = []

    def spy(owner, name):
        f = getattr(owner, name)

        def wrapped(*args, **kwargs):
            given.append((name, inspect.signature(f).bind(*args, **kwargs).arguments["noise"]))
            return f(*args, **kwargs)
        monkeypatch.setattr(owner, name, wrapped)

    spy(chain, "load_saved_state")          # each run's state: its named problem is built with the model
    spy(mrclam_seed_vote, "vote_runs")      # the vote's smoothing and its last step
    row = mrclam_seed_vote.vote_robot(log, [str(tmp_path)], [0, 1, 2])
    assert [name for name, _ in given] == ["load_saved_state"] * 3 + ["vote_runs"]
    assert all(noise == model for _, noise in given)
    assert row["final"]["names"] == len(np.unique(log.landmark_ids))


def test_a_file_holding_the_in_sample_model_votes_as_the_in_sample_runs_and_a_missing_one_is_refused(
        tmp_path, monkeypatch, capsys):
    from benchmarks import mrclam_seed_vote
    from benchmarks.mrclam_seed_vote import vote_robot
    from estimation.noise_model import NoiseModelError

    from .conftest import MRCLAM2

    log, noise, config, drift = _robot2(until=120.0)
    path = tmp_path / "in-sample.toml"
    noise.save(path)
    for name, command in (("in-sample", None), ("file", {"noise": str(path)})):
        _runs_given(tmp_path / name, log, noise, config, drift, command)
    a = vote_robot(log, [str(tmp_path / "in-sample")], [0, 1, 2])
    b = vote_robot(log, [str(tmp_path / "file")], [0, 1, 2])
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)

    path.write_text("format = 'not a noise model'\n")
    with pytest.raises(NoiseModelError, match=f"{path}"):
        vote_robot(log, [str(tmp_path / "file")], [0, 1, 2])
    path.unlink()
    monkeypatch.setattr(mrclam_seed_vote, "read_mrclam", lambda data, robot: log)
    assert mrclam_seed_vote.main(["--data", str(MRCLAM2), "--state-dir", str(tmp_path / "file"), "--seeds", "0,1,2",
                                  "--robots", "2"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(path) in err and "no such noise-model file" in err, err


def test_the_vote_smooths_with_the_heading_loss_its_runs_had(tmp_path, monkeypatch):
    """Runs made with ``--heading-loss student-t`` record it in their states: the vote's smoothing and last naming
    step use it too (until session 37 the vote smoothed with the Gaussian whatever the runs had)."""
    from benchmarks import mrclam_constellation as chain
    from benchmarks.mrclam_seed_vote import vote_robot
    from estimation import seed_vote
    from estimation.landmark_smoother import HeadingLoss
    from estimation.named_smoothing import MergeRound, smooth_named

    log, noise, config, drift = _robot2(until=120.0)
    names = np.asarray(log.landmark_ids, np.int64)
    loss = HeadingLoss("student-t", 3.0)
    for directory, heading_loss in ((tmp_path / "t", loss), (tmp_path / "gaussian", None)):
        named, solution = smooth_named(log, names, noise, config, heading_drift=drift, path_step_s=0.25,
                                       heading_loss=heading_loss)
        for seed in (0, 1, 2):
            meta = {"robot": log.name, "seed": seed, "drift": chain._drift_meta(drift), "path_step_s": 0.25,
                    "round": 9, "scores": {}, "sighting_offset_m": 0.03,
                    **({"heading_loss": chain._loss_meta(heading_loss)} if heading_loss else {})}
            for tag in ("final", "round0"):
                chain.save_state(chain.state_path(directory, log, seed, tag), MergeRound(
                    [], 0.0, 0.0, True, names, named, solution), meta)
    smoothers = []
    resmoothed = seed_vote.resmoothed

    def spy(smoother, *args, **kwargs):
        smoothers.append(smoother)
        return resmoothed(smoother, *args, **kwargs)

    monkeypatch.setattr(seed_vote, "resmoothed", spy)
    vote_robot(log, [str(tmp_path / "t")], [0, 1, 2])
    vote_robot(log, [str(tmp_path / "gaussian")], [0, 1, 2])
    assert [s.heading_loss for s in smoothers] == [loss, None]


def test_the_command_s_vote_gives_the_vote_the_heading_loss_its_runs_ended_with(monkeypatch):
    """:func:`estimation.seed_vote.chain_vote` (``p3at slam dataset --chain --seeds``) passes the runs' smoother
    settings to the vote, the heading loss with them (the runs stood in for: no data)."""
    from types import SimpleNamespace

    from estimation import seed_vote
    from estimation.landmark_smoother import HeadingDrift, HeadingLoss, SightingOffset
    from estimation.name_chain import ChainResult, ChainSettings
    from estimation.name_merging import NamedSmoother

    loss = HeadingLoss("student-t", 4.0)
    smoother = NamedSmoother(None, None, None, HeadingDrift(0.16, 10.0), 0.25, SightingOffset(0.03), None, loss)
    state = SimpleNamespace(names=np.array([0, 0, 1]))

    def run_chain(log, noise, config, settings, observer):
        observer.state_kept("round0", state, 0, smoother, None)
        return ChainResult(state, smoother, 3)

    given = {}
    monkeypatch.setattr(seed_vote, "run_chain", run_chain)
    monkeypatch.setattr(seed_vote, "vote_runs", lambda *args, **kwargs: given.update(args=args, kwargs=kwargs))
    seed_vote.chain_vote(None, None, None, [0, 1], ChainSettings(heading_loss="student-t", heading_dof=4.0))
    drift, path_step_s, offset_m = given["args"][5:]
    assert (drift, path_step_s, offset_m) == (smoother.heading_drift, 0.25, 0.03)
    assert given["kwargs"] == {"heading_loss": loss}
