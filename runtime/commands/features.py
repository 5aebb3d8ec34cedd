"""``p3at features LEFT RIGHT``: run the visual front end on one stereo pair and write every match to CSV."""
from __future__ import annotations

import argparse
import csv
import dataclasses
import io
import struct
import sys
from pathlib import Path

import cv2
import numpy as np

from estimation.fileio import atomic_write_bytes
from estimation.frontend import (
    FrontEnd,
    FrontEndConfig,
    FrontEndError,
    RectificationMaps,
    StereoGeometry,
    StereoMatchConfig,
)
from runtime.commands.options import check_output_apart, check_output_file, finite_float, positive_float
from runtime.json_output import json_text

DEFAULTS = StereoGeometry()
# the largest image the command decodes: 64 Mpx (one grey frame of 64 MB), 50 times the STH-MDCS2's 1280×960
MAX_IMAGE_PIXELS = 1 << 26
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
CSV_COLUMNS = ("u_left", "v_left", "u_right", "v_right", "disparity", "x", "y", "z",
               "cov_xx", "cov_xy", "cov_xz", "cov_yy", "cov_yz", "cov_zz", "descriptor_distance")


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "features", help="stereo features of one image pair -> CSV of matches with 3-D points",
        description="Detect Harris corners, describe them (U-SURF, SIFT or ORB), match them along the rows of a "
                    "rectified pair (or a raw pair with --calib), triangulate, and write every match: left and "
                    "right pixels, disparity, 3-D point and covariance (base_link, or the left camera frame). "
                    "The pair's geometry must be given: --calib FILE (a raw pair, rectified here), --fx PX and "
                    "--baseline M (a rectified pair; points in the left camera frame), or --virtual-head (a pair "
                    "from 'p3at camera grab --mock --rectify'; a raw one, without --rectify, goes with --calib "
                    "mocks/stereo_head/data/sth_mdcs2_default.ini, the virtual head's calibration).")
    parser.add_argument("left", type=Path, help="left image (the reference camera)")
    parser.add_argument("right", type=Path, help="right image")
    parser.add_argument("--calib", type=Path, help="calibration (.ini SVS or .yaml/.xml OpenCV): the pair is raw "
                                                   "and gets rectified; its intrinsics and head pose are used")
    parser.add_argument("--descriptor", choices=("usurf", "sift", "orb"), default="usurf",
                        help="corner descriptor: usurf (upright SURF, the paper's; default), sift or orb")
    parser.add_argument("--virtual-head", action="store_true",
                        help="the pair is a rectified one of the virtual STH-MDCS2 ('p3at camera grab --mock "
                             "--rectify'): its intrinsics and mount")
    parser.add_argument("--fx", type=positive_float, metavar="PX", help="rectified focal length (without --calib)")
    parser.add_argument("--fy", type=positive_float, metavar="PX", help="default: fx")
    parser.add_argument("--cx", type=finite_float, metavar="PX", help="default: (width - 1) / 2")
    parser.add_argument("--cy", type=finite_float, metavar="PX", help="default: (height - 1) / 2")
    parser.add_argument("--baseline", type=positive_float, metavar="M", help="metres (without --calib)")
    parser.add_argument("--max-disparity", type=positive_float, default=StereoMatchConfig().max_disparity,
                        metavar="PX", help="largest disparity searched (default %(default)s px)")
    parser.add_argument("--frame", choices=("base_link", "camera"), default=None,
                        help="frame of the written points and covariances (default: base_link when the head's "
                             "mount is known, --calib or --virtual-head; camera otherwise)")
    parser.add_argument("--out", type=Path, required=True, help="CSV file to write (atomically)")
    parser.add_argument("--json", action="store_true", help="print a JSON summary")
    parser.set_defaults(handler=run_features)


def _read_grey(path: Path) -> np.ndarray:
    if not path.is_file():   # else OpenCV prints its own warning line before the answer
        raise FrontEndError(f"{path}: {'not a file' if path.exists() else 'no such file'}")
    with path.open("rb") as f:   # a PNG states its size before its data: refuse a huge one before decoding it
        head = f.read(24)
    if head[:8] == _PNG_SIGNATURE and head[12:16] == b"IHDR":
        width, height = struct.unpack(">II", head[16:24])
        if width * height > MAX_IMAGE_PIXELS:
            raise FrontEndError(f"{path}: a {width}×{height} image ({width * height / 1e6:.0f} Mpx); the front end "
                                f"decodes at most {MAX_IMAGE_PIXELS / 1e6:.0f} Mpx")
    try:
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    except cv2.error as e:   # e.g. a header claiming 100000×100000 pixels: OpenCV's size check is an exception
        why = f"OpenCV's check '{e.err}' failed" if e.err else str(e).strip().splitlines()[-1]
        raise FrontEndError(f"{path}: cannot read an image from this file ({why})") from None
    if image is None:
        raise FrontEndError(f"{path}: cannot read an image from this file")
    return image


def front_end_from_calibration(calib, config: FrontEndConfig | None = None) -> FrontEnd:
    """A FrontEnd for raw frames of a calibrated head (``drivers.videre.calibration.StereoCalibration``).

    The geometry (rectified intrinsics, baseline, left rectified camera in base_link) replaces
    ``config.geometry`` (default config otherwise); the calibration's rectification maps make ``process`` accept
    raw pairs.
    """
    from runtime.adapters import stereo_geometry  # where driver calibrations become estimation geometry

    config = FrontEndConfig() if config is None else config
    (l1, l2), (r1, r2) = calib.rectify_maps
    return FrontEnd(dataclasses.replace(config, geometry=stereo_geometry(calib)), RectificationMaps(l1, l2, r1, r2))


