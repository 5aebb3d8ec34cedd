"""ROS ``camera_info`` YAML: the calibration files ``camera_calibration`` writes and ``camera_info_manager`` reads.

A stereo head is two files, one per camera, in one folder: ``left.yaml`` and ``right.yaml`` (the names in the
archive ``camera_calibration``'s stereo calibrator saves). Each holds::

    image_width, image_height        pixels
    camera_name                      e.g. sth_mdcs2/left
    camera_matrix                    K (3x3): the raw camera's intrinsics          = K1 / K2
    distortion_model                 plumb_bob (k1 k2 p1 p2 k3)                    = D1 / D2
    distortion_coefficients          D (1x5)
    rectification_matrix             R (3x3): raw camera frame -> rectified frame  = R1 / R2
    projection_matrix                P (3x4): rectified projection                 = P1 / P2; the right's
                                     P[0][3] = -fx' * baseline (metres x pixels)

each matrix as ``{rows, cols, data: [row-major numbers]}``. The pair gives back the stereo extrinsics: with the
rectified translation t = (P2[0][3] / fx', P2[1][3] / fy', 0), ``x_right = R x_left + T`` with R = R2ᵀ R1 and
T = R2ᵀ t. The head's pose on the robot is not part of camera_info (ROS keeps it in the TF tree): reading gives
a zero head pose. Numbers are written in their shortest exact form, so a round trip loses nothing.
"""
from __future__ import annotations

import os
import re
from pathlib import Path

import cv2
import numpy as np

from drivers.errors import BadFileError
from drivers.fileio import InputTooLargeError, atomic_write_bytes, read_bounded

from .calibration import GIVEN_TWICE, MAX_IMAGE_SIDE, StereoCalibration, check_calibration, duplicate_key, refuse_base64

SIDES = ("left", "right")
MAX_FILE_BYTES = 64 << 10      # a camera_info file is about 1 kB
MAX_BRACKETS = 16              # flow sequences/maps a file may open (4 matrices): bounds the parser's nesting
DEFAULT_NAME = "sth_mdcs2"
_MATRICES = {"camera_matrix": (3, 3), "distortion_coefficients": (1, 5), "rectification_matrix": (3, 3),
             "projection_matrix": (3, 4)}


def _number(v: float) -> str:
    """The shortest exact decimal, with a '.' in the mantissa so that YAML 1.1 readers (PyYAML) see a float."""
    text = repr(float(v))
    mantissa, e, exponent = text.partition("e")
    return f"{mantissa}.0e{exponent}" if e and "." not in mantissa else text


def camera_info_text(calib: StereoCalibration, side: str, name: str = DEFAULT_NAME) -> str:
    """The camera_info YAML of one camera (``side`` "left" or "right") of ``calib``."""
    if side not in SIDES:
        raise ValueError(f"side must be left or right, not {side!r}")
    left = side == "left"
    K, D, R, P = (calib.K1, calib.D1, calib.R1, calib.P1) if left else (calib.K2, calib.D2, calib.R2, calib.P2)
    lines = [f"image_width: {int(calib.size[0])}", f"image_height: {int(calib.size[1])}",
             f"camera_name: {name}/{side}"]

    def matrix(key: str, value: np.ndarray, rows: int, cols: int) -> None:
        data = np.asarray(value, float).reshape(rows * cols)
        lines.extend([f"{key}:", f"  rows: {rows}", f"  cols: {cols}",
                      f"  data: [{', '.join(_number(v) for v in data)}]"])

    matrix("camera_matrix", K, 3, 3)
    lines.append("distortion_model: plumb_bob")
    matrix("distortion_coefficients", D, 1, 5)
    matrix("rectification_matrix", R, 3, 3)
    matrix("projection_matrix", P, 3, 4)
    return "\n".join(lines) + "\n"


