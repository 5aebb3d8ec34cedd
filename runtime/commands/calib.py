"""``p3at calib convert|show``: stereo calibration files (SVS ``.ini``, OpenCV ``.yaml/.yml/.xml``, ROS camera_info).

A ROS camera_info calibration is a folder holding ``left.yaml`` and ``right.yaml`` (see
``drivers.videre.camera_info``); a path without a suffix, or an existing folder, names one.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

from drivers.errors import BadFileError, DriverError
from drivers.videre import calibration, camera_info
from runtime.commands.options import OutputPathError, check_output_apart, check_output_file, check_output_folder
from runtime.json_output import json_text


def register(subparsers: argparse._SubParsersAction) -> None:
    calib = subparsers.add_parser("calib", help="stereo calibration files: convert, show",
                                  description="Convert between SVS parameter files (.ini), OpenCV stereo "
                                              "calibration files (.yaml/.yml/.xml) and ROS camera_info YAML (a "
                                              "folder holding left.yaml and right.yaml), or show one.")
    sub = calib.add_subparsers(dest="calib_command", metavar="ACTION", required=True)
    convert = sub.add_parser("convert", help="IN -> OUT, formats by suffix",
                             description="Read IN and write OUT (atomically), each format chosen by its suffix: "
                                         ".ini (SVS; translations in mm), .yaml/.yml/.xml (OpenCV; metres), or "
                                         "no suffix / an existing folder: ROS camera_info, FOLDER/left.yaml and "
                                         "FOLDER/right.yaml as camera_calibration writes them and "
                                         "camera_info_manager reads them (the head's pose on the robot is not "
                                         "part of camera_info).")
    convert.add_argument("input", type=Path, metavar="IN")
    convert.add_argument("output", type=Path, metavar="OUT")
    convert.add_argument("--camera-name", default=camera_info.DEFAULT_NAME,
                         help="camera_info camera_name prefix (NAME/left, NAME/right; default %(default)s)")
    convert.set_defaults(handler=run_convert)
    show = sub.add_parser("show", help="print a calibration's numbers",
                          description="Print size, rectified intrinsics, baseline, distortion, R, T and head pose.")
    show.add_argument("file", type=Path, metavar="FILE", help="a calibration file, or a camera_info folder")
    show.add_argument("--json", action="store_true", help="print JSON")
    show.set_defaults(handler=run_show)


SUFFIXES = (".ini", ".yaml", ".yml", ".xml")   # the file formats calibration.save writes


def _is_camera_info_target(path: Path) -> bool:
    return path.is_dir() or path.suffix == ""


def load_any(path: Path) -> calibration.StereoCalibration:
    """A calibration from an SVS/OpenCV file or a camera_info folder (one camera_info file is refused: half a head)."""
    if path.is_dir():
        return camera_info.read_pair(path)
    if camera_info.is_camera_info(path):
        raise BadFileError(f"{path}: a ROS camera_info file holds one camera; give the folder holding left.yaml and "
                           "right.yaml")
    return calibration.load(path)


def run_convert(args: argparse.Namespace) -> int:
    try:
        if _is_camera_info_target(args.output):
            check_output_folder(args.output, "OUT")
        else:
            check_output_file(args.output, "OUT")
            if args.output.suffix.lower() not in SUFFIXES:
                raise OutputPathError(f"OUT {args.output}: unknown calibration format (give .ini, .yaml, .yml or "
                                      ".xml, or a folder for camera_info)")
        # IN rewritten in place would lose what the writer does not carry (comments, fields of another format)
        check_output_apart(args.output, "OUT", files={"IN": args.input})
    except OutputPathError as exc:
        print(f"p3at calib convert: {exc}", file=sys.stderr)
        return 2
    try:
        calib = load_any(args.input)
        if _is_camera_info_target(args.output):
            written = camera_info.write_pair(calib, args.output, args.camera_name)
        else:
            calibration.save(calib, args.output)
            written = [args.output]
    except BadFileError as exc:  # a bad input file: one line, exit 2
        print(f"p3at calib convert: {exc}", file=sys.stderr)
        return 2
    except (DriverError, ValueError, OSError) as exc:
        print(f"p3at calib convert: {exc}", file=sys.stderr)
        return 1
    print(f"{args.input} -> {', '.join(map(str, written))} ({calib.size[0]}x{calib.size[1]}, "
          f"baseline {calib.baseline:.5f} m)")
    if _is_camera_info_target(args.output) and np.any(calib.head_pose != 0):
        print("note: camera_info has no place for the head's pose on the robot (ROS keeps it in TF): "
              f"{calib.head_pose.tolist()} (x y z m, roll pitch yaw rad) was not written")
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
        calib = load_any(args.file)
    except BadFileError as exc:
        print(f"p3at calib show: {exc}", file=sys.stderr)
        return 2
    except (DriverError, ValueError, OSError) as exc:
        print(f"p3at calib show: {exc}", file=sys.stderr)
        return 1
    if args.json:
        print(json_text(summary(calib), indent=2))
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
