"""benchmarks/demo_frame_errors.py: a map's frame error by creation time, the turns on the spot, and the supports
refitted with the drift the landmarks of one map share (the GLS of step (a), measured in docs/fusion-history.md
"Session 26 … (B)")."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from benchmarks import demo_frame_errors as dfe
from estimation.geometry import transform_points, wrap_angle
from estimation.landmark_map import LandmarkMap
from fusion.ransac import refine_pose

angles = st.floats(-0.2, 0.2).filter(lambda e: abs(e) > 1e-3)


def _turned(points: np.ndarray, e: float, about=(0.0, 0.0)) -> np.ndarray:
    """points (K, 2) turned by e about ``about``: a map whose heading was e off when it made them."""
    o = np.asarray(about, float)
    return transform_points(np.array([*(o - np.array([[np.cos(e), -np.sin(e)], [np.sin(e), np.cos(e)]]) @ o), e]),
                            np.column_stack([points, np.zeros(len(points))]))[:, :2]


@settings(max_examples=100)
@given(angles, st.integers(0, 2**32 - 1))
def test_a_map_turned_about_its_start_has_minus_that_turn_as_its_frame_error(e, seed):
    truth = np.random.default_rng(seed).uniform(-8, 8, (30, 2))
    fit = dfe.frame_error(_turned(truth, e), truth)
    assert abs(wrap_angle(fit[2] + e)) < 1e-9
    assert np.hypot(fit[0], fit[1]) < 1e-9


@settings(max_examples=60)
@given(angles, st.floats(20.0, 100.0), st.integers(0, 2**32 - 1))
def test_the_windows_tell_when_the_frame_went_off(e, t_turn, seed):
    """Landmarks made before a turn at t_turn sit in the start frame; those made after it are turned by e about the
    place of the turn: windows before it fit zero, windows after it −e."""
    rng = np.random.default_rng(seed)
    truth = rng.uniform(-8, 8, (400, 2))
    times = rng.uniform(0, 140, 400)
    place = rng.uniform(-5, 5, 2)
    after = times >= t_turn
    mapped = truth.copy()
    mapped[after] = _turned(truth[after], e, place)
    for a, b, n, fit in dfe.windowed_frame_errors(mapped, truth, times):
        assert n >= 4
        if b <= t_turn:
            assert abs(fit[2]) < 1e-9
        elif a >= t_turn:
            assert abs(wrap_angle(fit[2] + e)) < 1e-9


def _map(positions, times, trajectory, cov=1e-4, drift=None, origins=None) -> LandmarkMap:
    n = len(positions)
    return LandmarkMap(np.column_stack([positions, np.zeros(n)]), np.tile(np.eye(3) * cov, (n, 1, 1)),
                       np.zeros((n, 4), np.float32), ids=np.argsort(np.argsort(times)), trajectory=trajectory,
                       drift_covariances=np.zeros((n, 3, 3)) if drift is None else drift,
                       drift_origins=np.zeros((n, 2)) if origins is None else origins)


@settings(max_examples=40)
@given(st.integers(0, 2**32 - 1))
def test_creation_times_come_from_where_the_robot_was(seed):
    """Each landmark's drift origin is a pose of the trajectory (a few mm off, as the ancestry moved since): its time
    is that pose's, and the times do not decrease with the id."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 60.0, 0.25)
    trajectory = np.column_stack([t, 0.3 * t, np.sin(t / 5), np.zeros_like(t)])       # never back where it was
    k = np.sort(rng.integers(0, len(t), 80))
    origins = trajectory[k, 1:3] + rng.normal(0, 0.003, (80, 2))
    m = _map(rng.uniform(-5, 5, (80, 2)), t[k], trajectory, origins=origins)
    made = dfe.creation_times(m)
    assert np.all(np.abs(made - t[k]) <= 0.25 + 1e-9)
    assert np.all(np.diff(made[np.argsort(m.ids)]) >= 0)


def test_a_turn_on_the_spot_is_found_and_a_turn_while_driving_is_not():
    t = np.arange(0.0, 30.0, 0.25)
    x = np.where(t < 10, 0.35 * t, 3.5)
    x = np.where(t >= 15, 3.5 + 0.35 * (t - 15), x)
    heading = np.clip((t - 10) * 0.4, 0, 2.0)                       # 2 rad on the spot between 10 and 15 s
    heading = heading + np.where(t >= 20, 0.3 * np.sin(t - 20), 0)  # a weave while driving
    turns = dfe.turns_on_the_spot(np.column_stack([t, x, np.zeros_like(t), heading]))
    assert len(turns) == 1
    a, b = turns[0]
    assert 10.0 <= t[a] <= 10.5 and 14.5 <= t[b] <= 15.0


