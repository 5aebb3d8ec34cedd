"""Triangulation of rectified stereo matches to 3-D points with first-order covariances.

Left-camera optical frame: z forward, x right, y down; the left camera is the reference. With focal
lengths fx, fy (px), principal point (cx, cy), baseline B (m) and disparity d = u_left - u_right (px):
    Z = fx·B / d,   X = (u - cx)·B / d,   Y = (v - cy)·(fx / fy)·B / d.
The covariance is J·diag(σu², σv², σd²)·Jᵀ with J = ∂(X, Y, Z)/∂(u, v, d); u, v and d are taken as
independent (σ_d being the sub-pixel disparity's own error), as the team's noise model specifies.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from estimation.frontend.caching import once_per_value
from estimation.frontend.errors import FrontEndError

# base_link axes (x forward, y left, z up) in terms of the optical axes: x_b = z_c, y_b = -x_c, z_b = -y_c
OPTICAL_TO_BODY = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True)
class StereoGeometry:
    """Rectified stereo intrinsics and the head's pose on the robot (defaults: the virtual STH-MDCS2).

    fx, fy, cx, cy: px;  baseline: m (left to right optical centre);
    head_pose: (x, y, z, roll, pitch, yaw) in base_link of the midpoint of the two optical centres, with the
    head's axes x forward, y left, z up (rotation Rz(yaw)·Ry(pitch)·Rx(roll)); the left camera sits at
    y = +baseline / 2 in the head frame.
    left_camera_pose: optional 16 numbers (row-major 4×4) of the left (rectified) optical frame in base_link,
    which then replaces the head_pose construction (a calibration's rectifying rotation included).
    """

    fx: float = 520.0
    fy: float = 520.0
    cx: float = 319.5
    cy: float = 239.5
    baseline: float = 0.09
    head_pose: tuple[float, float, float, float, float, float] = (0.12, 0.0, 0.50, 0.0, 0.0, 0.0)
    left_camera_pose: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        if self.left_camera_pose is not None and len(self.left_camera_pose) != 16:
            raise FrontEndError(f"left_camera_pose must hold 16 numbers (a 4×4), got {len(self.left_camera_pose)}")
        if self.fx <= 0 or self.fy <= 0 or self.baseline <= 0:
            raise FrontEndError(f"fx, fy and baseline must be positive, got {self.fx}, {self.fy}, {self.baseline}")
        if len(self.head_pose) != 6:
            raise FrontEndError(f"head_pose must be (x, y, z, roll, pitch, yaw), got {self.head_pose}")

    def to_dict(self) -> dict:
        """Plain numbers for a file's settings (a sensor log's metadata); :meth:`from_dict` reads them back."""
        return {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy, "baseline": self.baseline,
                "head_pose": list(self.head_pose),
                "left_camera_pose": None if self.left_camera_pose is None else list(self.left_camera_pose)}

    @classmethod
    def from_dict(cls, d: dict) -> StereoGeometry:
        """The geometry :meth:`to_dict` wrote (``head_pose`` defaults to the virtual head's). A missing field is a
        KeyError, a field that is no number a TypeError or ValueError: the reader of the file names it."""
        pose = d.get("left_camera_pose")
        return cls(float(d["fx"]), float(d["fy"]), float(d["cx"]), float(d["cy"]), float(d["baseline"]),
                   tuple(float(v) for v in d.get("head_pose", cls.head_pose)),
                   None if pose is None else tuple(float(v) for v in pose))

    @classmethod
    def with_head_matrix(cls, head_to_base: np.ndarray, **intrinsics: float) -> StereoGeometry:
        """Geometry whose head pose is given as a 4×4 head-to-base_link transform."""
        head_to_base = np.asarray(head_to_base, dtype=float)
        if head_to_base.shape != (4, 4):
            raise FrontEndError(f"head pose matrix must be 4×4, got {head_to_base.shape}")
        roll, pitch, yaw = Rotation.from_matrix(head_to_base[:3, :3]).as_euler("xyz")
        x, y, z = head_to_base[:3, 3]
        return cls(**intrinsics, head_pose=(float(x), float(y), float(z), float(roll), float(pitch), float(yaw)))

    @classmethod
    def with_camera_matrix(cls, left_camera_to_base: np.ndarray, **intrinsics: float) -> StereoGeometry:
        """Geometry whose left optical frame is given directly as a 4×4 camera-to-base_link transform."""
        T = np.asarray(left_camera_to_base, dtype=float)
        if T.shape != (4, 4):
            raise FrontEndError(f"camera pose matrix must be 4×4, got {T.shape}")
        return cls(**intrinsics, left_camera_pose=tuple(float(x) for x in T.reshape(-1)))

    def head_to_base(self) -> np.ndarray:
        """4×4 transform of the head frame (x forward, y left, z up) into base_link."""
        x, y, z, roll, pitch, yaw = self.head_pose
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("xyz", [roll, pitch, yaw]).as_matrix()
        T[:3, 3] = (x, y, z)
        return T

    def left_camera_to_base(self) -> np.ndarray:
        """4×4 transform of left-camera optical coordinates into base_link."""
        if self.left_camera_pose is not None:
            return np.array(self.left_camera_pose, dtype=float).reshape(4, 4)
        camera_in_head = np.eye(4)
        camera_in_head[:3, :3] = OPTICAL_TO_BODY
        camera_in_head[1, 3] = self.baseline / 2.0
        return self.head_to_base() @ camera_in_head


@dataclass(frozen=True)
class TriangulationNoise:
    """Pixel noise of the covariance model and the limits beyond which points are dropped.

    sigma_u, sigma_v: px, a corner's position;  sigma_d: px, the sub-pixel disparity;
    max_depth: m;  min_disparity: px.
    """

    sigma_u: float = 0.5
    sigma_v: float = 0.5
    sigma_d: float = 0.3
    max_depth: float = 12.0
    min_disparity: float = 3.0


def triangulate(pixels: np.ndarray, disparities: np.ndarray,
                geometry: StereoGeometry = StereoGeometry()) -> np.ndarray:
    """Left-camera points (N, 3) of left pixels (N, 2) (u, v) with disparities (N,) > 0."""
    pixels = np.asarray(pixels, dtype=float).reshape(-1, 2)
    d = np.asarray(disparities, dtype=float)
    ratio = geometry.baseline / d  # B / d
    return np.stack([(pixels[:, 0] - geometry.cx) * ratio,
                     (pixels[:, 1] - geometry.cy) * (geometry.fx / geometry.fy) * ratio,
                     geometry.fx * ratio], axis=1)


def triangulation_jacobian(pixels: np.ndarray, disparities: np.ndarray,
                           geometry: StereoGeometry = StereoGeometry()) -> np.ndarray:
    """J = ∂(X, Y, Z)/∂(u, v, d) at each match: (N, 3, 3)."""
    points = triangulate(pixels, disparities, geometry)
    d = np.asarray(disparities, dtype=float)
    J = np.zeros((len(d), 3, 3))
    J[:, 0, 0] = geometry.baseline / d
    J[:, 1, 1] = geometry.fx * geometry.baseline / (geometry.fy * d)
    J[:, :, 2] = -points / d[:, None]  # each coordinate is ∝ 1/d
    return J


def triangulation_covariances(pixels: np.ndarray, disparities: np.ndarray,
                              geometry: StereoGeometry = StereoGeometry(),
                              noise: TriangulationNoise = TriangulationNoise()) -> np.ndarray:
    """Left-camera covariances (N, 3, 3) m²: J·diag(σu², σv², σd²)·Jᵀ.

    Written out (J's only non-zeros are ∂X/∂u = B/d, ∂Y/∂v = fx·B/(fy·d) and ∂p/∂d = -p/d) rather than as
    a product of (N, 3, 3) arrays: the same numbers to rounding, without the einsum's per-call cost.
    """
    d = np.asarray(disparities, dtype=float)
    points = triangulate(pixels, d, geometry)
    ratio = geometry.baseline / d
    along_ray = points / d[:, None]  # -∂p/∂d, (N, 3)
    cov = along_ray[:, :, None] * (along_ray[:, None, :] * noise.sigma_d**2)  # σd² (p/d)(p/d)ᵀ
    cov[:, 0, 0] += (ratio * noise.sigma_u) ** 2
    cov[:, 1, 1] += (ratio * (geometry.fx / geometry.fy) * noise.sigma_v) ** 2
    return cov


@once_per_value
def _camera_rotation_translation(geometry: StereoGeometry) -> tuple[np.ndarray, np.ndarray]:
    """(R (3, 3), t (3,)) of ``geometry.left_camera_to_base()``, computed once per geometry (read-only)."""
    T = geometry.left_camera_to_base()
    R, t = np.ascontiguousarray(T[:3, :3]), T[:3, 3].copy()
    R.setflags(write=False)
    t.setflags(write=False)
    return R, t


def camera_to_base(points: np.ndarray, covariances: np.ndarray,
                   geometry: StereoGeometry = StereoGeometry()) -> tuple[np.ndarray, np.ndarray]:
    """Left-camera points (N, 3) and covariances (N, 3, 3) expressed in base_link: p' = R p + t, C' = R C Rᵀ."""
    R, t = _camera_rotation_translation(geometry)
    return points @ R.T + t, np.matmul(np.matmul(R, covariances), R.T)


def keep_triangulable(disparities: np.ndarray, geometry: StereoGeometry = StereoGeometry(),
                      noise: TriangulationNoise = TriangulationNoise()) -> np.ndarray:
    """Mask (N,) of disparities at least ``min_disparity`` whose depth fx·B/d is within ``max_depth``."""
    d = np.asarray(disparities, dtype=float)
    return (d >= noise.min_disparity) & (d > 0) & (geometry.fx * geometry.baseline <= noise.max_depth * d)
