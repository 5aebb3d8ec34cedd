"""`p3at slam dataset ... --association unknown --chain --truth-heading travel`: the chain reads no ground truth, so
the truth's heading moves only its scoring — the same names and map, the true start turned by the robot's offset from
the direction of travel (robot 2: −0.0136 rad), recorded in the map, and the frame warning for a model referenced to
the other truth (MRCLAM robot 2's first 150 s, 10 particles; skips without data)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from estimation.landmark_map import LandmarkMap
from tests.datasets.conftest import run_cli


@pytest.mark.timeout(1200)  # CPU-bound: the chain twice on 150 s of one robot (~4 s CPU each)
def test_the_chain_scored_against_the_travel_truth_is_the_same_chain_in_another_frame(mrclam_dir, tmp_path):
    from estimation.datasets import read_mrclam
    from estimation.noise_estimation import DATASET_CALIBRATIONS, estimate_noise

    # a model fitted against Vicon's heading (robot 3's first 600 s), given to both runs: the chain's inputs are equal
    estimate_noise([read_mrclam(mrclam_dir, 3, until=600.0)], **DATASET_CALIBRATIONS).model.save(tmp_path / "n.toml")
    runs, maps = {}, {}
    for heading in ("mocap", "travel"):
        status, out, err = run_cli("slam", "dataset", "mrclam", str(mrclam_dir), "--robot", "2", "--until", "150",
                                   "--association", "unknown", "--chain", "--particles", "10", "--noise",
                                   str(tmp_path / "n.toml"), "--truth-heading", heading,
                                   "--out", str(tmp_path / f"{heading}.npz"), "--json")
        assert status == 0, err
        runs[heading], maps[heading] = json.loads(out), LandmarkMap.load(tmp_path / f"{heading}.npz")
    mocap, travel = maps["mocap"], maps["travel"]
    for field in ("positions", "covariances", "trajectory", "counts"):
        np.testing.assert_array_equal(getattr(travel, field), getattr(mocap, field), err_msg=field)
    for key in ("chain_names", "chain_rounds", "chain_sightings_named", "smoother_chi2_per_dof"):
        assert runs["travel"][key] == runs["mocap"][key], key
    assert mocap.metadata["truth_heading"] == "mocap" and travel.metadata["truth_heading"] == "travel"
    turn = travel.metadata["true_start_pose"][2] - mocap.metadata["true_start_pose"][2]
    assert turn == pytest.approx(-0.0136, abs=0.002)
    assert runs["travel"]["true_start_pose"] == travel.metadata["true_start_pose"]
    assert runs["travel"]["ate_m"] != runs["mocap"]["ate_m"]       # scored in the other frame
    warned = {h: [w for w in runs[h]["warnings"] if "referenced to the motion capture's heading" in w] for h in runs}
    assert warned["mocap"] == [] and len(warned["travel"]) == 1
