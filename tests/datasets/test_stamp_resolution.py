"""The reader reports stamps written coarser than their rows (estimation/datasets/stamps.py): a file written with S
significant digits loses a decimal at every power of ten, so from C = 10^c on its stamps sit on a 10^(c+1-S) grid."""
from __future__ import annotations

import gzip
import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from estimation.datasets import read_mrclam, stamp_quantization
from estimation.datasets.stamps import MIN_STAMPS, stamp_grids
from tests.datasets.conftest import run_cli as _cli

LANDMARK, BARCODE = 6, 18


def written(times: np.ndarray, digits: int) -> np.ndarray:
    """``times`` as a file with ``digits`` significant digits holds them."""
    return np.array([float(f"{t:.{digits}g}") for t in times])


def expected(stamps: np.ndarray, step: float, digits: int, c: int):
    """(resolution, earlier resolution or None, from) the construction implies, or None if nothing is coarse.

    A grid held by fewer than MIN_STAMPS distinct stamps is not told apart from chance: a short coarse tail counts
    as the finer grid before it, and a log of fewer stamps is not judged at all."""
    late = max(10.0 ** (c + 1 - digits), 0.01)           # the true times are multiples of 0.01 s
    early = max(10.0 ** (c - digits), 0.01)
    below, tail = stamps[stamps < 10.0 ** c], stamps[stamps >= 10.0 ** c]
    if len(np.unique(stamps)) < MIN_STAMPS:
        return None
    if len(below) and len(np.unique(tail)) < MIN_STAMPS:
        late = early                                       # the tail is merged into the grid before it
    earlier = early if len(below) and late > early else None
    if earlier is None and late <= 1.5 * step:
        return None
    start = float(tail[0]) if earlier is not None else float(stamps[0])
    return late, earlier, start


def log_times(step: float, before: float, after: float, c: int) -> np.ndarray:
    k0, k1 = int(round(before / step)), int(round(after / step))
    return np.round(10.0 ** c + step * np.arange(-k0, k1 + 1), 2)


quantized_logs = st.tuples(
    st.sampled_from([0.01, 0.02, 0.05]),            # the rows' interval (s)
    st.integers(3, 7),                             # significant digits
    st.integers(2, 3),                             # the power of ten the log crosses
    st.floats(0.0, 40.0), st.floats(0.0, 80.0))      # seconds before and after it


@settings(max_examples=300, deadline=None, derandomize=True)
@given(quantized_logs)
def test_the_grid_and_its_onset_are_found(case):
    step, digits, c, before, after = case
    stamps = written(log_times(step, before, after, c), digits)
    q = stamp_quantization(stamps, "odometry")
    want = expected(stamps, step, digits, c)
    if want is None:
        assert q is None
        return
    resolution, earlier, start = want
    assert q is not None
    assert q.resolution_s == pytest.approx(resolution)
    assert (q.earlier_resolution_s is None) == (earlier is None)
    if earlier is not None:
        assert q.earlier_resolution_s == pytest.approx(earlier)
    assert q.from_s == start
    tail = stamps[stamps >= start]
    assert q.rows == len(tail) and q.stamps == len(np.unique(tail))
    assert q.row_interval_s == pytest.approx((stamps[-1] - stamps[0]) / (len(stamps) - 1))


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.floats(0.0, 5000.0), st.sampled_from([0.001, 0.01, 0.02, 0.05, 0.1]), st.integers(20, 400))
def test_stamps_as_fine_as_their_rows_are_not_reported(t0, step, n):
    """Stamps exact to the rows (any start, no rounding beyond the float's own) are never reported."""
    stamps = np.round(t0, 3) + step * np.arange(n)
    assert stamp_quantization(stamps, "odometry") is None


def test_jittered_stamps_are_not_reported():
    rng = np.random.default_rng(0)
    stamps = np.cumsum(rng.uniform(0.015, 0.025, 5000)) + 1234.5678
    assert stamp_quantization(stamps, "odometry") is None


def test_a_last_stamp_on_a_coarse_grid_by_chance_is_not_a_grid():
    """1900.0 is a multiple of 100: a few last rows on it are the 0.1 s grid's, not a 100 s one."""
    stamps = written(np.round(np.arange(1850.0, 1900.0001, 0.02), 2), 5)
    q = stamp_quantization(stamps, "odometry")
    assert q is not None and q.resolution_s == pytest.approx(0.1) and q.earlier_resolution_s is None
    assert q.from_s == 1850.0 and q.rows_per_stamp == pytest.approx(len(stamps) / 501)


