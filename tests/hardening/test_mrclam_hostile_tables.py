"""MRCLAM tables that parse but cannot serve (session 25, C). An id or barcode of 1e20 passed the integer check and
was cast to int64 with a RuntimeWarning on stderr (3 lines) and a wrong id; an empty Landmark_Groundtruth (or a FIFO
in its place, which reads as empty) was taken as no landmarks; a log without sightings of known landmarks gave
`slam noise` a model without its sensor part, written without a word (exit 0), which `slam dataset --noise` then
refused, and `slam dataset` said its own fitted model 'has no [range_bearing] section'."""
from __future__ import annotations

import warnings

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from estimation.datasets import DatasetError
from estimation.datasets.mrclam import read_barcodes
from tests.datasets.conftest import run_cli, write_mrclam


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(pairs=st.lists(st.tuples(st.integers(-10**30, 10**30), st.integers(-10**30, 10**30)), min_size=1,
                      max_size=5, unique_by=(lambda p: p[0], lambda p: p[1])))
def test_barcodes_of_any_size_are_read_exactly_or_refused_in_one_line(tmp_path_factory, pairs) -> None:
    folder = tmp_path_factory.mktemp("barcodes")
    (folder / "Barcodes.dat").write_text("".join(f"{s} {b}\n" for s, b in pairs))
    with warnings.catch_warnings():
        warnings.simplefilter("error")      # a RuntimeWarning is a line on the user's stderr
        try:
            table = read_barcodes(folder)
        except DatasetError as e:
            assert "\n" not in str(e) and "Barcodes.dat:" in str(e)
            assert any(max(abs(s), abs(b)) > 2**31 - 1 for s, b in pairs), e
            return
    assert table == {b: s for s, b in pairs}


@pytest.fixture
def data(tmp_path):
    folder = tmp_path / "data"
    write_mrclam(folder, gz=False, seconds=150.0)
    return folder


def _fails(argv, says: str) -> None:
    status, _, err = run_cli(*argv)
    assert status == 2 and err.count("\n") == 1 and says in err, (status, err)


def test_an_empty_landmark_table_is_refused(data, tmp_path) -> None:
    (data / "Landmark_Groundtruth.dat").write_text("# Subject #    x [m]    y [m]    x std-dev [m]    y std-dev [m]\n")
    _fails(["slam", "noise", "mrclam", str(data), "--robot", "1", "--out", str(tmp_path / "n.toml")],
           "Landmark_Groundtruth.dat: no entries")
    assert not (tmp_path / "n.toml").exists()


def test_a_log_without_known_sightings_fits_no_model_without_its_sensor_part(data, tmp_path) -> None:
    (data / "Robot1_Measurement.dat").write_text("# Time [s]    Subject #    range [m]    bearing [rad]\n")
    out = tmp_path / "n.toml"
    _fails(["slam", "noise", "mrclam", str(data), "--robot", "1", "--out", str(out)],
           "too few sightings of landmarks with known positions to fit the sensor noise (0 in the log)")
    assert not out.exists()
    _fails(["slam", "dataset", "mrclam", str(data), "--robot", "1", "--out", str(tmp_path / "m.npz")],
           "fitting this log's own noise model: too few sightings")
