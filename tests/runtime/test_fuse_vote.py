"""A voted map's record of its vote (metadata["vote"], estimation/name_vote.py, read by runtime/map_vote.py) is
read by `p3at fuse`: a warning line per map with contested landmarks (held by fewer than all the runs voted), the
record in --json; maps without it, or whose every landmark all runs hold, fuse as before."""
from __future__ import annotations

import importlib
import json
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from estimation.landmark_map import LandmarkMap
from estimation.name_vote import vote_metadata
from runtime.map_vote import CONTESTED_SHOWN, contested_text, read_vote
from tests.runtime.test_fuse_self_check import _fuse

_BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


@given(st.lists(st.integers(0, 2**32), min_size=1, max_size=7, unique=True).flatmap(
    lambda seeds: st.tuples(st.just(seeds), st.lists(st.integers(0, len(seeds)), max_size=40))))
def test_the_record_is_read_back_and_its_contested_landmarks_are_those_fewer_than_all_runs_hold(vote):
    seeds, held_by = vote
    record = read_vote(json.loads(json.dumps({"vote": vote_metadata(seeds, np.array(held_by))})), len(held_by))
    assert record["seeds"] == seeds and record["runs"] == len(seeds) and record["held_by"] == held_by
    assert record["contested"] == [i for i, h in enumerate(held_by) if h < len(seeds)]
    positions = np.column_stack([np.arange(len(held_by)) ** 2, np.zeros((len(held_by), 2))])   # gaps 1, 3, 5, ...
    text = contested_text(record, positions)
    assert (text is None) == (not record["contested"])
    if text is not None:
        assert "\n" not in text and f"has {len(record['contested'])} contested landmark" in text
        assert text.count("held by") == min(len(record["contested"]), CONTESTED_SHOWN)
        first = record["contested"][0]          # its nearest is the landmark before it (after it: the first)
        near = 1 if first == 0 else first - 1
        if len(held_by) > 1:
            assert f"({abs(first**2 - near**2):.2f} m from landmark {near})" in text


def test_a_support_beyond_the_runs_is_not_written():
    with pytest.raises(ValueError, match="0 to 3 runs"):
        vote_metadata([0, 1, 2], np.array([3, 4]))


def test_a_map_without_a_record_has_none():
    assert read_vote({"true_start_pose": [0, 0, 0]}, 15) is None


@pytest.mark.parametrize("bad", [
    [1], {"held_by": [3, 3]}, {"seeds": [], "held_by": [3, 3]}, {"seeds": "0,1,2", "held_by": [3, 3]},
    {"seeds": [0, 1, 1], "held_by": [3, 3]}, {"seeds": [0, -1, 2], "held_by": [3, 3]},
    {"seeds": [0, 1, 2], "held_by": [3]}, {"seeds": [0, 1, 2], "held_by": [3, 4]},
    {"seeds": [0, 1, 2], "held_by": [3, True]}, {"seeds": [0, 1, 2], "held_by": [3, 2.0]},
    {"seeds": list(range(1001)), "held_by": [3, 3]}, {"seeds": [0, 1, 2], "held_by": [3] * 10**5}])
def test_a_malformed_or_hostile_record_is_named_in_one_line(bad):
    with pytest.raises(ValueError, match="metadata vote") as raised:
        read_vote({"vote": bad}, 2)
    assert "\n" not in str(raised.value) and len(str(raised.value)) < 300


@pytest.fixture(scope="module")
def maps(tmp_path_factory):
    if str(_BENCHMARKS) not in sys.path:
        sys.path.insert(0, str(_BENCHMARKS))
    sim = importlib.import_module("fusion_sim")
    d = tmp_path_factory.mktemp("vote")
    first, second = sim.building_pair(1.0, seed=5)
    for suffix in ("old", "contested", "settled", "bad"):
        for k, simulated in enumerate((first, second)):
            m = simulated.map
            m.metadata = {key: v for key, v in m.metadata.items() if key != "vote"}
            held_by = np.full(len(m), 3)
            if suffix == "contested" and k == 1:
                held_by[[4, 9]] = 2
            if suffix != "old":
                m.metadata["vote"] = vote_metadata([0, 1, 2], held_by)
            if suffix == "bad" and k == 0:
                m.metadata["vote"]["held_by"] = m.metadata["vote"]["held_by"][:-1]
            m.save(d / f"r{k + 1}-{suffix}.npz")
    return d


def test_fuse_names_the_contested_landmarks_of_a_voted_map_and_json_carries_the_record(maps, capsys):
    status, out, err = _fuse(capsys, maps, "contested")
    assert status == 0, err
    warnings = [line for line in err.splitlines() if "contested" in line]
    assert len(warnings) == 1
    assert warnings[0].startswith("p3at fuse: warning: map 1 (robot2) has 2 contested landmarks of ")
    assert all(f"landmark {i} at (" in warnings[0] for i in (4, 9)) and "held by 2 of 3 runs" in warnings[0]
    status, out, err = _fuse(capsys, maps, "contested", "--json")
    report = json.loads(out)
    assert [m["vote"]["contested"] for m in report["maps"]] == [[], [4, 9]]
    assert report["maps"][0]["contested"] is None and report["maps"][1]["contested"].startswith("has 2 contested")
    merged = LandmarkMap.load(maps / "merged-contested.npz")
    assert "vote" not in merged.metadata            # its per-landmark record described the voted map's rows


def test_maps_without_a_record_or_settled_fuse_as_before_and_a_malformed_one_is_a_note(maps, capsys):
    status, out, err = _fuse(capsys, maps, "old", "--json")
    assert status == 0 and "contested" not in err
    old = json.loads(out)
    assert [m["vote"] for m in old["maps"]] == [None, None]
    for suffix in ("settled", "contested"):          # the warning does not change the decision
        status, out, err = _fuse(capsys, maps, suffix, "--json")
        assert status == 0 and json.loads(out)["alignments"] == old["alignments"]
        assert ("contested" in err) == (suffix == "contested")
    status, out, err = _fuse(capsys, maps, "bad")
    notes = [line for line in err.splitlines() if "metadata vote" in line]
    assert status == 0 and len(notes) == 1 and notes[0].startswith("p3at fuse: note: ") and "r1-bad.npz" in notes[0]
