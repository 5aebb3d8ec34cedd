"""A fused map names the maps it holds by content (fusion/provenance.py): ``p3at fuse`` refuses a map a fused map
among its inputs already holds (its landmarks would count twice), and fuses another map of the same robot as new
evidence with a note saying so; fused maps written before fingerprints keep the old, uncertain note."""
from __future__ import annotations

import importlib
import json

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.landmark_map import LandmarkMap
from fusion.provenance import content_fingerprint, held_fingerprints
from runtime.cli import main
from tests.runtime.test_cli_outputs import _map as _raw_map


def _map(robot: str, pose=(0.0, 0.0, 0.0)) -> LandmarkMap:
    """tests/runtime/test_cli_outputs.py's map of one world from ``pose``, its descriptors unit vectors as a fused
    map's are (so that a fused map aligns with a third map)."""
    m = _raw_map(robot, pose=pose)
    m.descriptors /= np.linalg.norm(m.descriptors, axis=1, keepdims=True)
    return m


def _files(tmp_path):
    paths = {}
    for robot, pose in (("robot1", (0.0, 0.0, 0.0)), ("robot2", (2.0, 1.0, 0.5)), ("robot3", (-1.0, 2.0, -0.4))):
        paths[robot] = str(tmp_path / f"{robot}.npz")
        _map(robot, pose=pose).save(paths[robot])
    return paths


def _err_lines(capsys) -> list[str]:
    return capsys.readouterr().err.strip().splitlines()


def test_the_fused_map_records_its_sources_fingerprints(tmp_path, capsys):
    f = _files(tmp_path)
    fused = str(tmp_path / "fused.npz")
    assert main(["fuse", f["robot1"], f["robot2"], "--out", fused]) == 0
    info = LandmarkMap.load(fused).metadata["fusion"]
    expected = [content_fingerprint(LandmarkMap.load(f[r])) for r in ("robot1", "robot2")]
    assert info["maps"] == ["robot1", "robot2"] and info["fingerprints"] == expected
    assert info["holds"] == sorted(expected) and all(len(p) == 16 for p in expected)
    # fused again with a third map: the new fused map holds all three, the first fused map's sources included
    twice = str(tmp_path / "twice.npz")
    assert main(["fuse", fused, f["robot3"], "--out", twice]) == 0
    held = held_fingerprints(LandmarkMap.load(twice))
    assert held == {*expected, content_fingerprint(LandmarkMap.load(f["robot3"])),
                    content_fingerprint(LandmarkMap.load(fused))}


def test_a_map_the_fused_map_holds_is_refused_in_one_line(tmp_path, capsys):
    """Session 12: fused.npz + robot2.npz (robot2's landmarks moved into robot1's frame, so not bit-equal) merged
    robot2's estimates twice after a note saying they might be. Now the fingerprint says they are: exit 2."""
    f = _files(tmp_path)
    fused, again = str(tmp_path / "fused.npz"), tmp_path / "again.npz"
    assert main(["fuse", f["robot1"], f["robot2"], "--out", fused]) == 0
    twice = str(tmp_path / "twice.npz")
    assert main(["fuse", fused, f["robot3"], "--out", twice]) == 0
    capsys.readouterr()
    for inputs, held in (([fused, f["robot2"]], f["robot2"]), ([f["robot2"], fused], f["robot2"]),
                         ([twice, f["robot2"]], f["robot2"]), ([f["robot3"], twice], f["robot3"])):
        code = main(["fuse", *inputs, "--out", str(again)])
        err = _err_lines(capsys)
        assert code == 2 and len(err) == 1, err
        container = inputs[0] if inputs[1] == held else inputs[1]
        assert f"{container} is a fused map that already holds {held}" in err[0], err
        assert "count its landmarks twice" in err[0] and f"leave {held} out" in err[0]
        assert not again.exists()


