"""MRCLAM robot 1 named from submaps (benchmarks/mrclam_submap_association.py, fusion/submap_names.py): the windows
are nearly right, and no found alignment joins two barcodes. Skips without ../shared/data."""
from __future__ import annotations

import contextlib
import io
import json

import pytest

from benchmarks.mrclam_submap_association import main

from .conftest import MRCLAM2

needs_data = pytest.mark.skipif(not MRCLAM2.is_dir(), reason="MRCLAM dataset 2 not in ../shared/data")


def _run(*argv) -> dict:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main([*argv, "--json"]) == 0
    return json.loads(out.getvalue())


@needs_data
def test_robot_1_windows_are_named_nearly_right_and_nothing_is_joined_wrongly():
    rows = _run("--data", str(MRCLAM2), "--robots", "1", "--window", "40", "--until", "400", "--calibrated",
                "--prior", "--smooth", "never")["rows"]
    (row,) = rows
    windows = row["windows_total"]
    # the calibrated sensor over 40 s: a few sightings of another post (the whole log in one run: 6 % on robot 1)
    assert windows["named"] + windows["unnamed"] == row["joined_names"]["sightings"]
    assert windows["wrong_fraction"] < 0.05
    assert row["joins_wrong"] == 0
    assert len(row["per_window"]) == row["windows"] >= 8


def test_no_data_set_is_an_error_not_a_crash(tmp_path):
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        assert main(["--data", str(tmp_path / "absent"), "--robots", "1"]) == 2
    assert "no data set" in err.getvalue()
