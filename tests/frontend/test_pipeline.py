"""The whole front end: functional core and class agree, observations are consistent, bad input is refused."""
from __future__ import annotations

import json

import numpy as np
import pytest

from estimation.frontend import (
    FrontEnd,
    FrontEndConfig,
    FrontEndError,
    RectificationMaps,
    StereoGeometry,
    run_frontend,
)
from estimation.observations import StereoObservations

from .conftest import shifted_pair


@pytest.fixture(scope="module")
def plane_pair():
    """A fronto-parallel textured plane at disparity 23.4 px, i.e. depth fx·B/d = 520·0.09/23.4 = 2 m."""
    return shifted_pair((240, 320), 23.4, seed=11)


def test_plane_is_triangulated_at_its_depth(plane_pair):
    left, right = plane_pair
    geometry = StereoGeometry(cx=159.5, cy=119.5)
    observations = FrontEnd(FrontEndConfig(geometry=geometry)).process(left, right, timestamp=12.5)
    assert isinstance(observations, StereoObservations)
    assert len(observations) > 50 and observations.timestamp == 12.5 and observations.frame == "base_link"
    assert observations.descriptors.shape == (len(observations), 64)
    assert observations.descriptors.dtype == np.float32
    # base_link x = depth + 0.12 for the default head
    np.testing.assert_allclose(np.median(observations.points[:, 0]), 2.12, atol=0.01)
    assert np.mean(np.abs(observations.points[:, 0] - 2.12) < 0.05) > 0.95
    # left pixels project back onto the points: u = cx - fx·(y - 0.045)/depth
    depth = observations.points[:, 0] - 0.12
    u = geometry.cx - geometry.fx * (observations.points[:, 1] - 0.045) / depth
    np.testing.assert_allclose(u, observations.pixels[:, 0], atol=1e-6)
    assert np.all(np.linalg.eigvalsh(observations.covariances) > 0)


def test_class_and_functional_core_agree(plane_pair):
    left, right = plane_pair
    config = FrontEndConfig(geometry=StereoGeometry(cx=159.5, cy=119.5))
    core = run_frontend(left, right, config)
    front_end = FrontEnd(config)
    observations = front_end.process(left, right, 3.0)
    np.testing.assert_array_equal(core.points_base, observations.points)
    np.testing.assert_array_equal(core.covariances_base, observations.covariances)
    assert front_end.last_matches is not None and len(front_end.last_matches) == len(observations)


def test_identity_rectification_changes_nothing(plane_pair):
    left, right = plane_pair
    h, w = left.shape
    map_x, map_y = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    maps = RectificationMaps(map_x, map_y, map_x, map_y)
    config = FrontEndConfig(geometry=StereoGeometry(cx=159.5, cy=119.5))
    np.testing.assert_array_equal(FrontEnd(config, maps).process(left, right, 0.0).points,
                                  FrontEnd(config).process(left, right, 0.0).points)


@pytest.mark.parametrize("descriptor, size", [("sift", 128), ("orb", 256)])
def test_other_descriptors_run_the_same_pipeline(plane_pair, descriptor, size):
    left, right = plane_pair
    observations = FrontEnd(FrontEndConfig(descriptor=descriptor, geometry=StereoGeometry(cx=159.5, cy=119.5))
                            ).process(left, right, 0.0)
    assert len(observations) > 30 and observations.descriptors.shape[1] == size
    assert np.mean(np.abs(observations.points[:, 0] - 2.12) < 0.05) > 0.9


def test_config_dumps_to_json():
    text = json.dumps(FrontEndConfig().to_dict())
    assert '"descriptor": "usurf"' in text and '"baseline": 0.09' in text


def test_bad_input_is_refused_clearly(plane_pair):
    left, right = plane_pair
    front_end = FrontEnd()
    with pytest.raises(FrontEndError, match="differ in size"):
        front_end.process(left, right[:, :-1], 0.0)
    with pytest.raises(FrontEndError, match="grey"):
        front_end.process(left[None], right[None], 0.0)
    with pytest.raises(FrontEndError):
        FrontEndConfig(descriptor="brief")
    with pytest.raises(FrontEndError):
        StereoGeometry(baseline=0.0)


def test_blank_pair_gives_an_empty_observation_set():
    blank = np.full((120, 160), 128, np.uint8)
    observations = FrontEnd().process(blank, blank, 1.0)
    assert len(observations) == 0 and observations.descriptors.shape == (0, 64)


def test_reused_buffers_never_leak_between_frames(plane_pair):
    # frames of different content and size through one FrontEnd give what the fresh functional core gives
    config = FrontEndConfig(geometry=StereoGeometry(cx=159.5, cy=119.5))
    near = plane_pair
    far = shifted_pair((240, 320), 9.7, seed=12)
    small = shifted_pair((200, 260), 15.2, seed=13)
    front_end = FrontEnd(config)
    for left, right in (near, far, small, near):
        expected = run_frontend(left, right, config)
        got = front_end.process(left, right, 0.0)
        np.testing.assert_array_equal(got.points, expected.points_base)
        np.testing.assert_array_equal(got.descriptors, expected.descriptors)


def test_settings_given_as_lists_work_like_tuples(plane_pair):
    # the front end caches per-configuration values; a configuration holding lists is unhashable and must still run
    from estimation.frontend import HarrisConfig

    left, right = plane_pair
    as_tuples = FrontEndConfig(harris=HarrisConfig(grid=(4, 3)),
                               geometry=StereoGeometry(cx=159.5, cy=119.5, head_pose=(0.1, 0.0, 0.5, 0.0, 0.0, 0.2)))
    as_lists = FrontEndConfig(harris=HarrisConfig(grid=[4, 3]),
                              geometry=StereoGeometry(cx=159.5, cy=119.5, head_pose=[0.1, 0.0, 0.5, 0.0, 0.0, 0.2]))
    expected, got = run_frontend(left, right, as_tuples), run_frontend(left, right, as_lists)
    assert len(expected) > 20
    np.testing.assert_array_equal(got.points_base, expected.points_base)
