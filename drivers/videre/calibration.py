"""Stereo calibration: Videre SVS parameter files (``.ini``), OpenCV stereo files (YAML/XML), rectification.

Conventions (OpenCV's): camera 1 is the LEFT camera and the reference; ``R, T`` map a left-camera point to
the right camera, ``x_right = R @ x_left + T``, with ``T`` in metres (about ``(-0.09, 0, 0)`` for the 9 cm
head). ``R1, R2`` rotate each raw camera frame into its rectified frame and ``P1, P2`` (3x4) project rectified
points to rectified pixels, with their translation column in metres (``P2[0, 3] = -fx * baseline``).
Camera optical frames are x right, y down, z forward.

SVS files keep translations in millimetres (``[external] Tx`` and the ``proj`` translation column); SVS
``[external] Rx, Ry, Rz`` are read as a rotation vector (Rodrigues), which for the milliradian angles of a
real head is the same as any Euler convention. ``[global]`` GTx, GTy, GTz (mm) and GRx, GRy, GRz (rad; roll,
pitch, yaw) give the pose on the robot (base_link, REP-103) of the midpoint of the two optical centres of a
head looking along its own x axis.
"""
from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path

import cv2
import numpy as np

from drivers.errors import BadFileError
from drivers.fileio import InputTooLargeError, atomic_write_bytes, read_bounded

SVS_HEADER = "# SVS Engine v "
SVS_MIN_VERSION = (2, 1)
SVS_WRITE_VERSION = "4.4d"
# Optical frame (x right, y down, z forward) to body axes (x forward, y left, z up).
OPTICAL_TO_BODY = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])

# What a calibration may hold (see check_calibration); a file past these bounds is refused, whatever its format.
MAX_FILE_BYTES = 1 << 20  # real calibration files are a few kB
MAX_IMAGE_SIDE = 16384  # pixels
MAX_FOCAL = 1e5  # pixels
MAX_DISTORTION = 100.0  # |coefficient|
MAX_BASELINE = 10.0  # metres
MAX_HEAD_OFFSET = 10.0  # metres from base_link
ROTATION_TOLERANCE = 1e-3  # max |R^T R - I| (files keep 6 to 9 digits)
_MAX_MATRIX_SIDE = 16  # rows/cols an OpenCV matrix of this format may claim before anything is read


