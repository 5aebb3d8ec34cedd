"""Calibration files that give a key twice (session 44, A). OpenCV's FileStorage keeps both and ``getNode``
returns the first in silence: a camera_info ``left.yaml`` ending in a second ``image_height: 240`` was read as 480
(PyYAML, as ROS's Python tools use, takes the last), and an OpenCV YAML or XML file with two ``M1`` or a matrix with
two ``rows`` the same. Two readers of one file disagreeing is refused: one line naming the file and key, exit 2."""
from __future__ import annotations

import re

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.errors import BadFileError
from drivers.videre import calibration as cal
from drivers.videre import camera_info
from mocks.stereo_head import default_calibration
from runtime.cli import main
from tests.hardening.calibration_texts import good_calibration_texts

# a "key: value" line whose value is on the line (not the head of a matrix mapping)
SCALAR = re.compile(r"^(\s*)(\w+):\s+(?!!!opencv-matrix)\S")


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> dict[str, str]:
    return good_calibration_texts(tmp_path_factory.mktemp("good"))


def _key_of(lines: list[str], i: int) -> str:
    """The dotted name of line i's key: ``image_width``, or ``M1.rows`` under an unindented ``M1:`` line."""
    indent, key = SCALAR.match(lines[i]).group(1, 2)
    if not indent:
        return key
    parent = next(ln for ln in reversed(lines[:i]) if not ln[:1].isspace())
    return f"{parent.split(':')[0]}.{key}"


def _read(tmp_path, good, where: str, text: str):
    if where == "yaml":
        path = tmp_path / "calib.yaml"
        path.write_text(text)
        return path, cal.load
    folder = tmp_path / "ci"
    folder.mkdir(exist_ok=True)
    (folder / "left.yaml").write_text(text)
    (folder / "right.yaml").write_text(good["right"])
    return folder, camera_info.read_pair


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data(), where=st.sampled_from(["yaml", "left"]))
def test_any_key_given_twice_is_refused_by_name(tmp_path_factory, good, data, where):
    """Any scalar key of an OpenCV YAML file or a camera_info file, top level or inside a matrix, repeated on the
    next line with the same value: refused, naming the key."""
    lines = good[where].splitlines(keepends=True)
    candidates = [i for i, ln in enumerate(lines) if SCALAR.match(ln) and ("[" not in ln or "]" in ln)]  # whole
    i = data.draw(st.sampled_from(candidates), label="line")
    text = "".join(lines[: i + 1] + [lines[i]] + lines[i + 1:])
    path, read = _read(tmp_path_factory.mktemp("twice"), good, where, text)
    with pytest.raises(BadFileError, match="given twice") as error:
        read(path)
    assert f"field '{_key_of(lines, i)}'" in str(error.value)


def test_a_second_value_is_not_read_in_silence(tmp_path, good, capsys):
    """The case that was read wrong: the first value taken, the second ignored, exit 0."""
    path, _ = _read(tmp_path, good, "left", good["left"] + "image_height: 240\n")
    assert main(["calib", "show", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "field 'image_height': given twice" in err[0] and str(path) in err[0]


def test_an_xml_element_given_twice_is_refused(tmp_path, good):
    path = tmp_path / "calib.xml"
    path.write_text(good["xml"].replace("</opencv_storage>", "<image_width>320</image_width>\n</opencv_storage>"))
    with pytest.raises(BadFileError, match="field 'image_width': given twice"):
        cal.load(path)


def test_files_without_repeats_read_as_before(tmp_path, good):
    for suffix in ("yaml", "xml"):
        (tmp_path / f"c.{suffix}").write_text(good[suffix])
        assert cal.load(tmp_path / f"c.{suffix}").size == default_calibration().size
    path, read = _read(tmp_path, good, "left", good["left"])
    assert read(path).size == default_calibration().size


@pytest.mark.parametrize(("value", "shown"), [("99999999999999999999999999", "a number past 2^62"), ("0", "0"),
                                              ("-640", "-640"), ("16385", "16385")])
def test_an_image_size_no_head_has_is_blamed_on_its_own_file(tmp_path, good, value, shown):
    """A left.yaml whose width OpenCV reads as 2^63 (26 digits) was reported as 'right.yaml: field image_width:
    (640, 480) differs from the left camera's (9223372036854775808, 480)': the right file blamed, a number the file
    does not hold."""
    path, read = _read(tmp_path, good, "left", re.sub(r"(?m)^image_width: \d+", f"image_width: {value}",
                                                      good["left"]))
    with pytest.raises(BadFileError) as error:
        read(path)
    assert "left.yaml:1: field 'image_width': " + shown in str(error.value), str(error.value)
