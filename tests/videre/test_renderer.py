"""The building renderer: ground truth consistency, and rectified rendered pairs obeying epipolar geometry."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from drivers.videre import StereoHead
from mocks.stereo_head import VirtualStereoHead, default_calibration
from mocks.stereo_head.evaluation import project_rectified, window_alignment
from mocks.stereo_head.renderer import StereoRenderer


@pytest.fixture(scope="module")
def renderer(world) -> StereoRenderer:
    return StereoRenderer(world, default_calibration())


def _project(renderer, pose, points, camera):
    return project_rectified(renderer, pose, points, camera)


def test_true_points_reproject_to_their_pixels(renderer, world):
    pose = np.array([6.0, 4.6, 0.4])
    pixels = np.array([[10.0, 10.0], [320.0, 240.0], [600.0, 400.0], [100.0, 450.0], [500.3, 77.7]])
    points = renderer.true_points(pose, pixels, "left", rectified=True)
    assert np.all(np.isfinite(points))
    back, depth = _project(renderer, pose, points, "left")
    assert np.abs(back - pixels).max() < 1e-6 and np.all(depth > 0)
    # every true point lies on a wall face, the floor or the ceiling
    on_floor = np.isclose(points[:, 2], 0.0) | np.isclose(points[:, 2], renderer.ceiling_height)
    walls = np.asarray(world.walls)
    a, b = walls[:, :2], walls[:, 2:]
    t = np.clip(np.einsum("kij,ij->ki", points[:, None, :2] - a, b - a) / np.sum((b - a) ** 2, axis=1), 0, 1)
    dist = np.linalg.norm(points[:, None, :2] - (a + t[..., None] * (b - a)), axis=2).min(axis=1)
    assert np.all(on_floor | (dist < 1e-6))


def test_raw_pixels_see_the_same_points_as_their_rectified_images(renderer):
    pose = np.array([6.0, 4.6, 0.4])
    calib = renderer.calibration
    raw = np.array([[50.0, 60.0], [320.0, 240.0], [610.0, 420.0]])
    rect = cv2.undistortPoints(raw.reshape(-1, 1, 2), calib.K1, calib.D1, R=calib.R1, P=calib.P1).reshape(-1, 2)
    assert np.allclose(renderer.true_points(pose, raw, "left"),
                       renderer.true_points(pose, rect, "left", rectified=True), atol=1e-6)


def test_rendering_is_deterministic_and_distorted(renderer):
    pose = np.array([12.0, 5.2, -0.3])
    left_a, right_a = renderer.render(pose, (640, 480))
    left_b, _ = renderer.render(pose, (640, 480))
    assert np.array_equal(left_a, left_b)
    assert left_a.dtype == np.float32 and left_a.shape == (480, 640)
    assert not np.array_equal(left_a, right_a)
    assert 0.1 < left_a.mean() < 0.9 and left_a.std() > 0.05  # textured, not blank


@pytest.mark.parametrize("pose", [np.array([3.0, 5.0, 0.0]), np.array([9.0, 4.8, 2.6]), np.array([21.0, 5.2, 3.0]),
                                  np.array([14.0, 4.6, 0.5])])
def test_rectified_rendered_pairs_put_points_on_the_same_row(world, renderer, pose):
    """Grab a raw pair through the driver, rectify it with the calibration read from the head, and measure
    where each textured 32x32 window of the left image really is in the right image (phase correlation
    around the position the true 3-D point predicts): the vertical offset is the epipolar error (< 0.5 px),
    the horizontal residual the disparity error."""
    world.set_pose("robot1", pose)
    virtual = VirtualStereoHead(world, "robot1", rng=np.random.default_rng(7), renderer=renderer)
    with StereoHead.open(backend=virtual) as head:
        calib = head.read_calibration()
        head.start()
        frame = head.grab()
    vertical, horizontal = window_alignment(renderer, pose, *calib.rectify(frame.left, frame.right))
    vertical, horizontal = np.abs(vertical), np.abs(horizontal)
    assert len(vertical) >= 10, f"only {len(vertical)} textured windows"
    assert np.percentile(vertical, 90) < 0.5 and np.median(vertical) < 0.2
    assert np.median(horizontal) < 0.5


def test_point_image_depth_matches_the_wall_the_camera_faces(renderer, world):
    pose = np.array([3.0, 5.0, np.pi / 2])  # in the corridor, looking at its north wall
    points = renderer.point_image(pose, "left", (64, 48), rectified=True)
    assert points.shape == (48, 64, 3)
    cam = renderer.camera_pose_world(pose, "left", (64, 48), rectified=True)
    centre_ray_point = points[24, 32]
    ranges, _ = world.raycast(cam[:2, 3], np.array([np.pi / 2]), 50.0)
    assert np.hypot(*(centre_ray_point[:2] - cam[:2, 3])) == pytest.approx(ranges[0], abs=0.05)
