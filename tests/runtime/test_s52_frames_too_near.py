"""A robot's frames that face a surface nearer than its stereo head measures give no reading, and are counted and said.

The scene: a wall of tiles (a random texture repeated every 100 px, each tile with a weaker texture of its own), so
that every corner has a look-alike one tile along the row; at a disparity of 150 px (0.31 m, nearer than the head's
fx·B / max_disparity = 0.4875 m) the window search of the front end before session 52 gave it that look-alike, a wrong
depth; at 40 px (1.17 m) it is in range.
"""
from __future__ import annotations

import cv2
import numpy as np

from estimation.frontend import FrontEndConfig, StereoGeometry
from runtime.onboard import CameraFrame, OnboardConfig, SlamCore
from runtime.report import too_near_line

SHAPE, PERIOD = (200, 400), 100


def _texture(shape, seed):
    noise = cv2.GaussianBlur(np.random.default_rng(seed).uniform(0, 255, shape), (0, 0), 1.5)
    return (noise - noise.min()) / (noise.max() - noise.min()) * 235 + 10


def _wall(disparity: int) -> tuple[np.ndarray, np.ndarray]:
    h, w = SHAPE
    width = w + disparity + PERIOD
    scene = np.tile(_texture((h, PERIOD), 3), (1, width // PERIOD + 1))[:, :width]
    scene = scene + 0.35 * (_texture((h, width), 4) - 127.5)
    image = np.clip(np.rint(scene), 0, 255).astype(np.uint8)
    return image[:, :w], image[:, disparity:disparity + w]


def test_frames_facing_a_wall_too_near_give_no_reading_and_are_counted():
    core = SlamCore("robot1", OnboardConfig(frontend=FrontEndConfig(geometry=StereoGeometry(cx=199.5, cy=99.5))))
    near, far = _wall(150), _wall(40)
    readings = []
    for k, pair in enumerate((far, near, near, far)):
        result = core.step(CameraFrame(0.25 * k, k, *pair), np.array([0.0, 0.0, 0.0]))
        readings.append(result.n_observations)
    assert readings[1] == readings[2] == 0 and readings[0] > 20 and readings[3] > 20
    assert core.frames_too_near == 2


def test_the_summary_line_names_the_robot_and_the_count():
    assert too_near_line("robot2", 48) == ("robot2: 48 frames faced a surface nearer than the stereo head measures "
                                           "(most matches beyond its disparity range): no reading taken from them, "
                                           "the filter only predicted")
    assert too_near_line("robot1", 1).startswith("robot1: 1 frame faced") and "from it," in too_near_line("robot1", 1)