@settings(max_examples=30)
@given(st.floats(-3, 3), st.floats(-3, 3), st.floats(-np.pi, np.pi), st.integers(0, 2**32 - 1))
def test_without_drift_the_gls_is_the_alignments_weighted_fit(tx, ty, th, seed):
    rng = np.random.default_rng(seed)
    p2 = rng.uniform(-6, 6, (25, 2))
    pose = np.array([tx, ty, th])
    p1 = transform_points(pose, np.column_stack([p2, np.zeros(25)]))[:, :2] + rng.normal(0, 0.03, (25, 2))
    traj = np.zeros((1, 4))
    m1, m2 = _map(p1, np.zeros(25), traj, cov=4e-4), _map(p2, np.zeros(25), traj, cov=9e-4)
    supports = np.column_stack([np.arange(25), np.arange(25)])
    gls, _ = dfe.gls_alignment(m1, m2, supports, pose + [0.05, -0.05, 0.01], floor=0.02)
    wls, _, _ = refine_pose(m1.positions, m1.covariances, m2.positions, m2.covariances, pose + [0.05, -0.05, 0.01],
                            0.02)
    assert np.allclose(gls[:2], wls[:2], atol=1e-7) and abs(wrap_angle(gls[2] - wls[2])) < 1e-8


@settings(max_examples=40)
@given(angles, st.integers(0, 2**32 - 1))
def test_with_a_shared_drift_the_start_landmarks_hold_the_frame(e, seed):
    """Map 2: 8 landmarks made at its start (no drift) and 40 made after a turn that left its heading e off, all
    sharing that drift (σθ 0.05, as the file says). Fitted as independent (the alignment's weighted fit), the 40
    pull the pose towards it, most layouts by a few per cent of e; with their shared drift (GLS) the start's landmarks
    hold the frame (below a quarter of e, and at most half the independent fit's error when that is not negligible)."""
    rng = np.random.default_rng(seed)
    early, late = rng.uniform(-6, 6, (8, 2)), rng.uniform(-6, 6, (40, 2))
    place = np.array([4.0, 1.0])                                      # where the robot was when it turned
    pose = np.array([1.0, -2.0, 0.7])                                 # map 2's start in map 1
    true2 = np.vstack([early, late])
    p1 = transform_points(pose, np.column_stack([true2, np.zeros(48)]))[:, :2]
    p2 = np.vstack([early, _turned(late, e, place)])
    D = np.zeros((48, 3, 3))
    D[8:] = np.diag([0.05 ** 2, 0.05 ** 2, 0.05 ** 2])
    origins = np.zeros((48, 2))
    origins[8:] = place
    lever = dfe._lever(p2, origins)
    m2 = _map(p2, np.r_[np.zeros(8), np.ones(40)], np.zeros((1, 4)), drift=D, origins=origins)
    m2.covariances[:, :2, :2] += lever @ D @ np.swapaxes(lever, 1, 2)   # the file's covariance: local + drift
    m1 = _map(p1, np.zeros(48), np.zeros((1, 4)))
    supports = np.column_stack([np.arange(48), np.arange(48)])
    gls, _ = dfe.gls_alignment(m1, m2, supports, pose, floor=0.02)
    wls, _, _ = refine_pose(m1.positions, m1.covariances, m2.positions, m2.covariances, pose, 0.02)
    gls_err, wls_err = abs(wrap_angle(gls[2] - pose[2])), abs(wrap_angle(wls[2] - pose[2]))
    assert gls_err < 0.25 * abs(e)
    # at most half the independent fit's error, unless both are negligible: a layout whose turned landmarks the
    # independent fit already weighs down leaves it a thousandth of e off (e 0.117 rad, seed 335615813: 4e-6 rad,
    # GLS 1.6e-5), and there is nothing left to halve
    assert gls_err <= max(0.5 * wls_err, 1e-3 * abs(e))


def test_the_script_refuses_a_folder_without_maps(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        dfe.main([str(tmp_path)])
    assert exit_.value.code == 2
    assert "no robot1.npz / robot2.npz" in capsys.readouterr().err
