"""The detection term of the weight (``detection_in_weight``, detection_term.py): a particle pays log(1 − P_D) for
each landmark its map holds well in view that the sensor did not report, and log P_D for each one it did.

The scene: a standing robot, one post 3 m ahead seen every frame. A second post, 2 m to the left of the first,
is seen in the first frames and then no more (the sensor misses it while it stays well in view). With the
"sampled" rule some particles also make a duplicate of the first post. Two filters with the same seed, one with
the term and one without, make the same draws (the term changes only the weights; resampling and merging are
off so that nothing else depends on them): the difference of their log-weights is the term alone.
"""
from __future__ import annotations

from functools import cache

import numpy as np

from estimation.fastslam import FastSLAM, range_bearing_config, range_bearing_observations
from estimation.fastslam.detection_term import detection_log_likelihood
from estimation.fastslam.existence import evidence_per_frame
from estimation.observations import OdometryIncrement

POSTS = np.array([[3.0, 0.0], [3.0, 2.0]])
SIGMA_RANGE, SIGMA_BEARING = 0.05, 0.04
RATES = dict(detection_probabilities=(0.6, 0.3), detection_range_edges=(3.3,), false_alarm_probability=0.05,
             detection_correlation=0.5)


def _config(term: bool, rule: str = "nearest"):
    return range_bearing_config(n_particles=30, version=1, resample_threshold=0.0, merge_gate=0.0,
                                unknown_association_rule=rule, detection_in_weight=term, **RATES)


@cache
def _run(term: bool, rule: str, both_frames: int = 3, frames: int = 12, bearing_error: float = 0.0):
    """Both posts for ``both_frames`` frames, then the first alone (with ``bearing_error`` on odd frames). Returns
    the final log-weights (before normalisation) and the landmarks each particle holds."""
    rng = np.random.default_rng(3)
    slam = FastSLAM(_config(term, rule), np.random.default_rng(4))
    total = np.zeros(slam.config.n_particles)
    ranges, bearings = np.hypot(*POSTS.T), np.arctan2(POSTS[:, 1], POSTS[:, 0])
    for frame in range(frames):
        n = 2 if frame < both_frames else 1
        slam.predict(OdometryIncrement(0.0, 0.0, 0.0))
        error = bearing_error if frame % 2 else 0.0
        before = slam.log_weights.copy()
        slam.update(range_bearing_observations(ranges[:n] + rng.normal(0, SIGMA_RANGE, n),
                                               bearings[:n] + error + rng.normal(0, SIGMA_BEARING, n),
                                               SIGMA_RANGE, SIGMA_BEARING))
        # log_weights are kept relative to their maximum: sum the increments to undo that shift
        step = slam.log_weights - before
        total += step - step.max()
    return total, slam.particle_landmark_count()


def test_the_term_is_p_d_per_detection_and_one_minus_p_d_per_miss():
    cfg = _config(True)
    got = detection_log_likelihood(cfg, 3, np.array([0, 0, 2]), np.array([2.0, 5.0, 2.0]), np.array([1, 2]),
                                   np.array([5.0, 1.0]), miss_weight=0.5)
    w = evidence_per_frame(cfg)
    expected = w * np.array([np.log(0.6) + np.log(0.3), 0.5 * np.log(0.7), np.log(0.6) + 0.5 * np.log(0.4)])
    np.testing.assert_allclose(got, expected)


def test_particles_holding_one_map_are_reweighted_alike():
    on, counts_on = _run(True, "nearest")
    off, counts_off = _run(False, "nearest")
    np.testing.assert_array_equal(counts_on, counts_off)          # the same maps: the term touches weights only
    assert np.all(counts_on == counts_on[0])
    diff = on - off
    np.testing.assert_allclose(diff - diff.max(), 0.0, atol=1e-9)   # one map in every particle: no one is favoured


def test_a_particle_holding_a_duplicate_loses_weight_for_its_misses():
    on, counts = _run(True, "sampled", both_frames=1, frames=16, bearing_error=0.1)
    off, counts_off = _run(False, "sampled", both_frames=1, frames=16, bearing_error=0.1)
    np.testing.assert_array_equal(counts, counts_off)              # the same draws
    extra = counts > counts.min()                                   # particles that made a duplicate somewhere
    assert extra.any() and (~extra).any()                           # both kinds present (else: no test)
    gain = on - off                                                 # the detection term alone, per particle
    assert gain[extra].max() < gain[~extra].min()                   # every duplicate holder paid more


def test_known_id_runs_are_unchanged_by_the_option():
    def run(term: bool):
        rng = np.random.default_rng(5)
        slam = FastSLAM(range_bearing_config(n_particles=10, association="id", detection_in_weight=term, **RATES),
                        np.random.default_rng(6))
        ranges, bearings = np.hypot(*POSTS.T), np.arctan2(POSTS[:, 1], POSTS[:, 0])
        for frame in range(8):
            slam.predict(OdometryIncrement(0.05, 0.0, 0.01))
            n = 2 if frame < 3 else 1
            slam.update(range_bearing_observations(ranges[:n] + rng.normal(0, SIGMA_RANGE, n), bearings[:n],
                                                   SIGMA_RANGE, SIGMA_BEARING, ids=np.arange(n)))
        return slam.log_weights, slam.poses

    for a, b in zip(run(True), run(False), strict=True):
        np.testing.assert_array_equal(a, b)
