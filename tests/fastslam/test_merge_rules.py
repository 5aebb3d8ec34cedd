"""What a merge of two alike landmarks keeps: the estimate (``merge_estimate``) and the look (``merge_look``)."""
from __future__ import annotations

import numpy as np
import pytest

from estimation.fastslam import FastSLAM, FastSLAMConfig
from estimation.observations import StereoObservations


def _unit_pair(seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    base, other = rng.standard_normal((2, 64))
    base /= np.linalg.norm(base)
    other -= (other @ base) * base
    return base, other / np.linalg.norm(other)


def _look(base: np.ndarray, other: np.ndarray, angle: float) -> np.ndarray:
    """A unit descriptor 2 sin(angle / 2) from ``base`` (a look that changed with the viewing range)."""
    return np.cos(angle) * base + np.sin(angle) * other


def _frame(points, looks, t: float) -> StereoObservations:
    n = len(points)
    return StereoObservations(np.array(points, float), np.tile(np.eye(3) * 0.03 ** 2, (n, 1, 1)),
                              np.array(looks, np.float32), timestamp=t)


def _slam(**overrides) -> FastSLAM:
    settings = dict(n_particles=3, merge_every=1, max_observations=0, merge_descriptor_threshold=0.8) | overrides
    return FastSLAM(FastSLAMConfig(**settings), np.random.default_rng(0))


@pytest.mark.parametrize("look", ["older", "newer"])
def test_a_merged_landmark_with_the_newer_look_takes_the_next_sightings(look):
    # A corner approached from afar: its look moves away from the first (0.59, beyond the association's 0.5), a
    # duplicate is made and merged (0.8). The next sightings look like the newer one (0.2 from it) and 0.77 from the
    # first: with the older look kept they make the corner again; with the newer one they are its sightings.
    base, other = _unit_pair(1)
    corner = [4.0, 0.5, 1.0]
    slam = _slam(merge_look=look)
    slam.update(_frame([corner], [base], 0.0))
    slam.update(_frame([corner], [_look(base, other, 0.6)], 1.0))
    assert slam.stats.landmarks_merged == 3 and len(slam.particle_map(0)) == 1   # the duplicate, merged
    merges = slam.stats.landmarks_merged
    report = slam.update(_frame([corner], [_look(base, other, 0.8)], 2.0))
    if look == "newer":
        assert report.best_matches[0] >= 0 and slam.stats.landmarks_merged == merges
        assert slam.particle_map(0).counts.max() == 3
    else:
        assert report.new_landmark_ids[0] >= 0   # made again beside itself


@pytest.mark.parametrize("estimate", ["fuse", "older"])
def test_a_merge_keeps_the_older_estimate_or_fuses_the_two(estimate):
    # the same corner made again 4 cm off (the pose drifted since): "fuse" moves the landmark halfway (equal
    # covariances); "older" keeps where the map made it and takes the newer one's sighting
    base, other = _unit_pair(2)
    slam = _slam(merge_estimate=estimate, n_particles=1)
    slam.update(_frame([[4.0, 0.5, 1.0]], [base], 0.0))
    slam.update(_frame([[4.0, 0.54, 1.0]], [_look(base, other, 0.6)], 1.0))
    kept = slam.particle_map(0)
    assert len(kept) == 1 and kept.counts[0] == 2
    expected = 0.5 if estimate == "older" else 0.52
    assert kept.positions[0][1] == pytest.approx(expected, abs=2e-3)


@pytest.mark.parametrize("field", ["merge_estimate", "merge_look"])
def test_an_unknown_merge_rule_is_refused_in_one_line(field):
    with pytest.raises(ValueError, match=field):
        FastSLAMConfig(**{field: "both"})
