"""``p3at camera`` and ``p3at calib`` through ``runtime.cli.main``."""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from drivers.videre import calibration
from mocks.stereo_head import default_calibration
from mocks.stereo_head.backend import DEFAULT_CALIBRATION_PATH
from runtime.cli import main


def test_camera_info_mock_json(capsys):
    assert main(["camera", "info", "--mock", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert (info["model"], info["stereo"], info["firmware"]) == ("MDS-STH", True, "2.3")
    assert {"name": "gain", "value": 0, "value2": None, "auto": False, "min": 0, "max": 48} in info["controls"]
    assert info["calibration"]["baseline_m"] == 0.09
    assert {(m["width"], m["height"]) for m in info["modes"]} >= {(320, 240), (640, 480), (1280, 960)}


def test_camera_info_text(capsys):
    assert main(["camera", "info", "--mock"]) == 0
    out = capsys.readouterr().out
    assert "Videre Design MDS-STH" in out and "baseline 0.0900 m" in out and "exposure" in out


def test_camera_grab_mock_rectified(tmp_path: Path, capsys):
    assert main(["camera", "grab", "--mock", "--rectify", "--mode", "320x240", "--out", str(tmp_path)]) == 0
    left = cv2.imread(str(tmp_path / "left.png"), cv2.IMREAD_UNCHANGED)
    right = cv2.imread(str(tmp_path / "right.png"), cv2.IMREAD_UNCHANGED)
    assert left.shape == right.shape == (240, 320) and left.std() > 5
    assert "rectified" in capsys.readouterr().out


def test_camera_errors_are_one_line(tmp_path: Path, capsys):
    assert main(["camera", "grab", "--mock", "--mode", "1280x960", "--camera-rate", "30", "--out", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("p3at camera grab: the head has no mode 1280x960 at 30 Hz") and err.count("\n") == 1
    assert main(["camera", "info", "--mock", "--world", str(tmp_path / "absent.json")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("p3at camera info:") and "absent.json" in err
    assert main(["camera", "info", "--mock", "--name", "nobody"]) == 2
    assert "start poses" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


def test_calib_convert_and_show(tmp_path: Path, capsys):
    out = tmp_path / "head.xml"
    assert main(["calib", "convert", str(DEFAULT_CALIBRATION_PATH), str(out)]) == 0
    assert calibration.load(out) == default_calibration()
    capsys.readouterr()
    assert main(["calib", "show", str(out), "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert (shown["fx"], shown["cx"], shown["baseline_m"]) == (520.0, 319.5, 0.09)
    assert np.allclose(shown["head_pose"]["xyz_m"], [0.12, 0.0, 0.5])
    assert main(["calib", "show", str(out)]) == 0
    assert "baseline 0.09000 m" in capsys.readouterr().out


def test_calib_bad_file(tmp_path: Path, capsys):
    bad = tmp_path / "bad.ini"
    bad.write_text("# SVS Engine v 1.0\n")
    assert main(["calib", "convert", str(bad), str(tmp_path / "out.yaml")]) == 2  # a bad file: exit 2
    err = capsys.readouterr().err
    assert "bad.ini:1: field 'version'" in err
    assert not (tmp_path / "out.yaml").exists()
