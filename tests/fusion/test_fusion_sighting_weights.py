"""fuse_all(calibration="sightings"): each landmark weighted by the spread of its map's own sightings of it."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.geometry import between, inverse, transform_points
from estimation.landmark_map import LandmarkMap
from fusion import fuse_all
from fusion.alignment import Alignment

_FRAMES = (np.array([0.0, 0.0, 0.0]), np.array([4.0, -3.0, 1.2]))


def _pair(seed: int, taus: tuple[float, float], n: int = 60):
    """Two maps of one 60-landmark world in their own frames; landmark l is seen m_l times by both robots (4-15), each
    sighting of robot k off the truth by N(0, τ_k² I): its map holds their mean, their scatter about it and m_l.
    Returns the maps, the truth in map 0's frame and their alignment (the true one, on every landmark)."""
    rng = np.random.default_rng(seed)
    world = np.column_stack([rng.uniform(0, 30, n), rng.uniform(0, 20, n), np.zeros(n)])
    sightings = rng.integers(4, 16, n)
    maps = []
    for frame, tau in zip(_FRAMES, taus, strict=True):
        local = transform_points(inverse(frame), world)
        x, S = np.zeros((n, 3)), np.zeros((n, 3, 3))
        for i, m in enumerate(sightings):
            p = local[i] + np.column_stack([rng.normal(scale=tau, size=(m, 2)), np.zeros(m)])
            x[i] = p.mean(axis=0)
            S[i] = (p - x[i]).T @ (p - x[i]) / m
        maps.append(LandmarkMap(x, np.tile(np.diag([0.01, 0.01, 1e-6]), (n, 1, 1)), np.zeros((n, 0), np.float32),
                                counts=sightings, robot=f"robot{len(maps) + 1}", sighting_covariances=S))
    pose = between(_FRAMES[0], _FRAMES[1])
    supports = np.column_stack([np.arange(n), np.arange(n)])
    return maps, transform_points(inverse(_FRAMES[0]), world)[:, :2], {(0, 1): Alignment.from_pose(pose,
                                                                                                    supports=supports)}


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), better=st.sampled_from([0, 1]), ratio=st.floats(1.5, 4.0),
       tau=st.floats(0.02, 0.2))
def test_the_better_map_weighs_more_and_the_merge_is_no_worse_than_it(seed, better, ratio, tau):
    taus = (tau, tau * ratio) if better == 0 else (tau * ratio, tau)
    maps, truth, alignments = _pair(seed, taus)
    fused = fuse_all(maps, alignments=alignments, calibration="sightings")
    assert fused.map.metadata["fusion"]["calibration"] == "sightings"
    placed = [transform_points(fused.placements[k], maps[k].positions)[:, :2] for k in range(2)]
    merged = fused.map.positions[fused.rows[0], :2]
    np.testing.assert_array_equal(fused.rows[0], fused.rows[1])          # every landmark merged
    good, bad = placed[better], placed[1 - better]
    weight = np.sum((merged - bad) * (good - bad), axis=1) / np.sum((good - bad) ** 2, axis=1)
    # the better map weighs more, and about as much as the noise levels say it should (τ_bad² / (τ_good² + τ_bad²))
    assert np.mean(weight) > 0.5
    assert abs(np.mean(weight) - ratio ** 2 / (1 + ratio ** 2)) < 0.1
    # merged no worse than the better map, in expectation: the mean paired difference of squared errors is not
    # above zero by more than two of its standard errors (expected: -(1 / (1 + ratio²)) of the better map's)
    d = np.sum((merged - truth) ** 2, axis=1) - np.sum((good - truth) ** 2, axis=1)
    assert np.mean(d) <= 2 * np.std(d) / np.sqrt(len(d))


def test_maps_without_the_sightings_spread_fall_back_to_the_default():
    maps, _, alignments = _pair(0, (0.05, 0.1))
    bare = [LandmarkMap(m.positions, m.covariances, m.descriptors, counts=m.counts, robot=m.robot) for m in maps]
    fallback = fuse_all(bare, alignments=alignments, calibration="sightings")
    default = fuse_all(bare, alignments=alignments)
    assert fallback.map.metadata["fusion"] == default.map.metadata["fusion"]
    np.testing.assert_array_equal(fallback.map.positions, default.map.positions)
    with_spread = fuse_all(maps, alignments=alignments, calibration="sightings")
    assert not np.allclose(with_spread.map.positions, default.map.positions)
