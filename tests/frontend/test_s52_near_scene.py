"""The matcher's disparity range as a validity test (``StereoMatchConfig(search="full_row")``) and the frames that
look at a scene nearer than the head can measure (``near_scene_share``), the defaults since session 52.

The scene: a fronto-parallel wall of tiles (one random texture repeated every ``PERIOD`` px, each tile with its own
weaker texture on top, like bricks), so that a corner has look-alikes one period along the row. Nearer than the
head's minimum depth fx·B / max_disparity (520 · 0.09 / 96 = 0.4875 m) its true disparity lies beyond the window,
and the window search (the default before) gives it the look-alike inside the window: a wrong depth (the failure
helper C found on the rendered demo, where a robot turns 0.3 m from a wall). The whole-row search finds the true
match, beyond the range, and refuses it.
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.frontend import (
    FrontEnd,
    FrontEndConfig,
    FrontEndError,
    StereoGeometry,
    StereoMatchConfig,
    run_frontend,
)
from estimation.frontend.stereo import NEAR_SCENE_SHARE

from .conftest import texture

SHAPE = (200, 400)
PERIOD = 100
GEOMETRY = StereoGeometry(cx=199.5, cy=99.5)
MIN_DEPTH = GEOMETRY.fx * GEOMETRY.baseline / StereoMatchConfig().max_disparity   # 0.4875 m


def tiled_wall(disparity: int, seed: int = 3, overlay: float = 0.35) -> tuple[np.ndarray, np.ndarray]:
    """A rectified uint8 pair of the tiled wall at an integer disparity: right(u) = left(u + disparity)."""
    h, w = SHAPE
    width = w + disparity + PERIOD
    tile = np.tile(texture((h, PERIOD), seed), (1, width // PERIOD + 1))[:, :width]
    scene = tile + overlay * (texture((h, width), seed + 1) - 127.5)
    as_image = lambda a: np.clip(np.rint(a), 0, 255).astype(np.uint8)   # noqa: E731
    return as_image(scene[:, :w]), as_image(scene[:, disparity:disparity + w])


def frontend(pair, **matching):
    return run_frontend(*pair, FrontEndConfig(geometry=GEOMETRY, matching=StereoMatchConfig(**matching)))


@pytest.fixture(scope="module")
def near_wall():
    """The wall at disparity 150 px: 0.312 m, nearer than the head can measure."""
    return tiled_wall(150)


def test_the_window_search_makes_up_wrong_depths_for_a_wall_too_near(near_wall):
    m = frontend(near_wall, search="window")   # the default before session 52
    assert len(m) > 50 and m.beyond_range == 0 and not m.near_scene
    # every match is wrong: the truth (150 px) is not in the window (the sub-pixel step moves a match by < 2.5 px);
    # most take the look-alike one tile along
    assert np.all(m.disparities < 96 + 2.5)
    assert np.mean(np.abs(m.disparities - (150 - PERIOD)) < 1) > 0.8
    depth = m.points_camera[:, 2]
    assert np.median(depth) > 2.5 * 0.312   # 0.94 m for a wall at 0.31 m


def test_the_whole_row_search_refuses_the_true_matches_beyond_the_range(near_wall):
    window = frontend(near_wall, search="window")
    m = frontend(near_wall, search="full_row", near_scene_share=None)
    # the true matches are found, at the true disparity, and refused (counted, not returned)
    assert m.beyond_range > 0.8 * len(window)
    assert not m.near_scene and np.all(m.disparities <= 96)
    # what is left in range are look-alikes that neither the ratio test nor the left-right check could tell from
    # the truth (the true partner of their right corner is not among the left corners): a few, not the frame
    assert len(m) < 0.05 * (len(m) + m.beyond_range)


@pytest.mark.parametrize("share", [0.3, 0.0, 0.9])
def test_a_frame_mostly_beyond_the_range_gives_no_reading(near_wall, share):
    m = frontend(near_wall, search="full_row", near_scene_share=share)
    assert m.near_scene and len(m) == 0 and m.beyond_range > 50
    assert m.left_pixels.shape == (0, 2) and m.right_pixels.shape == (0, 2) and m.points_base.shape == (0, 3)
    assert m.covariances_base.shape == (0, 3, 3) and m.descriptors.shape == (0, 64)
    config = FrontEndConfig(geometry=GEOMETRY, matching=StereoMatchConfig(search="full_row", near_scene_share=share))
    front_end = FrontEnd(config)
    observations = front_end.process(*near_wall, timestamp=4.0)
    assert len(observations) == 0 and observations.descriptors.shape == (0, 64) and observations.timestamp == 4.0
    assert front_end.last_matches.near_scene


def test_a_wall_within_the_range_loses_at_most_a_few_ambiguous_matches():
    pair = tiled_wall(40)   # 1.17 m
    window, full = frontend(pair, search="window"), frontend(pair, search="full_row", near_scene_share=0.3)
    assert not full.near_scene and np.median(full.disparities) == pytest.approx(40, abs=0.2)
    # every match kept by the whole-row search is one of the window's, to the bit: its nearest, second nearest
    # and left-right partner over the whole row are within the window, so the window's tests pass too
    index = {tuple(p): k for k, p in enumerate(window.left_pixels)}
    same = np.array([index[tuple(p)] for p in full.left_pixels])
    np.testing.assert_array_equal(window.disparities[same], full.disparities)
    np.testing.assert_array_equal(window.points_base[same], full.points_base)
    np.testing.assert_array_equal(window.descriptors[same], full.descriptors)
    # the others: a look-alike one tile along (disparity 140, beyond the range) made the ratio test or the
    # left-right check refuse them, or was itself the nearest (counted beyond the range)
    assert len(full) >= 0.95 * len(window) and full.beyond_range <= 0.05 * len(full)


def test_the_default_is_the_whole_row_search_with_the_frame_rule(tsukuba, near_wall):
    assert StereoMatchConfig().search == "full_row" and StereoMatchConfig().near_scene_share == NEAR_SCENE_SHARE
    default = run_frontend(*tsukuba)
    window = run_frontend(*tsukuba, FrontEndConfig(matching=StereoMatchConfig(search="window")))
    # a real scene (tsukuba, disparities up to ~15 px) within the range: the whole row keeps all but a few of the
    # window's matches, and refuses few
    assert len(default) > 100 and not default.near_scene
    assert len(default) >= 0.9 * len(window) and default.beyond_range <= 0.05 * len(window)
    # the wall too near: no reading by default
    assert frontend(near_wall).near_scene and len(frontend(near_wall)) == 0


@pytest.mark.parametrize("bad", [
    {"search": "row"}, {"search": None}, {"near_scene_share": 1.0}, {"search": "window", "near_scene_share": -1},
    {"search": "full_row", "near_scene_share": 1.0}, {"search": "full_row", "near_scene_share": -0.1},
    {"search": "full_row", "near_scene_share": float("nan")}, {"search": "full_row", "near_scene_share": "0.3"},
    {"search": "full_row", "near_scene_share": True}])
def test_bad_option_values_are_refused_in_one_line(bad):
    with pytest.raises(FrontEndError) as error:
        StereoMatchConfig(**bad)
    assert "\n" not in str(error.value) and ("search" in str(error.value) or "near_scene_share" in str(error.value))


@settings(max_examples=30, deadline=None)
@given(disparity=st.integers(110, 190), seed=st.integers(0, 50))
def test_any_wall_nearer_than_the_minimum_depth_gives_no_reading(disparity, seed):
    """Over the wall's depth (0.25-0.43 m, all nearer than 0.4875 m) and its texture: the window search returns
    wrong depths, the whole-row search with the frame rule none."""
    pair = tiled_wall(disparity, seed)
    assert GEOMETRY.fx * GEOMETRY.baseline / disparity < MIN_DEPTH
    window = frontend(pair, search="window")
    nearest = GEOMETRY.fx * GEOMETRY.baseline / (96 + 2.5)   # the window's, after the sub-pixel step
    assert len(window) > 0 and np.all(window.points_camera[:, 2] > nearest)   # every one wrong
    m = frontend(pair, search="full_row", near_scene_share=0.3)
    assert m.near_scene and len(m) == 0 and m.beyond_range > 0
