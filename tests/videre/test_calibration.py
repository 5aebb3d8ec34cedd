"""SVS and OpenCV calibration files: round trips, geometry, and the promised errors."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.errors import BadFileError
from drivers.videre import calibration as cal
from mocks.stereo_head import default_calibration, default_calibration_text


def test_default_head_matches_the_shared_geometry():
    c = default_calibration()
    assert (c.fx, c.fy, c.cx, c.cy) == (520.0, 520.0, 319.5, 239.5)
    assert c.baseline == pytest.approx(0.09)
    assert c.size == (640, 480)
    assert c.D1[0] == pytest.approx(-0.05)
    # a left-camera point (X, Y, Z) maps to base_link as (Z + 0.12, -X + 0.045, -Y + 0.50)
    X, Y, Z = 0.3, -0.2, 2.0
    p = c.left_camera_to_base() @ np.array([X, Y, Z, 1.0])
    assert p[:3] == pytest.approx([Z + 0.12, -X + 0.045, -Y + 0.50])


def test_q_reprojects_disparity_to_depth():
    c = default_calibration()
    u, v, d = 400.0, 300.0, 520.0 * 0.09 / 3.0  # 3 m away
    X, Y, Z, W = c.Q @ np.array([u, v, d, 1.0])
    assert Z / W == pytest.approx(3.0)
    assert X / W == pytest.approx((u - c.cx) * 3.0 / c.fx)


def _random_calibration(seed: int) -> cal.StereoCalibration:
    rng = np.random.default_rng(seed)
    f = rng.uniform(400, 900)
    K1 = np.array([[f, 0, rng.uniform(300, 340)], [0, f * rng.uniform(0.98, 1.02), rng.uniform(220, 260)], [0, 0, 1]])
    K2 = K1 + np.diag([rng.uniform(-3, 3), rng.uniform(-3, 3), 0])
    D1, D2 = rng.normal(0, 0.02, 5), rng.normal(0, 0.02, 5)
    R, _ = cv2.Rodrigues(rng.normal(0, 0.01, 3))
    T = np.array([-rng.uniform(0.05, 0.2), rng.normal(0, 0.002), rng.normal(0, 0.002)])
    pose = np.concatenate([rng.uniform(-0.5, 0.5, 3), rng.normal(0, 0.05, 3)])
    return cal.from_intrinsics((640, 480), K1, D1, K2, D2, R, T, pose)


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 10_000))
def test_svs_round_trip(seed):
    c = _random_calibration(seed)
    again = cal.parse_svs(cal.format_svs(c))
    assert again == c


@pytest.mark.parametrize("suffix", [".yaml", ".xml", ".yml"])
def test_svs_to_opencv_and_back(tmp_path: Path, suffix):
    svs = tmp_path / "head.ini"
    svs.write_text(default_calibration_text())
    original = cal.load(svs)
    cal.save(original, tmp_path / f"head{suffix}")
    via_opencv = cal.load(tmp_path / f"head{suffix}")
    assert via_opencv == original
    cal.save(via_opencv, tmp_path / "back.ini")
    assert cal.load(tmp_path / "back.ini") == original


def test_opencv_without_rectification_gets_it_computed(tmp_path: Path):
    c = _random_calibration(5)
    path = tmp_path / "minimal.yaml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    for name, value in (("M1", c.K1), ("D1", c.D1), ("M2", c.K2), ("D2", c.D2), ("R", c.R), ("T", c.T)):
        fs.write(name, np.asarray(value, float))
    fs.release()
    loaded = cal.load(path)
    assert np.allclose(loaded.P1, c.P1) and np.allclose(loaded.R2, c.R2)
    assert loaded.baseline == pytest.approx(np.linalg.norm(c.T), rel=1e-6)


def test_scaled_keeps_pixel_centres():
    c = default_calibration()
    half = c.scaled(320, 240)
    assert (half.fx, half.cx, half.cy) == (260.0, 159.5, 119.5)
    assert half.baseline == pytest.approx(0.09)
    double = c.scaled(1280, 960)
    assert (double.fx, double.cx) == (1040.0, 639.5)


def test_rectification_of_undistorted_point_lands_on_same_row():
    c = default_calibration()
    point = np.array([0.4, -0.3, 2.5])  # raw-left camera frame
    left = cv2.projectPoints(point[None], np.zeros(3), np.zeros(3), c.K1, c.D1)[0].reshape(2)
    right = cv2.projectPoints(point[None], cv2.Rodrigues(c.R)[0], c.T, c.K2, c.D2)[0].reshape(2)
    rl = cv2.undistortPoints(left.reshape(1, 1, 2), c.K1, c.D1, R=c.R1, P=c.P1).reshape(2)
    rr = cv2.undistortPoints(right.reshape(1, 1, 2), c.K2, c.D2, R=c.R2, P=c.P2).reshape(2)
    assert abs(rl[1] - rr[1]) < 1e-3
    assert rl[0] - rr[0] == pytest.approx(c.fx * c.baseline / 2.5, rel=1e-3)
    (m1, m2), _ = c.rectify_maps
    assert m1.shape == (480, 640, 2)


# ---------------------------------------------------------------- malformed files

def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "bad.ini"
    path.write_text(text)
    return path


def test_old_svs_version_is_rejected(tmp_path: Path):
    text = default_calibration_text().replace("# SVS Engine v 4.4d", "# SVS Engine v 2.0", 1)
    with pytest.raises(BadFileError, match=r"bad\.ini:1: field 'version'.*older than 2\.1"):
        cal.load(_write(tmp_path, text))


def test_not_an_svs_file(tmp_path: Path):
    with pytest.raises(BadFileError, match=r"bad\.ini:1: field 'header'"):
        cal.load(_write(tmp_path, "hello\n"))


def test_bad_number_names_line_and_field(tmp_path: Path):
    lines = default_calibration_text().splitlines()
    index = next(i for i, ln in enumerate(lines) if ln.startswith("Cx ")) + 0
    lines[index] = "Cx three-hundred"
    with pytest.raises(BadFileError, match=rf"bad\.ini:{index + 1}: field 'left camera\.Cx': not a number"):
        cal.load(_write(tmp_path, "\n".join(lines)))


def test_short_proj_row_names_line(tmp_path: Path):
    lines = default_calibration_text().splitlines()
    index = next(i for i, ln in enumerate(lines) if ln == "proj")
    lines[index + 2] = "  1 2 3"
    with pytest.raises(BadFileError, match=rf"bad\.ini:{index + 3}: field 'left camera\.proj': row 2 has 3"):
        cal.load(_write(tmp_path, "\n".join(lines)))


def test_missing_field_names_its_section(tmp_path: Path):
    lines = [ln for ln in default_calibration_text().splitlines() if not ln.startswith("Tx ")]
    with pytest.raises(BadFileError, match=r"bad\.ini:\d+: field 'external\.Tx': missing"):
        cal.load(_write(tmp_path, "\n".join(lines)))


def test_missing_section(tmp_path: Path):
    text = default_calibration_text().replace("[right camera]", "[other camera]")
    with pytest.raises(BadFileError, match=r"field '\[right camera\]': section missing"):
        cal.load(_write(tmp_path, text))


def test_malformed_opencv_files(tmp_path: Path):
    good = tmp_path / "good.yaml"
    cal.save(default_calibration(), good)
    text = good.read_text()
    missing = tmp_path / "missing.yaml"
    missing.write_text(text.replace("M2:", "M9:"))
    with pytest.raises(BadFileError, match=r"missing\.yaml:\?: field 'M2': missing"):
        cal.load(missing)
    broken = tmp_path / "broken.yaml"
    broken.write_text(text[: len(text) // 2] + "\n  : : [\n")
    with pytest.raises(BadFileError, match=r"broken\.yaml:\d+: field '\(syntax\)'"):
        cal.load(broken)
    with pytest.raises(BadFileError, match="unknown calibration format"):
        cal.load(tmp_path / "x.txt")
    with pytest.raises(BadFileError, match="no such file"):
        cal.load(tmp_path / "absent.yaml")


def test_writes_are_atomic_and_leave_no_temporaries(tmp_path: Path):
    target = tmp_path / "head.ini"
    target.write_text("old contents")
    cal.save(default_calibration(), target)
    assert cal.load(target) == default_calibration()
    assert [p.name for p in tmp_path.iterdir()] == ["head.ini"]


_svs_lines = st.sampled_from(default_calibration_text().splitlines())


@settings(max_examples=150, deadline=None)
@given(st.lists(st.one_of(_svs_lines, st.text(max_size=40)), max_size=60), st.booleans())
def test_svs_parser_never_fails_with_anything_but_bad_file(lines, with_header):
    text = "\n".join((["# SVS Engine v 4.4d"] if with_header else []) + lines)
    try:
        calib = cal.parse_svs(text, "fuzz.ini")
    except BadFileError as exc:
        assert str(exc).startswith("fuzz.ini:")
    else:
        assert np.isfinite(calib.baseline)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 1400), st.text(alphabet="0123456789.-eE x[]#\n", min_size=1, max_size=8))
def test_svs_parser_survives_corruption_of_the_default_file(position, junk):
    text = default_calibration_text()
    corrupted = text[:position] + junk + text[position + len(junk):]
    try:
        cal.parse_svs(corrupted, "corrupt.ini")
    except BadFileError as exc:
        assert str(exc).startswith("corrupt.ini:")


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000))
def test_head_pose_is_the_midpoint_of_the_optical_centres(seed):
    c = _random_calibration(seed)
    left_to_base = c.left_camera_to_base(rectified=False)
    left_centre = left_to_base[:3, 3]
    right_centre = (left_to_base @ np.append(-c.R.T @ c.T, 1.0))[:3]
    assert (left_centre + right_centre) / 2 == pytest.approx(c.head_pose[:3], abs=1e-9)
    # the rectified frame shares the left optical centre and differs only by R1
    rectified = c.left_camera_to_base(rectified=True)
    assert rectified[:3, 3] == pytest.approx(left_centre)
    assert rectified[:3, :3] @ c.R1 == pytest.approx(left_to_base[:3, :3])


def test_svs_keeps_sections_it_does_not_interpret_and_sizes_follow_scaling():
    text = default_calibration_text().replace("[external]", "[stereo]\ncorrxsize 11 \nndisp 48 \n\n[external]")
    calib = cal.parse_svs(text)
    assert calib.extras["stereo"] == {"corrxsize": "11", "ndisp": "48"}
    again = cal.format_svs(calib.scaled(1280, 960))
    assert "[stereo]\ncorrxsize 11 \nndisp 48 " in again
    assert "\nwidth 1280 \n" in again and "\npwidth 1280 \n" in again and "\ndecimation 1 \n" in again
