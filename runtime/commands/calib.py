"""``p3at calib convert|show``: stereo calibration files (SVS ``.ini``, OpenCV ``.yaml/.yml/.xml``)."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

from drivers.errors import DriverError
from drivers.videre import calibration


def register(subparsers: argparse._SubParsersAction) -> None:
    calib = subparsers.add_parser("calib", help="stereo calibration files: convert, show",
                                  description="Convert between SVS parameter files (.ini) and OpenCV stereo "
                                              "calibration files (.yaml/.yml/.xml), or show one.")
    sub = calib.add_subparsers(dest="calib_command", metavar="ACTION", required=True)
    convert = sub.add_parser("convert", help="IN -> OUT, formats by suffix",
                             description="Read IN and write OUT (atomically), each format chosen by its suffix: "
                                         ".ini (SVS; translations in mm) or .yaml/.yml/.xml (OpenCV; metres).")
    convert.add_argument("input", type=Path, metavar="IN")
    convert.add_argument("output", type=Path, metavar="OUT")
    convert.set_defaults(handler=run_convert)
    show = sub.add_parser("show", help="print a calibration's numbers",
                          description="Print size, rectified intrinsics, baseline, distortion, R, T and head pose.")
    show.add_argument("file", type=Path, metavar="FILE")
    show.add_argument("--json", action="store_true", help="print JSON")
    show.set_defaults(handler=run_show)


def run_convert(args: argparse.Namespace) -> int:
    try:
        calib = calibration.load(args.input)
        calibration.save(calib, args.output)
    except (DriverError, ValueError, OSError) as exc:
        print(f"p3at calib convert: {exc}", file=sys.stderr)
        return 1
    print(f"{args.input} -> {args.output} ({calib.size[0]}x{calib.size[1]}, baseline {calib.baseline * 1000:.1f} mm)")
    return 0


def summary(calib: calibration.StereoCalibration) -> dict:
    return {
        "size": list(calib.size), "fx": calib.fx, "fy": calib.fy, "cx": calib.cx, "cy": calib.cy,
        "baseline_m": calib.baseline, "K1": calib.K1.tolist(), "D1": calib.D1.tolist(), "K2": calib.K2.tolist(),
        "D2": calib.D2.tolist(), "R": calib.R.tolist(), "T_m": calib.T.tolist(), "Q": calib.Q.tolist(),
        "head_pose": {"xyz_m": calib.head_pose[:3].tolist(), "roll_pitch_yaw_rad": calib.head_pose[3:].tolist()},
    }


def run_show(args: argparse.Namespace) -> int:
    try:
        calib = calibration.load(args.file)
    except (DriverError, ValueError, OSError) as exc:
        print(f"p3at calib show: {exc}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(summary(calib), indent=2))
        return 0
    fmt = lambda a: np.array2string(np.asarray(a), precision=5, suppress_small=True)  # noqa: E731
    print(f"{args.file}: {calib.size[0]}x{calib.size[1]}")
    print(f"rectified: fx {calib.fx:.3f}  fy {calib.fy:.3f}  cx {calib.cx:.3f}  cy {calib.cy:.3f}  "
          f"baseline {calib.baseline:.5f} m")
    print(f"left  K {fmt(calib.K1[[0, 1, 0, 1], [0, 1, 2, 2]])} (fx fy cx cy)  D {fmt(calib.D1)}")
    print(f"right K {fmt(calib.K2[[0, 1, 0, 1], [0, 1, 2, 2]])} (fx fy cx cy)  D {fmt(calib.D2)}")
    print(f"T {fmt(calib.T)} m   R (Rodrigues) {fmt(cv2.Rodrigues(calib.R)[0].ravel())} rad")
    print(f"head pose on the robot: xyz {fmt(calib.head_pose[:3])} m  roll/pitch/yaw {fmt(calib.head_pose[3:])} rad")
    return 0
