"""ROS camera_info YAML: round trip with the stereo calibration type, standard YAML, validation on read, CLI."""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from drivers.errors import BadFileError
from drivers.videre import calibration, camera_info
from mocks.stereo_head import default_calibration
from runtime.cli import main

_fuzz_settings = settings(max_examples=40, suppress_health_check=[HealthCheck.function_scoped_fixture])


@st.composite
def calibrations(draw) -> calibration.StereoCalibration:
    width = draw(st.integers(160, 2048))
    height = draw(st.integers(120, 1536))
    K = []
    f0 = draw(st.floats(300.0, 3000.0))
    for _ in range(2):  # two cameras of one head: alike focal lengths, principal points near the centre
        f = f0 * draw(st.floats(0.98, 1.02))
        K.append(np.array([[f, 0.0, draw(st.floats(0.45, 0.55)) * width],
                           [0.0, f * draw(st.floats(0.99, 1.01)), draw(st.floats(0.45, 0.55)) * height],
                           [0.0, 0.0, 1.0]]))
    D = [np.array([draw(st.floats(-0.3, 0.3)), draw(st.floats(-0.1, 0.1)), draw(st.floats(-1e-3, 1e-3)),
                   draw(st.floats(-1e-3, 1e-3)), draw(st.floats(-0.01, 0.01))]) for _ in range(2)]
    rvec = np.array([draw(st.floats(-0.02, 0.02)) for _ in range(3)])
    import cv2

    R = cv2.Rodrigues(rvec)[0]
    T = np.array([-draw(st.floats(0.03, 0.5)), draw(st.floats(-0.005, 0.005)), draw(st.floats(-0.005, 0.005))])
    calib = calibration.from_intrinsics((width, height), K[0], D[0], K[1], D[1], R, T)
    try:  # strong distortion on a small image can rectify to what no head has: the project refuses those
        calibration.check_calibration(calib, "generated")
    except BadFileError:
        assume(False)
    return calib


@_fuzz_settings
@given(calib=calibrations())
def test_camera_info_round_trip_keeps_every_number_but_the_head_pose(tmp_path, calib):
    folder = tmp_path / "ros"
    paths = camera_info.write_pair(calib, folder)
    assert [p.name for p in paths] == ["left.yaml", "right.yaml"]
    back = camera_info.read_pair(folder)
    for name in ("K1", "D1", "K2", "D2", "R1", "R2", "P1", "P2"):  # written and read exactly
        np.testing.assert_array_equal(getattr(back, name), getattr(calib, name), err_msg=name)
    # R and T are rebuilt from the rectification and the projections. R is exactly the rotation the files carry
    # (R2ᵀ R1); that differs from the calibration's own R by what OpenCV's stereoRectify resolves when it makes
    # R1 and R2 (up to 9.3e-6 over 2,000 random heads: a 1e-6 rad twist can come back as identity)
    np.testing.assert_allclose(back.R, calib.R2.T @ calib.R1, rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.R, calib.R, rtol=0, atol=1e-4)
    np.testing.assert_allclose(back.T, calib.T, rtol=1e-6, atol=1e-8)
    assert back.size == calib.size and np.all(back.head_pose == 0)


@_fuzz_settings
@given(calib=calibrations())
def test_the_files_are_the_camera_info_yaml_any_yaml_reader_reads(tmp_path, calib):
    camera_info.write_pair(calib, tmp_path, "head")
    for side, K, D, R, P in (("left", calib.K1, calib.D1, calib.R1, calib.P1),
                             ("right", calib.K2, calib.D2, calib.R2, calib.P2)):
        doc = yaml.safe_load((tmp_path / f"{side}.yaml").read_text())
        assert set(doc) == {"image_width", "image_height", "camera_name", "camera_matrix", "distortion_model",
                            "distortion_coefficients", "rectification_matrix", "projection_matrix"}
        assert (doc["image_width"], doc["image_height"]) == calib.size and doc["camera_name"] == f"head/{side}"
        assert doc["distortion_model"] == "plumb_bob"
        for key, value, shape in (("camera_matrix", K, (3, 3)), ("distortion_coefficients", D, (1, 5)),
                                  ("rectification_matrix", R, (3, 3)), ("projection_matrix", P, (3, 4))):
            assert (doc[key]["rows"], doc[key]["cols"]) == shape
            np.testing.assert_array_equal(np.reshape(doc[key]["data"], shape), np.reshape(value, shape))
    right = yaml.safe_load((tmp_path / "right.yaml").read_text())["projection_matrix"]["data"]
    assert right[3] == pytest.approx(-calib.fx * calib.baseline)  # P[0][3] = -fx' * baseline


