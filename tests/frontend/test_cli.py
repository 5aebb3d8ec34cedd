"""``p3at features`` through ``runtime.cli.main``: CSV output, JSON summary, calibration, clear errors."""
from __future__ import annotations

import csv
import json

import cv2
import numpy as np
import pytest

from runtime.cli import main
from runtime.commands.features import CSV_COLUMNS

from .conftest import shifted_pair


@pytest.fixture()
def pair_files(tmp_path):
    left, right = shifted_pair((240, 320), 23.4, seed=11)
    paths = tmp_path / "left.png", tmp_path / "right.png"
    for path, image in zip(paths, (left, right), strict=True):
        cv2.imwrite(str(path), image)
    return paths


def read_rows(path):
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    return rows


def test_features_writes_every_match_and_a_json_summary(pair_files, tmp_path, capsys):
    out = tmp_path / "matches.csv"
    status = main(["features", str(pair_files[0]), str(pair_files[1]), "--virtual-head", "--out", str(out), "--json"])
    assert status == 0
    summary = json.loads(capsys.readouterr().out)
    rows = read_rows(out)
    assert tuple(rows[0].keys()) == CSV_COLUMNS
    assert summary["matches"] == len(rows) > 50 and summary["geometry_source"] == "virtual head"
    disparity = np.array([float(r["disparity"]) for r in rows])
    np.testing.assert_allclose(np.median(disparity), 23.4, atol=0.1)
    # base_link x = depth + 0.12 with depth = 520·0.09/23.4 = 2 m; right pixel = left pixel - disparity
    np.testing.assert_allclose(np.median([float(r["x"]) for r in rows]), 2.12, atol=0.01)
    u_left = np.array([float(r["u_left"]) for r in rows])
    u_right = np.array([float(r["u_right"]) for r in rows])
    np.testing.assert_allclose(u_left - u_right, disparity, atol=1e-3)
    assert all(float(r["cov_xx"]) > 0 for r in rows)


def test_camera_frame_and_other_descriptor(pair_files, tmp_path):
    out = tmp_path / "m.csv"
    assert main(["features", *map(str, pair_files), "--descriptor", "orb", "--frame", "camera",
                 "--fx", "400", "--baseline", "0.12", "--out", str(out)]) == 0
    z = np.array([float(r["z"]) for r in read_rows(out)])
    np.testing.assert_allclose(np.median(z), 400 * 0.12 / 23.4, rtol=0.01)


def test_raw_pair_with_a_calibration_file(tmp_path):
    calibration = pytest.importorskip("drivers.videre.calibration")
    from pathlib import Path
    ini = Path(__file__).resolve().parents[2] / "mocks" / "stereo_head" / "data" / "sth_mdcs2_default.ini"
    if not ini.is_file():
        pytest.skip("the virtual head's calibration file is not installed")
    calib = calibration.load(ini)
    # a raw pair whose rectified images show a plane at 2 m: distort a rectified pair back with the inverse maps
    width, height = calib.size
    left, right = shifted_pair((height, width), calib.fx * calib.baseline / 2.0, seed=4)
    raw = []
    for image, K, D, R, P in ((left, calib.K1, calib.D1, calib.R1, calib.P1), (right, calib.K2, calib.D2, calib.R2,
                                                                           calib.P2)):
        u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
        raw_points = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
        rectified = cv2.undistortPoints(raw_points, K, D, R=R, P=P[:, :3]).reshape(height, width, 2)
        raw.append(cv2.remap(image, rectified[..., 0].astype(np.float32), rectified[..., 1].astype(np.float32),
                             cv2.INTER_LINEAR))
    paths = tmp_path / "raw_l.png", tmp_path / "raw_r.png"
    for path, image in zip(paths, raw, strict=True):
        cv2.imwrite(str(path), image)
    out = tmp_path / "m.csv"
    assert main(["features", *map(str, paths), "--calib", str(ini), "--out", str(out), "--frame", "camera"]) == 0
    z = np.array([float(r["z"]) for r in read_rows(out)])
    assert len(z) > 50
    assert np.mean(np.abs(z - 2.0) < 0.05) > 0.9


def test_errors_are_one_line_and_non_zero(pair_files, tmp_path, capsys):
    out = tmp_path / "m.csv"
    assert main(["features", str(tmp_path / "missing.png"), str(pair_files[1]), "--virtual-head",
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("p3at features:") and "missing.png" in err and err.count("\n") == 1
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((10, 10), np.uint8))
    assert main(["features", str(pair_files[0]), str(small), "--virtual-head", "--out", str(out)]) == 2
    assert "small.png" in capsys.readouterr().err
    bad_calib = tmp_path / "head.ini"
    bad_calib.write_text("not a calibration\n")
    assert main(["features", *map(str, pair_files), "--calib", str(bad_calib), "--out", str(out)]) == 2
    assert "head.ini" in capsys.readouterr().err
    assert not out.exists()


def test_without_a_geometry_it_refuses_to_guess_and_otherwise_says_which_it_used(pair_files, tmp_path, capsys):
    out = tmp_path / "m.csv"
    assert main(["features", *map(str, pair_files), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--calib" in err and "--fx" in err and "--virtual-head" in err and err.count("\n") == 1
    assert main(["features", *map(str, pair_files), "--fx", "400", "--out", str(out)]) == 2
    assert "--baseline" in capsys.readouterr().err
    assert main(["features", *map(str, pair_files), "--fx", "400", "--baseline", "0.12", "--frame", "base_link",
                 "--out", str(out)]) == 2
    assert "mount" in capsys.readouterr().err
    assert not out.exists()
    assert main(["features", *map(str, pair_files), "--fx", "400", "--baseline", "0.12", "--out", str(out)]) == 0
    said = capsys.readouterr().out
    rows = read_rows(out)
    assert f"{len(rows)} matches" in said and str(out) in said and "in camera" in said
    assert "fx 400.00 px" in said and "baseline 0.1200 m" in said and "mount" not in said
    assert main(["features", *map(str, pair_files), "--virtual-head", "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "virtual STH-MDCS2" in said and "in base_link" in said and "0.120 0.000 0.500" in said


def test_help(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["features", "--help"])
    assert exit_info.value.code == 0
    assert "--descriptor" in capsys.readouterr().out
