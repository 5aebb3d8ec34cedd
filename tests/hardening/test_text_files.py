"""CARMEN logs, world files and route files against damage and nonsense: one line naming the file and what is
wrong, the readings before a damaged .gz given back when asked for, fuzzed files never escaping as another
exception, memory bounded."""
from __future__ import annotations

import gzip
import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from estimation.scanmatch import LogFormatError, read_laser_log
from estimation.scanmatch.carmen import MAX_LINE_BYTES, TruncatedLogError
from mocks.world import DEFAULT_WORLD_PATH, World, WorldFileError
from runtime.cli import main
from runtime.motion import RouteFileError, load_route

from .memory import read_bounded

FUZZ = settings(max_examples=60, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _flaser(index: int, n: int = 30) -> str:
    ranges = " ".join(f"{2.0 + 0.01 * k:.3f}" for k in range(n))
    return f"FLASER {n} {ranges} {0.1 * index:.3f} 0 0 0 0 0 {index} host {index}"


def _log_bytes(n_readings: int = 400) -> bytes:
    lines = ["# synthetic", "PARAM x y"] + [_flaser(i) for i in range(n_readings)]
    return gzip.compress(("\n".join(lines) + "\n").encode(), mtime=0)


# ------------------------------------------------------------------------------------------------ CARMEN
def test_a_gz_cut_in_the_middle_gives_back_what_came_before(tmp_path, capsys) -> None:
    data = _log_bytes()
    path = tmp_path / "cut.log.gz"
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(TruncatedLogError) as info:
        read_laser_log(path)
    error = info.value
    assert str(error).startswith(f"{path}: cannot read the log after line") and "\n" not in str(error)
    assert 0 < len(error.readings) < 400
    assert [r.line for r in error.readings] == list(range(3, 3 + len(error.readings)))  # in order, none skipped
    assert main(["scanmatch", str(path)]) == 2
    assert "--allow-truncated" in capsys.readouterr().err


def test_a_gz_corrupted_mid_file_is_one_line_and_exit_2(tmp_path, capsys) -> None:
    data = bytearray(_log_bytes())
    middle = len(data) // 2
    data[middle: middle + 40] = bytes(range(40))
    path = tmp_path / "corrupt.log.gz"
    path.write_bytes(bytes(data))
    with pytest.raises(LogFormatError):
        read_laser_log(path)
    assert main(["scanmatch", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"p3at scanmatch: {path}") and err.count("\n") == 1


def test_allow_truncated_uses_the_readings_before_the_damage_and_says_so(tmp_path, capsys) -> None:
    path = tmp_path / "cut.log"
    path.write_text("\n".join([_flaser(i, 180) for i in range(6)] + ["FLASER 180 1 2 3"]) + "\n")
    assert main(["scanmatch", str(path), "--allow-truncated", "--json"]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["links"] == 5
    assert "warning" in captured.err and "using those 6 readings" in captured.err


def test_a_file_without_newlines_is_refused_without_reading_it_whole(tmp_path) -> None:
    path = tmp_path / "one-line.log"
    path.write_bytes(b"FLASER " + b"1 " * MAX_LINE_BYTES)
    with pytest.raises(LogFormatError, match=f"{path}:1: line longer than"):
        read_bounded(lambda: read_laser_log(path), ())


@pytest.mark.parametrize("argument", [["--max-distance", "nan"], ["--max-distance", "inf"],
                                      ["--max-distance", "-1"], ["--max-distance", "x"], ["--step", "0"],
                                      ["--limit", "1"], ["--limit", "1e3"]])
def test_nonsense_numbers_are_refused_with_status_2(tmp_path, capsys, argument) -> None:
    path = tmp_path / "ok.log"
    path.write_text(_flaser(0) + "\n")
    assert main(["scanmatch", str(path), *argument]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"p3at scanmatch: argument {argument[0]}") and err.count("\n") == 1


@FUZZ
@given(st.data())
def test_fuzz_carmen_gz(tmp_path, data) -> None:
    raw = bytearray(_log_bytes(60))
    for _ in range(data.draw(st.integers(1, 4))):
        raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
    raw = raw[: data.draw(st.integers(0, len(raw)))]
    path = tmp_path / "fuzz.log.gz"
    path.write_bytes(bytes(raw))
    readings = read_bounded(lambda: read_laser_log(path), LogFormatError)
    if readings is not None:
        assert all(np.all(np.isfinite(r.ranges)) for r in readings)


@FUZZ
@given(st.lists(st.one_of(st.sampled_from([_flaser(0), _flaser(1, 3), "FLASER 99999999999 1", "FLASER -2",
                                           "FLASER 2 1 1 nan 0 0 0 0 0 0 h 0", "# c", "ODOM 1 2 3"]),
                          st.text(max_size=60).map(lambda t: "FLASER " + t)), max_size=20))
def test_fuzz_carmen_lines(tmp_path, lines) -> None:
    path = tmp_path / "fuzz.log"
    path.write_text("\n".join(lines), encoding="utf-8")
    read_bounded(lambda: read_laser_log(path), LogFormatError)


# ------------------------------------------------------------------------------------------------ world files
WORLD = json.loads(DEFAULT_WORLD_PATH.read_text())


@pytest.mark.parametrize("text, field", [
    ("[" * 100_000 + "]" * 100_000, "w.json: JSON nested too deeply"),
    ('{"version": 1, "feature_seed": ' + "9" * 5000 + "}", "w.json: invalid JSON"),
    (json.dumps({**WORLD, "walls": [{"from": [0, 0], "to": [1e300, 0]}]}), "walls[0].to"),
    (json.dumps({**WORLD, "walls": [{"from": [0, 0], "to": [1, 0]}] * 10_001}), "walls: 10001 entries"),
    (json.dumps({**WORLD, "feature_seed": 2**70}), "feature_seed"),
    (json.dumps({**WORLD, "default_wall_height": 1e9}), "default_wall_height"),
])
def test_bad_world_files_name_the_field(tmp_path, text, field) -> None:
    path = tmp_path / "w.json"
    path.write_text(text)
    with pytest.raises(WorldFileError) as info:
        World.load(path)
    assert str(info.value).startswith(f"{path}: ") and field in str(info.value) and len(str(info.value)) < 300


def test_an_oversized_world_file_is_refused_before_reading(tmp_path) -> None:
    path = tmp_path / "big.json"
    with open(path, "wb") as f:
        f.truncate(17 << 20)  # sparse: costs no disk
    with pytest.raises(WorldFileError, match="a world file has at most"):
        read_bounded(lambda: World.load(path), ())


def _mutate(value, draw):
    """Replace one leaf or list of the world document with something drawn."""
    junk = st.one_of(st.none(), st.booleans(), st.integers(-10**20, 10**20), st.floats(), st.text(max_size=5),
                     st.lists(st.floats(allow_nan=False), max_size=4), st.dictionaries(st.text(max_size=3),
                                                                                       st.integers(), max_size=2))
    if isinstance(value, dict) and value:
        key = draw(st.sampled_from(sorted(value)))
        return {**value, key: _mutate(value[key], draw) if draw(st.booleans()) else draw(junk)}
    if isinstance(value, list) and value:
        i = draw(st.integers(0, len(value) - 1))
        return value[:i] + [_mutate(value[i], draw) if draw(st.booleans()) else draw(junk)] + value[i + 1:]
    return draw(junk)


@settings(max_examples=30, suppress_health_check=[HealthCheck.function_scoped_fixture])  # a load builds features
@given(st.data())
def test_fuzz_world_documents(tmp_path, data) -> None:
    doc = _mutate(WORLD, data.draw)
    path = tmp_path / "w.json"
    path.write_text(json.dumps(doc))
    world = read_bounded(lambda: World.load(path), WorldFileError)
    if world is not None:
        assert np.all(np.isfinite(world.walls)) and len(world.walls) > 0


# ------------------------------------------------------------------------------------------------ route files
@pytest.mark.parametrize("text, problem", [
    ("1 2\n3 nan\n", ":2: bad waypoint"),
    ("1 2\n1e300 0\n", ":2: bad waypoint '1e300 0' (beyond"),
    ("1 2 3\n", ":1: bad waypoint"),
    ("# only a comment\n", "no waypoints"),
    ("0 0\n" * 100_001, ":100001: more than 100000 waypoints"),
])
def test_bad_route_files_name_the_line(tmp_path, text, problem) -> None:
    path = tmp_path / "r.route"
    path.write_text(text)
    with pytest.raises(RouteFileError) as info:
        load_route(path)
    assert str(info.value).startswith(str(path)) and problem in str(info.value)


@FUZZ
@given(st.binary(max_size=300) | st.text(alphabet="0123456789.-e, #\nnaifNAIF", max_size=200).map(str.encode))
def test_fuzz_route_files(tmp_path, raw) -> None:
    path = tmp_path / "r.route"
    path.write_bytes(raw)
    route = read_bounded(lambda: load_route(path), RouteFileError)
    if route is not None:
        assert route.ndim == 2 and route.shape[1] == 2 and np.all(np.isfinite(route))

