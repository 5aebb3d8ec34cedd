"""Calibration readers (SVS .ini, OpenCV YAML/XML) against malformed and physically impossible files: one line
naming the file and field, nothing allocated that a header claims, and nothing written that cannot be read."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.errors import BadFileError
from drivers.videre import calibration as cal
from mocks.stereo_head import default_calibration, default_calibration_text

from .memory import read_bounded


@pytest.fixture(scope="module")
def texts(tmp_path_factory) -> dict[str, str]:
    folder = tmp_path_factory.mktemp("good")
    out = {".ini": default_calibration_text()}
    for suffix in (".yaml", ".xml"):
        cal.save(default_calibration(), folder / f"good{suffix}")
        out[suffix] = (folder / f"good{suffix}").read_text()
    return out


def _yaml_matrix(text: str, name: str, data: str, rows: int = 3, cols: int = 3) -> str:
    """Replace the rows, cols and data of matrix ``name`` in an OpenCV YAML text."""
    pattern = re.compile(rf"({name}: !!opencv-matrix\n\s+rows: )\d+(\n\s+cols: )\d+(\n\s+dt: d\n\s+data: )\[[^\]]*\]")
    new, count = pattern.subn(rf"\g<1>{rows}\g<2>{cols}\g<3>[ {data} ]", text)
    assert count == 1
    return new


def _svs_value(text: str, section: str, key: str, value: str) -> str:
    head, rest = text.split(f"[{section}]", 1)
    new, count = re.subn(rf"(?m)^{key} .*$", f"{key} {value} ", rest, count=1)
    assert count == 1
    return f"{head}[{section}]{new}"


def _svs_matrix(text: str, section: str, key: str, rows: list[str]) -> str:
    head, rest = text.split(f"[{section}]", 1)
    lines = rest.split("\n")
    at = lines.index(key)
    lines[at + 1: at + 1 + len(rows)] = [f"  {row} " for row in rows]
    return f"{head}[{section}]" + "\n".join(lines)


YAML_CASES = [
    (lambda t: t.replace("image_width: 640", "image_width: -640"), "image_width", "not an integer in 1..16384"),
    (lambda t: t.replace("image_width: 640", "image_width: 100000000000"), "image_width", "not an integer"),
    (lambda t: t.replace("image_width: 640", 'image_width: "wide"'), "image_width", "not a number"),
    (lambda t: t.replace("image_width: 640", "image_width: 640.5"), "image_width", "not an integer"),
    (lambda t: _yaml_matrix(t, "M1", "0.", 100000, 100000), "M1", "claims 100000 rows"),
    (lambda t: _yaml_matrix(t, "M1", '"a", b, 319.5, 0., 520., 239.5, 0., 0., 1.'), "M1", "not a number"),
    (lambda t: _yaml_matrix(t, "M1", "-520., 0., 319.5, 0., 520., 239.5, 0., 0., 1."), "M1", "focal lengths"),
    (lambda t: _yaml_matrix(t, "M1", "520., 0., 3190.5, 0., 520., 239.5, 0., 0., 1."), "M1", "principal point"),
    (lambda t: _yaml_matrix(t, "M1", "520., 0., 319.5, 0., 520., 239.5, 0., 0., 1.", 4, 3), "M1", "holds 9 numbers"),
    (lambda t: _yaml_matrix(t, "R1", ", ".join(["0."] * 9)), "R1", "not a rotation matrix"),
    (lambda t: _yaml_matrix(t, "R", "1., 0., 0., 0., 1., 0., 0., 0., -1."), "R", "not a rotation matrix"),
    (lambda t: _yaml_matrix(t, "P2", "520., 0., 319.5, 46.8, 0., 520., 239.5, 0., 0., 0., 1., 0.", 3, 4), "P2",
     "baseline -0.09"),
    (lambda t: _yaml_matrix(t, "P2", "520., 0., 319.5, .nan, 0., 520., 239.5, 0., 0., 0., 1., 0.", 3, 4), "P2",
     "non-finite"),
]


@pytest.mark.parametrize("case", range(len(YAML_CASES)))
def test_bad_opencv_yaml_files_name_the_file_and_field(tmp_path, texts, case) -> None:
    edit, field, problem = YAML_CASES[case]
    path = tmp_path / "bad.yaml"
    path.write_text(edit(texts[".yaml"]))
    with pytest.raises(BadFileError) as info:
        read_bounded(lambda: cal.load(path), ())
    message = str(info.value)
    assert message.startswith(str(path)) and f"field '{field}'" in message and problem in message, message
    assert "\n" not in message


def _xml_matrix(text: str, name: str, rows: int, cols: int, data: str) -> str:
    pattern = re.compile(rf'(<{name} type_id="opencv-matrix">\s*<rows>)\d+(</rows>\s*<cols>)\d+(</cols>\s*'
                         rf'<dt>d</dt>\s*<data>)[^<]*(</data>)')
    new, count = pattern.subn(rf"\g<1>{rows}\g<2>{cols}\g<3>{data}\g<4>", text)
    assert count == 1
    return new


XML_CASES = [
    (lambda t: t.replace("<image_width>640", "<image_width>-640"), "image_width", "not an integer"),
    (lambda t: t.replace("<image_width>640", "<image_width>wide"), "image_width", "not a number"),
    (lambda t: _xml_matrix(t, "M1", 100000, 100000, "0."), "M1", "claims 100000 rows"),
    (lambda t: _xml_matrix(t, "M1", 3, 3, "a b 319.5 0. 520. 239.5 0. 0. 1."), "M1", "not a number"),
    (lambda t: _xml_matrix(t, "R1", 3, 3, " ".join(["0."] * 9)), "R1", "not a rotation matrix"),
]


@pytest.mark.parametrize("case", range(len(XML_CASES)))
def test_bad_opencv_xml_files_name_the_file_and_field(tmp_path, texts, case) -> None:
    edit, field, problem = XML_CASES[case]
    path = tmp_path / "bad.xml"
    path.write_text(edit(texts[".xml"]))
    with pytest.raises(BadFileError) as info:
        read_bounded(lambda: cal.load(path), ())
    message = str(info.value)
    assert message.startswith(str(path)) and f"field '{field}'" in message and problem in message, message


SVS_CASES = [
    (lambda t: _svs_value(t, "left camera", "pwidth", "-640"), "left camera.pwidth", "not an integer"),
    (lambda t: _svs_value(t, "left camera", "pwidth", "1e11"), "left camera.pwidth", "not an integer"),
    (lambda t: _svs_value(t, "left camera", "pwidth", "wide"), "left camera.pwidth", "not a number"),
    (lambda t: _svs_value(t, "left camera", "pwidth", "640 480"), "left camera.pwidth", "not a number"),
    (lambda t: _svs_value(t, "left camera", "f", "0"), "left camera.f", "focal length must be positive"),
    (lambda t: _svs_value(t, "left camera", "kappa1", "1e9"), "left camera.kappa1", "distortion"),
    (lambda t: _svs_value(t, "external", "Tx", "0"), "external.Tx", "|T| = 0"),
    (lambda t: _svs_matrix(t, "left camera", "rect", ["0 0 0"] * 3), "left camera.rect", "not a rotation"),
    (lambda t: _svs_matrix(t, "right camera", "proj", ["5.2e2 0 3.195e2 4.68e4", "0 5.2e2 2.395e2 0", "0 0 1 0"]),
     "right camera.proj", "baseline -0.09"),
    (lambda t: _svs_value(t, "global", "GTx", "1e9"), "global.GTx", "head pose"),
]


@pytest.mark.parametrize("case", range(len(SVS_CASES)))
def test_bad_svs_files_name_the_file_and_field(tmp_path, texts, case) -> None:
    edit, field, problem = SVS_CASES[case]
    path = tmp_path / "bad.ini"
    path.write_text(edit(texts[".ini"]), encoding="latin-1")
    with pytest.raises(BadFileError) as info:
        cal.load(path)
    message = str(info.value)
    assert message.startswith(f"{path}:") and f"field '{field}'" in message and problem in message, message


def test_oversized_files_are_refused_before_parsing(tmp_path, texts) -> None:
    for suffix in (".ini", ".yaml"):
        path = tmp_path / f"big{suffix}"
        path.write_text(texts[suffix] + "#" * cal.MAX_FILE_BYTES)
        with pytest.raises(BadFileError, match="a calibration file has at most"):
            cal.load(path)


@pytest.mark.parametrize("suffix", [".ini", ".yaml", ".xml"])
def test_what_load_rejects_is_never_written(tmp_path, suffix) -> None:
    from dataclasses import replace
    bad = replace(default_calibration(), size=(-640, 480))
    with pytest.raises(BadFileError, match="refusing to write: field 'size.width'"):
        cal.save(bad, tmp_path / f"out{suffix}")
    assert not list(tmp_path.iterdir())


# ------------------------------------------------------------------------------------------------ fuzzing
def _roundtrip_or_clean_error(tmp_path: Path, suffix: str, data: bytes) -> None:
    """Load the bytes; if accepted, every format writes it and reads it back (convert never writes what show
    rejects)."""
    path = tmp_path / f"fuzz{suffix}"
    path.write_bytes(data)
    calib = read_bounded(lambda: cal.load(path), BadFileError)
    if calib is None:
        return
    for out in (".ini", ".yaml", ".xml"):
        cal.save(calib, tmp_path / f"out{out}")
        again = cal.load(tmp_path / f"out{out}")
        assert again.size == calib.size and np.isclose(again.baseline, calib.baseline)


@settings(max_examples=80, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.sampled_from([".ini", ".yaml", ".xml"]), st.data())
def test_fuzz_corrupted_calibrations(tmp_path, texts, suffix, data) -> None:
    raw = bytearray(texts[suffix].encode("latin-1"))
    at = data.draw(st.integers(0, len(raw) - 1))
    junk = data.draw(st.binary(min_size=1, max_size=12) | st.text("0123456789.-+eE x[]:,\n<>/", min_size=1,
                                                                   max_size=12).map(str.encode))
    raw[at: at + len(junk)] = junk
    _roundtrip_or_clean_error(tmp_path, suffix, bytes(raw))


def test_a_value_that_is_not_utf8_is_one_clean_error(tmp_path, texts) -> None:
    """Found by the fuzz test above (a matrix's dt byte replaced by 0x80): cv2's FileNode.string() raised
    UnicodeDecodeError through load()."""
    path = tmp_path / "calib.yaml"
    raw = texts[".yaml"].encode("latin-1")
    assert b"dt: d\n" in raw
    path.write_bytes(raw.replace(b"dt: d\n", b"dt: \x80\n", 1))
    with pytest.raises(BadFileError, match=r"calib\.yaml:\?: field '\(text\)': not UTF-8 text"):
        cal.load(path)


numbers = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**12, 10**12),
                    st.sampled_from(["'x'", "[1, 2]", "{}", ".nan", "-.inf", ""]))


@settings(max_examples=80, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.sampled_from(["M1", "M2", "R", "R1", "R2", "P1", "P2", "D1"]), st.lists(numbers, max_size=14),
       st.integers(-3, 20), st.integers(-3, 20), numbers)
def test_fuzz_opencv_values(tmp_path, texts, name, values, rows, cols, width) -> None:
    text = texts[".yaml"].replace("image_width: 640", f"image_width: {width}")
    pattern = re.compile(rf"({name}: !!opencv-matrix\n\s+rows: )\d+(\n\s+cols: )\d+(\n\s+dt: d\n\s+data: )\[[^\]]*\]")
    text = pattern.sub(lambda m: f"{m.group(1)}{rows}{m.group(2)}{cols}{m.group(3)}[ "
                       + ", ".join(map(str, values)) + " ]", text)
    _roundtrip_or_clean_error(tmp_path, ".yaml", text.encode())
