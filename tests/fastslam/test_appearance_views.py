"""A landmark's descriptors per viewing direction (appearance.py, ``descriptor_slot_key``): upright U-SURF changes
with the angle a point is seen from, so a landmark learns its look from new directions, on strong evidence only."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from estimation.fastslam import FastSLAM, FastSLAMConfig
from estimation.fastslam.appearance import DescriptorBands
from estimation.geometry import between
from estimation.observations import OdometryIncrement, StereoObservations
from tests.fastslam.conftest import orthonormal_descriptors, turned


def test_an_observation_is_compared_with_the_descriptor_made_from_the_nearest_direction():
    a, b, c = orthonormal_descriptors(3)
    bands = DescriptorBands(slots=3, ratio=1.25, size=64, key="direction", angle=0.2)
    bands.append(a[None], np.array([4.0]), np.array([0.0]))
    assert bands.learn(np.array([0]), b[None], np.array([4.0]), np.array([0.5])) == 1
    ids, r = np.array([0]), np.array([4.0])
    # b seen from 0.45 rad matches (compared with b), from 0.1 rad it does not (compared with a), at any range
    assert len(bands.matches(ids, b[None], r, 0.5, np.array([0.45]))[0]) == 1
    assert len(bands.matches(ids, b[None], np.array([1.5]), 0.5, np.array([0.45]))[0]) == 1
    assert len(bands.matches(ids, b[None], r, 0.5, np.array([0.1]))[0]) == 0
    assert len(bands.matches(ids, a[None], r, 0.5, np.array([0.1]))[0]) == 1
    assert len(bands.matches(ids, c[None], r, 0.5, np.array([0.5]))[0]) == 0
    assert bands.distance(ids, b[None], r, np.array([0.45]))[0] == pytest.approx(0.0, abs=1e-3)
    assert bands.distance(ids, b[None], r, np.array([0.1]))[0] == pytest.approx(np.sqrt(2.0), abs=1e-3)


@given(st.floats(-np.pi, np.pi), st.floats(-0.19, 0.19))
def test_directions_are_compared_across_the_wrap(first: float, step: float):
    a, b = orthonormal_descriptors(2)
    bands = DescriptorBands(slots=2, ratio=1.25, size=64, key="direction", angle=0.2)
    bands.append(a[None], np.array([3.0]), np.array([first]))
    seen = np.array([first + step + 2.0 * np.pi * np.sign(first)])   # the same direction, a turn away
    assert bands.learn(np.array([0]), b[None], np.array([3.0]), seen) == 0   # within 0.2 rad: nothing new
    assert len(bands.matches(np.array([0]), a[None], np.array([3.0]), 0.5, seen)[0]) == 1


def test_a_landmark_learns_only_new_directions_never_overwrites_and_never_without_a_direction():
    a, b, c = orthonormal_descriptors(3)
    bands = DescriptorBands(slots=2, ratio=1.25, size=64, key="direction", angle=0.2)
    bands.append(np.stack([a, a]), np.array([4.0, 4.0]), np.array([1.0, np.nan]))   # id 1: direction unknown
    assert bands.learn(np.array([0]), b[None], np.array([1.0]), np.array([1.15])) == 0   # a new range alone
    assert bands.learn(np.array([0]), b[None], np.array([4.0]), np.array([1.3])) == 1
    assert bands.learn(np.array([0]), c[None], np.array([4.0]), np.array([2.0])) == 0   # no free slot
    assert bands.learn(np.array([1]), b[None], np.array([4.0]), np.array([2.0])) == 0
    np.testing.assert_array_equal(bands.desc[0], np.stack([a, b]))
    np.testing.assert_allclose(bands.bearing[0], [1.0, 1.3])


def test_range_and_direction_learn_when_either_steps():
    a, b, c = orthonormal_descriptors(3)
    bands = DescriptorBands(slots=3, ratio=1.25, size=64, key="range+direction", angle=0.2)
    bands.append(a[None], np.array([4.0]), np.array([0.0]))
    assert bands.learn(np.array([0]), b[None], np.array([2.0]), np.array([0.05])) == 1   # range
    assert bands.learn(np.array([0]), c[None], np.array([4.0]), np.array([0.5])) == 1    # direction
    # seen from 2.1 m straight on: b's view (ratio 1.05, 0.05 rad) is nearer than a's (ratio 1.9) or c's
    assert len(bands.matches(np.array([0]), b[None], np.array([2.1]), 0.5, np.array([0.0]))[0]) == 1


@pytest.mark.parametrize(("settings", "message"), [
    ({"descriptor_slot_key": "bearing"}, "descriptor_slot_key must be one of"),
    ({"descriptor_slot_angle": 0.0}, "descriptor_slot_angle must be in"),
    ({"descriptor_slot_angle": 4.0}, "descriptor_slot_angle must be in"),
    ({"descriptor_learn_gate": -1.0}, "descriptor_learn_gate must be finite"),
    ({"descriptor_learn_gate": float("inf")}, "descriptor_learn_gate must be finite"),
])
def test_bad_view_settings_are_refused(settings: dict, message: str):
    with pytest.raises(ValueError, match=message):
        FastSLAMConfig(**settings)


def _circle(settings: dict, steps: int = 24, arc_step: float = 0.05) -> FastSLAM:
    """A robot walks round a corner 3 m away, facing it, 0.05 rad of arc a frame (1.15 rad in all). The corner's
    upright descriptor turns with the direction it is seen from, angle = 1.2 Δφ: beyond the 0.5 threshold after
    0.42 rad of arc. The range never changes."""
    a, b = orthonormal_descriptors(2, seed=5)
    slam = FastSLAM(FastSLAMConfig(n_particles=5, max_observations=0, merge_every=1, **settings),
                    np.random.default_rng(0))
    corner = np.array([5.0, 1.0, 0.6])

    def pose(k: int) -> np.ndarray:
        phi = k * arc_step
        return np.array([corner[0] - 3.0 * np.cos(phi), corner[1] - 3.0 * np.sin(phi), phi])

    t = 0.0
    for k in range(steps):
        p = pose(k)
        c, s = np.cos(p[2]), np.sin(p[2])
        d = corner[:2] - p[:2]
        z = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], corner[2]])
        slam.update(StereoObservations(z[None], (np.eye(3) * 0.01 ** 2)[None],
                                       turned(a, b, 1.2 * k * arc_step)[None], timestamp=t))
        slam.predict(OdometryIncrement(*map(float, between(p, pose(k + 1))), t, t + 0.5))
        t += 0.5
    return slam


def test_a_corner_walked_round_stays_one_landmark_with_descriptors_per_direction():
    one = _circle({})
    assert len(one.particle_map(one.best_index)) >= 2          # the first look alone: a duplicate is made
    by_range = _circle({"descriptor_slots": 8})
    assert len(by_range.particle_map(by_range.best_index)) >= 2   # the range never changes: nothing learned
    kept = _circle({"descriptor_slots": 8, "descriptor_slot_key": "direction", "descriptor_slot_angle": 0.2,
                    "descriptor_learn_gate": 2.366})
    landmarks = kept.particle_map(kept.best_index)
    assert len(landmarks) == 1 and landmarks.counts[0] == 24


def test_a_look_is_learned_only_from_a_confirmed_landmark():
    # the look turns 0.36 rad of descriptor a frame: the second sighting still matches (0.36 < 0.5), the third
    # needs a look learned from the second; under the strong-evidence rule the landmark (seen once) learns nothing
    settings = {"descriptor_slots": 8, "descriptor_slot_key": "direction", "descriptor_slot_angle": 0.2}
    eager = _circle({**settings, "descriptor_learn_gate": 0.0}, steps=6, arc_step=0.3)
    strict = _circle({**settings, "descriptor_learn_gate": 2.366}, steps=6, arc_step=0.3)
    assert len(eager.particle_map(eager.best_index, min_count=1)) == 1
    assert len(strict.particle_map(strict.best_index, min_count=1)) >= 2
