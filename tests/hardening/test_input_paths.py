"""Paths that are not plain files, and numbers a float cannot hold, given to every reader of a user's file.

A FIFO that nothing writes to used to hang the route, world, CARMEN, noise-model, start-pose, SVS calibration,
camera_info and robot-parameter readers for ever (``open`` waits for a writer); each now reads it as empty and
says what is wrong in one line, while a pipe that is written to (``--noise <(command)``) still reads. A folder is
one line naming it.
A noise model or a start-pose file with a 400-digit integer or arrays nested 100 000 deep raised OverflowError or
RecursionError (an "internal error", exit 70); fuzzed ones now give the reader's own error or a valid object.
"""
from __future__ import annotations

import json
import math
import os
import threading
from collections.abc import Callable
from pathlib import Path

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from drivers.arcos.params import load_params
from drivers.errors import BadFileError
from drivers.videre.calibration import load as load_calibration
from drivers.videre.camera_info import read_camera
from estimation.datasets import DatasetError
from estimation.datasets.mrclam import read_barcodes
from estimation.noise_model import P3AT_VIDERE_DEFAULT, NoiseModel, NoiseModelError
from estimation.scanmatch import LogFormatError, read_laser_log
from fusion.errors import IncompatibleMapsError
from fusion.prior import load_starts
from mocks.world import World, WorldFileError
from runtime.cli import main
from runtime.motion import RouteFileError, load_route

from .memory import read_bounded

FUZZ = settings(max_examples=150, suppress_health_check=[HealthCheck.function_scoped_fixture])

# (reader, its error class, a file name the reader accepts by its suffix)
READERS: dict[str, tuple[Callable[[Path], object], type[Exception], str]] = {
    "route": (load_route, RouteFileError, "r.route"),
    "world": (World.load, WorldFileError, "w.json"),
    "carmen": (read_laser_log, LogFormatError, "l.log"),
    "carmen-gz": (read_laser_log, LogFormatError, "l.log.gz"),
    "noise": (NoiseModel.load, NoiseModelError, "n.toml"),
    "start-poses": (load_starts, IncompatibleMapsError, "s.json"),
    "calibration-ini": (load_calibration, BadFileError, "c.ini"),
    "calibration-yaml": (load_calibration, BadFileError, "c.yaml"),
    "robot-params": (load_params, BadFileError, "p.json"),
    "camera-info": (read_camera, BadFileError, "left.yaml"),
    "mrclam-barcodes": (lambda p: read_barcodes(p.parent), DatasetError, "Barcodes.dat"),
}
# a failure bound, far above what the read takes: a reader that waits for a writer waits for ever
HANG_BOUND_S = 60.0


def _read_in_thread(read: Callable[[], object], fifo: Path) -> tuple[bool, BaseException | None]:
    """(finished, exception) of ``read()``; if it has not finished within HANG_BOUND_S, the FIFO gets a writer
    (and at once loses it) so that the thread ends, and finished is False."""
    outcome: list[BaseException | None] = []

    def run() -> None:
        try:
            read()
            outcome.append(None)
        except BaseException as error:  # noqa: BLE001 - handed to the test
            outcome.append(error)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(HANG_BOUND_S)
    if thread.is_alive():
        os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))  # unblock the waiting open; EOF follows
        thread.join(HANG_BOUND_S)
        return False, outcome[0] if outcome else None
    return True, outcome[0]


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
@pytest.mark.parametrize("kind", sorted(READERS))
def test_a_fifo_nothing_writes_to_is_a_clean_error_not_a_hang(tmp_path, kind):
    read, error_class, name = READERS[kind]
    fifo = tmp_path / name
    os.mkfifo(fifo)
    finished, error = _read_in_thread(lambda: read(fifo), fifo)
    assert finished, f"the {kind} reader waited for a writer on {fifo}"
    assert isinstance(error, error_class), f"{kind}: {error!r}"
    assert str(error).startswith(str(fifo)) and "\n" not in str(error)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
def test_a_noise_model_fifo_that_gives_nothing_says_so_not_key_format_is_none(tmp_path):
    """`slam dataset --noise FIFO` said "key 'format' is None" (session 25's note; fixed in session 26, C)."""
    fifo = tmp_path / "n.toml"
    os.mkfifo(fifo)
    finished, error = _read_in_thread(lambda: NoiseModel.load(fifo), fifo)
    assert finished and isinstance(error, NoiseModelError)
    assert str(error) == f"{fifo}: a FIFO that gave nothing, not a noise model (TOML, see `p3at slam noise`)"


