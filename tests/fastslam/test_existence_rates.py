"""Landmark existence from the sensor's own detection and false-alarm rates (estimation/fastslam/existence.py), and
the "id" gate under a heading error (the pose's uncertainty must be in it)."""
from __future__ import annotations

import numpy as np
import pytest

from estimation.fastslam import FastSLAM, range_bearing_config, range_bearing_observations
from estimation.observations import OdometryIncrement

# a camera-like footprint: ±0.6 rad, 0.5-9 m (misses count well inside it: 85 %)
FOOTPRINT = dict(fov_horizontal=1.2, min_range=0.5, max_range=9.0, n_particles=10, association="id")
RATES = dict(detection_probabilities=(0.7, 0.25), detection_range_edges=(3.0,), false_alarm_probability=0.02)


def _stare(slam, frames, p_detect, rng) -> int:
    """A robot standing still with a landmark (id 1) 6 m ahead that the sensor reports with probability
    ``p_detect`` per frame, and a near one (id 2, 2 m) it always reports. Returns how often 1 was reported."""
    reported = 0
    for _ in range(frames):
        seen = rng.random() < p_detect
        reported += seen
        ranges, bearings, ids = ([6.0, 2.0], [0.0, 0.3], [1, 2]) if seen else ([2.0], [0.3], [2])
        slam.update(range_bearing_observations(ranges, bearings, 0.05, 0.01, ids=ids))
    return reported


def _count_of(slam, external_id):
    landmark_map = slam.particle_map(slam.best_index)
    return int(landmark_map.counts[slam.external_ids(landmark_map.ids) == external_id].sum())


def test_a_real_landmark_reported_in_a_quarter_of_the_frames_is_kept_with_the_sensors_rates():
    # the constants (+1 / -0.5) break even at P_D = 1/3: a landmark reported a quarter of the time is removed
    # (and made again from scratch at its next sighting), which is what happened to MRCLAM's far landmarks;
    # with the rates (log(P_D/P_FA), log(1 - P_D)) it is kept and every sighting goes into one estimate
    constant = FastSLAM(range_bearing_config(**FOOTPRINT), np.random.default_rng(0))
    reported = _stare(constant, 200, 0.25, np.random.default_rng(5))
    assert constant.stats.landmarks_removed > 0 and _count_of(constant, 1) < reported
    rates = FastSLAM(range_bearing_config(**FOOTPRINT, **RATES), np.random.default_rng(0))
    assert _stare(rates, 200, 0.25, np.random.default_rng(5)) == reported
    assert rates.stats.landmarks_removed == 0 and _count_of(rates, 1) == reported


def test_a_false_alarm_is_still_removed_with_the_sensors_rates():
    # one reading of an id at 2 m, never again while well in view: P_D = 0.7 there, so each miss costs
    # log(0.3) = -1.2 and the single detection's log(0.7 / 0.02) = 3.6 is spent within 5 frames
    slam = FastSLAM(range_bearing_config(**FOOTPRINT, **RATES), np.random.default_rng(0))
    slam.update(range_bearing_observations([2.0, 2.5], [0.0, -0.2], 0.05, 0.01, ids=[9, 2]))
    for _ in range(5):
        slam.update(range_bearing_observations([2.5], [-0.2], 0.05, 0.01, ids=[2]))
    assert set(slam.external_ids(slam.particle_map(0).ids).tolist()) == {2}


def test_correlated_frames_count_as_fewer_independent_ones():
    # lag-1 correlation ρ of the detected / missed sequence: every step is worth (1 − ρ)/(1 + ρ) of an
    # independent frame's (the AR(1) argument of the sensor variances' inflation)
    from estimation.fastslam.existence import hit_log_odds, miss_log_odds
    ranges = np.array([1.0, 6.0])
    independent = range_bearing_config(**RATES)
    correlated = range_bearing_config(**RATES, detection_correlation=0.5)
    np.testing.assert_allclose(hit_log_odds(correlated, ranges), hit_log_odds(independent, ranges) / 3)
    np.testing.assert_allclose(miss_log_odds(correlated, ranges), np.log([0.3, 0.75]) / 3)


@pytest.mark.parametrize("bad", [dict(detection_probabilities=(0.5, 0.2)),                       # edges missing
                                 dict(detection_probabilities=(1.0,)),                          # certain detection
                                 dict(detection_probabilities=(0.5,), false_alarm_probability=0.0),
                                 dict(detection_probabilities=(0.5, 0.4, 0.2), detection_range_edges=(5.0, 3.0)),
                                 dict(detection_correlation=1.0)])
def test_impossible_rates_are_refused(bad):
    with pytest.raises(ValueError):
        range_bearing_config(**bad)


@pytest.mark.parametrize("version", [1, 2])
def test_a_heading_off_by_0_2_rad_is_corrected_not_rejected(version):
    # known ids around the robot; the odometry then reports a half turn 0.2 rad too far (within the motion
    # model: σ_θ = 0.12·√π = 0.21 rad). The gate must judge the readings with the pose's uncertainty (2.0: the
    # motion covariance in S; 1.0: the sampled cloud), accept the correct ids and bring the heading back
    rng = np.random.default_rng(3)
    angles = np.linspace(-np.pi, np.pi, 12, endpoint=False)
    landmarks = 5.0 * np.column_stack([np.cos(angles), np.sin(angles)])
    ids = np.arange(12)
    slam = FastSLAM(range_bearing_config(n_particles=50, version=version, association="id",
                                         odom_theta_var_per_rad=0.12 ** 2), np.random.default_rng(4))

    def look(heading):
        d = landmarks - 0.0
        r = np.hypot(d[:, 0], d[:, 1]) + rng.normal(0, 0.02, 12)
        b = np.arctan2(d[:, 1], d[:, 0]) - heading + rng.normal(0, 0.005, 12)
        slam.update(range_bearing_observations(r, b, 0.02, 0.005, ids=ids))

    for _ in range(5):
        look(0.0)
    slam.predict(OdometryIncrement(0.0, 0.0, np.pi + 0.2))       # truly turned π
    look(np.pi)
    # the first frame after the turn: some readings fail in some particles (the 0.2 rad turn also moves them
    # 5 (1 - cos 0.2) = 0.1 m radially, a second-order effect the linearised pose term does not cover), but
    # enough pass to correct the pose; without the pose's uncertainty in the gate every reading would fail
    assert slam.stats.id_outliers < 12 * 50
    look(np.pi)                          # (1.0: the particles far off are resampled away over this frame)
    before = slam.stats.id_outliers
    for _ in range(3):
        look(np.pi)
    heading_error = abs((slam.best_pose()[2] - np.pi + np.pi) % (2 * np.pi) - np.pi)
    assert heading_error < 0.03
    assert slam.stats.id_outliers - before <= 0.01 * 3 * 12 * 50       # correct ids are not rejected again
