"""Calibration files holding an OpenCV base64 block (session 44, A). OpenCV's FileStorage decodes YAML ``!!binary``
and XML ``$base64$`` blocks in a loop a damaged block keeps spinning for ever: ``p3at calib show`` of the 60-byte
YAML file ``a: !!binary`` + 40 x ``A`` ran at 100 % CPU until killed, as did a camera_info folder holding such a
``left.yaml`` (and ``features --calib``, which reads the same files). Such a block is now refused before OpenCV
parses the file: one line naming file and line, exit 2."""
from __future__ import annotations

import base64
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.errors import BadFileError
from drivers.videre import calibration as cal
from drivers.videre import camera_info
from mocks.stereo_head import default_calibration
from tests.hardening.calibration_texts import good_calibration_texts

REPO = Path(__file__).resolve().parents[2]
HANG = "a: !!binary " + "A" * 40 + "\n"   # decodes to 30 zero bytes: OpenCV 5.1's parser never returns


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> dict[str, str]:
    return good_calibration_texts(tmp_path_factory.mktemp("good"))


def _files(tmp_path: Path, good: dict[str, str], where: str) -> Path:
    """A calibration whose text holds a base64 block that hangs OpenCV: an OpenCV YAML file, an XML file, or a
    camera_info folder."""
    if where == "yaml":
        path = tmp_path / "calib.yaml"
        path.write_text(good["yaml"] + HANG)
    elif where == "xml":
        path = tmp_path / "calib.xml"
        path.write_text(good["xml"].replace("</opencv_storage>", f"<a>$base64${'A' * 40}</a>\n</opencv_storage>"))
    else:
        path = tmp_path / "ci"
        path.mkdir()
        (path / "left.yaml").write_text(good["left"] + HANG)
        (path / "right.yaml").write_text(good["right"])
    return path


@pytest.mark.parametrize("where", ["yaml", "xml", "camera_info"])
def test_calib_show_refuses_a_base64_block_in_one_line(tmp_path, good, where):
    """Through the command, in a process of its own: before the fix it never returned (killed after 60 s)."""
    path = _files(tmp_path, good, where)
    try:
        done = subprocess.run([sys.executable, "-m", "runtime.cli", "calib", "show", str(path)], cwd=REPO,
                              capture_output=True, text=True, timeout=60)
    except subprocess.TimeoutExpired:
        pytest.fail(f"p3at calib show {path.name} still runs after 60 s")
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1 and "base64" in lines[0], done.stderr
    assert str(path) in lines[0] and "Traceback" not in done.stderr


def test_features_with_such_a_calibration_is_refused(tmp_path, good):
    path = _files(tmp_path, good, "yaml")
    image = np.zeros((480, 640), np.uint8)
    for name in ("l.png", "r.png"):   # images that read: the calibration is what is refused
        assert cv2.imwrite(str(tmp_path / name), image)
    try:
        done = subprocess.run([sys.executable, "-m", "runtime.cli", "features", str(tmp_path / "l.png"),
                               str(tmp_path / "r.png"), "--calib",
                               str(path), "--out", str(tmp_path / "m.csv")], cwd=REPO, capture_output=True,
                              text=True, timeout=60)
    except subprocess.TimeoutExpired:
        pytest.fail("p3at features --calib still runs after 60 s")
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "base64" in done.stderr and str(path) in done.stderr
    assert not (tmp_path / "m.csv").exists()


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(payload=st.binary(min_size=1, max_size=300), block=st.booleans(), where=st.sampled_from(["yaml", "left"]),
       line=st.integers(0, 5))
def test_any_base64_block_is_refused_with_its_line(tmp_path_factory, good, payload, block, where, line):
    """Any payload, inline or as a block scalar, on any line: refused by the reader itself, never parsed."""
    encoded = base64.b64encode(payload).decode()
    entry = f"junk: !!binary |\n  {encoded}\n" if block else f"junk: !!binary {encoded}\n"
    lines = good[where].splitlines(keepends=True)
    at = min(len(lines), 1 + line)   # after the %YAML header line
    text = "".join(lines[:at]) + entry + "".join(lines[at:])
    folder = tmp_path_factory.mktemp("fuzz")
    if where == "yaml":
        path = folder / "calib.yaml"
        path.write_text(text)
        read = cal.load
    else:
        path = folder
        (folder / "left.yaml").write_text(text)
        (folder / "right.yaml").write_text(good["right"])
        read = camera_info.read_pair
    with pytest.raises(BadFileError, match="base64") as error:
        read(path)
    assert f":{at + 1}: field '(syntax)'" in str(error.value)


def test_calibrations_without_base64_still_read(tmp_path, good):
    for suffix in ("yaml", "xml"):
        (tmp_path / f"c.{suffix}").write_text(good[suffix])
        assert cal.load(tmp_path / f"c.{suffix}").size == default_calibration().size
    folder = tmp_path / "ci"
    folder.mkdir()
    (folder / "left.yaml").write_text(good["left"])
    (folder / "right.yaml").write_text(good["right"])
    assert camera_info.read_pair(folder).size == default_calibration().size
