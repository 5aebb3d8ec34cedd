"""`p3at slam noise --out` refuses one of the project's other files: `--out robot1.npz` (a slip beside `p3at slam
dataset ... --out robot1.npz`) overwrote the robot's map with a TOML noise model, exit 0 (session 48's walkthrough of
docs/fastslam.md). One line, exit 2, the file untouched; FILE.toml still writes."""
from __future__ import annotations

import pytest

from tests.datasets.conftest import run_cli


@pytest.fixture
def log(tmp_path, synthetic):
    folder = tmp_path / "log"
    synthetic.write(folder, seconds=30.0)
    return folder


@pytest.mark.parametrize(("name", "content", "complaint"), [
    ("robot1.npz", b"PK\x03\x04 a map", "--out {out} holds a landmark map: a noise model (TOML) would overwrite it"),
    ("new.npz", None, "--out {out}: .npz is a landmark map's suffix, and a noise model is TOML; give FILE.toml"),
    ("run.toml", b"RRF2 a recording", "--out {out} holds a Rerun recording"),
])
def test_out_naming_another_kind_of_file_is_refused(tmp_path, log, name, content, complaint):
    out = tmp_path / name
    if content is not None:
        out.write_bytes(content)
    status, stdout, err = run_cli("slam", "noise", "mrclam", str(log), "--robot", "1", "--window", "2",
                                  "--out", str(out))
    assert status == 2 and stdout == "" and err.count("\n") == 1, err
    assert complaint.format(out=out) in err, err
    assert (out.read_bytes() == content) if content is not None else not out.exists()


def test_a_toml_out_still_writes(tmp_path, log):
    out = tmp_path / "noise.toml"
    status, stdout, err = run_cli("slam", "noise", "mrclam", str(log), "--robot", "1", "--window", "2",
                                  "--out", str(out))
    assert status == 0 and out.read_text().startswith("# p3at-fusion noise model"), err
