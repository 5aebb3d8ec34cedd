"""MRCLAM folders with odd stamps and values (session 23): the reader gives one DatasetError line naming file, line
and field, or a log whose poses are finite, with no RuntimeWarning on the way (a warning is two lines on a user's
stderr and meant an overflow to inf)."""
from __future__ import annotations

import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from estimation.datasets.errors import DatasetError
from estimation.datasets.mrclam import MAX_TIME_S, read_mrclam
from tests.datasets.conftest import run_cli, write_mrclam

TABLES = ("Robot1_Odometry.dat", "Robot1_Groundtruth.dat", "Robot1_Measurement.dat")


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("mrclam") / "base"
    write_mrclam(folder, gz=False, seconds=30.0)
    return folder


def _variant(base: Path, folder: Path, table: str, row: int, column: int, value: str) -> Path:
    """A copy of ``base`` with one field of one row of ``table`` replaced by ``value`` (row from the end if < 0)."""
    if folder.exists():
        shutil.rmtree(folder)
    shutil.copytree(base, folder)
    path = folder / table
    lines = path.read_text().splitlines()
    rows = [i for i, line in enumerate(lines) if not line.startswith("#")]
    fields = lines[rows[row]].split()
    fields[column] = value
    lines[rows[row]] = " ".join(fields)
    path.write_text("\n".join(lines) + "\n")
    return folder


def _read(folder: Path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")    # an overflow's RuntimeWarning fails the test
        try:
            return read_mrclam(folder, 1, barcodes="table")
        except DatasetError as e:
            assert "\n" not in str(e)
            return None


@pytest.mark.parametrize("table", TABLES)
def test_a_last_stamp_of_1e300_is_refused_naming_file_line_and_field(base, tmp_path, table) -> None:
    """Before: the odometry's last row at t = 1e300 overflowed the integration and the stamp grids (RuntimeWarnings
    on stderr) and `slam dataset` went on, exit 0; the ground truth's and the sightings' likewise warned."""
    folder = _variant(base, tmp_path / "d", table, -1, 0, "1e300")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(DatasetError, match=rf"{table}:\d+: field time is out of range \(1e\+300"):
            read_mrclam(folder, 1, barcodes="table")
    status, _, err = run_cli("slam", "dataset", "mrclam", str(folder), "--robot", "1", "--out",
                             str(tmp_path / "m.npz"))
    assert status == 2 and err.count("\n") == 1 and "field time is out of range" in err, err
    assert not (tmp_path / "m.npz").exists()


def test_unix_time_stamps_still_read(base, tmp_path) -> None:
    """MRCLAM's own stamps are Unix times (1.25e9 s): every table shifted there reads as before."""
    folder = tmp_path / "epoch"
    shutil.copytree(base, folder)
    for table in TABLES:
        path = folder / table
        lines = [line if line.startswith("#") else " ".join([f"{1.248e9 + float(line.split()[0]):.3f}",
                                                            *line.split()[1:]])
                 for line in path.read_text().splitlines()]
        path.write_text("\n".join(lines) + "\n")
    log = _read(folder)
    assert log is not None and np.all(np.isfinite(log.odometry))
    assert log.odometry[0, 0] == pytest.approx(1.248e9)


@settings(max_examples=120, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(table=st.sampled_from(TABLES), row=st.sampled_from([0, 1, 5, -2, -1]), column=st.integers(0, 3),
       value=st.one_of(st.floats(allow_nan=False, allow_infinity=False),
                       st.floats(min_value=-1e305, max_value=1e305).map(lambda v: v * 1e3),
                       st.sampled_from([MAX_TIME_S, 2 * MAX_TIME_S, 1e300, -1e300, 1e-300, 0.0])))
@example(table="Robot1_Odometry.dat", row=-1, column=0, value=1e300)
@example(table="Robot1_Odometry.dat", row=-1, column=1, value=1e300)
@example(table="Robot1_Groundtruth.dat", row=-1, column=0, value=1e300)
@example(table="Robot1_Measurement.dat", row=-1, column=0, value=1e300)
def test_fuzz_one_field(base, tmp_path, table, row, column, value) -> None:
    """Any one finite value in any field: a one-line DatasetError or a log whose poses are finite, no warning."""
    if column == 3 and table == "Robot1_Odometry.dat":
        column = 2                       # the odometry has three columns
    folder = _variant(base, tmp_path / "f", table, row, column, repr(float(value)))
    log = _read(folder)
    if log is not None:
        assert np.all(np.isfinite(log.odometry)) and np.all(np.isfinite(log.ground_truth))
