"""Stereo matching: the ratio test, the left-right check, row and disparity gates, sub-pixel disparity."""
from __future__ import annotations

import numpy as np
import pytest

from estimation.frontend import FrontEndError, StereoMatchConfig, match_rows, refine_disparity_ssd
from estimation.frontend.descriptors import distance_matrix

from .conftest import shifted_pair


def unit(*rows):
    a = np.array(rows, dtype=np.float32)
    return a / np.linalg.norm(a, axis=1, keepdims=True)


def test_gates_ratio_and_left_right_check():
    config = StereoMatchConfig(row_tolerance=1.0, min_disparity=0.0, max_disparity=50.0, ratio=0.8, max_distance=None)
    left = np.array([[100.0, 10.0], [200.0, 20.0], [300.0, 30.0], [400.0, 40.0]])
    left_desc = unit([1, 0, 0], [0, 1, 0.005], [0, 0, 1], [1, 1, 0])
    right = np.array([
        [90.0, 10.5],    # 0: matches left 0 (same descriptor)
        [95.0, 13.0],    # 1: same descriptor as left 0 but 3 rows away: gated out
        [180.0, 20.0],   # 2: left 1's descriptor ...
        [185.0, 20.0],   # 3: ... and an almost identical one: ambiguous, the ratio test rejects left 1
        [310.0, 30.0],   # 4: left 2's descriptor at negative disparity: gated out
        [380.0, 40.0],   # 5: nearest for left 3 ...
    ])
    right_desc = unit([1, 0, 0], [1, 0, 0], [0, 1, 0], [0, 1, 0.01], [0, 0, 1], [1, 0.9, 0])
    li, ri, dist = match_rows(left, left_desc, right, right_desc, config)
    # left 3's nearest is right 5, but right 5's nearest left is left 0 only if nearer; here left 3 wins
    assert dict(zip(li.tolist(), ri.tolist(), strict=True)) == {0: 0, 3: 5}
    assert np.all(dist >= 0)


def test_left_right_check_rejects_a_one_sided_match():
    config = StereoMatchConfig(max_distance=None)
    left = np.array([[100.0, 10.0], [120.0, 10.0]])
    left_desc = unit([1, 0], [1, 0.1])
    right = np.array([[90.0, 10.0]])  # both left corners want it; it prefers left 0
    right_desc = unit([1, 0])
    li, ri, _ = match_rows(left, left_desc, right, right_desc, config)
    assert li.tolist() == [0] and ri.tolist() == [0]


def test_hamming_distance_of_bits():
    a = np.array([[1, 0, 1, 1], [0, 0, 0, 0]], np.float32)
    b = np.array([[1, 1, 1, 1]], np.float32)
    np.testing.assert_array_equal(distance_matrix(a, b, binary=True), [[1.0], [4.0]])


@pytest.mark.parametrize("true_disparity", [12.0, 12.3, 17.75])
def test_ssd_refinement_recovers_sub_pixel_disparity(true_disparity):
    left, right = shifted_pair((120, 200), true_disparity, seed=3)
    rng = np.random.default_rng(5)
    pixels = np.column_stack([rng.uniform(60, 190, 40), rng.uniform(10, 110, 40)])
    coarse = np.full(40, np.round(true_disparity) + rng.choice([-1.0, 0.0, 1.0], 40))
    refined, ok = refine_disparity_ssd(left, right, pixels, coarse, half_window=3)
    assert ok.all()
    assert np.median(np.abs(refined - true_disparity)) < 0.1
    assert np.abs(refined - true_disparity).max() < 0.35


def test_refinement_leaves_points_at_the_border_alone():
    left, right = shifted_pair((60, 80), 10.0)
    refined, ok = refine_disparity_ssd(left, right, np.array([[1.0, 30.0], [40.0, 30.0]]), np.array([9.0, 9.0]))
    assert ok.tolist() == [False, True] and refined[0] == 9.0


def test_bad_settings_are_refused():
    with pytest.raises(FrontEndError):
        StereoMatchConfig(subpixel="magic")
    with pytest.raises(FrontEndError):
        StereoMatchConfig(min_disparity=10, max_disparity=5)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_corners_without_candidates_can_be_left_out_before_matching(seed):
    # the front end describes only corners with a candidate on the other side; matching the subsets must give
    # exactly the matches of the full sets (ties included: descriptors drawn from a small set repeat)
    from estimation.frontend.stereo import with_candidates

    rng = np.random.default_rng(seed)
    left = np.column_stack([rng.uniform(0, 640, 150), rng.integers(0, 480, 150) + rng.uniform(-0.3, 0.3, 150)])
    right = np.column_stack([rng.uniform(0, 640, 140), rng.integers(0, 480, 140) + rng.uniform(-0.3, 0.3, 140)])
    palette = unit(*rng.normal(size=(12, 8)))
    left_desc, right_desc = palette[rng.integers(0, 12, 150)], palette[rng.integers(0, 12, 140)]
    config = StereoMatchConfig(max_distance=None, ratio=0.95)
    li, ri, dist = match_rows(left, left_desc, right, right_desc, config)
    keep_left, keep_right = with_candidates(left, right, config)
    assert 0 < keep_left.sum() < len(left) and 0 < keep_right.sum() < len(right)
    sli, sri, sdist = match_rows(left[keep_left], left_desc[keep_left], right[keep_right], right_desc[keep_right],
                                 config)
    assert len(li) > 5
    np.testing.assert_array_equal(np.flatnonzero(keep_left)[sli], li)
    np.testing.assert_array_equal(np.flatnonzero(keep_right)[sri], ri)
    np.testing.assert_allclose(sdist, dist, rtol=1e-6)
