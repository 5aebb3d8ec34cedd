"""``p3at slam dataset ... --chain`` says when its map rests on a naming nothing checks (estimation.naming_reliability
through estimation.chain_map.chain_run): the figures in the JSON, the warning in its ``warnings``, one line on stderr
beside ``--json`` and a WARNING line in the text; none on a log whose every naming is checked."""
from __future__ import annotations

import json

import pytest

import estimation.datasets
import estimation.name_chain
import estimation.seed_vote
from estimation.name_chain import ChainResult
from tests.datasets.conftest import run_cli, write_mrclam
from tests.datasets.test_no_ground_truth import _noise
from tests.estimation.test_naming_reliability import Q, island_log, misnamed_state

CHAIN = ("--association", "unknown", "--chain", "--particles", "10")


@pytest.fixture
def misnamed_island(monkeypatch):
    """The command reads the island log (estimation.test_naming_reliability) and its chain ends with P's glimpse named
    as Q: the chain's own naming is not under test here, what the command says of its final map is."""
    def misnamed_chain(log, *args, **kwargs):
        return ChainResult(misnamed_state(log), None, 1)

    monkeypatch.setattr(estimation.datasets, "read_mrclam", lambda *args, **kwargs: island_log())
    monkeypatch.setattr(estimation.name_chain, "run_chain", misnamed_chain)
    # seed_vote binds run_chain by name when it is first imported: imported here before the patch (and patched as
    # well), it keeps the real one for every later test of the process (a first import under the patch kept the fake,
    # and the next chain vote in the same worker failed)
    monkeypatch.setattr(estimation.seed_vote, "run_chain", misnamed_chain)


def test_the_json_carries_the_unchecked_naming_and_stderr_says_it(tmp_path, misnamed_island):
    (tmp_path / "data").mkdir()
    status, out, err = run_cli("slam", "dataset", "mrclam", str(tmp_path / "data"), "--robot", "1", *CHAIN,
                               "--out", str(tmp_path / "map.npz"), "--json")
    assert status == 0, err
    m = json.loads(out)
    assert m["naming_reliability_unchecked"] and m["untestable_naming_runs"] >= 1
    n = m["untestable_namings"][0]
    assert (n["name"], n["sightings"], n["barcodes"]) == (100 + Q + 6, 7, {"8": 7})
    assert n["start_s"] == pytest.approx(1.5) and n["end_s"] == pytest.approx(4.5)
    naming = [w for w in m["warnings"] if w.startswith("the map rests on a naming nothing checks")]
    assert len(naming) == 1 and "at 1.50–4.50 s (barcodes 8: 7)" in naming[0]
    assert err.splitlines() == [f"p3at slam dataset: warning: {w}" for w in m["warnings"]]


def test_the_text_says_it_as_a_warning(tmp_path, misnamed_island):
    (tmp_path / "data").mkdir()
    status, out, err = run_cli("slam", "dataset", "mrclam", str(tmp_path / "data"), "--robot", "1", *CHAIN,
                               "--out", str(tmp_path / "map.npz"))
    assert status == 0, err
    assert sum(line.startswith(f"  WARNING: the map rests on a naming nothing checks: name {100 + Q + 6}'s 7 sightings")
               for line in out.splitlines()) == 1


def test_a_circle_whose_every_naming_is_checked_has_the_figures_and_no_naming_warning(tmp_path):
    """The synthetic circle (90 s, four posts seen lap after lap) named by the chain itself."""
    write_mrclam(tmp_path / "data", seconds=90.0)
    status, out, err = run_cli("slam", "dataset", "mrclam", str(tmp_path / "data"), "--robot", "1", *CHAIN,
                               "--noise", str(_noise(tmp_path)), "--out", str(tmp_path / "map.npz"), "--json")
    assert status == 0, err
    m = json.loads(out)
    assert m["untestable_namings"] == [] and m["naming_reliability_unchecked"] is False
    assert m["naming_runs"] >= 0 and m["untestable_naming_runs"] == 0
    assert not any("naming nothing checks" in w for w in m["warnings"])
    assert err.splitlines() == [f"p3at slam dataset: warning: {w}" for w in m["warnings"]]
