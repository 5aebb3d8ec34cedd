"""A map that flagged itself (metadata["self_check"], estimation/fastslam/self_check.py, read by
runtime/map_self_check.py) is named by `p3at fuse`: one warning line per such map, the verdict in --json; maps
without the key, or whose check holds, fuse as before."""
from __future__ import annotations

import importlib
import json
import sys
from pathlib import Path

import pytest

from runtime.cli import main
from runtime.map_self_check import lost_text, read_self_check
from tests.fastslam.conftest import corridor_features
from tests.fastslam.test_self_check import KICK, _run

_BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


@pytest.fixture(scope="module")
def verdicts():
    """The verdicts of the synthetic corridor run, kicked off its heading (lost) and not (holds), as FastSLAM
    writes them into a map."""
    return {kick: _run(corridor_features, kick)[0].best_map().metadata["self_check"] for kick in (0.0, KICK)}


@pytest.fixture(scope="module")
def maps(tmp_path_factory, verdicts):
    if str(_BENCHMARKS) not in sys.path:
        sys.path.insert(0, str(_BENCHMARKS))
    sim = importlib.import_module("fusion_sim")
    d = tmp_path_factory.mktemp("self_check")
    first, second = sim.building_pair(1.0, seed=5)
    for suffix, checks in (("old", None), ("lost", (verdicts[0.0], verdicts[KICK])),
                           ("bad", ({"lost": "yes", "alarms": []}, verdicts[0.0]))):
        for k, simulated in enumerate((first, second)):
            m = simulated.map
            m.metadata = {key: v for key, v in m.metadata.items() if key != "self_check"}
            if checks is not None:
                m.metadata["self_check"] = checks[k]
            m.save(d / f"r{k + 1}-{suffix}.npz")
    return d


def _fuse(capsys, maps: Path, suffix: str, *extra: str) -> tuple[int, str, str]:
    status = main(["fuse", str(maps / f"r1-{suffix}.npz"), str(maps / f"r2-{suffix}.npz"), "--out",
                   str(maps / f"merged-{suffix}.npz"), *extra])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def test_the_verdict_is_read_back_and_says_when_the_map_lost_its_place(verdicts):
    lost, holds = read_self_check({"self_check": verdicts[KICK]}), read_self_check({"self_check": verdicts[0.0]})
    assert lost["lost"] and not holds["lost"] and lost_text(holds) is None
    text = lost_text(lost)
    assert text.startswith(f"may have lost its place at t≈{lost['alarms'][0]['t']:.1f} s") and "old landmarks" in text
    assert read_self_check({"true_start_pose": [0, 0, 0]}) is None


@pytest.mark.parametrize("bad", [[1], {"lost": "yes", "alarms": []}, {"lost": True, "alarms": "x"},
                                 {"lost": True, "alarms": [{"t": 1.0}]}, {"lost": False, "alarms": [], "frames": "9"},
                                 {"lost": True, "alarms": [], "threshold": 1.0}])
def test_a_malformed_verdict_is_named_in_one_line(bad, verdicts):
    value = {**verdicts[0.0], **bad} if isinstance(bad, dict) else bad
    with pytest.raises(ValueError, match="self_check") as raised:
        read_self_check({"self_check": value})
    assert "\n" not in str(raised.value) and len(str(raised.value)) < 300


def test_fuse_warns_of_the_map_that_lost_its_place_and_json_carries_the_verdict(maps, capsys, verdicts):
    status, out, err = _fuse(capsys, maps, "lost")
    assert status == 0, err
    warnings = [line for line in err.splitlines() if "lost its place" in line]
    assert len(warnings) == 1
    assert warnings[0].startswith("p3at fuse: warning: map 1 (robot2) may have lost its place at t≈")
    status, out, err = _fuse(capsys, maps, "lost", "--json")
    report = json.loads(out)
    assert [m["self_check"]["lost"] for m in report["maps"]] == [False, True]
    assert report["maps"][0]["lost"] is None and report["maps"][1]["lost"].startswith("may have lost its place")
    assert report["maps"][1]["self_check"]["alarms"][0]["t"] == verdicts[KICK]["alarms"][0]["t"]


def test_maps_without_a_verdict_fuse_as_before_and_a_malformed_one_is_a_note(maps, capsys):
    status, out, err = _fuse(capsys, maps, "old", "--json")
    assert status == 0 and "lost its place" not in err
    old = json.loads(out)
    assert [m["self_check"] for m in old["maps"]] == [None, None]
    status, out, err = _fuse(capsys, maps, "lost", "--json")
    assert json.loads(out)["alignments"] == old["alignments"]   # the warning does not change the decision
    status, out, err = _fuse(capsys, maps, "bad")
    notes = [line for line in err.splitlines() if "self_check" in line]
    assert status == 0 and len(notes) == 1 and notes[0].startswith("p3at fuse: note: ") and "r1-bad.npz" in notes[0]
