"""benchmarks.mrclam_encounter_heading: the heading faults of the odometry split by whether another robot is near;
the counting on synthetic steps (hypothesis), and robot 2's meeting with robot 5 in the real data (skipped without
it)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from benchmarks.mrclam_encounter_heading import FAULTS_RAD, TURNING_RAD, fault_shares, heading_steps

step_lists = st.lists(st.tuples(st.floats(0.0, 0.5), st.floats(-0.5, 0.5), st.floats(0.1, 5.0)),
                      min_size=1, max_size=60).map(
    lambda rows: {"error": np.array([r[0] for r in rows]), "turn": np.array([r[1] for r in rows]),
                  "nearest_m": np.array([r[2] for r in rows])})


@given(st.lists(step_lists, min_size=1, max_size=3), st.floats(0.2, 4.0))
def test_every_step_is_counted_once_near_or_far_and_turning_or_straight(steps, near_m):
    shares = fault_shares(steps, near_m)
    error = np.concatenate([s["error"] for s in steps])
    near = np.concatenate([s["nearest_m"] for s in steps]) < near_m
    turning = np.abs(np.concatenate([s["turn"] for s in steps])) > TURNING_RAD
    for side, where in (("near", near), ("far", ~near)):
        row = shares[f"all {side}"]
        assert row["steps"] == int(where.sum()) == shares[f"turning {side}"]["steps"] + shares[f"straight {side}"][
            "steps"]
        for fault in FAULTS_RAD:
            faults = int(np.sum(where & (error > fault)))
            assert row[f"> {fault:.2f} rad"] == (pytest.approx(faults / where.sum()) if where.any() else None)
    assert shares["turning near"]["steps"] + shares["turning far"]["steps"] == int(turning.sum())


def test_shares_of_four_steps():
    steps = {"error": np.array([0.2, 0.0, 0.2, 0.0]), "turn": np.array([0.5, 0.0, 0.0, 0.5]),
             "nearest_m": np.array([0.5, 0.5, 2.0, 2.0])}
    shares = fault_shares([steps], 1.0)
    assert shares["all near"] == {"steps": 2, "> 0.06 rad": 0.5, "> 0.10 rad": 0.5}
    assert shares["turning near"] == {"steps": 1, "> 0.06 rad": 1.0, "> 0.10 rad": 1.0}
    assert shares["straight far"] == {"steps": 1, "> 0.06 rad": 1.0, "> 0.10 rad": 1.0}
    assert shares["turning far"] == {"steps": 1, "> 0.06 rad": 0.0, "> 0.10 rad": 0.0}
    assert fault_shares([steps], 0.5)["all near"] == {"steps": 0, "> 0.06 rad": None, "> 0.10 rad": None}


def test_robot_2s_worst_heading_step_in_1290_1330_s_is_in_its_meeting(mrclam_dir):
    # session 34 (A): robot 2 wiggles facing robots 1 and 5 at about 1 m in 1,304-1,318 s, the stretch over which the
    # chain's odometry increment between two sighting frames is 0.3 rad off; here in 1-s steps the worst is 0.10 rad
    # (1,314 s), the next 0.054 (1,327 s). The distance bounds were read off this data (1.06 m at 1,303 s, 1.08 m at
    # 1,317 s)
    from estimation.datasets import read_mrclam

    logs = {r: read_mrclam(mrclam_dir, r) for r in (1, 2, 3, 4, 5)}
    steps = heading_steps(logs[2], [logs[r] for r in (1, 3, 4, 5)])
    minute = (steps["start_s"] >= 1290.0) & (steps["start_s"] < 1330.0)
    meeting = (steps["start_s"] >= 1304.0) & (steps["start_s"] < 1318.0)
    assert np.all(steps["nearest_m"][meeting] < 1.1) and np.all(steps["nearest_m"][minute & ~meeting] > 1.0)
    worst = np.flatnonzero(minute)[np.argmax(steps["error"][minute])]
    assert meeting[worst] and steps["error"][worst] > 0.06
