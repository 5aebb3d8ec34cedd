"""A log without ground truth, read by `p3at slam dataset` / `p3at slam noise` without --barcodes table, is refused
in one line that names the command's option (it named only read_mrclam's keyword, barcodes='table', which a user of
the command cannot type). Found in session 48's walkthrough of docs/fastslam.md, "Logs without ground truth"."""
from __future__ import annotations

from pathlib import Path

import pytest

from tests.datasets.conftest import run_cli


def _without_truth(source: Path, target: Path) -> Path:
    target.mkdir()
    for f in source.iterdir():
        if "Groundtruth" not in f.name:
            (target / f.name).symlink_to(f.resolve())
    return target


@pytest.mark.parametrize("command", ["dataset", "noise"])
def test_the_refusal_names_the_commands_barcodes_option(mrclam_dir, tmp_path, command):
    folder = _without_truth(mrclam_dir, tmp_path / "nogt")
    out_file = tmp_path / ("m.npz" if command == "dataset" else "n.toml")
    status, out, err = run_cli("slam", command, "mrclam", str(folder), "--robot", "1", "--out", str(out_file))
    assert status == 2 and out == "" and err.count("\n") == 1, err
    assert "Barcodes.dat cannot be verified without ground truth" in err and "--barcodes table" in err, err
    assert not out_file.exists()
