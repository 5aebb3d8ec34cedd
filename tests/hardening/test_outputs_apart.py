"""An output path that is one of the command's inputs, or inside its data set (session 23): refused in one line,
exit 2, before any work, and the input left as it was. Before, `slam noise --out DIR/Robot1_Odometry.dat` replaced
the data set's odometry with a TOML noise model (exit 0), `slam dataset --noise n.toml --out n.toml` the noise model
with a map, `fuse --start-poses s.json --out s.json` the start poses with the merged map."""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from runtime.commands.options import OutputPathError, check_output_apart
from tests.datasets.conftest import run_cli, write_mrclam
from tests.hardening.test_map_metadata import _pair


def _digests(*paths: Path) -> dict[str, str]:
    return {str(p): hashlib.sha256(p.read_bytes()).hexdigest() for p in paths}


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("h") / "mrclam"
    write_mrclam(folder, gz=False, seconds=60.0)
    return folder


def _fails_apart(argv: list[str], *kept: Path, says: str) -> None:
    before = _digests(*kept)
    status, out, err = run_cli(*argv)
    assert status == 2 and err.count("\n") == 1 and says in err, (status, err)
    assert _digests(*kept) == before


def test_slam_noise_never_writes_into_its_data_set(data, tmp_path) -> None:
    tables = sorted(data.iterdir())
    _fails_apart(["slam", "noise", "mrclam", str(data), "--robot", "1", "--out", str(data / "Robot1_Odometry.dat")],
                 *tables, says="is inside the data set folder")
    _fails_apart(["slam", "noise", "mrclam", str(data), "--robot", "1", "--out", str(data / "noise.toml")],
                 *tables, says="is inside the data set folder")
    assert sorted(data.iterdir()) == tables
    link = tmp_path / "link"
    link.symlink_to(data, target_is_directory=True)          # another spelling of the folder
    _fails_apart(["slam", "noise", "mrclam", str(link), "--robot", "1", "--out", str(data / "n.toml")],
                 *tables, says="is inside the data set folder")


def test_slam_dataset_outputs_replace_no_input(data, tmp_path) -> None:
    noise = tmp_path / "n.toml"        # a whole noise model: the old code ran on it and wrote its map over it
    status, _, err = run_cli("slam", "noise", "mrclam", str(data), "--robot", "1", "--out", str(noise))
    assert status == 0, err
    tables = sorted(data.iterdir())
    base = ["slam", "dataset", "mrclam", str(data), "--robot", "1"]
    _fails_apart([*base, "--noise", str(noise), "--out", str(noise)], noise, says="is the --noise file")
    _fails_apart([*base, "--out", str(data / "Robot1_Groundtruth.dat")], *tables, says="is inside the data set")
    _fails_apart([*base, "--out", str(tmp_path / "x.rrd"), "--rerun", str(tmp_path / "x.rrd")],
                 noise, says="is the --rerun file")
    assert not (tmp_path / "x.rrd").exists()


def test_fuse_out_is_not_its_start_poses(tmp_path) -> None:
    maps = []
    for m in _pair():                  # maps that fuse: the old code wrote the merged map over the start poses
        m.save(tmp_path / f"{m.robot}.npz")
        maps.append(str(tmp_path / f"{m.robot}.npz"))
    starts = tmp_path / "s.json"
    starts.write_text(json.dumps({"sigma_xy": 1, "sigma_yaw": 0.3, "starts": {"robot1": [0, 0, 0],
                                                                             "robot2": [1, -2, 0.4]}}))
    _fails_apart(["fuse", *maps, "--start-poses", str(starts), "--out", str(starts)], starts,
                 says="is the --start-poses file")
    _fails_apart(["fuse", "--live", "--start-poses", str(starts), "--out", str(starts), "--seconds", "1"], starts,
                 says="is the --start-poses file")


def test_check_output_apart_admits_what_is_apart(tmp_path) -> None:
    (tmp_path / "data").mkdir()
    (tmp_path / "in.toml").write_text("x")
    check_output_apart(tmp_path / "out.npz", files={"--noise": tmp_path / "in.toml", "--rerun": None},
                       folders={"data set": tmp_path / "data"})
    check_output_apart(tmp_path / "data-out" / "m.npz", folders={"data set": tmp_path / "data"})  # beside, not in
    check_output_apart(None, files={"--noise": tmp_path / "in.toml"})
    with pytest.raises(OutputPathError, match="is the --noise file"):
        check_output_apart(tmp_path / "x" / ".." / "in.toml", files={"--noise": tmp_path / "in.toml"})


def test_one_file_is_one_file_by_any_spelling_or_link(tmp_path) -> None:
    """`same_file`, the one comparison of an output with an input (`fuse`'s maps given twice and its --out among
    them used their own, which saw hard links that check_output_apart did not)."""
    from runtime.commands.options import same_file

    (tmp_path / "d").mkdir()
    original = tmp_path / "d" / "m.npz"
    original.write_bytes(b"x")
    (tmp_path / "soft.npz").symlink_to(original)
    (tmp_path / "hard.npz").hardlink_to(original)
    (tmp_path / "dlink").symlink_to(tmp_path / "d", target_is_directory=True)
    for other in (tmp_path / "soft.npz", tmp_path / "hard.npz", tmp_path / "d" / ".." / "d" / "m.npz",
                  tmp_path / "dlink" / "m.npz"):
        assert same_file(other, original), other
        with pytest.raises(OutputPathError, match="is the --noise file"):
            check_output_apart(other, files={"--noise": original})
    # not there yet: compared by the resolved path (through the folder's link too)
    assert same_file(tmp_path / "dlink" / "new.npz", tmp_path / "d" / "new.npz")
    assert not same_file(tmp_path / "d" / "new.npz", original)
    (tmp_path / "copy.npz").write_bytes(b"x")
    assert not same_file(tmp_path / "copy.npz", original)   # equal bytes, another file