@pytest.mark.parametrize("kind", sorted(READERS))
def test_a_folder_is_one_line_naming_it(tmp_path, kind):
    read, error_class, name = READERS[kind]
    folder = tmp_path / name
    folder.mkdir()
    with pytest.raises(error_class) as info:
        read(folder)
    assert str(info.value).startswith(str(folder)) and "\n" not in str(info.value)


@pytest.mark.skipif(not Path("/dev/fd").is_dir(), reason="no /dev/fd here")
def test_a_pipe_that_is_written_to_still_reads(tmp_path):
    """What ``--noise <(command)`` gives the reader: /dev/fd/N, a pipe with a writer."""
    text = P3AT_VIDERE_DEFAULT.to_toml().encode()
    read_end, write_end = os.pipe()
    try:
        os.write(write_end, text)  # smaller than a pipe's buffer
        os.close(write_end)
        write_end = -1
        assert NoiseModel.load(f"/dev/fd/{read_end}") == NoiseModel.load(_written(tmp_path / "n.toml", text))
    finally:
        os.close(read_end)
        if write_end >= 0:
            os.close(write_end)


def _written(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
def test_the_cli_says_a_fifo_route_is_empty_in_one_line(tmp_path, capsys):
    fifo = tmp_path / "r.route"
    os.mkfifo(fifo)
    out = tmp_path / "map.npz"
    code: list[int] = []
    finished, error = _read_in_thread(
        lambda: code.append(main(["slam", "simulate", "--world-route", str(fifo), "--out", str(out)])), fifo)
    assert finished and error is None and code == [2]
    err = capsys.readouterr().err
    assert err.startswith(f"p3at slam simulate: {fifo}") and err.count("\n") == 1
    assert not out.exists()


# ------------------------------------------------------------------------------------------------ noise model
_BIG = 10 ** 400
_TOML_VALUES = st.one_of(
    st.integers(min_value=-(10 ** 500), max_value=10 ** 500), st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([str(_BIG), "-" + str(_BIG), "nan", "inf", "-inf", "1e400", "true", '"x"', "[]", "{}",
                     "[" * 5000 + "]" * 5000, "{a = " * 2000 + "1" + "}" * 2000, "0x7fffffffffffffffffff",
                     "1979-05-27T07:32:00Z"]))


def _toml_literal(value) -> str:
    if isinstance(value, str):
        return value
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    return repr(value)


@FUZZ
@given(line=st.integers(min_value=0, max_value=200), value=_TOML_VALUES)
@example(line=8, value=_BIG)              # [odometry] xy_var_per_m: OverflowError in float()
@example(line=8, value="[" * 5000 + "]" * 5000)  # RecursionError in tomllib
def test_a_noise_model_with_any_value_in_any_key_is_a_clean_error_or_a_valid_model(tmp_path, line, value):
    lines = P3AT_VIDERE_DEFAULT.to_toml().splitlines()
    keyed = [i for i, text in enumerate(lines) if " = " in text]
    k = keyed[line % len(keyed)]
    lines[k] = lines[k].split(" = ")[0] + " = " + _toml_literal(value)
    path = _written(tmp_path / "n.toml", ("\n".join(lines) + "\n").encode())
    model = read_bounded(lambda: NoiseModel.load(path), NoiseModelError)
    if model is not None:
        assert all(math.isfinite(v) for v in model.fastslam_overrides().values())
        model.existence_overrides()   # reads the fit's figures as floats
        assert NoiseModel.load(_written(tmp_path / "again.toml", model.to_toml().encode())) == model


def test_a_noise_model_error_names_the_file_and_the_key(tmp_path):
    text = P3AT_VIDERE_DEFAULT.to_toml().replace("xy_var_per_m = ", f"xy_var_per_m = {_BIG} #", 1)
    path = _written(tmp_path / "n.toml", text.encode())
    with pytest.raises(NoiseModelError, match=r"n\.toml: \[odometry\] xy_var_per_m is out of range \(401 digits\)$"):
        NoiseModel.load(path)


# ------------------------------------------------------------------------------------------------ start poses
_JSON_LEAVES = st.one_of(st.none(), st.booleans(), st.integers(min_value=-(10 ** 400), max_value=10 ** 400),
                         st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=20))
