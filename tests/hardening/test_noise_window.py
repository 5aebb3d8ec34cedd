"""`p3at slam noise --window S` shorter than a few odometry intervals: one line, exit 2, no model written. Session 23
found `--window 1e-300` fitting windows of one row (exit 0, a model written from them)."""
from __future__ import annotations

from pathlib import Path

import pytest

from tests.datasets.conftest import run_cli, write_mrclam


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("w") / "mrclam"
    write_mrclam(folder, gz=False, seconds=60.0)   # odometry every 0.02 s
    return folder


@pytest.mark.parametrize("window", ["1e-300", "0.001", "0.02", "0.059"])
def test_a_window_of_fewer_than_three_odometry_intervals_is_refused(data, tmp_path, window) -> None:
    out = tmp_path / "n.toml"
    status, stdout, err = run_cli("slam", "noise", "mrclam", str(data), "--robot", "1", "--window", window,
                                  "--out", str(out))
    assert status == 2 and err.count("\n") == 1 and stdout == "", err
    assert err.startswith(f"p3at slam noise: --window {float(window):g}: shorter than 3 odometry intervals of ") and \
        "(0.02 s, the median)" in err, err
    assert not out.exists()


def test_a_window_of_three_intervals_and_more_is_fitted(data, tmp_path) -> None:
    status, _, err = run_cli("slam", "noise", "mrclam", str(data), "--robot", "1", "--window", "0.06", "--out",
                             str(tmp_path / "n.toml"))
    assert status == 0 and (tmp_path / "n.toml").exists(), err