def test_grids():
    assert list(stamp_grids([1000.1, 999.98, 1000.0, 0.0, 0.5, 1234.5678])) == pytest.approx(
        [0.1, 0.01, 1000.0, 1e6, 0.1, 1e-4])


def _table(path, header, rows, digits):
    text = header + "".join(" ".join(f"{v:.{digits}g}" for v in row) + "\n" for row in rows)
    with gzip.open(path, "wt") as stream:
        stream.write(text)


def write_log(folder, times: np.ndarray, digits: int) -> None:
    """A robot turning on the spot at 0.2 rad/s; every file's stamps (and only they) with ``digits`` digits."""
    folder.mkdir(parents=True, exist_ok=True)
    theta = 0.2 * (times - times[0])
    _table(folder / "Robot1_Odometry.dat.gz", "# t v w\n", [(t, 0.0, 0.2) for t in times], digits)
    _table(folder / "Robot1_Groundtruth.dat.gz", "# t x y theta\n",
           [(t, 0.0, 0.0, np.angle(np.exp(1j * a))) for t, a in zip(times, theta, strict=True)], digits)
    rows = [(t, BARCODE, 2.0, 0.1) for t in times[::5]]
    _table(folder / "Robot1_Measurement.dat.gz", "# t barcode r b\n", rows, digits)
    _table(folder / "Barcodes.dat.gz", "# subject barcode\n", [(1, 5), (LANDMARK, BARCODE)], 10)
    _table(folder / "Landmark_Groundtruth.dat.gz", "# subject x y sx sy\n", [(LANDMARK, 2.0, 0.0, 0.001, 0.001)], 10)


@settings(max_examples=25, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.tuples(st.sampled_from([0.01, 0.02, 0.05]), st.integers(3, 7), st.integers(2, 3), st.floats(1.0, 40.0),
                 st.floats(1.0, 80.0)))
def test_read_mrclam_reports_each_coarse_file(tmp_path_factory, case):
    step, digits, c, before, after = case
    times = log_times(step, before, after, c)
    folder = tmp_path_factory.mktemp("log")
    write_log(folder, times, digits)
    log = read_mrclam(folder, 1, barcodes="table")
    stamps = written(times, digits)
    streams = {q.stream: q for q in log.stamp_resolution}
    want_rows = expected(stamps, step, digits, c)
    want_sightings = expected(stamps[::5], 5 * step, digits, c)
    assert ("odometry" in streams) == (want_rows is not None) == ("ground truth" in streams)
    assert ("sightings" in streams) == (want_sightings is not None)
    for name, want in (("odometry", want_rows), ("ground truth", want_rows), ("sightings", want_sightings)):
        if want is not None:
            assert streams[name].resolution_s == pytest.approx(want[0]) and streams[name].from_s == want[2]
    notes = [n for n in log.notes if n.startswith("time stamps")]
    assert len(notes) == (1 if streams else 0)
    if streams:
        assert all(f"{name} on a " in notes[0] for name in streams)
        widest = max(q.resolution_s for q in log.stamp_resolution)
        assert f"±{widest / 2:.3g} s" in notes[0]
    # the stamps are used as written: the odometry rows' times are the file's
    assert np.array_equal(log.odometry[:, 0], stamps)


def _coarsen(folder, offset: float, digits: int) -> None:
    """Every robot file's stamps moved by ``offset`` s and written with ``digits`` significant digits."""
    for path in folder.glob("Robot*.dat.gz"):
        with gzip.open(path, "rt") as stream:
            lines = stream.read().splitlines()
        out = [line if line.startswith("#") else
               " ".join([f"{float(line.split()[0]) + offset:.{digits}g}", *line.split()[1:]]) for line in lines]
        with gzip.open(path, "wt") as stream:
            stream.write("\n".join(out) + "\n")