def test_another_map_of_a_robot_the_fused_map_holds_is_fused_with_a_note(tmp_path, capsys):
    f = _files(tmp_path)
    fused, again = str(tmp_path / "fused.npz"), str(tmp_path / "again.npz")
    assert main(["fuse", f["robot1"], f["robot2"], "--out", fused]) == 0
    tuesday = str(tmp_path / "robot2-tuesday.npz")        # robot2 again, its own estimates of the same landmarks
    other = _map("robot2", pose=(2.0, 1.0, 0.5))
    other.positions += np.random.default_rng(9).normal(0, 0.01, other.positions.shape)
    other.save(tuesday)
    capsys.readouterr()
    assert main(["fuse", fused, tuesday, "--out", again]) == 0
    notes = [line for line in _err_lines(capsys) if "already holds" in line]
    assert len(notes) == 1 and notes[0].startswith(f"p3at fuse: note: {fused} is a fused map that already holds a "
                                                   f"map of robot2; {tuesday} is another one"), notes
    assert "new evidence" in notes[0]


def test_an_older_fused_map_without_fingerprints_keeps_the_uncertain_note(tmp_path, capsys):
    f = _files(tmp_path)
    fused, again = tmp_path / "fused.npz", str(tmp_path / "again.npz")
    assert main(["fuse", f["robot1"], f["robot2"], "--out", str(fused)]) == 0
    old = LandmarkMap.load(fused)
    for key in ("fingerprints", "holds"):
        del old.metadata["fusion"][key]
    old.save(fused)
    capsys.readouterr()
    assert main(["fuse", str(fused), f["robot2"], "--out", again]) in (0, 1)
    notes = [line for line in _err_lines(capsys) if "already holds" in line]
    assert len(notes) == 1 and f"if {f['robot2']} is that map, its landmarks count twice" in notes[0], notes


@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 30), row=st.integers(0, 29), column=st.integers(0, 2), seed=st.integers(0, 2 ** 32 - 1))
def test_the_fingerprint_is_the_content(tmp_path_factory, n, row, column, seed):
    """A map read back or copied keeps its fingerprint; one position moved by one ulp, one covariance changed, or
    another robot name gives another."""
    rng = np.random.default_rng(seed)
    m = LandmarkMap(rng.normal(0, 5, (n, 3)), np.tile(np.eye(3) * 1e-2, (n, 1, 1)),
                    rng.normal(size=(n, 8)).astype(np.float32), robot="r1")
    path = tmp_path_factory.mktemp("fp") / "m.npz"
    m.save(path)
    fp = content_fingerprint(m)
    assert content_fingerprint(LandmarkMap.load(path)) == fp
    assert content_fingerprint(LandmarkMap(m.positions.copy(), m.covariances.copy(), m.descriptors[:, :4],
                                           robot="r1")) == fp          # descriptors are not part of it
    moved = m.positions.copy()
    moved[row % n, column] = np.nextafter(moved[row % n, column], np.inf)
    assert content_fingerprint(LandmarkMap(moved, m.covariances, m.descriptors, robot="r1")) != fp
    cov = m.covariances.copy()
    cov[row % n, column, column] *= 2
    assert content_fingerprint(LandmarkMap(m.positions, cov, m.descriptors, robot="r1")) != fp
    assert content_fingerprint(LandmarkMap(m.positions, m.covariances, m.descriptors, robot="r2")) != fp


def test_a_fused_map_holds_the_file_of_a_map_merged_in_parts(tmp_path, capsys):
    """A map that flagged itself is split and its parts fused (fusion/split.py); the fused map records the file's
    fingerprint, not its parts', so that file given again beside the fused map is refused."""
    import tests.fusion.conftest  # noqa: F401  (puts benchmarks/ on sys.path for fusion_sim)
    from tests.fusion.test_fusion_split import KICK, _pair

    m1, m2, _, _ = _pair(importlib.import_module("fusion_sim"), KICK)
    paths = [str(tmp_path / "r1.npz"), str(tmp_path / "r2.npz")]
    m1.save(paths[0])
    m2.save(paths[1])
    fused = str(tmp_path / "fused.npz")
    assert main(["fuse", *paths, "--out", fused, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["maps"][1]["split"]["decision"] == "parts"
    info = LandmarkMap.load(fused).metadata["fusion"]
    prints = [content_fingerprint(LandmarkMap.load(p)) for p in paths]
    assert set(info["holds"]) == set(prints) and set(info["fingerprints"]) == set(prints)
    assert main(["fuse", fused, paths[1], "--out", str(tmp_path / "again.npz")]) == 2
    err = _err_lines(capsys)
    assert len(err) == 1 and f"already holds {paths[1]}" in err[0], err
