"""``p3at camera info|grab``: talk to a Videre STH-MDCS2 on USB, or to the virtual one with ``--mock``."""
from __future__ import annotations

import argparse
import sys
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np

from drivers.errors import DeviceNotFoundError, DriverError
from drivers.fileio import atomic_write_bytes
from drivers.videre import DEFAULT_PRODUCT_ID, DEFAULT_VENDOR_ID, LEFT_FIRST, RIGHT_FIRST, StereoHead
from drivers.videre.head import NoCalibrationError
from runtime.commands.options import (
    OutputPathError,
    add_deprecated_alias,
    check_output_folder,
    float_where,
    non_negative_int,
    positive_float,
)
from runtime.json_output import json_text


def _unsigned_hex(bits: int):
    """The argparse type of a hex number that fits ``bits`` unsigned bits (USB ids 16, IEEE-1394 GUIDs 64)."""
    high = (1 << bits) - 1

    def parse(text: str) -> int:
        try:
            value = int(text, 16)
        except ValueError:
            value = -1
        if not 0 <= value <= high:
            raise argparse.ArgumentTypeError(f"expected a hex number from 0 to {high:x}, not {text!r}")
        return value

    parse.__name__ = parse.__qualname__ = f"hex_{bits}_bits"
    return parse


_usb_id, _guid = _unsigned_hex(16), _unsigned_hex(64)


def _add_device_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--mock", action="store_true",
                        help="use the virtual head (renders the simulated building) instead of USB hardware")
    parser.add_argument("--vendor-id", type=_usb_id, default=DEFAULT_VENDOR_ID,
                        help=f"USB vendor id, hex 0-ffff (default {DEFAULT_VENDOR_ID:04x})")
    parser.add_argument("--product-id", type=_usb_id, default=DEFAULT_PRODUCT_ID,
                        help=f"USB product id, hex 0-ffff (default {DEFAULT_PRODUCT_ID:04x})")
    parser.add_argument("--byte-order", choices=(RIGHT_FIRST, LEFT_FIRST), default=RIGHT_FIRST,
                        help="which imager is byte 0 of each interleaved pixel (default: right)")
    parser.add_argument("--colour", action="store_true", help="a colour (Bayer) head")
    parser.add_argument("--ieee1394", action="store_true",
                        help="an IEEE-1394 head through the system's libdc1394 instead of USB")
    parser.add_argument("--guid", type=_guid, help="--ieee1394: the camera's GUID, hex (default: the first)")
    parser.add_argument("--world", type=Path, help="--mock: building file (default: the packaged one)")
    parser.add_argument("--name", default="robot1",
                        help="--mock: the world's robot (its start pose) the head is mounted on (default robot1)")
    parser.add_argument("--seed", type=non_negative_int, default=0,
                        help="--mock: sensor noise seed, a whole number >= 0 (default 0)")


MAX_GRAB_TIMEOUT = 86400.0   # s: a day; 1e308 overflowed the USB read's milliseconds (exit 70)


def grab_timeout(text: str) -> float:
    """--timeout: seconds > 0, at most MAX_GRAB_TIMEOUT."""
    return float_where(text, f"a number of seconds > 0 and at most {MAX_GRAB_TIMEOUT:g}",
                       lambda value: 0 < value <= MAX_GRAB_TIMEOUT)


def register(subparsers: argparse._SubParsersAction) -> None:
    camera = subparsers.add_parser("camera", help="the STH-MDCS2 stereo head: identification, grabbing",
                                   description="Identify the stereo head or grab a left/right pair.")
    sub = camera.add_subparsers(dest="camera_command", metavar="ACTION", required=True)
    info = sub.add_parser("info", help="identification, modes, controls, calibration summary",
                          description="Print the head's identification, video modes, feature controls with their "
                                      "ranges, and a summary of the calibration stored on it.")
    _add_device_options(info)
    info.add_argument("--json", action="store_true", help="print JSON")
    add_deprecated_alias(info, "--robot", "--name")
    info.set_defaults(handler=run_info)
    grab = sub.add_parser("grab", help="save one left/right pair as PNG",
                          description="Grab one stereo pair and save left.png and right.png in DIR.")
    _add_device_options(grab)
    add_deprecated_alias(grab, "--robot", "--name")
    grab.add_argument("--out", type=Path, required=True, metavar="DIR", help="directory for left.png and right.png")
    grab.add_argument("--rectify", action="store_true", help="rectify with the calibration stored on the head")
    grab.add_argument("--mode", default="640x480", help="WIDTHxHEIGHT (default %(default)s)")
    grab.add_argument("--camera-rate", type=positive_float, default=15.0, metavar="HZ",
                      help="frame rate (default %(default)s Hz)")
    grab.add_argument("--timeout", type=grab_timeout, default=2.0, metavar="S",
                      help=f"seconds to wait for a frame (at most {MAX_GRAB_TIMEOUT:g})")
    add_deprecated_alias(grab, "--rate", "--camera-rate")
    grab.set_defaults(handler=run_grab)


class BadArgumentError(ValueError):
    """--mock's building (--world) or robot (--name) cannot serve: exit 2, not a device's exit 1."""