def write_pair(calib: StereoCalibration, folder: str | os.PathLike, name: str = DEFAULT_NAME) -> list[Path]:
    """Write ``folder/left.yaml`` and ``folder/right.yaml`` (atomically); returns their paths."""
    check_calibration(calib, f"{folder}: refusing to write")
    folder = Path(folder)
    if not re.fullmatch(r"[A-Za-z0-9_/\-]{1,128}", name):
        raise ValueError(f"camera name {name!r}: letters, digits, _ - / only")
    paths = []
    for side in SIDES:
        path = folder / f"{side}.yaml"
        atomic_write_bytes(path, camera_info_text(calib, side, name).encode("ascii"))
        paths.append(path)
    return paths


def read_camera(path: str | os.PathLike) -> dict:
    """One camera_info file: {"size": (w, h), "name", "K" (3, 3), "D" (5,), "R" (3, 3), "P" (3, 4)}, validated
    (size bounds before parsing, every field present, shapes, finite numbers). Raises BadFileError."""
    path = Path(path)
    try:
        text = read_bounded(path, MAX_FILE_BYTES).decode("utf-8")   # never waits on a FIFO
    except InputTooLargeError as e:
        raise BadFileError(f"{path}: {e}; a camera_info file holds about 1 kB (at most {MAX_FILE_BYTES})") from None
    except FileNotFoundError:
        raise BadFileError(f"{path}: no such file") from None
    except OSError as e:
        raise BadFileError(f"{path}: cannot read: {e.strerror}") from None
    except UnicodeDecodeError:
        raise BadFileError(f"{path}: not a text file") from None
    if not text.strip():  # also what a FIFO that nothing writes to reads as
        raise BadFileError(f"{path}: an empty file, not a camera_info file")
    if text.count("[") + text.count("{") > MAX_BRACKETS or "\x00" in text:
        raise BadFileError(f"{path}: field '(syntax)': not a camera_info file (nested or binary content)")
    refuse_base64(path, text.encode())   # OpenCV's parser can spin for ever on a damaged base64 block
    lines = text.splitlines()

    def line_of(key: str) -> int | str:
        return next((n + 1 for n, ln in enumerate(lines) if re.match(rf"\s*{key}\s*:", ln)), "?")

    def bad(key: str, problem: str) -> BadFileError:
        return BadFileError(f"{path}:{line_of(key.split('.')[0])}: field '{key}': {problem}")

    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY | cv2.FILE_STORAGE_FORMAT_YAML)
    except (cv2.error, SystemError) as exc:
        raise BadFileError(f"{path}: field '(syntax)': not readable YAML ({str(exc).strip().splitlines()[-1]})") \
            from None
    try:
        if not fs.isOpened() or not fs.root().isMap():
            raise BadFileError(f"{path}: field '(syntax)': not a YAML mapping")
        if (twice := duplicate_key(fs.root())) is not None:
            raise bad(twice, GIVEN_TWICE)

        def integer(key: str) -> int:
            node = fs.getNode(key)
            if node.empty() or not node.isInt():
                raise bad(key, "missing or not an integer")
            return int(node.real())

        def text_field(key: str) -> str:
            node = fs.getNode(key)
            if node.empty() or not node.isString():
                raise bad(key, "missing or not text")
            return node.string()

        def matrix(key: str) -> np.ndarray:
            rows, cols = _MATRICES[key]
            node = fs.getNode(key)
            if node.empty() or not node.isMap():
                raise bad(key, "missing or not a {rows, cols, data} mapping")
            for part, want in (("rows", rows), ("cols", cols)):
                sub = node.getNode(part)
                if sub.empty() or not sub.isInt() or int(sub.real()) != want:
                    # plumb_bob with 4 coefficients (k3 = 0) is also written by some tools
                    if not (key == "distortion_coefficients" and part == "cols" and sub.isInt()
                            and int(sub.real()) == 4):
                        raise bad(f"{key}.{part}", f"expected {want}")
            data = node.getNode("data")
            expected = rows * int(node.getNode("cols").real())
            if data.empty() or not data.isSeq() or data.size() != expected:
                raise bad(f"{key}.data", f"expected a list of {expected} numbers")
            values = []
            for i in range(expected):
                item = data.at(i)
                if not (item.isReal() or item.isInt()):
                    raise bad(f"{key}.data", f"item {i} is not a number")
                values.append(item.real())
            array = np.array(values, float)
            if not np.all(np.isfinite(array)):
                raise bad(f"{key}.data", "non-finite number")
            if key == "distortion_coefficients":
                return np.concatenate([array, np.zeros(5 - len(array))])
            return array.reshape(rows, cols)

        width, height = integer("image_width"), integer("image_height")
        for key, value in (("image_width", width), ("image_height", height)):
            # checked here, in its own file: a 26-digit width (OpenCV reads it as 2^63) was reported as the right
            # file's differing from it
            if not 1 <= value <= MAX_IMAGE_SIDE:
                shown = f"{value}" if abs(value) < 2**62 else "a number past 2^62"
                raise bad(key, f"{shown}; an image side is 1..{MAX_IMAGE_SIDE} pixels")
        name = text_field("camera_name")
        if len(name) > 256:
            raise bad("camera_name", "longer than 256 characters")
        model = text_field("distortion_model")
        if model != "plumb_bob":
            raise bad("distortion_model", f"{model!r} is not supported (plumb_bob: k1 k2 p1 p2 k3)")
        out = {"size": (width, height), "name": name, "K": matrix("camera_matrix"),
               "D": matrix("distortion_coefficients"), "R": matrix("rectification_matrix"),
               "P": matrix("projection_matrix")}
    finally:
        fs.release()
    return out