def test_slam_dataset_reports_the_stamp_resolution(tmp_path, synthetic):
    data = tmp_path / "data"
    synthetic.write(data, seconds=40.0)
    _coarsen(data, 980.0, 5)                      # 980-1020 s: a 0.01 s grid, then 0.1 s from 1000 s
    noise = tmp_path / "noise.toml"
    assert _cli("slam", "noise", "mrclam", str(data), "--robot", "1", "--out", str(noise), "--window", "2")[0] == 0
    argv = ("slam", "dataset", "mrclam", str(data), "--robot", "1", "--out", str(tmp_path / "map.npz"),
            "--particles", "5", "--noise", str(noise), "--no-smooth")
    status, out, err = _cli(*argv, "--json")
    assert status == 0, err
    m = json.loads(out)
    by_stream = {q["stream"]: q for q in m["stamp_resolution"]}
    # the synthetic sightings come every 0.2 s: their stamps were on the 0.1 s grid all along
    assert set(by_stream) == {"odometry", "ground truth"}
    odometry = by_stream["odometry"]
    assert odometry["resolution_s"] == pytest.approx(0.1) and odometry["earlier_resolution_s"] == pytest.approx(0.01)
    assert odometry["from_s"] == 1000.0 and odometry["rows_per_stamp"] == pytest.approx(5.0, abs=0.05)
    assert sum(n.startswith("time stamps written coarser") for n in m["notes"]) == 1
    status, out, err = _cli(*argv)
    assert status == 0, err
    assert sum("note: time stamps written coarser than the rows" in line for line in out.splitlines()) == 1


def test_a_log_written_finely_reports_nothing(tmp_path, synthetic):
    synthetic.write(tmp_path / "data", seconds=20.0)
    log = read_mrclam(tmp_path / "data", 1)
    assert log.stamp_resolution == ()
    assert not any(n.startswith("time stamps") for n in log.notes)


def test_mrclam_dataset_2(mrclam_dir):
    """The real data set: every robot's three files are on a 0.1 s grid from t ≈ 1000 s (0.01 s before)."""
    for robot in (1, 4):
        log = read_mrclam(mrclam_dir, robot)
        streams = {q.stream: q for q in log.stamp_resolution}
        assert set(streams) == {"odometry", "sightings", "ground truth"}
        for q in streams.values():
            assert q.resolution_s == pytest.approx(0.1) and q.earlier_resolution_s == pytest.approx(0.01)
            assert 995.0 < q.from_s <= 1001.0
        assert streams["odometry"].rows_per_stamp == pytest.approx(5.0, abs=0.01)


@settings(max_examples=100, deadline=None, derandomize=True)
@given(st.integers(3, 6), st.integers(2, 3), st.floats(1.0, 40.0), st.floats(5.0, 80.0))
def test_spreading_a_coarse_stamp_places_its_rows_about_it(digits, c, before, after):
    """The measurement opt-in (read_mrclam(spread=...)): rows of one stamp evenly about it, within its interval,
    non-decreasing, the rows before the coarse grid untouched."""
    from estimation.datasets.stamps import spread_rows

    stamps = written(log_times(0.02, before, after, c), digits)
    q = stamp_quantization(stamps, "odometry")
    if q is None:
        return
    spread = spread_rows(stamps, q)
    assert np.all(np.diff(spread) >= 0)
    early = stamps < q.from_s
    assert np.array_equal(spread[early], stamps[early])
    assert np.all(np.abs(spread[~early] - stamps[~early]) <= q.resolution_s / 2 + 1e-9)
    for t in np.unique(stamps[~early])[1:-1]:          # a whole stamp's rows are centred on it
        assert np.mean(spread[stamps == t]) == pytest.approx(t, abs=1e-9)


def test_a_50_hz_log_written_with_5_digits_gets_its_times_back(tmp_path):
    times = log_times(0.02, 20.0, 30.0, 3)
    write_log(tmp_path, times, 5)
    log = read_mrclam(tmp_path, 1, barcodes="table", spread=("odometry", "ground truth"))
    inner = (times >= 1000.06) & (times <= 1029.94)     # every whole 0.1 s stamp: the true times, to rounding
    np.testing.assert_allclose(log.odometry[inner, 0], times[inner], atol=1e-4)
    np.testing.assert_allclose(log.ground_truth[inner, 0], times[inner], atol=1e-4)
    assert sum("spread evenly" in n for n in log.notes) == 2
    with pytest.raises(ValueError, match="spread"):
        read_mrclam(tmp_path, 1, barcodes="table", spread=("sightings",))