def _geometry_source(args: argparse.Namespace) -> str:
    """Where the pair's geometry comes from: 'calibration', 'virtual head' or 'given'; ValueError if from nowhere."""
    given = args.fx is not None or args.baseline is not None
    sources = [name for name, used in (("calibration", args.calib is not None), ("virtual head", args.virtual_head),
                                       ("given", given)) if used]
    if len(sources) != 1:
        raise ValueError("give the pair's geometry one way: --calib FILE, --fx PX --baseline M, or --virtual-head"
                         if not sources else f"--calib, --virtual-head and --fx/--baseline exclude each other "
                                             f"(got {' and '.join(sources)})")
    if sources == ["given"] and (args.fx is None or args.baseline is None):
        raise ValueError("a rectified pair needs both --fx PX and --baseline M")
    if sources == ["given"] and args.frame == "base_link":
        raise ValueError("--frame base_link needs the head's mount on the robot: give --calib or --virtual-head")
    return sources[0]


def _front_end(args: argparse.Namespace, size: tuple[int, int]) -> FrontEnd:
    config = FrontEndConfig(descriptor=args.descriptor, matching=StereoMatchConfig(max_disparity=args.max_disparity))
    width, height = size
    if args.virtual_head:
        return FrontEnd(dataclasses.replace(config, geometry=DEFAULTS))
    if args.calib is None:
        geometry = StereoGeometry(fx=args.fx, fy=args.fy if args.fy is not None else args.fx,
                                  cx=args.cx if args.cx is not None else (width - 1) / 2.0,
                                  cy=args.cy if args.cy is not None else (height - 1) / 2.0,
                                  baseline=args.baseline)
        return FrontEnd(dataclasses.replace(config, geometry=geometry))
    from drivers.videre import calibration  # only the runtime adapts a driver's calibration

    calib = calibration.load(args.calib)
    if tuple(calib.size) != (width, height):
        calib = calib.scaled(width, height)
    return front_end_from_calibration(calib, config)


def matches_csv(matches, frame: str) -> bytes:
    """CSV text of a ``StereoMatches``: one row per match, the columns of ``CSV_COLUMNS``."""
    points = matches.points_base if frame == "base_link" else matches.points_camera
    covs = matches.covariances_base if frame == "base_link" else matches.covariances_camera
    upper = covs[:, [0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]]
    table = np.column_stack([matches.left_pixels, matches.right_pixels, matches.disparities, points, upper,
                             matches.descriptor_distances])
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    writer.writerows([[f"{v:.6g}" for v in row] for row in table])
    return out.getvalue().encode()


def run_features(args: argparse.Namespace) -> int:
    try:
        check_output_file(args.out)
        check_output_apart(args.out, files={"left image": args.left, "right image": args.right,
                                            "--calib": args.calib})
        source = _geometry_source(args)
        if args.frame is None:
            args.frame = "camera" if source == "given" else "base_link"
        left, right = _read_grey(args.left), _read_grey(args.right)
        if left.shape != right.shape:
            raise FrontEndError(f"{args.left} is {left.shape[1]}×{left.shape[0]} but {args.right} is "
                                f"{right.shape[1]}×{right.shape[0]}")
        front_end = _front_end(args, (left.shape[1], left.shape[0]))
        matches = front_end.match(left, right)
        atomic_write_bytes(args.out, matches_csv(matches, args.frame))
    except (FrontEndError, OSError, ValueError) as exc:  # the calibration's BadFileError is a ValueError
        print(f"p3at features: {exc}", file=sys.stderr)
        return 2  # every failure here is a bad input: an unreadable image or calibration, or a bad argument
    geometry = front_end.config.geometry
    if args.json:
        depth = matches.points_camera[:, 2]
        summary = {
            "left": str(args.left), "right": str(args.right), "out": str(args.out), "descriptor": args.descriptor,
            "frame": args.frame, "size": [int(left.shape[1]), int(left.shape[0])], "matches": len(matches),
            "disparity_px": _range(matches.disparities), "depth_m": _range(depth),
            "geometry": front_end.config.to_dict()["geometry"], "geometry_source": source,
            "rectified_here": args.calib is not None,
        }
        print(json_text(summary, indent=2))
        return 0
    where = {"calibration": f"from {args.calib}", "virtual head": "of the virtual STH-MDCS2", "given": "as given"}
    print(f"{len(matches)} matches ({args.descriptor}) written to {args.out}: pixels, disparity (px), 3-D points and "
          f"covariances in {args.frame} (m, m²)")
    print(f"geometry {where[source]}: fx {geometry.fx:.2f} px, fy {geometry.fy:.2f} px, cx {geometry.cx:.2f} px, "
          f"cy {geometry.cy:.2f} px, baseline {geometry.baseline:.4f} m"
          + ("" if args.frame == "camera" else ", head mount (x y z roll pitch yaw) "
             + " ".join(f"{v:.3f}" for v in geometry.head_pose) + " m/rad in base_link")
          + ("; the pair was rectified here" if args.calib is not None else ""))
    return 0


def _range(values: np.ndarray) -> dict:
    if len(values) == 0:
        return {"min": None, "median": None, "max": None}
    return {"min": float(np.min(values)), "median": float(np.median(values)), "max": float(np.max(values))}
