"""MRCLAM's commanded-velocity odometry overstates the forward travel in turns (benchmarks/mrclam_turn_translation.py,
docs/fastslam-history.md "Session 16 (Q)"): measured on the first 900 s of robot 1 against Vicon; skips without the
data."""
from __future__ import annotations

import functools

import numpy as np
import pytest

from benchmarks import mrclam_turn_translation as bench
from estimation.datasets import read_mrclam


@functools.cache
def _measure(folder) -> dict:
    return bench.measure(read_mrclam(folder, 1, until=900.0))


@pytest.fixture
def robot1(mrclam_dir):
    return _measure(mrclam_dir)      # measured once for both tests (mrclam_dir is function-scoped)


def _band(bands, w_from, v):
    (band,) = [b for b in bands if b["w_from"] == w_from and b["v"] == v]
    return band


def test_the_forward_travel_falls_in_turns_and_the_deficit_per_radian_restores_it(robot1):
    calibrated, deficit = robot1["models"]["calibrated"], robot1["models"]["deficit"]
    c, se = deficit["forward_deficit_per_rad"], deficit["forward_deficit_per_rad_standard_error"]
    assert 0.06 < c < 0.13 and c > 10 * se
    steps = calibrated["bands"]["0.25"], deficit["bands"]["0.25"]
    straight = [_band(b, 0.0, "cruise")["forward_ratio"] for b in steps]
    arcs = [_band(b, 0.3, "cruise")["forward_ratio"] for b in steps]     # |ω| 0.3-0.5 rad/s at ~0.08 m/s
    assert straight[0] > 1.04 and arcs[0] < 0.8           # one scale: straight runs short, arcs long
    assert abs(straight[1] - 1.0) < 0.05 and abs(arcs[1] - 1.0) < 0.1
    assert abs(_band(steps[0], 0.3, "cruise")["turn_ratio"] - 1.0) < 0.1   # the turn itself is right
    error = calibrated["position_error"]["1"]["rms_m"], deficit["position_error"]["1"]["rms_m"]
    assert error[1] < 0.8 * error[0]
    assert deficit["sigma_xy_per_sqrt_m"] < 0.6 * calibrated["sigma_xy_per_sqrt_m"]


def test_the_deficit_is_per_radian_not_a_scale_of_the_turn_rate(robot1):
    """At the same |ω| (0.1-0.2 rad/s), slow arcs lose a larger share of their travel than fast ones: a distance
    per radian (a scale falling with the curvature) predicts it, a scale falling with |ω| at any speed does not."""
    split = robot1["forms"]["w_0.1_to_0.2_by_speed"]
    slow, cruise = split["slow"], split["cruise"]
    assert slow["true_over_odometry"] < cruise["true_over_odometry"] - 0.1
    # both forms are fitted where most steps are (cruise); they differ on the slow arcs
    assert abs(slow["deficit_per_rad_predicts"] - slow["true_over_odometry"]) < \
        0.5 * abs(slow["scale_falling_with_w_predicts"] - slow["true_over_odometry"])
    assert np.isfinite(robot1["forms"]["spin"]["true_forward_per_rad_m"])
