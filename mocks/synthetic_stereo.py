"""A simulated stereo sensor and simulated odometry: ground truth in, estimator inputs out (no images).

:class:`SyntheticStereo` sees the world's feature points that a real head at the robot's true pose could see
(in the image, within depth and disparity limits, facing the camera and in line of sight), perturbs their
pixel coordinates and disparity with the front end's noise model (σ_u = σ_v = 0.5 px, σ_d = 0.3 px) and
triangulates them exactly as the front end does, so the reported covariances are the front end's first-order
ones and the errors are the real non-linear ones. Descriptors are the feature's own plus a little noise.

:class:`SyntheticOdometry` turns consecutive true poses into :class:`OdometryIncrement` s with a fixed
per-run scale error on distance and on turning (what wheel-diameter and wheel-base errors do) plus
random-walk noise.

Both draw only from the ``np.random.Generator`` they are given. The observer is pluggable: anything with
``observe(pose, timestamp) -> (StereoObservations, feature_index)`` can stand in for it (rendered frames
through the front end, later).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from estimation.frontend.triangulation import (
    StereoGeometry,
    TriangulationNoise,
    camera_to_base,
    keep_triangulable,
    triangulate,
    triangulation_covariances,
)
from estimation.geometry import between, rot_z
from estimation.observations import OdometryIncrement, StereoObservations

WIDTH, HEIGHT = 640, 480  # the decimated images of the virtual STH-MDCS2


@dataclass(frozen=True)
class SyntheticStereoConfig:
    """Sensor settings. detection_probability: chance a visible feature is detected in a frame;
    max_points: cap on points per frame (a random subset, like a front end's best-N corners);
    descriptor_noise: σ of the noise added to each descriptor element before renormalising."""

    geometry: StereoGeometry = StereoGeometry()
    noise: TriangulationNoise = TriangulationNoise()
    width: int = WIDTH
    height: int = HEIGHT
    detection_probability: float = 0.9
    max_points: int = 80
    descriptor_noise: float = 0.02


class SyntheticStereo:
    """Simulated stereo observations of known 3-D feature points.

    features (K, 3) world metres; descriptors (K, D) unit rows; ``visible(camera_pose (3,), eye_height) ->
    (K,) bool`` decides occlusion and facing (``World.visible_features`` via :meth:`from_world`; default:
    everything in view is visible).
    """

    def __init__(self, features: np.ndarray, descriptors: np.ndarray, rng: np.random.Generator,
                 config: SyntheticStereoConfig = SyntheticStereoConfig(),
                 visible: Callable[[np.ndarray, float], np.ndarray] | None = None) -> None:
        self.features = np.asarray(features, float).reshape(-1, 3)
        self.descriptors = np.asarray(descriptors, np.float32).reshape(len(self.features), -1)
        self.rng = rng
        self.config = config
        self._visible = visible
        cam = config.geometry.left_camera_to_base()
        self._cam_rotation, self._cam_translation = cam[:3, :3], cam[:3, 3]

    @classmethod
    def from_world(cls, world, rng: np.random.Generator,
                   config: SyntheticStereoConfig = SyntheticStereoConfig()) -> SyntheticStereo:
        """An observer of ``world.features`` that respects the world's walls (``world.visible_features``)."""
        g = config.geometry
        hfov = 2.0 * np.arctan(config.width / 2.0 / g.fx) + 0.05
        max_range = 1.5 * config.noise.max_depth  # a generous disc; depth is checked exactly afterwards

        def visible(camera_pose: np.ndarray, eye_height: float) -> np.ndarray:
            return world.visible_features(camera_pose, eye_height, hfov, max_range)

        return cls(world.features, world.feature_descriptors, rng, config, visible)

    def observe(self, pose, timestamp: float = 0.0) -> tuple[StereoObservations, np.ndarray]:
        """Observations in base_link from the robot's true world pose (3,), and the index (N,) of the feature
        each came from."""
        cfg, g = self.config, self.config.geometry
        pose = np.asarray(pose, float)
        base = (self.features - np.array([pose[0], pose[1], 0.0])) @ rot_z(pose[2])     # world -> base_link
        cam = (base - self._cam_translation) @ self._cam_rotation                       # base_link -> left optical
        depth = cam[:, 2]
        ok = depth > 1e-3
        u = np.where(ok, g.fx * cam[:, 0] / np.where(ok, depth, 1.0) + g.cx, -1.0)
        v = np.where(ok, g.fy * cam[:, 1] / np.where(ok, depth, 1.0) + g.cy, -1.0)
        disparity = np.where(ok, g.fx * g.baseline / np.where(ok, depth, 1.0), 0.0)
        ok &= (u >= 0) & (u <= cfg.width - 1) & (v >= 0) & (v <= cfg.height - 1)
        ok &= keep_triangulable(disparity, g, cfg.noise)
        ok &= self.rng.random(len(ok)) < cfg.detection_probability
        if self._visible is not None and ok.any():
            head = np.asarray(g.head_pose[:3])
            camera_xy = pose[:2] + rot_z(pose[2])[:2, :2] @ head[:2]
            ok &= self._visible(np.array([camera_xy[0], camera_xy[1], pose[2]]), float(head[2]))
        index = np.flatnonzero(ok)
        if len(index) > cfg.max_points:
            index = np.sort(self.rng.choice(index, cfg.max_points, replace=False))
        n = len(index)
        pixels = np.stack([u[index] + self.rng.normal(0.0, cfg.noise.sigma_u, n),
                           v[index] + self.rng.normal(0.0, cfg.noise.sigma_v, n)], axis=1)
        noisy_d = disparity[index] + self.rng.normal(0.0, cfg.noise.sigma_d, n)
        keep = keep_triangulable(noisy_d, g, cfg.noise)
        index, pixels, noisy_d = index[keep], pixels[keep], noisy_d[keep]
        points_cam = triangulate(pixels, noisy_d, g)
        points, covariances = camera_to_base(points_cam, triangulation_covariances(pixels, noisy_d, g, cfg.noise), g)
        desc = self.descriptors[index] + self.rng.normal(0.0, cfg.descriptor_noise, (len(index),
                                                                                     self.descriptors.shape[1]))
        norms = np.linalg.norm(desc, axis=1, keepdims=True)
        desc = (desc / np.where(norms > 0, norms, 1.0)).astype(np.float32)
        return StereoObservations(points, covariances, desc, pixels, float(timestamp)), index


@dataclass(frozen=True)
class OdometryErrorModel:
    """Odometry error: fixed scale errors (σ of the per-run draw) and random-walk noise variances."""

    distance_scale_sigma: float = 0.02     # the run's distance scale error ~ N(0, σ²)
    turn_scale_sigma: float = 0.03         # the run's turning scale error ~ N(0, σ²)
    xy_var_per_m: float = 0.01 ** 2        # m² per metre
    theta_var_per_rad: float = 0.02 ** 2   # rad² per radian
    theta_var_per_m: float = 0.01 ** 2     # rad² per metre


class SyntheticOdometry:
    """Odometry increments between true poses, with the errors of :class:`OdometryErrorModel`."""

    def __init__(self, rng: np.random.Generator, model: OdometryErrorModel = OdometryErrorModel()) -> None:
        self.rng = rng
        self.model = model
        self.distance_scale = 1.0 + rng.normal(0.0, model.distance_scale_sigma)
        self.turn_scale = 1.0 + rng.normal(0.0, model.turn_scale_sigma)

    def increment(self, previous_pose, pose, t0: float = 0.0, t1: float = 0.0) -> OdometryIncrement:
        """The measured motion from ``previous_pose`` to ``pose`` (world, (3,) each)."""
        m = self.model
        true = between(np.asarray(previous_pose, float), np.asarray(pose, float))
        trans = float(np.hypot(true[0], true[1]))
        xy_sigma = np.sqrt(m.xy_var_per_m * trans)
        theta_sigma = np.sqrt(m.theta_var_per_rad * abs(true[2]) + m.theta_var_per_m * trans)
        dx = true[0] * self.distance_scale + self.rng.normal(0.0, xy_sigma)
        dy = true[1] * self.distance_scale + self.rng.normal(0.0, xy_sigma)
        dtheta = true[2] * self.turn_scale + self.rng.normal(0.0, theta_sigma)
        return OdometryIncrement(float(dx), float(dy), float(dtheta), float(t0), float(t1))