def read_pair(folder: str | os.PathLike) -> StereoCalibration:
    """The stereo calibration of ``folder/left.yaml`` and ``folder/right.yaml``, checked as any calibration is
    (:func:`~drivers.videre.calibration.check_calibration`). Raises BadFileError naming file and field."""
    folder = Path(folder)
    left, right = (read_camera(folder / f"{side}.yaml") for side in SIDES)
    if left["size"] != right["size"]:
        raise BadFileError(f"{folder / 'right.yaml'}: field 'image_width': {right['size']} differs from the left "
                           f"camera's {left['size']}")
    for side, cam in (("left", left), ("right", right)):
        if not (cam["P"][0, 0] > 0 and cam["P"][1, 1] > 0):
            raise BadFileError(f"{folder / (side + '.yaml')}: field 'projection_matrix': focal lengths must be "
                               "positive")
        if np.linalg.det(cam["R"]) <= 0:  # checked properly below; R2ᵀ needs a rotation to mean anything
            raise BadFileError(f"{folder / (side + '.yaml')}: field 'rectification_matrix': not a rotation")
    P2 = right["P"]
    t = np.array([P2[0, 3] / P2[0, 0], P2[1, 3] / P2[1, 1], 0.0])
    R = right["R"].T @ left["R"]
    T = right["R"].T @ t
    size = tuple(int(v) for v in left["size"])
    calib = StereoCalibration(size, left["K"], left["D"], right["K"], right["D"], R, T, left["R"], right["R"],
                              left["P"], right["P"], np.zeros(6))
    names = {"K1": "left.yaml camera_matrix", "D1": "left.yaml distortion_coefficients",
             "R1": "left.yaml rectification_matrix", "P1": "left.yaml projection_matrix",
             "K2": "right.yaml camera_matrix", "D2": "right.yaml distortion_coefficients",
             "R2": "right.yaml rectification_matrix", "P2": "right.yaml projection_matrix",
             "R": "R (from the rectification matrices)", "T": "T (from the right projection)",
             "size.width": "image_width", "size.height": "image_height"}
    check_calibration(calib, str(folder), names)
    return calib


def is_camera_info(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a camera_info pair's folder, or one camera_info file (which alone is half a head)."""
    path = Path(path)
    if path.is_dir():
        return (path / "left.yaml").is_file() or (path / "right.yaml").is_file()
    if path.suffix.lower() in (".yaml", ".yml") and path.is_file() and path.stat().st_size <= MAX_FILE_BYTES:
        head = path.read_bytes()[:4096]
        return b"camera_matrix" in head and b"projection_matrix" in head
    return False


__all__ = ["SIDES", "camera_info_text", "is_camera_info", "read_camera", "read_pair", "write_pair"]
