"""Images of the simulated building seen by the stereo head on a virtual P3-AT (a 2.5-D column renderer).

Walls are vertical and the floor is flat, so for a LEVEL pinhole camera every image column is one
horizontal ray: one ``world.raycast`` per column gives the wall, and the rows of that column are a straight
line through the wall texture (height z), the floor or the ceiling. Each physical camera is rendered as
such a level "ideal" camera at its optical centre and heading, and one ``cv2.remap`` per image then applies
its real orientation (pitch/roll, the stereo rotation) and lens distortion. Texture lookups are a second
``cv2.remap`` into the baked atlas (``textures.py``), so a 640x480 pair costs two raycasts of ~700 rays and
four remaps.

Every remap takes fixed-point maps (``cv2.convertMaps``: 1/32 px), never float maps: OpenCV 4.x quantizes
float maps to 1/32 px inside ``remap`` while 5.x interpolates them exactly, so float maps made the simulated
hardware, and every figure measured on it, depend on the OpenCV build. Fixed-point maps give the same
pixels in both.

The output is radiance (albedo, float32 0..1); the virtual head's sensor model turns it into digital
numbers with exposure, gain and noise. ``true_points`` gives the exact 3-D point behind any pixel.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from drivers.videre.calibration import OPTICAL_TO_BODY, StereoCalibration
from mocks.stereo_head.textures import FLOOR_TILE_M, Atlas, build_atlas

CAMERAS = ("left", "right")


@dataclass(frozen=True)
class _CameraSetup:
    """One camera at one image size: its mounting and the raw-pixel -> ideal-level-pixel map."""

    K: np.ndarray  # (3, 3) raw intrinsics at this size
    D: np.ndarray  # (5,)
    rotation_body: np.ndarray  # (3, 3) optical frame -> base_link
    centre_body: np.ndarray  # (3,) optical centre in base_link
    yaw: float  # heading of the optical axis in base_link
    to_level: np.ndarray  # (3, 3) optical frame -> level optical frame
    focal: float  # of the ideal level camera
    ideal_cx: float
    ideal_cy: float
    ideal_size: tuple[int, int]  # (width, height)
    map_x: np.ndarray  # (H, W) float32: ideal-image column of each raw pixel
    map_y: np.ndarray
    fixed_maps: tuple[np.ndarray, np.ndarray]  # the same as cv2's fixed-point maps (faster remap)
    rays_x: np.ndarray  # (W',) level-frame x/z of each ideal column
    rays_y: np.ndarray  # (H',) level-frame y/z of each ideal row


def _remap(image: np.ndarray, map_x: np.ndarray, map_y: np.ndarray, border: int) -> np.ndarray:
    """Bilinear ``cv2.remap`` of ``image`` through float32 maps, quantized to OpenCV's fixed point first."""
    fixed = cv2.convertMaps(map_x, map_y, cv2.CV_16SC2)
    return cv2.remap(image, *fixed, cv2.INTER_LINEAR, borderMode=border)


