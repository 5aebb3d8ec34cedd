"""Unknown association beyond the nearest landmark (``unknown_association_rule``, association_rules.py).

The scene: two look-alike posts 0.6 m apart, 3 m ahead, both seen in every frame from a standing robot until each
has its landmark. Then one reading of post B arrives with a bearing error of 2.9 σ (0.115 rad) that puts it nearer
A's landmark than B's, both inside the gate: maximum likelihood matches it to A, a wrong association, and the
"unambiguous" rule leaves it unused (d² 5.6 and 9.3: the nearest's posterior among the gated landmarks is 0.86,
below the gate's 0.99).
"""
from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from estimation.fastslam import FastSLAM, FastSLAMConfig, range_bearing_config, range_bearing_observations
from estimation.fastslam.association_rules import sample_associations, unambiguous_associations
from estimation.observations import OdometryIncrement

POSTS = np.array([[3.0, 0.0], [3.0, 0.6]])   # A, B
SIGMA_RANGE, SIGMA_BEARING = 0.05, 0.04
GATE = range_bearing_config().mahalanobis_gate


@cache
def _last_reading(rule: str, bearing_error: float, seed: int = 0):
    """Map both posts, then one reading of B with ``bearing_error`` (rad). Returns the ids the most probable particle
    gave A and B, what it matched the last reading to, the new landmark it made (-1: none), the pairs left unused
    in that frame, and the particles."""
    rng = np.random.default_rng(seed)
    slam = FastSLAM(range_bearing_config(n_particles=20, unknown_association_rule=rule),
                    np.random.default_rng(seed + 1))
    ranges, bearings = np.hypot(*POSTS.T), np.arctan2(POSTS[:, 1], POSTS[:, 0])
    for _ in range(30):
        slam.predict(OdometryIncrement(0.0, 0.0, 0.0))
        report = slam.update(range_bearing_observations(ranges + rng.normal(0, SIGMA_RANGE, 2),
                                                        bearings + rng.normal(0, SIGMA_BEARING, 2),
                                                        SIGMA_RANGE, SIGMA_BEARING))
    posts = report.best_matches.tolist()
    slam.predict(OdometryIncrement(0.0, 0.0, 0.0))
    unused = slam.stats.unknown_unused
    report = slam.update(range_bearing_observations(ranges[1:], bearings[1:] + bearing_error, SIGMA_RANGE,
                                                    SIGMA_BEARING))
    return (posts, int(report.best_matches[0]), int(report.new_landmark_ids[0]), slam.stats.unknown_unused - unused,
            slam.config.n_particles)


def test_maximum_likelihood_takes_a_displaced_reading_of_b_for_a():
    (a, b), matched, new, _unused, _n = _last_reading("nearest", -0.115)
    assert a >= 0 and b >= 0 and a != b            # both posts have their landmark (else: no test)
    assert matched == a and new == -1              # the wrong post, confidently


def test_the_unambiguous_rule_leaves_that_reading_unused():
    (a, b), matched, new, unused, n_particles = _last_reading("unambiguous", -0.115)
    assert a >= 0 and b >= 0 and a != b
    assert matched == -1 and new == -1             # neither the wrong post nor a duplicate
    assert unused == n_particles                   # said so in the stats, in every particle


def test_the_unambiguous_rule_still_matches_a_reading_that_is_not_ambiguous():
    for error in (0.0, 0.02):                      # B's reading on B (posterior of B ≈ 1)
        (a, b), matched, new, unused, _n = _last_reading("unambiguous", error)
        assert (matched, new, unused) == (b, -1, 0)
        assert _last_reading("nearest", error)[1] == b


def test_the_draw_follows_the_posterior_and_the_weight_does_not_depend_on_it():
    n_particles = 20_000                           # one reading, two gated landmarks (d² 1 and 3) in each particle
    key = np.repeat(np.arange(n_particles), 2)
    d2 = np.tile([1.0, 3.0], n_particles)
    choice = sample_associations(key, d2, d2 < GATE, n_particles, 1, GATE, np.random.default_rng(7))
    terms = np.exp(-0.5 * np.array([1.0, 3.0, GATE]))
    expected = terms / terms.sum()
    first, second = choice.gated[0::2].sum(), choice.gated[1::2].sum()
    counts = np.array([first, second, choice.new.sum()])
    assert counts.sum() == n_particles and np.all(choice.gated.reshape(-1, 2).sum(axis=1) <= 1)
    sigma = np.sqrt(n_particles * expected * (1 - expected))
    assert np.all(np.abs(counts - n_particles * expected) < 5 * sigma)
    np.testing.assert_array_equal(choice.log_lik, np.full(n_particles, -0.5))


def test_a_reading_with_one_landmark_in_the_gate_is_not_ambiguous():
    key = np.array([0, 0, 1])                       # particle 0: two gated at d² 1 and 1.2; particle 1: one at 9
    d2 = np.array([1.0, 1.2, 9.0])
    choice = unambiguous_associations(key, d2, d2 < GATE, 2, 1, GATE)
    assert choice.unused.tolist() == [True, False] and choice.gated.tolist() == [False, False, True]
    np.testing.assert_allclose(choice.log_lik, [-0.5, -4.5])


def test_the_rule_is_checked_and_nearest_by_default():
    assert FastSLAMConfig().unknown_association_rule == "nearest"
    assert range_bearing_config().unknown_association_rule == "nearest"
    with pytest.raises(ValueError, match="unknown_association_rule"):
        FastSLAMConfig(unknown_association_rule="joint")


@pytest.mark.parametrize("rule", ["sampled", "unambiguous"])
def test_known_id_association_does_not_enter_it(rule):
    def run(rule: str) -> np.ndarray:
        rng = np.random.default_rng(3)
        slam = FastSLAM(range_bearing_config(n_particles=20, association="id", unknown_association_rule=rule),
                        np.random.default_rng(4))
        for _ in range(20):
            slam.predict(OdometryIncrement(0.05, 0.0, 0.1))
            pose = slam.best_pose()
            d = POSTS - pose[:2]
            slam.update(range_bearing_observations(np.hypot(d[:, 0], d[:, 1]) + rng.normal(0, 0.05, len(d)),
                                                   np.arctan2(d[:, 1], d[:, 0]) - pose[2], 0.05, 0.01, ids=[0, 1]))
        return slam.poses

    np.testing.assert_array_equal(run(rule), run("nearest"))