@dataclass(frozen=True)
class StereoCalibration:
    """A calibrated stereo head.

    K1, K2: (3, 3) raw intrinsics; D1, D2: (5,) k1 k2 p1 p2 k3; R: (3, 3), T: (3,) metres (left -> right);
    R1, R2: (3, 3) rectifying rotations; P1, P2: (3, 4) rectified projections (translation in metres);
    size: (width, height) pixels; head_pose: (6,) x y z (m) roll pitch yaw (rad) of the head on the robot;
    extras: SVS sections/keys this class does not interpret, kept so that an SVS round trip loses nothing.
    """

    size: tuple[int, int]
    K1: np.ndarray
    D1: np.ndarray
    K2: np.ndarray
    D2: np.ndarray
    R: np.ndarray
    T: np.ndarray
    R1: np.ndarray
    R2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    head_pose: np.ndarray = field(default_factory=lambda: np.zeros(6))
    extras: dict[str, dict[str, str]] = field(default_factory=dict, compare=False)

    # --- the numbers everyone asks for (of the rectified pair) ---
    @property
    def fx(self) -> float:
        return float(self.P1[0, 0])

    @property
    def fy(self) -> float:
        return float(self.P1[1, 1])

    @property
    def cx(self) -> float:
        return float(self.P1[0, 2])

    @property
    def cy(self) -> float:
        return float(self.P1[1, 2])

    @property
    def baseline(self) -> float:
        """Metres between the rectified optical centres (``-P2[0, 3] / P2[0, 0]``)."""
        return float(-self.P2[0, 3] / self.P2[0, 0])

    @property
    def Q(self) -> np.ndarray:
        """(4, 4) reprojection matrix: ``[X Y Z W] = Q @ [u v d 1]`` with d = u_left - u_right (metres)."""
        cx2 = float(self.P2[0, 2])
        tx = float(self.P2[0, 3] / self.P2[0, 0])  # = -baseline
        return np.array([
            [1.0, 0.0, 0.0, -self.cx],
            [0.0, 1.0, 0.0, -self.cy],
            [0.0, 0.0, 0.0, self.fx],
            [0.0, 0.0, -1.0 / tx, (self.cx - cx2) / tx],
        ])

    def left_camera_to_base(self, rectified: bool = True) -> np.ndarray:
        """(4, 4) transform from the left (rectified, by default) camera frame to base_link."""
        right_centre = -self.R.T @ self.T  # right optical centre in raw-left coordinates
        roll, pitch, yaw = self.head_pose[3:]
        head_rotation = _rot_zyx(roll, pitch, yaw)
        out = np.eye(4)
        raw_rotation = head_rotation @ OPTICAL_TO_BODY
        out[:3, :3] = raw_rotation @ self.R1.T if rectified else raw_rotation
        out[:3, 3] = self.head_pose[:3] - raw_rotation @ (right_centre / 2.0)
        return out

    # --- rectification ---
    @cached_property
    def rectify_maps(self) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
        """Left and right ``cv2.remap`` maps (fixed-point CV_16SC2 + CV_16UC1 pairs) at ``size``."""
        maps = []
        for K, D, Rr, P in ((self.K1, self.D1, self.R1, self.P1), (self.K2, self.D2, self.R2, self.P2)):
            maps.append(cv2.initUndistortRectifyMap(K, D, Rr, P[:, :3], self.size, cv2.CV_16SC2))
        return maps[0], maps[1]

    def rectify(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rectify a raw pair of images of ``size`` (H, W) or (H, W, 3)."""
        (l1, l2), (r1, r2) = self.rectify_maps
        return (cv2.remap(left, l1, l2, cv2.INTER_LINEAR), cv2.remap(right, r1, r2, cv2.INTER_LINEAR))

    def scaled(self, width: int, height: int) -> StereoCalibration:
        """The same head at another resolution (decimation/binning), pixel centres kept consistent."""
        if (width, height) == tuple(self.size):
            return self
        sx, sy = width / self.size[0], height / self.size[1]

        def scale(M: np.ndarray) -> np.ndarray:
            M = M.astype(float).copy()
            M[0, :] *= sx
            M[1, :] *= sy
            # pixel centres: u' + 0.5 = (u + 0.5) * s, i.e. the principal point moves by (s - 1) / 2
            M[0, :3] += (sx - 1) / 2 * M[2, :3]
            M[1, :3] += (sy - 1) / 2 * M[2, :3]
            return M

        return replace(self, size=(int(width), int(height)), K1=scale(self.K1), K2=scale(self.K2),
                       P1=scale(self.P1), P2=scale(self.P2))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, StereoCalibration):
            return NotImplemented
        return tuple(self.size) == tuple(other.size) and all(
            np.allclose(getattr(self, n), getattr(other, n), rtol=1e-6, atol=1e-9)
            for n in ("K1", "D1", "K2", "D2", "R", "T", "R1", "R2", "P1", "P2", "head_pose"))

    __hash__ = None  # type: ignore[assignment]


def _rot_zyx(roll: float, pitch: float, yaw: float) -> np.ndarray:
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch),
                              math.cos(yaw), math.sin(yaw))
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return rz @ ry @ rx


def from_intrinsics(size: tuple[int, int], K1: np.ndarray, D1: np.ndarray, K2: np.ndarray, D2: np.ndarray,
                    R: np.ndarray, T: np.ndarray, head_pose: np.ndarray | None = None) -> StereoCalibration:
    """Build a calibration, computing R1, R2, P1, P2 with ``cv2.stereoRectify`` (zero disparity, alpha 0)."""
    R1, R2, P1, P2, _, _, _ = cv2.stereoRectify(
        np.asarray(K1, float), np.asarray(D1, float), np.asarray(K2, float), np.asarray(D2, float),
        tuple(size), np.asarray(R, float), np.asarray(T, float).reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
    return StereoCalibration(tuple(size), np.asarray(K1, float), np.asarray(D1, float).ravel(),
                             np.asarray(K2, float), np.asarray(D2, float).ravel(), np.asarray(R, float),
                             np.asarray(T, float).ravel(), R1, R2, P1, P2,
                             np.zeros(6) if head_pose is None else np.asarray(head_pose, float))


def check_calibration(calib: StereoCalibration, source: str, names: dict[str, str] | None = None,
                      lines: dict[str, int] | None = None) -> None:
    """Refuse what no stereo head can have: sizes not positive integers or past MAX_IMAGE_SIDE, focal lengths
    not positive (or past MAX_FOCAL), principal points far outside the image, K or P not of the pinhole form,
    distortion past MAX_DISTORTION, R, R1, R2 not rotations, T zero or past MAX_BASELINE, a baseline that is
    not positive, a head pose past MAX_HEAD_OFFSET. ``names`` maps this class's field names (K1, size, ...) to
    the file's (``left camera.f``, ``M1``, ...) for the message, ``lines`` to their line numbers. Raises
    BadFileError."""
    names = names or {}
    lines = lines or {}

    def bad(name: str, problem: str) -> BadFileError:
        where = f":{lines[name]}" if name in lines else ""
        return BadFileError(f"{source}{where}: field '{names.get(name, name)}': {problem}")

    width, height = calib.size
    for side, value in (("width", width), ("height", height)):
        if not isinstance(value, int | np.integer) or not 1 <= value <= MAX_IMAGE_SIDE:
            raise bad(f"size.{side}", f"image {side} {value!r} is not an integer in 1..{MAX_IMAGE_SIDE}")
    arrays = {n: np.asarray(getattr(calib, n), float) for n in ("K1", "D1", "K2", "D2", "R", "T", "R1", "R2",
                                                               "P1", "P2", "head_pose")}
    shapes = {"K1": (3, 3), "K2": (3, 3), "D1": (5,), "D2": (5,), "R": (3, 3), "T": (3,), "R1": (3, 3),
              "R2": (3, 3), "P1": (3, 4), "P2": (3, 4), "head_pose": (6,)}
    for name, a in arrays.items():
        if a.shape != shapes[name]:
            raise bad(name, f"shape {a.shape}, expected {shapes[name]}")
        if not np.all(np.isfinite(a)):
            raise bad(name, "non-finite number")
    for name in ("K1", "K2", "P1", "P2"):
        M = arrays[name]
        fx, fy, cx, cy = M[0, 0], M[1, 1], M[0, 2], M[1, 2]
        if not (0 < fx <= MAX_FOCAL and 0 < fy <= MAX_FOCAL):
            raise bad(name, f"focal lengths fx={fx:g}, fy={fy:g} px must be in (0, {MAX_FOCAL:g}]")
        if not (-0.5 * width <= cx <= 1.5 * width and -0.5 * height <= cy <= 1.5 * height):
            raise bad(name, f"principal point ({cx:g}, {cy:g}) px is far outside the {width}x{height} image")
        if M[1, 0] != 0 or M[2, 0] != 0 or M[2, 1] != 0 or abs(M[2, 2] - 1) > 1e-9 or abs(M[0, 1]) > fx:
            raise bad(name, "not a pinhole matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]]")
    for name in ("D1", "D2"):
        if np.max(np.abs(arrays[name])) > MAX_DISTORTION:
            raise bad(name, f"a distortion coefficient beyond ±{MAX_DISTORTION:g}")
    for name in ("R", "R1", "R2"):
        R = arrays[name]
        error = float(np.max(np.abs(R.T @ R - np.eye(3))))
        if error > ROTATION_TOLERANCE or np.linalg.det(R) <= 0:
            raise bad(name, f"not a rotation matrix (|R^T R - I| = {error:.2g}, det {np.linalg.det(R):.3g})")
    if not 0 < np.linalg.norm(arrays["T"]) <= MAX_BASELINE:
        raise bad("T", f"|T| = {np.linalg.norm(arrays['T']):g} m, expected in (0, {MAX_BASELINE:g}]")
    P1, P2 = arrays["P1"], arrays["P2"]
    if np.any(P1[:, 3] != 0) or P2[1, 3] != 0 or P2[2, 3] != 0:
        raise bad("P2" if np.all(P1[:, 3] == 0) else "P1", "translation column of a rectified projection must be "
                  "(0, 0, 0) on the left and (-fx * baseline, 0, 0) on the right")
    baseline = -P2[0, 3] / P2[0, 0]
    if not 0 < baseline <= MAX_BASELINE:
        raise bad("P2", f"baseline {baseline:g} m, expected in (0, {MAX_BASELINE:g}] (right camera to the right)")
    pose = arrays["head_pose"]
    if np.max(np.abs(pose[:3])) > MAX_HEAD_OFFSET or np.max(np.abs(pose[3:])) > 2 * math.pi:
        raise bad("head_pose", f"head pose {pose.tolist()} is beyond {MAX_HEAD_OFFSET:g} m or 2π rad")


# ============================== SVS parameter files ==============================

_CAMERA_FIELDS = ("pwidth", "pheight", "dpx", "dpy", "sx", "Cx", "Cy", "f", "fy", "alpha",
                  "kappa1", "kappa2", "kappa3", "tau1", "tau2")
_CAMERA_REQUIRED = ("pwidth", "pheight", "Cx", "Cy", "f", "kappa1", "kappa2", "tau1", "tau2")
_EXTERNAL_FIELDS = ("Tx", "Ty", "Tz", "Rx", "Ry", "Rz")
_GLOBAL_FIELDS = ("GTx", "GTy", "GTz", "GRx", "GRy", "GRz")
_SECTION_RE = re.compile(r"^\[([^\]]+)\]\s*$")


@dataclass
class _Entry:
    value: str | np.ndarray
    line: int


def _bad(source: str, line: int | str, field_name: str, problem: str) -> BadFileError:
    return BadFileError(f"{source}:{line}: field '{field_name}': {problem}")


def parse_svs(text: str, source: str = "<svs text>") -> StereoCalibration:
    """Parse the text of an SVS parameter file. Raises BadFileError naming ``source``, line and field."""
    lines = text.splitlines()
    if not lines or not lines[0].startswith(SVS_HEADER):
        raise _bad(source, 1, "header", f"expected a first line starting with {SVS_HEADER!r}")
    version_text = lines[0][len(SVS_HEADER):].strip().split()[0] if lines[0][len(SVS_HEADER):].strip() else ""
    match = re.match(r"(\d+)\.(\d+)", version_text)
    if not match:
        raise _bad(source, 1, "version", f"unreadable SVS version {version_text!r}")
    if (int(match.group(1)), int(match.group(2))) < SVS_MIN_VERSION:
        raise _bad(source, 1, "version", f"SVS version {version_text} is older than 2.1, which SVS rejects")

    sections: dict[str, dict[str, _Entry]] = {}
    section_lines: dict[str, int] = {}
    current: str | None = None
    i = 1
    while i < len(lines):
        raw = lines[i]
        lineno = i + 1
        i += 1
        if not raw.strip() or raw.startswith((" ", "\t", "#")):
            continue
        header = _SECTION_RE.match(raw.strip())
        if header:
            current = header.group(1).strip().lower()
            sections.setdefault(current, {})
            section_lines[current] = lineno
            continue
        tokens = raw.split()
        key = tokens[0]
        if current is None:
            raise _bad(source, lineno, key, "value outside any [section]")
        if key.lower() in ("proj", "rect"):
            rows, cols = (3, 4) if key.lower() == "proj" else (3, 3)
            numbers: list[float] = []
            for r in range(rows):
                if i >= len(lines):
                    raise _bad(source, lineno + r + 1, f"{current}.{key}", f"expected {rows} rows of {cols} numbers")
                row_tokens = lines[i].split()
                if len(row_tokens) != cols:
                    raise _bad(source, i + 1, f"{current}.{key}",
                               f"row {r + 1} has {len(row_tokens)} numbers, expected {cols}")
                try:
                    numbers += [float(t) for t in row_tokens]
                except ValueError:
                    raise _bad(source, i + 1, f"{current}.{key}", f"not a number in {lines[i].strip()!r}") from None
                i += 1
            matrix = np.array(numbers).reshape(rows, cols)
            if not np.all(np.isfinite(matrix)):
                raise _bad(source, lineno, f"{current}.{key}", "non-finite number")
            sections[current][key.lower()] = _Entry(matrix, lineno)
            continue
        if len(tokens) < 2:
            raise _bad(source, lineno, f"{current}.{key}", "missing value")
        sections[current][key.lower()] = _Entry(" ".join(tokens[1:]), lineno)

    def number(section: str, key: str, default: float | None = None) -> float:
        entry = sections.get(section, {}).get(key.lower())
        if entry is None:
            if default is not None:
                return default
            where = section_lines.get(section, len(lines))
            raise _bad(source, where, f"{section}.{key}", "missing")
        tokens = str(entry.value).split()
        try:
            if len(tokens) != 1:
                raise ValueError
            value = float(tokens[0])
        except ValueError:
            raise _bad(source, entry.line, f"{section}.{key}", f"not a number: {entry.value!r}") from None
        if not math.isfinite(value):
            raise _bad(source, entry.line, f"{section}.{key}", "non-finite number")
        return value

    def matrix(section: str, key: str) -> np.ndarray:
        entry = sections.get(section, {}).get(key)
        if entry is None:
            raise _bad(source, section_lines.get(section, len(lines)), f"{section}.{key}", "missing")
        return entry.value  # type: ignore[return-value]

    for required in ("left camera", "right camera", "external"):
        if required not in sections:
            raise _bad(source, len(lines), f"[{required}]", "section missing")
    cams = []
    for name in ("left camera", "right camera"):
        for key in _CAMERA_REQUIRED:
            number(name, key)
        f = number(name, "f")
        fy = number(name, "fy", f)
        if f <= 0 or fy <= 0:
            raise _bad(source, sections[name]["f"].line, f"{name}.f", "focal length must be positive")
        K = np.array([[f, number(name, "alpha", 0.0), number(name, "Cx")], [0.0, fy, number(name, "Cy")],
                      [0.0, 0.0, 1.0]])
        D = np.array([number(name, "kappa1"), number(name, "kappa2"), number(name, "tau1"), number(name, "tau2"),
                      number(name, "kappa3", 0.0)])
        P = matrix(name, "proj").copy()
        P[:, 3] /= 1000.0  # mm -> m
        size = []
        for key in ("pwidth", "pheight"):
            value = number(name, key)
            if value != int(value) or not 1 <= value <= MAX_IMAGE_SIDE:
                raise _bad(source, sections[name][key.lower()].line, f"{name}.{key}",
                           f"image size {value:g} is not an integer in 1..{MAX_IMAGE_SIDE}")
            size.append(int(value))
        cams.append((K, D, matrix(name, "rect"), P, size[0], size[1]))
    (K1, D1, R1, P1, w1, h1), (K2, D2, R2, P2, w2, h2) = cams
    if (w1, h1) != (w2, h2):
        raise _bad(source, sections["right camera"]["pwidth"].line, "right camera.pwidth",
                   f"image size {w2}x{h2} differs from the left camera's {w1}x{h1}")
    if w1 <= 0 or h1 <= 0:
        raise _bad(source, sections["left camera"]["pwidth"].line, "left camera.pwidth", "image size must be positive")
    if P2[0, 3] == 0:
        raise _bad(source, sections["right camera"]["proj"].line, "right camera.proj", "zero baseline")
    T = np.array([number("external", k) for k in ("Tx", "Ty", "Tz")]) / 1000.0
    R, _ = cv2.Rodrigues(np.array([number("external", k) for k in ("Rx", "Ry", "Rz")]).reshape(3, 1))
    head_pose = np.array([number("global", k, 0.0) for k in _GLOBAL_FIELDS])
    head_pose[:3] /= 1000.0
    known = {"left camera": {k.lower() for k in _CAMERA_FIELDS} | {"proj", "rect"},
             "right camera": {k.lower() for k in _CAMERA_FIELDS} | {"proj", "rect"},
             "external": {k.lower() for k in _EXTERNAL_FIELDS}, "global": {k.lower() for k in _GLOBAL_FIELDS}}
    extras = {sec: {k: str(e.value) for k, e in entries.items() if k not in known.get(sec, set())}
              for sec, entries in sections.items()}
    extras = {sec: kv for sec, kv in extras.items() if kv or sec not in known}
    calib = StereoCalibration((w1, h1), K1, D1, K2, D2, R, T, R1, R2, P1, P2, head_pose, extras)
    svs_names = {"K1": "left camera.f", "K2": "right camera.f", "D1": "left camera.kappa1",
                 "D2": "right camera.kappa1", "R": "external.Rx", "T": "external.Tx", "R1": "left camera.rect",
                 "R2": "right camera.rect", "P1": "left camera.proj", "P2": "right camera.proj",
                 "size.width": "left camera.pwidth", "size.height": "left camera.pheight", "head_pose": "global.GTx"}
    svs_lines = {}
    for name, label in svs_names.items():
        section, key = label.split(".", 1)
        entry = sections.get(section, {}).get(key.lower())
        if entry is not None:
            svs_lines[name] = entry.line
    check_calibration(calib, source, svs_names, svs_lines)
    return calib


def _fmt(x: float) -> str:
    return f"{x:.9g}"


def format_svs(calib: StereoCalibration) -> str:
    """The text of an SVS parameter file for ``calib`` (translations written in millimetres)."""
    w, h = calib.size
    image = {"max_linelen": "1280", "max_lines": "960", "max_decimation": "4", "max_binning": "2",
             "max_framediv": "1", "gamma": "1.000000", "color_right": "0", "color": "0", "ix": "0", "iy": "0",
             "vergence": "0.000000", "rectified": "0", "binning": "1", "framediv": "0", "subwindow": "0",
             "have_rect": "1"}
    image.update(calib.extras.get("image", {}))
    # the size keys always follow the calibration (a scaled calibration keeps its extras)
    image.update({"width": str(w), "height": str(h), "linelen": str(w), "lines": str(h),
                  "decimation": str(max(1, round(1280 / w)))})
    out = [f"{SVS_HEADER}{SVS_WRITE_VERSION} Stereo Camera Parameter File", "", "", "[image]"]
    out += [f"{k} {v} " for k, v in image.items()]
    for sec, kv in calib.extras.items():
        if sec in ("image", "left camera", "right camera", "external", "global"):
            continue
        out += ["", f"[{sec}]"] + [f"{k} {v} " for k, v in kv.items()]
    rvec, _ = cv2.Rodrigues(np.asarray(calib.R, float))
    ext = list(np.asarray(calib.T, float) * 1000.0) + list(rvec.ravel())
    out += ["", "[external]"] + [f"{k} {_fmt(v)} " for k, v in zip(_EXTERNAL_FIELDS, ext, strict=True)]
    for name, K, D, Rr, P in (("left camera", calib.K1, calib.D1, calib.R1, calib.P1),
                              ("right camera", calib.K2, calib.D2, calib.R2, calib.P2)):
        extra = calib.extras.get(name, {})
        values = {"pwidth": w, "pheight": h, "dpx": float(extra.get("dpx", 0.0104)),
                  "dpy": float(extra.get("dpy", 0.0104)), "sx": float(extra.get("sx", 1.0)),
                  "Cx": K[0, 2], "Cy": K[1, 2], "f": K[0, 0], "fy": K[1, 1], "alpha": K[0, 1],
                  "kappa1": D[0], "kappa2": D[1], "kappa3": D[4] if len(D) > 4 else 0.0, "tau1": D[2], "tau2": D[3]}
        out += ["", f"[{name}]"]
        out += [f"{k} {v} " if isinstance(v, int) else f"{k} {_fmt(v)} " for k, v in values.items()]
        proj = np.asarray(P, float).copy()
        proj[:, 3] *= 1000.0
        out.append("proj")
        out += ["  " + " ".join(f"{x:.9e}" for x in row) + " " for row in proj]
        out.append("rect")
        out += ["  " + " ".join(f"{x:.9e}" for x in row) + " " for row in np.asarray(Rr, float)]
    pose = np.asarray(calib.head_pose, float).copy()
    pose[:3] *= 1000.0
    out += ["", "[global]"] + [f"{k} {_fmt(v)} " for k, v in zip(_GLOBAL_FIELDS, pose, strict=True)]
    return "\n".join(out) + "\n"


# ============================== OpenCV stereo files ==============================

_OPENCV_REQUIRED = ("M1", "D1", "M2", "D2", "R", "T")
_OPENCV_SHAPES = {"M1": (3, 3), "M2": (3, 3), "R": (3, 3), "T": (3,), "R1": (3, 3), "R2": (3, 3),
                  "P1": (3, 4), "P2": (3, 4), "Q": (4, 4), "head_pose": (6,)}


def read_opencv(path: str | os.PathLike) -> StereoCalibration:
    """Read an OpenCV stereo calibration (YAML or XML, ``cv2.FileStorage``): M1 D1 M2 D2 R T, optional
    R1 R2 P1 P2 Q, image_width/image_height (or ``size``), and this project's optional ``head_pose`` (6).

    The file's size is bounded before it is parsed and every matrix's rows and cols before its data is read
    (numbers only, element by element: ``FileNode.mat()`` would allocate whatever the header claims)."""
    path = Path(path)
    if not path.is_file():  # a FIFO would block cv2.FileStorage forever
        kind = "a folder" if path.is_dir() else "a FIFO, a device or a socket"
        raise BadFileError(f"{path}: cannot read: not a regular file but {kind}" if path.exists() else
                           f"{path}: no such file")
    _check_file_size(path)
    if path.stat().st_size == 0:  # OpenCV would say '(-215:Assertion failed) buf in function 'open''
        raise BadFileError(f"{path}: an empty file, not an OpenCV calibration")
    try:
        refuse_base64(path, read_bounded(path, MAX_FILE_BYTES))
    except InputTooLargeError as e:   # it grew since its size was checked
        raise BadFileError(f"{path}: {e}; a calibration file has at most {MAX_FILE_BYTES}") from None
    except OSError as e:
        raise BadFileError(f"{path}: cannot read: {e.strerror or e}") from None
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:  # the Python binding wraps parse errors in SystemError
        cause = exc.__cause__ or exc.__context__ or exc
        raise BadFileError(f"{path}:{_cv_error_line(cause)}: field '(syntax)': not a readable OpenCV file: "
                           f"{_cv_error_text(cause)}") from None
    if not fs.isOpened():
        raise BadFileError(f"{path}:1: field '(syntax)': not a readable OpenCV YAML/XML file")
    try:
        text_lines = path.read_text(errors="replace").splitlines()

        def line_of(name: str) -> int | str:
            pattern = re.compile(rf"^\s*(<{name}\b|{name}\s*:)")
            return next((n + 1 for n, ln in enumerate(text_lines) if pattern.search(ln)), "?")

        def bad(name: str, problem: str) -> BadFileError:
            return BadFileError(f"{path}:{line_of(name)}: field '{name}': {problem}")

        root = fs.root()
        if not root.isMap():
            raise BadFileError(f"{path}:1: field '(top level)': expected a mapping of named matrices")
        if (twice := duplicate_key(root)) is not None:
            raise bad(twice, GIVEN_TWICE)

        def mat(name: str, required: bool) -> np.ndarray | None:
            node = fs.getNode(name)
            if node.empty():
                if required:
                    raise BadFileError(f"{path}:?: field '{name}': missing")
                return None
            value = _cv_matrix(node, name, bad)
            shape = _OPENCV_SHAPES.get(name)
            if name in ("D1", "D2"):
                if value.size not in (4, 5, 8, 12, 14):
                    raise bad(name, f"{value.size} distortion coefficients, expected 4, 5, 8, 12 or 14")
                flat = np.zeros(5)
                flat[:min(5, value.size)] = value.ravel()[:5]
                if value.size > 5 and np.any(value.ravel()[5:] != 0):
                    raise bad(name, "rational/thin-prism terms are not supported")
                return flat
            if shape is not None and value.size == int(np.prod(shape)):
                value = value.reshape(shape)
            elif shape is not None:
                raise bad(name, f"shape {value.shape}, expected {shape}")
            return value

        m = {name: mat(name, True) for name in _OPENCV_REQUIRED}
        opt = {name: mat(name, False) for name in ("R1", "R2", "P1", "P2", "head_pose")}
        width = _cv_size(fs.getNode("image_width"), "image_width", bad)
        height = _cv_size(fs.getNode("image_height"), "image_height", bad)
        size_node = fs.getNode("size")
        if (width is None or height is None) and not size_node.empty():
            if size_node.isMap():
                flat = _cv_matrix(size_node, "size", bad).ravel()
            elif size_node.isSeq() and size_node.size() == 2:
                flat = np.array([_cv_number(size_node.at(i), "size", bad) for i in range(2)])
            else:
                raise bad("size", "expected [width, height]")
            if flat.size != 2:
                raise bad("size", f"{flat.size} numbers, expected [width, height]")
            width, height = (_integral(v, "size", bad) for v in flat)
        if width is None or height is None:
            raise BadFileError(f"{path}:?: field 'image_width': missing image size (image_width/image_height)")
    except cv2.error as exc:
        raise BadFileError(f"{path}:?: field '(structure)': {_cv_error_text(exc)}") from None
    except UnicodeDecodeError as exc:   # a node's text (e.g. a matrix's dt) is not UTF-8: FileNode.string() raises
        raise BadFileError(f"{path}:?: field '(text)': not UTF-8 text ({exc.reason} at byte {exc.start} of a "
                           "value)") from None
    finally:
        fs.release()
    size = (width, height)
    names = {"size.width": "image_width", "size.height": "image_height", "K1": "M1", "K2": "M2"}
    lines = {k: line_of(v) for k, v in names.items()} | {k: line_of(k) for k in _OPENCV_SHAPES}
    if any(opt[k] is None for k in ("R1", "R2", "P1", "P2")):
        for name, canonical in (("M1", "K1"), ("M2", "K2"), ("R", "R"), ("T", "T")):
            _check_before_rectify(m[name], canonical, size, lambda problem, n=name: bad(n, problem))
        try:
            calib = from_intrinsics(size, m["M1"], m["D1"], m["M2"], m["D2"], m["R"], m["T"], opt["head_pose"])
        except cv2.error as exc:
            raise BadFileError(f"{path}:?: field 'M1': cannot compute the rectification: "
                               f"{_cv_error_text(exc)}") from None
    else:
        calib = StereoCalibration(size, m["M1"], m["D1"], m["M2"], m["D2"], m["R"], m["T"].ravel(), opt["R1"],
                                  opt["R2"], opt["P1"], opt["P2"],
                                  np.zeros(6) if opt["head_pose"] is None else opt["head_pose"])
    check_calibration(calib, str(path), names, {k: v for k, v in lines.items() if v != "?"})
    return calib


GIVEN_TWICE = "given twice (OpenCV reads the first, other readers may read the last)"


def duplicate_key(root) -> str | None:
    """The first key an OpenCV mapping (``cv2.FileNode``) or one of its mappings holds twice (``M1``,
    ``camera_matrix.rows``), None if none: FileStorage keeps both and ``getNode`` returns the first in silence."""
    nodes = [("", root)]
    for prefix, node in nodes:
        keys = node.keys()
        seen: set[str] = set()
        for key in keys:
            if key in seen:
                return prefix + key
            seen.add(key)
        if not prefix:   # the matrices' own keys (rows, cols, dt, data), one level down
            nodes.extend((f"{key}.", node.getNode(key)) for key in seen if node.getNode(key).isMap())
    return None


# OpenCV's FileStorage decodes base64 blocks (YAML "!!binary", XML "$base64$") in a loop that a damaged block keeps
# spinning for ever (OpenCV 5.1: a 60-byte YAML file "a: !!binary " + 40 x "A" never returns, at 100 % CPU). A
# calibration is a few numbers written as text (this module and camera_info write no base64), so a file holding such
# a block is refused before OpenCV parses it.
_BASE64_MARKERS = (b"!!binary", b"$base64$")


def refuse_base64(path: str | os.PathLike, data: bytes) -> None:
    """Raise BadFileError naming the line if ``data`` (a calibration file's bytes) holds a base64 block."""
    for marker in _BASE64_MARKERS:
        at = data.find(marker)
        if at >= 0:
            line = data.count(b"\n", 0, at) + 1
            raise BadFileError(f"{path}:{line}: field '(syntax)': a base64 block "
                               f"({marker.decode()}), which this reader does not read (OpenCV's parser can hang on "
                               "a damaged one): write the matrices as numbers")


def _check_file_size(path: Path) -> None:
    size = path.stat().st_size
    if size > MAX_FILE_BYTES:
        raise BadFileError(f"{path}: {size} bytes; a calibration file has at most {MAX_FILE_BYTES}")


def _cv_number(node, name: str, bad) -> float:
    if not (node.isInt() or node.isReal()):
        raise bad(name, "not a number")
    value = float(node.real())
    if not math.isfinite(value):
        raise bad(name, "non-finite number")
    return value


def _integral(value: float, name: str, bad) -> int:
    if value != int(value) or not 1 <= value <= MAX_IMAGE_SIDE:
        raise bad(name, f"image size {value:g} is not an integer in 1..{MAX_IMAGE_SIDE}")
    return int(value)


def _cv_size(node, name: str, bad) -> int | None:
    return None if node.empty() else _integral(_cv_number(node, name, bad), name, bad)


def _cv_matrix(node, name: str, bad) -> np.ndarray:
    """An ``opencv-matrix`` node (rows, cols, dt, data) as a float array, its size bounded before reading."""
    if not node.isMap():
        raise bad(name, "not an opencv-matrix (rows, cols, dt, data)")
    dims = []
    sizes = node.getNode("sizes")  # an opencv-nd-matrix (what FileStorage writes for a 1-D array)
    if not sizes.empty():
        if not sizes.isSeq() or not 1 <= sizes.size() <= 2:
            raise bad(name, "opencv-nd-matrix 'sizes' must list 1 or 2 dimensions")
        claims = [sizes.at(i) for i in range(sizes.size())]
    else:
        claims = [node.getNode("rows"), node.getNode("cols")]
    for key, sub in zip(("rows", "cols"), claims, strict=False):
        if sub.empty() or not sub.isInt():
            raise bad(name, f"opencv-matrix without an integer '{key}'")
        dims.append(int(sub.real()))
        if not 1 <= dims[-1] <= _MAX_MATRIX_SIDE:
            raise bad(name, f"opencv-matrix claims {dims[-1]} {key}; this format's matrices have 1..{_MAX_MATRIX_SIDE}")
    dt = node.getNode("dt")
    if not dt.empty() and (not dt.isString() or dt.string() not in ("d", "f", "i", "u", "s", "w", "c")):
        raise bad(name, "opencv-matrix 'dt' must be a single-channel number type (d, f, i, u, s, w, c)")
    data = node.getNode("data")
    count = math.prod(dims)
    if data.empty() or not data.isSeq() or data.size() != count:
        found = data.size() if data.isSeq() else 0
        raise bad(name, f"opencv-matrix data holds {found} numbers, {'x'.join(map(str, dims))} needs {count}")
    values = np.array([_cv_number(data.at(i), name, bad) for i in range(count)])
    return values.reshape(dims)


def _check_before_rectify(a: np.ndarray, name: str, size: tuple[int, int], fail) -> None:
    """What cv2.stereoRectify needs to give a meaningful answer (it would otherwise return NaNs or garbage)."""
    if name in ("K1", "K2") and not (0 < a[0, 0] <= MAX_FOCAL and 0 < a[1, 1] <= MAX_FOCAL):
        raise fail(f"focal lengths fx={a[0, 0]:g}, fy={a[1, 1]:g} px must be in (0, {MAX_FOCAL:g}]")
    if name == "R":
        error = float(np.max(np.abs(a.T @ a - np.eye(3))))
        if error > ROTATION_TOLERANCE or np.linalg.det(a) <= 0:
            raise fail(f"not a rotation matrix (|R^T R - I| = {error:.2g})")
    if name == "T" and not 0 < np.linalg.norm(a) <= MAX_BASELINE:
        raise fail(f"|T| = {np.linalg.norm(a):g} m, expected in (0, {MAX_BASELINE:g}]")


def _cv_error_text(exc: BaseException) -> str:
    return str(exc).strip().splitlines()[-1] if str(exc).strip() else "parse error"


def _cv_error_line(exc: BaseException) -> int | str:
    found = re.search(r"\((\d+)\): ", str(exc)) or re.search(r"line (\d+)", str(exc))
    return int(found.group(1)) if found else "?"


def write_opencv(calib: StereoCalibration, path: str | os.PathLike) -> None:
    """Write ``calib`` as OpenCV YAML or XML (by the suffix), atomically. T and P translations in metres."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".yaml", ".yml", ".xml"):
        raise ValueError(f"{path}: an OpenCV calibration file ends in .yaml, .yml or .xml")
    fs = cv2.FileStorage(f"out{suffix}", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    fs.write("image_width", int(calib.size[0]))
    fs.write("image_height", int(calib.size[1]))
    for name, value in (("M1", calib.K1), ("D1", calib.D1.reshape(1, -1)), ("M2", calib.K2),
                        ("D2", calib.D2.reshape(1, -1)), ("R", calib.R), ("T", calib.T.reshape(3, 1)),
                        ("R1", calib.R1), ("R2", calib.R2), ("P1", calib.P1), ("P2", calib.P2), ("Q", calib.Q),
                        ("head_pose", np.asarray(calib.head_pose, float).reshape(1, 6))):
        fs.write(name, np.asarray(value, np.float64))
    fs.writeComment("T and the P1/P2 translation column are in metres; head_pose is x y z (m) roll pitch yaw "
                    "(rad) of the head's midpoint on the robot (base_link)")
    text = fs.releaseAndGetString()
    atomic_write_bytes(path, text.encode())


# ============================== files by suffix ==============================

def load(path: str | os.PathLike) -> StereoCalibration:
    """Read a calibration file: ``.ini`` (SVS) or ``.yaml/.yml/.xml`` (OpenCV)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in (".yaml", ".yml", ".xml"):
        return read_opencv(path)
    if suffix == ".ini":
        try:
            text = read_bounded(path, MAX_FILE_BYTES).decode("latin-1")   # never waits on a FIFO
        except InputTooLargeError as exc:
            raise BadFileError(f"{path}: {exc}; a calibration file has at most {MAX_FILE_BYTES}") from None
        except OSError as exc:
            raise BadFileError(f"{path}: cannot read: {exc.strerror or exc}") from None
        return parse_svs(text, str(path))
    raise BadFileError(f"{path}: unknown calibration format (expected .ini, .yaml, .yml or .xml)")


def save(calib: StereoCalibration, path: str | os.PathLike) -> None:
    """Write a calibration file atomically, format by suffix (``.ini`` SVS, ``.yaml/.yml/.xml`` OpenCV).

    What :func:`load` would refuse is not written: raises BadFileError naming the field instead."""
    path = Path(path)
    check_calibration(calib, f"{path}: refusing to write")
    if path.suffix.lower() == ".ini":
        atomic_write_bytes(path, format_svs(calib).encode("latin-1"))
    else:
        write_opencv(calib, path)