@contextmanager
def _open_head(args: argparse.Namespace):
    backend = None
    if args.mock:
        from mocks.stereo_head import VirtualStereoHead
        from mocks.world import World

        try:
            world = World.load(args.world)
        except (ValueError, OSError) as exc:   # WorldFileError: the user's file, exit 2 (it was exit 1, a device's)
            raise BadArgumentError(str(exc)) from None
        if args.name not in world.start_poses:
            raise BadArgumentError(f"--name {args.name!r}: the building has start poses {sorted(world.start_poses)}")
        world.add_robot(args.name, world.start_poses[args.name])
        backend = VirtualStereoHead(world, args.name, rng=np.random.default_rng(args.seed),
                                    byte_order=args.byte_order, colour=args.colour,
                                    vendor_id=args.vendor_id, product_id=args.product_id)
    if args.ieee1394 and not args.mock:
        head = StereoHead.open_1394(args.guid, byte_order=args.byte_order, colour=args.colour)
    else:
        head = StereoHead.open(args.vendor_id, args.product_id, backend=backend, byte_order=args.byte_order,
                               colour=args.colour)
    try:
        yield head
    finally:
        head.close()


def _hint(exc: Exception, args: argparse.Namespace) -> str:
    """This command's way to the virtual head, after a driver's message that found no head (the driver's own
    messages name no option)."""
    if isinstance(exc, DeviceNotFoundError) and not args.mock:
        return "; without the head, --mock uses the virtual one"
    return ""


def _describe(head: StereoHead) -> dict:
    identity = head.identify()
    try:
        calib = head.read_calibration()
        calibration = {"size": list(calib.size), "fx": calib.fx, "fy": calib.fy, "cx": calib.cx, "cy": calib.cy,
                       "baseline_m": calib.baseline, "head_pose": [float(v) for v in calib.head_pose]}
    except NoCalibrationError:
        calibration = None
    return {
        "vendor": identity.vendor, "model": identity.model, "firmware": identity.firmware_text,
        "stereo": identity.stereo, "transport": identity.transport, "byte_order": head.byte_order,
        "current_mode": str(head.mode),
        "modes": [{"width": m.width, "height": m.height, "rate_hz": m.rate, "binning": m.binning,
                   "iidc_format": m.video_mode.fmt, "iidc_mode": m.video_mode.mode} for m in head.modes()],
        "controls": [{"name": c.name, "value": c.value, "value2": c.value2, "auto": c.auto, "min": c.minimum,
                      "max": c.maximum} for c in head.controls.all()],
        "calibration": calibration,
    }


def run_info(args: argparse.Namespace) -> int:
    try:
        with _open_head(args) as head:
            info = _describe(head)
    except BadArgumentError as exc:
        print(f"p3at camera info: {exc}", file=sys.stderr)
        return 2
    except (DriverError, ValueError) as exc:
        print(f"p3at camera info: {exc}{_hint(exc, args)}", file=sys.stderr)
        return 1
    if args.json:
        print(json_text(info, indent=2))
        return 0
    print(f"{info['vendor']} {info['model']}  firmware {info['firmware']}  stereo: {info['stereo']}")
    print(f"transport: {info['transport']}  byte order: {info['byte_order']}")
    print(f"current mode: {info['current_mode']}")
    sizes: dict[tuple[int, int], list[float]] = {}
    for m in info["modes"]:
        sizes.setdefault((m["width"], m["height"]), []).append(m["rate_hz"])
    print("modes: " + "; ".join(f"{w}x{h} @ {'/'.join(f'{r:g}' for r in rates)} Hz"
                                for (w, h), rates in sizes.items()))
    for c in info["controls"]:
        value = f"{c['value']}/{c['value2']}" if c["value2"] is not None else str(c["value"])
        print(f"  {c['name']:<14} {value:>7}  {'auto' if c['auto'] else 'manual':<6}  range {c['min']}..{c['max']}")
    cal = info["calibration"]
    if cal is None:
        print("calibration: none stored on the head")
    else:
        print(f"calibration: {cal['size'][0]}x{cal['size'][1]}  fx {cal['fx']:.2f} fy {cal['fy']:.2f}  "
              f"cx {cal['cx']:.2f} cy {cal['cy']:.2f}  baseline {cal['baseline_m']:.4f} m  "
              f"head at ({', '.join(f'{v:.3f}' for v in cal['head_pose'][:3])}) m")
    return 0


def run_grab(args: argparse.Namespace) -> int:
    try:
        width, height = (int(v) for v in args.mode.lower().split("x"))
    except ValueError:
        print(f"p3at camera grab: --mode {args.mode!r} is not WIDTHxHEIGHT", file=sys.stderr)
        return 2
    try:
        check_output_folder(args.out)
    except OutputPathError as exc:
        print(f"p3at camera grab: {exc}", file=sys.stderr)
        return 2
    try:
        with _open_head(args) as head:
            head.set_mode(width, height, args.camera_rate)
            calib = head.read_calibration().scaled(width, height) if args.rectify else None
            head.start()
            frame = head.grab(args.timeout)
        left, right = frame.left, frame.right
        if calib is not None:
            left, right = calib.rectify(left, right)
        paths = []
        for name, image in (("left", left), ("right", right)):
            ok, png = cv2.imencode(".png", image)
            if not ok:
                raise DriverError(f"could not encode the {name} image as PNG")
            path = args.out / f"{name}.png"
            atomic_write_bytes(path, png.tobytes())
            paths.append(path)
    except BadArgumentError as exc:
        print(f"p3at camera grab: {exc}", file=sys.stderr)
        return 2
    except (DriverError, ValueError, OSError) as exc:
        print(f"p3at camera grab: {exc}{_hint(exc, args)}", file=sys.stderr)
        return 1
    print(f"frame {frame.counter} at t={frame.timestamp:.3f} s ({width}x{height}"
          f"{', rectified' if args.rectify else ''}): {paths[0]} {paths[1]}")
    return 0
