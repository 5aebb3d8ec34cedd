"""The unknown-association chain's final map says which sightings its frame rests on (``frame_reliability_*`` of
estimation.chain_map.chain_run, from estimation.frame_reliability, as the known-ID smoother's): a log whose frame
rests on one lone first sighting is flagged, the sighting named by its time and the chain's name, and by its barcode
only when the landmarks' truth scores the map; the same figures without the truth; a frame tied by several first
sightings is not flagged. ``p3at slam dataset ... --chain`` (one seed and a vote) carries the figures in its JSON and
prints every warning on stderr too."""
from __future__ import annotations

import json

import numpy as np
import pytest

from estimation.chain_map import chain_run
from estimation.fastslam import range_bearing_config
from estimation.frame_reliability import reliability_warning
from estimation.name_chain import ChainSettings, run_chain
from tests.datasets.conftest import run_cli
from tests.datasets.test_no_ground_truth import _noise
from tests.datasets.turning_start import NOISE
from tests.datasets.turning_start import turning_start_log as _log

CHAIN = ("--association", "unknown", "--chain")


def _chain(first_landmarks: int, with_truth: bool = True):
    log = _log(first_landmarks, with_truth)
    state = run_chain(log, NOISE, range_bearing_config(n_particles=10), ChainSettings()).state
    return log, state, chain_run(log, state, "robot1").metrics


def test_the_chain_s_frame_resting_on_its_first_sighting_is_flagged_and_named_by_the_chain_s_name():
    """The lone first sighting (1 s) before a 3 rad turn: the chain's last smoothing (with its sighting offsets)
    has nothing checking its bearing; named by the chain's name and, with the truth, by the barcode it carries."""
    log, state, m = _chain(1)
    assert state.solution.sighting_offset is not None          # the offsets entered: the case the module had refused
    assert m["frame_reliability_unchecked"]
    first = m["frame_reliability_heading_sighting"]
    assert first["time_s"] == pytest.approx(1.0) and first["component"] == "bearing"
    assert first["component_redundancy"] < 0.05 and "landmark" not in first
    assert first["name"] in state.named.names.tolist()
    at_first = np.flatnonzero(np.isclose(log.sighting_times, 1.0))
    assert len(at_first) == 1 and first["barcode"] == int(log.landmark_ids[at_first[0]])
    assert state.names[at_first[0]] == first["name"]
    warning = reliability_warning(m)
    assert f"at 1.00 s (name {first['name']}, barcode {first['barcode']}; its redundancy" in warning
    # without the truth: the same chain and figures, the sighting named by the chain's name alone
    _, blind_state, blind = _chain(1, with_truth=False)
    np.testing.assert_array_equal(blind_state.names, state.names)
    assert "unscored" in blind and blind["frame_reliability_unchecked"]
    for key in ("frame_reliability_sd", "frame_reliability_effect", "frame_reliability_effect_sd"):
        np.testing.assert_allclose(blind[key], m[key], rtol=1e-9)
    assert blind["frame_reliability_heading_sighting"] == {k: v for k, v in first.items() if k != "barcode"}
    assert f"at 1.00 s (name {first['name']}; its redundancy" in reliability_warning(blind)


def test_the_chain_s_frame_tied_by_several_first_sightings_is_not_flagged():
    _, _, m = _chain(3)
    assert not m["frame_reliability_unchecked"] and reliability_warning(m) is None
    assert max(m["frame_reliability_effect_sd"]) < m["frame_reliability_delta0"]
    assert 0 < m["sighting_redundancy_min"] <= m["sighting_redundancy_median"] < 2


@pytest.mark.parametrize("seeds", [[], ["--seeds", "0,1"]])
def test_the_chain_s_json_carries_the_figures_and_stderr_every_warning(tmp_path, synthetic, seeds):
    """The synthetic circle (90 s, four posts) named by the chain (one seed, and a vote of two): the figures are in
    the JSON, the sightings named by the chain's names, and each of the JSON's warnings is one line on stderr."""
    synthetic.write(tmp_path / "data", seconds=90.0)
    status, out, err = run_cli("slam", "dataset", "mrclam", str(tmp_path / "data"), "--robot", "1", *CHAIN,
                               "--particles", "10", "--noise", str(_noise(tmp_path)), *seeds, "--out",
                               str(tmp_path / "map.npz"), "--json")
    assert status == 0, err
    m = json.loads(out)
    assert len(m["frame_reliability_sd"]) == 3 and isinstance(m["frame_reliability_unchecked"], bool)
    for which in ("heading", "translation"):
        sighting = m[f"frame_reliability_{which}_sighting"]
        assert "name" in sighting and "barcode" in sighting and "landmark" not in sighting
    assert err.splitlines() == [f"p3at slam dataset: warning: {w}" for w in m["warnings"]]
