"""The drift's heading lever in the export only (``estimation/fastslam/export_drift.py``, docs/fastslam-history.md
"Session 13 ... (N)"): the gate's tracker unchanged, the exported C_l that of the lever tracker."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.fastslam import FastSLAM, range_bearing_config
from estimation.fastslam.drift import DriftTracker
from estimation.fastslam.export_drift import ExportLeverDriftTracker
from estimation.fastslam.lever_drift import LeverDriftTracker
from estimation.fastslam.motion import propagate_covariance
from estimation.geometry import compose
from tests.fastslam.test_lever_drift import turn_then_drive

CHI2_2_95 = 5.991

step = st.tuples(st.floats(-1.0, 1.0), st.floats(-0.5, 0.5), st.floats(-1.0, 1.0),   # the odometry increment
                 st.integers(0, 3),                                                     # predicts before the update
                 st.lists(st.integers(0, 11), max_size=4),                              # landmark ids matched
                 st.integers(0, 2))                                                     # landmarks made


@settings(max_examples=60, deadline=None)
@given(steps=st.lists(step, min_size=1, max_size=12), local=st.floats(1e-6, 1e-2))
def test_the_export_is_the_lever_trackers_and_the_gate_reads_the_plain_trackers(steps, local):
    # the three trackers driven as the filter drives them: the robot's covariance propagated in place by the motion
    # model (the filter's predict writes `robot`), then an update at the robot's pose
    trackers = {"plain": DriftTracker(), "lever": LeverDriftTracker(), "export": ExportLeverDriftTracker()}
    pose, made, rng = np.zeros(3), 0, np.random.default_rng(0)
    local_cov = local * np.eye(3)
    for dx, dy, dth, predicts, matched, new in steps:
        for _ in range(predicts):
            delta, variance = np.array([dx, dy, dth]), np.array([0.01, 0.01, 0.005])
            for t in trackers.values():
                t.robot = propagate_covariance(pose[None], t.robot[None], delta, variance)[0]
            pose = compose(pose, delta)
        matched_ids = np.unique([m for m in matched if m < made]).astype(np.int64)
        new_ids = np.arange(made, made + new)
        positions = np.column_stack([pose[:2] + rng.normal(0.0, 3.0, (new, 2)), np.zeros(new)])
        for t in trackers.values():
            t.update(matched_ids, new_ids, positions, pose, local_cov, made + new)   # the ids that exist now
        made += new
    ids = np.arange(made)
    scale = 1.0 + np.abs(trackers["lever"].landmark_covariances(ids)).max(initial=0.0)
    # the export's C_l is the lever tracker's (the carried difference is exact: the motion's Jacobians are shears)
    assert np.allclose(trackers["export"].landmark_covariances(ids), trackers["lever"].landmark_covariances(ids),
                       rtol=1e-9, atol=1e-12 * scale)
    assert np.allclose(trackers["export"].export_pose_covariances(ids),
                       trackers["lever"].landmark_pose_covariances(ids), rtol=1e-9, atol=1e-12 * scale)
    # what the known-ID gate reads (D_r, D_l) is the plain tracker's, to the bit
    assert np.array_equal(trackers["export"].robot, trackers["plain"].robot)
    assert np.array_equal(trackers["export"].landmark_pose_covariances(ids),
                          trackers["plain"].landmark_pose_covariances(ids))


def _turn_then_drive(seed: int, export_lever: bool):
    """tests/fastslam/test_lever_drift.py's scenario with the known-ID gate's drift on: (trajectory, map, NEES)."""
    slam, nees = turn_then_drive(seed, drift_export="lever" if export_lever else "plain")
    return slam.trajectory(), slam.best_map(min_count=1), nees


def test_export_lever_changes_no_estimate_and_makes_far_landmarks_honest():
    with_lever, without = [], []
    for seed in range(24):
        traj_plain, map_plain, nees_plain = _turn_then_drive(seed, False)
        traj_export, map_export, nees_export = _turn_then_drive(seed, True)
        # the gate reads the plain tracker: the particles, the trajectory and the map's estimates are the same
        assert np.array_equal(traj_plain, traj_export)
        assert np.array_equal(map_plain.positions, map_export.positions)
        with_lever.append(nees_export[0])
        without.append(nees_plain[0])
    with_lever, without = np.array(with_lever), np.array(without)
    # the far landmarks sit off by ~10 m × δθ: honest with the lever (χ²₂: 95 % under the bound, median 1.39),
    # overconfident without it (claimed at the creation pose's few-cm σ)
    assert np.mean(with_lever < CHI2_2_95) >= 0.8
    assert 0.6 < np.median(with_lever) < 2.6
    assert np.mean(without < CHI2_2_95) < 0.5


def _spd(values) -> np.ndarray:
    a = np.array(values, float).reshape(3, 3)
    return a @ a.T + 1e-4 * np.eye(3)


@settings(max_examples=60, deadline=None)
@given(made=st.lists(st.tuples(st.floats(-8, 8), st.floats(-8, 8)), min_size=2, max_size=2),
       robot=st.tuples(st.floats(-8, 8), st.floats(-8, 8), st.floats(-np.pi, np.pi)),
       creation=st.lists(st.floats(-0.5, 0.5), min_size=9, max_size=9),
       predicted=st.lists(st.floats(-0.5, 0.5), min_size=9, max_size=9), two=st.booleans())
def test_one_landmark_pins_the_two_observed_degrees_of_freedom_and_keeps_the_turn_about_it(made, robot, creation,
                                                                                          predicted, two):
    # two landmarks made at the origin with creation drift D (the robot's own D_r then), the robot moved to `robot`
    # with predicted D⁻, then a frame that matches one (or both) of them
    made = np.array(made)
    trackers = [ExportLeverDriftTracker(one_landmark_heading=flag) for flag in (False, True)]
    for t in trackers:
        t.robot = _spd(creation)
        t.update(np.zeros(0, np.int64), np.arange(2), np.column_stack([made, np.zeros(2)]), np.zeros(3),
                 np.zeros((3, 3)), 2)
        t.robot = _spd(predicted)
        t.update(np.arange(2 if two else 1), np.zeros(0, np.int64), np.zeros((0, 3)), np.array(robot),
                 1e-4 * np.eye(3), 2)
    rule, kept = trackers[0].lever_robot, trackers[1].lever_robot
    if two:   # two landmarks observe the heading too: the rule
        assert np.allclose(kept, rule)
        return
    # in the coordinates (a, θ), a = δt − δθ J(t − p) the two the reading observes: a's block is the rule's ...
    arm = np.array(robot[:2]) - made[0]
    to_observed = np.array([[1.0, 0.0, arm[1]], [0.0, 1.0, -arm[0]], [0.0, 0.0, 1.0]])
    a_rule, a_kept = to_observed @ rule @ to_observed.T, to_observed @ kept @ to_observed.T
    scale = 1.0 + np.abs(a_rule).max()
    assert np.allclose(a_kept[:2, :2], a_rule[:2, :2], atol=1e-9 * scale)
    assert np.allclose(a_kept[:2, 2], a_rule[:2, 2], atol=1e-9 * scale)
    # ... and the heading keeps the predicted uncertainty where that was larger than the landmark's
    assert np.isclose(kept[2, 2], max(rule[2, 2], _spd(predicted)[2, 2]), rtol=1e-9)
    assert np.all(np.linalg.eigvalsh(kept) > -1e-12 * scale)


def test_the_export_tracker_serves_the_known_id_path_only():
    """range_bearing_config exports with the lever and the one-landmark heading, in "id" association only: in
    "unknown" association merges read the exported covariances (estimates would change), so the plain tracker
    stays there; with drift_lever the lever tracker gates and exports with the lever itself."""
    slam = FastSLAM(range_bearing_config(association="id"), np.random.default_rng(0))
    assert type(slam.drift) is ExportLeverDriftTracker and slam.drift.one_landmark_heading
    assert type(FastSLAM(range_bearing_config(association="unknown"), np.random.default_rng(0)).drift) is DriftTracker
    lever = FastSLAM(range_bearing_config(association="id", drift_lever=True), np.random.default_rng(0))
    assert type(lever.drift) is LeverDriftTracker
    plain = FastSLAM(range_bearing_config(association="id", drift_export="plain"), np.random.default_rng(0))
    assert type(plain.drift) is DriftTracker
    with pytest.raises(ValueError, match="drift_export must be one of plain, lever, lever\\+heading"):
        range_bearing_config(association="id", drift_export="levers")