def test_a_file_camera_calibration_wrote_reads_as_the_same_head(tmp_path):
    """Written in camera_calibration's layout (multi-line flow lists, integers, 4 distortion terms)."""
    left = """image_width: 640
image_height: 480
camera_name: narrow_stereo/left
camera_matrix:
  rows: 3
  cols: 3
  data: [520., 0, 319.5,
         0, 520, 239.5,
         0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 4
  data: [0, 0, 0, 0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [520, 0, 319.5, 0, 0, 520, 239.5, 0, 0, 0, 1, 0]
"""
    (tmp_path / "left.yaml").write_text(left)
    (tmp_path / "right.yaml").write_text(left.replace("/left", "/right").replace("319.5, 0, 0,", "319.5, -46.8, 0,"))
    calib = camera_info.read_pair(tmp_path)
    assert calib.baseline == pytest.approx(0.09) and calib.fx == 520.0 and calib.size == (640, 480)
    np.testing.assert_allclose(calib.T, [-0.09, 0.0, 0.0])


def _valid_text() -> str:
    return camera_info.camera_info_text(default_calibration(), "left")


@settings(max_examples=300, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.integers(0, 900), at=st.integers(0, 900), patch=st.sampled_from(
    ["", "x", "-", "1e400", "nan", "[", "]", "{a: 1}", "999999999", "\n  rows: 100000", ": :", "\x00", "ü",
     "[1, [2, [3, [4]]]]", "- 1\n- 2", "!!python/object:os.system", "&a [*a]"]))
def test_bad_camera_info_gives_a_clean_error_or_a_valid_camera(tmp_path, cut, at, patch):
    text = _valid_text()
    text = text[:cut] + text[cut:] if cut > len(text) else text[:at] + patch + text[at + len(patch) // 2:]
    path = tmp_path / "left.yaml"
    path.write_bytes(text.encode("utf-8"))
    try:
        camera = camera_info.read_camera(path)
    except BadFileError as e:
        assert str(path) in str(e) and "field" in str(e)
        return
    assert camera["K"].shape == (3, 3) and camera["P"].shape == (3, 4) and camera["D"].shape == (5,)
    assert all(np.all(np.isfinite(camera[k])) for k in "KDRP")


def test_read_refuses_what_no_head_has(tmp_path):
    calib = default_calibration()
    camera_info.write_pair(calib, tmp_path)
    right = tmp_path / "right.yaml"
    good = right.read_text()
    for old, new, field in (("-46.8", "46.8", "baseline"), ("image_width: 640", "image_width: 641", "image_width"),
                            ("plumb_bob", "equidistant", "distortion_model"),
                            ("rows: 3\n  cols: 4", "rows: 30000\n  cols: 4", "projection_matrix.rows")):
        right.write_text(good.replace(old, new, 1))
        with pytest.raises(BadFileError, match=field):
            camera_info.read_pair(tmp_path)
    right.write_text("x" * (camera_info.MAX_FILE_BYTES + 1))
    with pytest.raises(BadFileError, match="at most"):
        camera_info.read_pair(tmp_path)


def test_calib_convert_writes_and_reads_camera_info(tmp_path: Path, capsys):
    svs = tmp_path / "head.ini"
    calibration.save(default_calibration(), svs)
    out = tmp_path / "ros"
    assert main(["calib", "convert", str(svs), str(out)]) == 0
    printed = capsys.readouterr().out
    assert str(out / "left.yaml") in printed and str(out / "right.yaml") in printed
    assert "head's pose" in printed  # the default head sits on the robot: the note says it was not written
    back = tmp_path / "back.yaml"
    assert main(["calib", "convert", str(out), str(back)]) == 0
    assert calibration.load(back) == dataclasses.replace(default_calibration(), head_pose=np.zeros(6))
    capsys.readouterr()
    assert main(["calib", "show", str(out), "--json"]) == 0
    assert math.isclose(__import__("json").loads(capsys.readouterr().out)["baseline_m"], 0.09)
    assert main(["calib", "convert", str(out / "left.yaml"), str(tmp_path / "x.ini")]) == 2
    err = capsys.readouterr().err
    assert "holds one camera" in err and len(err.strip().splitlines()) == 1
