"""benchmarks/fusion_symmetry.py: rendered demo maps are studied; any other folder (MRCLAM maps, a missing or
descriptor-less map) is refused in one line with exit 2 and no table (it used to crash in a k-d tree query)."""
from __future__ import annotations

import numpy as np
import pytest

from benchmarks import fusion_sim
from benchmarks.fusion_symmetry import main
from estimation.landmark_map import LandmarkMap
from tests.datasets.conftest import write_mrclam


@pytest.fixture(scope="module")
def mrclam_maps(tmp_path_factory):
    data = tmp_path_factory.mktemp("mrclam")
    for robot in range(1, 6):
        write_mrclam(data, robot=robot, seconds=30.0)
    out = tmp_path_factory.mktemp("maps") / "maps"
    assert fusion_sim.main(["mrclam", "--data", str(data), "--out", str(out)]) == 0
    return out


def _one_line_refusal(capsys, argv, *words):
    assert main(argv) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("fusion_symmetry: ")
    for word in words:
        assert word in lines[0]


def test_mrclam_maps_are_refused_in_one_line(mrclam_maps, capsys):
    _one_line_refusal(capsys, [str(mrclam_maps)], "robot1.npz", "data set", "p3at demo --out")


def test_a_folder_without_maps_is_refused(tmp_path, capsys):
    _one_line_refusal(capsys, [str(tmp_path / "absent")], "no such map")


def test_a_map_without_descriptors_is_refused(tmp_path, capsys):
    for k in (1, 2):
        LandmarkMap(np.zeros((3, 3)), np.tile(np.eye(3), (3, 1, 1)), np.zeros((3, 0)), robot=f"robot{k}",
                    metadata={"true_start_pose": [0.0, 0.0, 0.0]}).save(tmp_path / f"robot{k}.npz")
    _one_line_refusal(capsys, [str(tmp_path)], "no descriptors")


def test_one_bad_folder_among_good_ones_stops_before_any_table(mrclam_maps, tmp_path, capsys):
    good = _rendered_folder(tmp_path / "good")
    _one_line_refusal(capsys, [str(good), str(mrclam_maps)], "data set")


def _rendered_folder(folder):
    folder.mkdir()
    for robot in ("robot1", "robot2"):
        fusion_sim.building_map(robot, seed=0).map.save(folder / f"{robot}.npz")
    return folder


def test_rendered_building_maps_give_the_table(tmp_path, capsys):
    folder = _rendered_folder(tmp_path / "run")
    assert main([str(folder)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 4
    assert all(line.count("|") == 12 for line in lines)
    assert lines[2].startswith("| run | true") and lines[3].startswith("| run | half turn")
