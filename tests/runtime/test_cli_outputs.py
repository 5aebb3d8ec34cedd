"""What a new user gets when an output path is wrong: one line naming the option and the path (exit 2), before the
command does its work, and never a lost or half-written file.

Each case runs ``p3at`` through ``runtime.cli.main`` as a user would. Read-only folders are not tried (the suite
may run as root, whom permissions do not stop); a folder where a file must go and a file where a folder must go
stop every user.
"""
from __future__ import annotations

import numpy as np
import pytest

from estimation.landmark_map import LandmarkMap
from runtime.cli import main


def _map(robot: str, n: int = 60, seed: int = 0, pose=(0.0, 0.0, 0.0)) -> LandmarkMap:
    """``n`` landmarks with distinct descriptors, seen from a robot at ``pose`` (x, y, yaw) of the same world."""
    rng = np.random.default_rng(seed)
    world = rng.uniform([-10, -10, 0], [10, 10, 3], (n, 3))
    x, y, yaw = pose
    c, s = np.cos(yaw), np.sin(yaw)
    local = (world - [x, y, 0]) @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    return LandmarkMap(positions=local, covariances=np.tile(np.eye(3) * 1e-3, (n, 1, 1)),
                       descriptors=rng.normal(size=(n, 16)).astype(np.float32), robot=robot)


@pytest.fixture
def two_maps(tmp_path):
    """Two maps of one place that align (so a fuse writes its merged map)."""
    paths = [tmp_path / "robot1.npz", tmp_path / "robot2.npz"]
    _map("robot1").save(paths[0])
    _map("robot2", pose=(2.0, 1.0, 0.5)).save(paths[1])
    return [str(p) for p in paths]


def test_the_two_maps_fuse(two_maps, tmp_path, capsys):
    """The premise of the tests below: written elsewhere, the merged map is written and the command succeeds."""
    assert main(["fuse", *two_maps, "--out", str(tmp_path / "merged.npz")]) == 0
    assert len(LandmarkMap.load(tmp_path / "merged.npz")) == 60


def _one_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


@pytest.mark.parametrize("which", [0, 1])
def test_fuse_refuses_to_write_the_merged_map_over_one_of_its_inputs(two_maps, capsys, which):
    """It did: `p3at fuse a.npz b.npz --out b.npz` replaced robot2's map with the merged one, exit 0."""
    before = open(two_maps[which], "rb").read()
    code = main(["fuse", *two_maps, "--out", two_maps[which]])
    line = _one_line(capsys)
    assert code == 2
    assert "is one of the input maps" in line and two_maps[which] in line
    assert open(two_maps[which], "rb").read() == before


def test_fuse_knows_an_input_by_another_spelling_of_its_path(two_maps, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code = main(["fuse", *two_maps, "--out", "./sub/../robot1.npz"])
    assert code == 2 and "is one of the input maps" in _one_line(capsys)


def test_fuse_into_a_folder_says_so_before_it_aligns(two_maps, tmp_path, capsys):
    folder = tmp_path / "merged"
    folder.mkdir()
    code = main(["fuse", *two_maps, "--out", str(folder)])
    line = _one_line(capsys)
    assert code == 2 and line == f"p3at fuse: --out {folder}: is a folder; give a file name"
    assert list(folder.iterdir()) == []


def test_fuse_under_a_file_says_which_is_not_a_folder(two_maps, tmp_path, capsys):
    code = main(["fuse", *two_maps, "--out", f"{two_maps[0]}/merged.npz"])
    line = _one_line(capsys)
    assert code == 2 and f"{two_maps[0]} is not a folder" in line
