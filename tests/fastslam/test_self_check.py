"""The map's self-check (estimation/fastslam/self_check.py): a map that lost its place says so in its metadata.

One synthetic corridor run, driven twice with the same seeds: along the centre line with two stretches of blind
frames (no observations: gaps in which the map does not hold the pose). After the first the map re-detects its old
landmarks (the check learns how its detections scatter); in one run the robot is turned by
0.3 rad during the stretch and the odometry does not see it (a heading jump the filter is not told about); the old
landmarks ahead are then predicted 0.6-1.5 m from where they are seen, fail the gate, and are not re-detected.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from estimation.fastslam import FastSLAM, FastSLAMConfig
from estimation.geometry import between, compose
from estimation.observations import OdometryIncrement, StereoObservations
from mocks.synthetic_stereo import SyntheticStereo

KICK = 0.3           # rad: the unseen heading jump
EARLY, BEFORE, BLIND, AFTER = 10, 30, 5, 30   # first blind stretch at, second at, blind frames, driven after
STEP, DT = 0.1, 0.2  # m per frame, s per frame


def _run(corridor, kick: float, config: FastSLAMConfig | None = None) -> tuple[FastSLAM, float]:
    """Drive the run (kick = the unseen turn in the blind stretch); returns the filter and the kick's time."""
    rng = np.random.default_rng(21)
    features, desc = corridor(rng)
    sensor = SyntheticStereo(features, desc, rng)
    slam = FastSLAM(config or FastSLAMConfig(n_particles=10), np.random.default_rng(4))
    pose, t = np.zeros(3), 0.0
    for i in range(BEFORE + BLIND + AFTER):
        blind = EARLY <= i < EARLY + BLIND or BEFORE <= i < BEFORE + BLIND
        new = compose(pose, [0.0 if blind else STEP, 0.0, 0.0])
        told = between(pose, new)                      # what the odometry reports
        if i == BEFORE:                                # pushed round, wheels still: odometry sees nothing
            new = compose(new, [0.0, 0.0, kick])
        slam.predict(OdometryIncrement(*told, t, t + DT))
        t += DT
        pose = new
        if blind:
            slam.update(StereoObservations(np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 64), np.float32),
                                           np.zeros((0, 2)), t))
        else:
            slam.update(sensor.observe(pose, timestamp=t)[0])
    return slam, BEFORE * DT + DT


@pytest.fixture(scope="module")
def runs():
    from tests.fastslam.conftest import corridor_features

    return {kick: _run(corridor_features, kick) for kick in (0.0, KICK)}


def test_a_map_whose_pose_was_kicked_off_flags_that_it_lost_its_place(runs):
    slam, t_kick = runs[KICK]
    verdict = slam.best_map().metadata["self_check"]
    assert verdict["lost"]
    first = verdict["alarms"][0]
    # flagged after the kick, within the frames driven after it: each old landmark in view missed adds
    # ln((1 - 0.025)/(1 - P_D)) = 0.47 to the statistic (P_D 0.39 from the constants, 0.025 the descriptors'
    # chance match), a frame holds 10+ of them and the dispersion learnt before the kick is a few, so
    # h = ln(1e5) = 11.5 is crossed within a few frames of the AFTER = 30
    assert t_kick <= first["since"] <= first["t"] <= t_kick + (BLIND + AFTER) * DT
    assert first["statistic"] >= verdict["threshold"] == pytest.approx(math.log(1e5), abs=1e-3)
    assert first["redetected"] < 0.5 * first["expected"]
    assert slam.self_check.lost


def test_the_same_run_without_the_kick_re_detects_its_old_landmarks_and_is_not_flagged(runs):
    slam, _ = runs[0.0]
    verdict = slam.best_map().metadata["self_check"]
    # the test did run (the blind stretch is a gap; the landmarks made before it come back into view) ...
    assert verdict["frames_tested"] >= AFTER // 2 and verdict["predicted"] >= 100
    # ... and found them where the map holds them: the sensor detects 90 % of what is in view, more than the
    # 39 % the test assumes of a consistent map, so every frame lowers the statistic
    assert verdict["redetected"] > verdict["expected"]
    assert not verdict["lost"] and verdict["alarms"] == [] and verdict["max_statistic"] < verdict["threshold"]


def test_the_threshold_follows_the_stated_false_alarm_rate(corridor):
    slam, _ = _run(corridor, KICK, FastSLAMConfig(n_particles=10, self_check_false_alarm=1e-3))
    verdict = slam.best_map().metadata["self_check"]
    assert verdict["threshold"] == pytest.approx(math.log(1e3), abs=1e-3)
    assert verdict["false_alarm_per_frame"] == 1e-3
    with pytest.raises(ValueError, match="self_check_false_alarm"):
        FastSLAMConfig(self_check_false_alarm=0.0)
