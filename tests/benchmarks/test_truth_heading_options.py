"""``--truth-heading mocap|travel`` on the MRCLAM benchmarks (eval_mrclam, eval_fusion, fusion_mrclam_diagnosis).

``travel`` reads every log with the ground truth's heading turned onto the robot's direction of travel
(``read_mrclam(truth_heading="travel")``): it moves headings only, so a map's true start differs from the mocap one in
θ alone, and a folder of maps made against one truth heading is refused when scored against the other (their start
frames would be mixed with the sighting maps' silently).
"""
from __future__ import annotations

import json
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from benchmarks import eval_fusion, eval_mrclam, fusion_mrclam_diagnosis
from benchmarks.fusion_sim import SightingMap, mrclam_sighting_map, start_heading_refusal
from estimation.geometry import wrap_angle
from estimation.landmark_map import LandmarkMap
from tests.datasets.conftest import MRCLAM2


@pytest.fixture
def mrclam_dir():
    if not (MRCLAM2 / "Robot1_Odometry.dat.gz").is_file() and not (MRCLAM2 / "Robot1_Odometry.dat").is_file():
        pytest.skip(f"MRCLAM data set 2 not found in {MRCLAM2.resolve()} (../shared/data/mrclam, see its README)")
    return MRCLAM2


def _map(robot: int, start) -> LandmarkMap:
    return LandmarkMap(np.zeros((1, 3)), np.eye(3)[None] * 0.01, np.zeros((1, 0), np.float32), robot=f"robot{robot}",
                       frame=f"robot{robot}/start", metadata={"true_start_pose": [float(v) for v in start]})


def _placed(starts) -> list[SightingMap]:
    return [SightingMap(_map(r, s), np.zeros(0, np.int64), np.asarray(s, float), {})
            for r, s in enumerate(starts, start=1)]


@pytest.mark.parametrize("main", [eval_mrclam.main, eval_fusion.main,
                                  lambda argv: fusion_mrclam_diagnosis.main(["DIR", *argv])])
def test_an_unknown_truth_heading_is_refused(main, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--truth-heading", "vicon"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "--truth-heading: invalid choice: 'vicon'" in err and "mocap" in err and "travel" in err


@settings(max_examples=50, deadline=None)
@given(st.floats(-10, 10), st.floats(-10, 10), st.floats(-np.pi, np.pi), st.floats(1e-5, 0.1),
       st.sampled_from([-1.0, 1.0]), st.integers(0, 4))
def test_a_map_whose_start_differs_only_in_heading_is_refused_and_named(x, y, theta, turn, sign, which):
    starts = [np.array([x + k, y - k, theta]) for k in range(5)]
    maps = [_map(r, s) for r, s in enumerate(starts, start=1)]
    assert start_heading_refusal(maps, _placed(starts), "travel") is None
    starts_of_maps = [s.copy() for s in starts]
    starts_of_maps[which][2] = wrap_angle(starts_of_maps[which][2] + sign * turn)
    text = start_heading_refusal([_map(r, s) for r, s in enumerate(starts_of_maps, start=1)], _placed(starts),
                                 "travel")
    assert text is not None and "\n" not in text
    assert text.startswith(f"robot{which + 1}'s true_start_pose heading is {sign * turn:+.4f} rad off the travel truth")


def test_a_map_placed_elsewhere_or_without_a_true_start_is_not_judged():
    starts = [np.array([k, 0.0, 0.1 * k]) for k in range(5)]
    elsewhere = [_map(r, s + [0.01, 0.0, 0.2]) for r, s in enumerate(starts, start=1)]
    assert start_heading_refusal(elsewhere, _placed(starts), "mocap") is None
    unscored = [_map(r, s) for r, s in enumerate(starts, start=1)]
    for m in unscored:
        del m.metadata["true_start_pose"]
    assert start_heading_refusal(unscored, _placed(starts), "mocap") is None


def test_travel_turns_only_the_sighting_maps_start_heading(mrclam_dir):
    for robot in range(1, 6):
        mocap = mrclam_sighting_map(mrclam_dir, robot)
        travel = mrclam_sighting_map(mrclam_dir, robot, truth_heading="travel")
        assert np.array_equal(mocap.true_start[:2], travel.true_start[:2])
        assert 1e-3 < abs(wrap_angle(travel.true_start[2] - mocap.true_start[2])) < 0.03   # Vicon's 3-17 mrad
        assert travel.map.metadata["true_start_pose"] == [float(v) for v in travel.true_start]
        assert mocap.truth.keys() == travel.truth.keys()
        assert all(np.array_equal(mocap.truth[k], travel.truth[k]) for k in mocap.truth)
        assert "direction of travel" in travel.map.metadata["map_source"]
        assert "direction of travel" not in mocap.map.metadata["map_source"]


def test_maps_of_the_other_truth_heading_are_refused_before_any_table(mrclam_dir, tmp_path, capsys):
    folder = tmp_path / "travel-maps"
    folder.mkdir()
    for robot in range(1, 6):
        mrclam_sighting_map(mrclam_dir, robot, truth_heading="travel").map.save(folder / f"robot{robot}.npz")
    with pytest.raises(SystemExit) as exit_:
        eval_fusion.main(["--trust-only", "--maps-only", "--mrclam-maps", str(folder)])
    assert exit_.value.code == 2
    out, err = capsys.readouterr()
    # robot 1's Vicon heading is a few mrad off its travel where it first sees a post (7.6 mrad in session 38)
    assert re.fullmatch(rf"eval_fusion: --mrclam-maps {re.escape(str(folder))}: robot1's true_start_pose heading is "
                        r"[+-]0\.0\d\d\d rad off the mocap truth's at the same place: .*\n", err)
    assert "###" not in out
    with pytest.raises(SystemExit) as exit_:
        fusion_mrclam_diagnosis.main([str(folder)])
    assert exit_.value.code == 2
    assert capsys.readouterr().err.startswith(f"fusion_mrclam_diagnosis: {folder}: robot1's true_start_pose heading")


@pytest.mark.timeout(1200)
def test_eval_mrclam_scores_against_the_travel_heading_and_says_so(mrclam_dir, tmp_path, capsys):
    runs = {}
    for heading in ("mocap", "travel"):
        assert eval_mrclam.main(["--data", str(mrclam_dir), "--robots", "2", "--association", "id", "--until", "120",
                                 "--particles", "20", "--maps", str(tmp_path / heading), "--json",
                                 "--truth-heading", heading]) == 0
        runs[heading] = json.loads(capsys.readouterr().out)
        assert runs[heading]["truth_heading"] == heading
    mocap, travel = (np.array(runs[h]["runs"]["id/robot2"]["true_start_pose"]) for h in ("mocap", "travel"))
    assert np.array_equal(mocap[:2], travel[:2])
    assert wrap_angle(travel[2] - mocap[2]) == pytest.approx(-0.0136, abs=0.002)   # robot 2's Vicon offset
    saved = LandmarkMap.load(tmp_path / "travel" / "id" / "robot2.npz")
    assert saved.metadata["true_start_pose"] == pytest.approx(list(travel))
