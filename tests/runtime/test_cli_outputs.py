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


# every command that writes a file: its arguments with the output replaced by OUT (nothing else is read before the
# output is checked, so the inputs need not exist)
FILE_WRITERS = {
    "slam simulate --out": ["slam", "simulate", "--seconds", "3", "--out", "OUT"],
    "slam simulate --ply": ["slam", "simulate", "--seconds", "3", "--out", "{tmp}/m.npz", "--ply", "OUT"],
    "slam dataset": ["slam", "dataset", "mrclam", "{tmp}/no-data", "--robot", "1", "--out", "OUT"],
    "slam noise": ["slam", "noise", "mrclam", "{tmp}/no-data", "--robot", "1", "--out", "OUT"],
    "replay": ["replay", "{tmp}/no-log", "--out", "OUT"],
    "features": ["features", "{tmp}/l.png", "{tmp}/r.png", "--virtual-head", "--out", "OUT"],
    "calib convert": ["calib", "convert", "{tmp}/head.ini", "OUT"],
    "fuse --live": ["fuse", "--live", "--exchange", "inprocess", "--seconds", "1", "--out", "OUT"],
}
FOLDER_WRITERS = {
    "camera grab": ["camera", "grab", "--mock", "--out", "OUT"],
    "review --export": ["review", "{tmp}/no.rrd", "--export", "OUT"],
}


def _argv(template, tmp_path, out) -> list[str]:
    return [str(out) if a == "OUT" else a.format(tmp=tmp_path) for a in template]


@pytest.mark.parametrize("command", sorted(set(FILE_WRITERS) - {"calib convert"}))   # its OUT may be a folder
def test_a_folder_where_a_file_must_go_is_one_line_before_any_work(command, tmp_path, capsys):
    folder = tmp_path / "taken"
    folder.mkdir()
    code = main(_argv(FILE_WRITERS[command], tmp_path, folder))
    line = _one_line(capsys)
    assert code == 2 and f"{folder}: is a folder; give a file name" in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["taken"] and list(folder.iterdir()) == []


@pytest.mark.parametrize("command", sorted(FILE_WRITERS))
def test_a_file_where_a_folder_must_go_is_one_line_before_any_work(command, tmp_path, capsys):
    blocker = tmp_path / "blocker"
    blocker.write_text("keep me")
    code = main(_argv(FILE_WRITERS[command], tmp_path, blocker / "out.x"))
    line = _one_line(capsys)
    assert code == 2 and f"{blocker} is not a folder" in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blocker"] and blocker.read_text() == "keep me"


@pytest.mark.parametrize("command", sorted(FOLDER_WRITERS))
def test_a_file_where_an_output_folder_must_go_is_one_line(command, tmp_path, capsys):
    blocker = tmp_path / "blocker"
    blocker.write_text("keep me")
    code = main(_argv(FOLDER_WRITERS[command], tmp_path, blocker))
    line = _one_line(capsys)
    assert code == 2 and f"{blocker}: a file is there; give a folder" in line, line
    assert blocker.read_text() == "keep me"


def test_features_on_a_missing_image_says_no_such_file_in_one_line(tmp_path, capsys):
    """It printed OpenCV's '[ WARN:0@0.638] global loadsave.cpp:279 findDecoder imread_(...)' line first, then
    'cannot read an image from this file'."""
    code = main(["features", str(tmp_path / "l.png"), str(tmp_path / "r.png"), "--virtual-head", "--out",
                 str(tmp_path / "m.csv")])
    assert code == 2 and _one_line(capsys) == f"p3at features: {tmp_path / 'l.png'}: no such file"


def test_slam_simulate_names_every_file_it_wrote(tmp_path, capsys):
    """It wrote the --ply file and said only 'map written to m.npz'."""
    out, ply = tmp_path / "m.npz", tmp_path / "m.ply"
    assert main(["slam", "simulate", "--seconds", "2", "--out", str(out), "--ply", str(ply)]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == f"  map written to {out} and {ply}"
    assert ply.read_bytes().startswith(b"ply\n") and len(LandmarkMap.load(out)) > 0


@pytest.mark.parametrize("spelling", ["same", "other"])
def test_fuse_refuses_a_map_given_twice(two_maps, tmp_path, capsys, monkeypatch, spelling):
    """It fused the demo's robot1.npz with itself (exit 0): every landmark merged with itself, the merged map's
    covariance traces 0.50 of the map's (median over 1,008 landmarks): twice as confident, from no new evidence."""
    monkeypatch.chdir(tmp_path)
    again = two_maps[0] if spelling == "same" else "./robot1.npz"
    merged = tmp_path / "merged.npz"
    code = main(["fuse", two_maps[0], two_maps[1], again, "--out", str(merged)])
    line = _one_line(capsys)
    assert code == 2 and f"{two_maps[0]} is given twice" in line and "halve its covariance" in line, line
    assert not merged.exists()


def test_fuse_refuses_a_copy_of_a_map_and_a_fused_map_beside_its_reference(two_maps, tmp_path, capsys):
    """A copy (another file, the same bytes) and a fused map beside the map it was made in the frame of both merged
    the same estimates twice (demo: fused.npz + robot1.npz, 971 of 1,008 positions equal bit for bit): every such
    landmark counted twice, its covariance halved. Session 12 warned and merged; now it is refused (exit 2, one line
    naming both files), and no merged map is written."""
    copy = tmp_path / "copy.npz"
    copy.write_bytes(open(two_maps[0], "rb").read())
    fused = tmp_path / "fused.npz"
    assert main(["fuse", *two_maps, "--out", str(fused)]) == 0
    capsys.readouterr()
    again = tmp_path / "again.npz"
    for pair in ([two_maps[0], str(copy)], [str(fused), two_maps[0]]):
        code = main(["fuse", *pair, "--out", str(again)])
        line = _one_line(capsys)
        assert code == 2 and f"{pair[0]} and {pair[1]} hold the same estimates" in line, line
        assert "count those landmarks twice" in line and "give only one of them" in line
        assert not again.exists()
    # the other robot's map sits in the fused map moved into the reference's frame: not bit-equal, but the fused
    # map records its sources' fingerprints (tests/runtime/test_fuse_sources.py)
    assert main(["fuse", str(fused), two_maps[1], "--out", str(again)]) == 2
    assert f"already holds {two_maps[1]}" in _one_line(capsys)


def test_two_runs_of_one_robot_are_fused(tmp_path, capsys):
    """The check is on the estimates, not on names: two maps named robot1 from different runs are evidence."""
    a, b = tmp_path / "monday.npz", tmp_path / "tuesday.npz"
    _map("robot1", seed=4).save(a)
    other = _map("robot1", seed=4, pose=(1.0, -1.0, 0.2))
    other.positions += np.random.default_rng(9).normal(0, 0.01, other.positions.shape)
    other.save(b)
    assert main(["fuse", str(a), str(b), "--out", str(tmp_path / "m.npz")]) == 0
    assert "hold the same estimates" not in capsys.readouterr().err
