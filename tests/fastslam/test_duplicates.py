"""Duplicate landmarks: merged on co-visibility evidence, never when two landmarks were detected together."""
from __future__ import annotations

import numpy as np
import pytest

from estimation.fastslam import FastSLAM, FastSLAMConfig, range_bearing_config, range_bearing_observations
from estimation.observations import OdometryIncrement, StereoObservations

SIGMA_R, SIGMA_B = 0.02, 0.005


def _drive(slam: FastSLAM, steps: int, step: float = 1.0, t: float = 0.0) -> float:
    """Drive straight with exact odometry and frames that see nothing: the map frame's drift grows."""
    for _ in range(steps):
        slam.predict(OdometryIncrement(step, 0.0, 0.0, t, t + 1.0))
        t += 1.0
        slam.update(range_bearing_observations(np.zeros(0), np.zeros(0), SIGMA_R, SIGMA_B, timestamp=t))
    return t


def _turn_and_see(slam: FastSLAM, turn: float, t: float, ranges, bearings) -> float:
    slam.predict(OdometryIncrement(0.0, 0.0, turn, t, t + 1.0))
    slam.update(range_bearing_observations(ranges, bearings, SIGMA_R, SIGMA_B, timestamp=t + 1.0))
    return t + 1.0


@pytest.mark.parametrize("covisibility", [True, False])
def test_a_duplicate_made_from_a_drifted_pose_is_merged(covisibility):
    # After 20 m without landmarks the map frame may be ~0.3 m off (drift.py). The robot then stands still and
    # sees one post, but its odometry claims a 0.15 rad turn and back, frame after frame: from the falsely turned
    # pose the post lands 0.45 m from its landmark, ~20 σ of the particle's EKF, so a second landmark is made,
    # and from then on the two take turns at being detected (each one's existence keeps growing). The sensor
    # never reports both in one frame although both are in view: one point, merged on that evidence.
    slam = FastSLAM(range_bearing_config(n_particles=1, merge_every=1, merge_covisibility=covisibility),
                    np.random.default_rng(0))
    t = _drive(slam, 20)
    for _ in range(5):
        t = _turn_and_see(slam, 0.0, t, [3.0], [0.0])
    original = slam.particle_map(0).positions[0]
    made, sightings = [], 5
    while not slam.merged_pairs and len(made) < 30:
        t = _turn_and_see(slam, 0.15 if len(made) % 2 == 0 else -0.15, t, [3.0], [0.0])
        made.append(len(slam.particle_map(0)))
    steady = [-0.15] * (len(made) % 2) + [0.0] * 4        # then the odometry stops lying (turned back)
    for turn in steady:
        t = _turn_and_see(slam, turn, t, [3.0], [0.0])
    assert max(made) == 2                                 # the duplicate was made
    kept = slam.particle_map(0)
    if covisibility:
        assert len(made) < 30 and len(kept) == 1
        assert slam.merged_pairs[0][2]                    # by co-visibility, not by the EKF gate
        assert kept.counts[0] == sightings + len(made) + len(steady)   # every sighting kept in the surviving landmark
        assert np.linalg.norm(kept.positions[0] - original) < 0.05   # where the older one was
        assert slam.stats.landmarks_removed == 0
    else:   # the merge of old: 0.45 m apart is no single point under the EKF covariances
        assert len(kept) == 2 and slam.stats.landmarks_merged == 0


@pytest.mark.parametrize("covisibility", [True, False])
def test_two_close_posts_without_descriptors_detected_together_are_not_merged(covisibility):
    # Two posts 0.15 m apart at 8 m: with σ_φ = 0.01 rad they are statistically one point under Σ_a + Σ_b
    # (d² ≈ 1.8 < 7.8), but the sensor reports both in the same frames: two points, never merged.
    slam = FastSLAM(range_bearing_config(n_particles=3, merge_every=1, merge_covisibility=covisibility),
                    np.random.default_rng(0))
    ranges, bearings = [8.0, 8.0014], [0.0, 0.15 / 8.0]
    for k in range(10):
        slam.update(range_bearing_observations(ranges, bearings, 0.05, 0.01, timestamp=float(k)))
    kept = slam.particle_map(0)
    if covisibility:
        assert len(kept) == 2 and slam.stats.landmarks_merged == 0
    else:
        assert len(kept) == 1 and slam.stats.landmarks_merged > 0


@pytest.mark.parametrize("covisibility", [True, False])
def test_two_close_corners_that_look_alike_detected_together_are_not_merged(covisibility):
    # Stereo corners 6 cm apart with descriptors 0.3 apart: one point by the merge's geometry and appearance
    # (d² ≈ 1.4, descriptor under 0.5), but seen together in every frame: two points.
    rng = np.random.default_rng(5)
    base, other = rng.standard_normal((2, 64))
    base /= np.linalg.norm(base)
    other -= (other @ base) * base
    other /= np.linalg.norm(other)
    alike = np.cos(0.3) * base + np.sin(0.3) * other                 # 2 sin(0.15) ≈ 0.3 from base
    slam = FastSLAM(FastSLAMConfig(n_particles=3, merge_every=1, max_observations=0,
                                   merge_covisibility=covisibility), np.random.default_rng(0))
    points = np.array([[4.0, 0.5, 1.0], [4.0, 0.56, 1.0]])
    for k in range(6):
        slam.update(StereoObservations(points, np.tile(np.eye(3) * 0.03 ** 2, (2, 1, 1)),
                                       np.array([base, alike], np.float32), timestamp=float(k)))
    kept = slam.particle_map(0)
    if covisibility:
        assert len(kept) == 2 and slam.stats.landmarks_merged == 0
    else:
        assert len(kept) == 1 and slam.stats.landmarks_merged > 0