def _rot_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class StereoRenderer:
    """Renders raw (distorted, unrectified) left/right radiance images of ``world`` for a robot pose.

    calibration: the head's calibration (any size; rendering at another size scales it).
    texture_resolution: atlas pixels per metre of wall. max_range: metres of the longest ray.
    """

    def __init__(self, world, calibration: StereoCalibration, texture_resolution: float = 100.0,
                 max_range: float = 60.0):
        self.world = world
        self.calibration = calibration
        self.max_range = float(max_range)
        self.ceiling_height = float(np.max(world.wall_heights)) if len(world.wall_heights) else 3.0
        self.atlas: Atlas = build_atlas(np.asarray(world.walls, float), list(world.decorations),
                                        self.ceiling_height, texture_resolution)
        walls = np.asarray(world.walls, float)
        self._wall_start = walls[:, :2]
        lengths = np.hypot(walls[:, 2] - walls[:, 0], walls[:, 3] - walls[:, 1])
        self._wall_dir = (walls[:, 2:] - walls[:, :2]) / np.maximum(lengths, 1e-12)[:, None]
        self._setups: dict[tuple[int, int], tuple[_CameraSetup, _CameraSetup]] = {}

    # ------------------------------------------------------------------ camera geometry
    def setups(self, size: tuple[int, int]) -> tuple[_CameraSetup, _CameraSetup]:
        size = (int(size[0]), int(size[1]))
        if size not in self._setups:
            calib = self.calibration.scaled(*size)
            left_to_base = calib.left_camera_to_base(rectified=False)
            r_left, c_left = left_to_base[:3, :3], left_to_base[:3, 3]
            r_right = r_left @ calib.R.T
            c_right = c_left - r_right @ calib.T
            self._setups[size] = (self._setup(calib.K1, calib.D1, r_left, c_left, size),
                                  self._setup(calib.K2, calib.D2, r_right, c_right, size))
        return self._setups[size]

    @staticmethod
    def _setup(K: np.ndarray, D: np.ndarray, rotation: np.ndarray, centre: np.ndarray,
               size: tuple[int, int]) -> _CameraSetup:
        width, height = size
        axis = rotation[:, 2]
        yaw = math.atan2(axis[1], axis[0])
        to_level = (_rot_z(yaw) @ OPTICAL_TO_BODY).T @ rotation
        u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
        pix = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
        normalized = cv2.undistortPoints(pix, K, D).reshape(-1, 2)
        rays = np.column_stack([normalized, np.ones(len(normalized))]) @ to_level.T
        xl, yl = rays[:, 0] / rays[:, 2], rays[:, 1] / rays[:, 2]
        focal = float(max(K[0, 0], K[1, 1]))
        margin = 2.0
        cx = -focal * xl.min() + margin
        cy = -focal * yl.min() + margin
        ideal_w = int(math.ceil(focal * (xl.max() - xl.min()) + 2 * margin)) + 1
        ideal_h = int(math.ceil(focal * (yl.max() - yl.min()) + 2 * margin)) + 1
        map_x = (focal * xl + cx).reshape(height, width).astype(np.float32)
        map_y = (focal * yl + cy).reshape(height, width).astype(np.float32)
        rays_x = (np.arange(ideal_w) - cx) / focal
        rays_y = (np.arange(ideal_h) - cy) / focal
        fixed = cv2.convertMaps(map_x, map_y, cv2.CV_16SC2)
        return _CameraSetup(np.asarray(K, float), np.asarray(D, float), rotation, centre, yaw, to_level, focal,
                            cx, cy, (ideal_w, ideal_h), map_x, map_y, fixed, rays_x, rays_y)

    def _camera_in_world(self, setup: _CameraSetup, pose: np.ndarray) -> tuple[np.ndarray, float, float]:
        x, y, theta = (float(p) for p in pose)
        c, s = math.cos(theta), math.sin(theta)
        cb = setup.centre_body
        return np.array([x + c * cb[0] - s * cb[1], y + s * cb[0] + c * cb[1]]), float(cb[2]), theta + setup.yaw

    # ------------------------------------------------------------------ rendering
    def render(self, pose: np.ndarray, size: tuple[int, int] = (640, 640 * 3 // 4)) -> tuple[np.ndarray, np.ndarray]:
        """Raw left and right radiance images, each (height, width) float32 in 0..1, for robot ``pose`` (3,)."""
        left_setup, right_setup = self.setups(size)
        return self._render_camera(left_setup, pose), self._render_camera(right_setup, pose)

    def _render_camera(self, setup: _CameraSetup, pose: np.ndarray) -> np.ndarray:
        ideal = self._render_ideal(setup, pose)
        raw = cv2.remap(ideal, *setup.fixed_maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return raw.astype(np.float32) * np.float32(1.0 / 255.0)

    def _render_ideal(self, setup: _CameraSetup, pose: np.ndarray) -> np.ndarray:
        """The level camera's image (H', W') uint8: walls from the atlas, floor and ceiling from their tiles."""
        atlas = self.atlas
        res = atlas.resolution
        f32 = np.float32
        centre, cam_z, heading = self._camera_in_world(setup, pose)
        xl = setup.rays_x  # (W',)
        yl = setup.rays_y.astype(f32)  # (H',), increasing downwards
        azimuth = heading - np.arctan(xl)
        cos_a, sin_a = np.cos(azimuth), np.sin(azimuth)
        ranges, walls = self.world.raycast(centre, azimuth, self.max_range)
        secant = np.sqrt(1.0 + xl * xl)
        depth = ranges / secant  # optical-axis depth of the wall (or of the end of the ray) in each column
        hit = walls >= 0
        w = np.where(hit, walls, 0)
        hit_xy = centre[None, :] + ranges[:, None] * np.column_stack([cos_a, sin_a])
        along = np.einsum("ij,ij->i", hit_xy - self._wall_start[w], self._wall_dir[w])
        to_cam = centre[None, :] - self._wall_start[w]
        side = ((self._wall_dir[w, 0] * to_cam[:, 1] - self._wall_dir[w, 1] * to_cam[:, 0]) > 0).astype(int)
        # Wall texel of pixel (row, col): x = x0 + s * res, y = y0 + (ceiling - z) * res, z = cam_z - yl * depth.
        col_x = np.where(hit, atlas.face_x0[w, side] + along * res, atlas.far_pixel[0]).astype(f32)
        col_y = np.where(hit, atlas.face_y0[w, side] + (atlas.ceiling_height - cam_z) * res,
                         atlas.far_pixel[1]).astype(f32)
        col_dy = np.where(hit, depth * res, 0.0).astype(f32)
        map_x = np.empty((len(yl), len(xl)), f32)
        map_x[:] = col_x
        map_y = col_y[None, :] + yl[:, None] * col_dy[None, :]
        image = _remap(atlas.image, map_x, map_y, cv2.BORDER_REPLICATE)
        # Floor (rows below the horizon) and ceiling (above): where the row meets the plane before the wall.
        texels_per_m = f32(atlas.tile_pixels / FLOOR_TILE_M)
        step_x = (secant * cos_a).astype(f32)[None, :] * texels_per_m
        step_y = (secant * sin_a).astype(f32)[None, :] * texels_per_m
        horizon = int(np.searchsorted(yl, 0.0, side="right"))
        depth32 = depth.astype(f32)[None, :]
        for rows, drop, tile in ((slice(horizon, len(yl)), cam_z, atlas.floor),
                                 (slice(0, horizon), cam_z - self.ceiling_height, atlas.ceiling)):
            band = yl[rows]
            band = band[band != 0]
            if len(band) != rows.stop - rows.start or drop == 0:
                continue
            dist = (f32(drop) / band)[:, None]  # optical depth where each row meets the plane
            # Wrapped into the tile first: fixed-point maps hold 16-bit integer parts.
            tx = np.mod(f32(centre[0] * texels_per_m) + dist * step_x, f32(tile.shape[1]))
            ty = np.mod(f32(centre[1] * texels_per_m) + dist * step_y, f32(tile.shape[0]))
            plane = _remap(tile, tx, ty, cv2.BORDER_WRAP)
            nearer = (dist < depth32) & (dist > 0)
            image[rows] = np.where(nearer, plane, image[rows])
        return image

    # ------------------------------------------------------------------ ground truth
    def camera_pose_world(self, pose: np.ndarray, camera: str = "left", size: tuple[int, int] = (640, 480),
                          rectified: bool = False) -> np.ndarray:
        """(4, 4) transform from the camera's (raw or rectified) optical frame to the world."""
        setup = self.setups(size)[CAMERAS.index(camera)]
        calib = self.calibration
        rotation = setup.rotation_body @ ((calib.R1 if camera == "left" else calib.R2).T if rectified else np.eye(3))
        x, y, theta = (float(p) for p in pose)
        body_to_world = np.eye(4)
        body_to_world[:3, :3] = _rot_z(theta)
        body_to_world[:3, 3] = (x, y, 0.0)
        cam_to_body = np.eye(4)
        cam_to_body[:3, :3] = rotation
        cam_to_body[:3, 3] = setup.centre_body
        return body_to_world @ cam_to_body

    def true_points(self, pose: np.ndarray, pixels: np.ndarray, camera: str = "left",
                    size: tuple[int, int] = (640, 480), rectified: bool = False) -> np.ndarray:
        """The 3-D world point (N, 3) behind each pixel (N, 2) (u, v) of the raw (or rectified) image of
        ``camera`` at ``size``, for robot ``pose``; NaN where the ray meets nothing within ``max_range``."""
        setup = self.setups(size)[CAMERAS.index(camera)]
        pixels = np.asarray(pixels, float).reshape(-1, 2)
        if rectified:
            calib = self.calibration.scaled(*size)
            P, Rr = (calib.P1, calib.R1) if camera == "left" else (calib.P2, calib.R2)
            homog = np.column_stack([pixels, np.ones(len(pixels))])
            rays_cam = (np.linalg.inv(P[:, :3]) @ homog.T).T @ Rr  # rectified ray -> raw camera frame (R^T r)
        else:
            normalized = cv2.undistortPoints(pixels.reshape(-1, 1, 2), setup.K, setup.D).reshape(-1, 2)
            rays_cam = np.column_stack([normalized, np.ones(len(normalized))])
        rays = rays_cam @ setup.to_level.T
        xl, yl = rays[:, 0] / rays[:, 2], rays[:, 1] / rays[:, 2]
        centre, cam_z, heading = self._camera_in_world(setup, pose)
        azimuth = heading - np.arctan(xl)
        ranges, walls = self.world.raycast(centre, azimuth, self.max_range)
        secant = np.sqrt(1.0 + xl * xl)
        depth = np.where(walls >= 0, ranges / secant, np.inf)
        with np.errstate(divide="ignore", invalid="ignore"):
            floor_depth = np.where(yl > 0, cam_z / yl, np.inf)
            ceiling_depth = np.where(yl < 0, (cam_z - self.ceiling_height) / yl, np.inf)
        depth = np.minimum(np.minimum(depth, floor_depth), ceiling_depth)
        depth = np.where(depth * secant <= self.max_range, depth, np.nan)
        horizontal = depth * secant
        out = np.column_stack([centre[0] + horizontal * np.cos(azimuth), centre[1] + horizontal * np.sin(azimuth),
                               cam_z - yl * depth])
        return out

    def point_image(self, pose: np.ndarray, camera: str = "left", size: tuple[int, int] = (640, 480),
                    rectified: bool = False) -> np.ndarray:
        """``true_points`` of every pixel: (height, width, 3) world points (NaN where nothing is hit)."""
        width, height = size
        u, v = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
        points = self.true_points(pose, np.column_stack([u.ravel(), v.ravel()]), camera, size, rectified)
        return points.reshape(height, width, 3)