_JSON = st.recursive(_JSON_LEAVES, lambda inner: st.lists(inner, max_size=6)
                     | st.dictionaries(st.text(max_size=8), inner, max_size=4), max_leaves=20)


@FUZZ
@given(sigma=_JSON, pose=_JSON, pose_length=st.integers(min_value=0, max_value=6))
@example(sigma=_BIG, pose=0.0, pose_length=3)   # OverflowError in float(sigma_xy)
@example(sigma=1.0, pose=_BIG, pose_length=3)   # OverflowError in a pose
def test_a_start_pose_file_with_any_values_is_a_clean_error_or_valid_starts(tmp_path, sigma, pose, pose_length):
    doc = {"sigma_xy": sigma, "sigma_yaw": 0.3,
           "starts": {"robot1": [0.0, 0.0, 0.0], "robot2": [pose] * pose_length if pose_length else pose}}
    path = _written(tmp_path / "s.json", json.dumps(doc).encode())  # NaN/Infinity as Python's json writes them
    starts = read_bounded(lambda: load_starts(str(path)), IncompatibleMapsError)
    if starts is not None:
        for pose_array, sig in starts.values():
            assert pose_array.shape == (3,) and all(math.isfinite(v) for v in pose_array)
            assert sig is None or all(math.isfinite(v) and v > 0 for v in sig)


@pytest.mark.parametrize(("content", "complaint"), [
    ('{"starts": ' + "[" * 100_000 + "]" * 100_000 + "}", "nested too deeply"),
    (" " * (1 << 20) + "{}", "1048578 bytes"),
    ('{"starts": {"robot1": [0, 0, 1' + "0" * 400 + "]}}", "starts.robot1 holds a number out of range"),
    ('{"starts": {"robot1": {"x": 1}}}', 'starts.robot1 must be [x, y, yaw]'),
])
def test_a_start_pose_file_error_is_one_line_naming_the_file(tmp_path, content, complaint):
    path = _written(tmp_path / "s.json", content.encode())
    with pytest.raises(IncompatibleMapsError) as info:
        read_bounded(lambda: load_starts(str(path)), ())
    assert str(info.value).startswith(str(path)) and complaint in str(info.value) and "\n" not in str(info.value)


def test_a_start_given_as_text_in_the_file_is_still_read(tmp_path):
    path = _written(tmp_path / "s.json", b'{"starts": {"robot1": "1,2,0.5,1,0.3"}}')
    (pose, sig), = load_starts(str(path)).values()
    assert list(pose) == [1.0, 2.0, 0.5] and sig == (1.0, 0.3)


# ------------------------------------------------------------------------------------------------ logs, recordings
@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
@pytest.mark.parametrize("command", ["replay", "review"])
def test_a_log_or_recording_that_is_a_fifo_or_a_broken_link_says_what_is_there(tmp_path, capsys, command):
    """Both said 'no such sensor log' / 'no such recording' of a path that is there."""
    fifo, dangling, loop = tmp_path / "f.x", tmp_path / "d.x", tmp_path / "l.x"
    os.mkfifo(fifo)
    dangling.symlink_to(tmp_path / "nothing")
    loop.symlink_to(loop)
    for path, said in ((fifo, "not a regular file but a FIFO"), (dangling, "a link to nothing"),
                       (loop, "cannot read it (Too many levels of symbolic links)"), (tmp_path / "absent", "no such")):
        extra = ["--no-export"] if command == "review" else []
        assert main([command, str(path), *extra]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"p3at {command}: {path}: {said}") and err.count("\n") == 1, err


@pytest.mark.parametrize("name", ["c.yaml", "c.yml", "c.xml"])
def test_an_empty_opencv_calibration_says_it_is_empty(tmp_path, name):
    """It said OpenCV's '(-215:Assertion failed) buf in function 'open''."""
    path = _written(tmp_path / name, b"")
    with pytest.raises(BadFileError, match=rf"^{path}: an empty file, not an OpenCV calibration$"):
        load_calibration(path)
