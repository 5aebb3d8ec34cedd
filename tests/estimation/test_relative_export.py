"""The landmark's shape part in the export (``export_drift.ExportLeverDriftTracker(relative=True)``,
``drift_export="lever+heading+relative"``, docs/fastslam-history.md "Session 14 ... (J)"): the drift of the poses that
re-sighted a landmark relative to the pose that made it, as the mean over its sightings, added to the exported C_l;
the gate's tracker, so every estimate, unchanged."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.fastslam import FastSLAM, range_bearing_config
from estimation.fastslam.export_drift import ExportLeverDriftTracker
from estimation.fastslam.lever_drift import shears
from tests.fastslam.test_lever_drift import turn_then_drive

CHI2_2_95 = 5.991


def _h(landmark: np.ndarray, robot_xy: np.ndarray) -> np.ndarray:
    """∂(landmark placed from the pose)/∂(pose error): [[1, 0, −w_y], [0, 1, w_x]], w = landmark − robot."""
    w = landmark - robot_xy
    return np.array([[1.0, 0.0, -w[1]], [0.0, 1.0, w[0]]])


def _chain_then_return(relative: bool, n_samples: int, rng: np.random.Generator):
    """A linear chain with known truth, driven as the filter drives the tracker. Landmark A is made at the start
    from a pose with a small error; the robot drives 8 m out making a landmark per metre, each frame pinned to the
    previous one only (so the chain drifts by P_local a frame), comes back 1 m to the side making new ones, and
    re-sights A ten times together with the two newest: its pose is held half-way by the drifted chain, so A's
    readings are placed off by the chain's drift relative to A's creation pose, all ten by nearly the same amount.

    The true errors follow the tracker's own model (the pose error at a frame is the mean over the matched landmarks
    of their creation-pose errors carried with the lever, plus a fresh local error ~ N(0, P_local)). A's estimate is
    the mean of its eleven placements (equal weights: equal readings' noise, no sensor noise). Returns A's error
    samples (n, 2) and its exported covariance's position block (2, 2)."""
    local = np.diag([0.02, 0.02, 0.002])                 # P_local, the frame's pose covariance relative to the map
    tracker = ExportLeverDriftTracker(relative=relative)
    made_at, made_error, made_from = {}, {}, {}          # landmark id -> position, creation-pose error samples, origin
    a_pos = np.array([2.0, 0.5])
    tracker.robot = 1e-4 * np.eye(3)
    e0 = rng.multivariate_normal(np.zeros(3), tracker.robot, n_samples)
    tracker.update(np.zeros(0, np.int64), np.array([0, 1]), np.array([[*a_pos, 0.0], [0.0, 1.0, 0.0]]),
                   np.zeros(3), local, 2)
    for lid, pos in ((0, a_pos), (1, np.array([0.0, 1.0]))):
        made_at[lid], made_error[lid], made_from[lid] = pos, e0, np.zeros(2)
    placements = [e0 @ _h(a_pos, np.zeros(2)).T]           # A's placement errors at its creation

    def frame(robot_xy, matched, new_ids=(), new_positions=()):
        pose = np.array([*robot_xy, 0.0])
        g = shears(np.array([robot_xy - made_from[m] for m in matched]))
        error = np.mean([made_error[m] @ gm.T for m, gm in zip(matched, g, strict=True)], axis=0)
        error = error + rng.multivariate_normal(np.zeros(3), local, n_samples)
        positions = np.array([[*p, 0.0] for p in new_positions]).reshape(-1, 3)
        tracker.update(np.array(matched, np.int64), np.array(new_ids, np.int64), positions, pose, local,
                       max([*matched, *new_ids]) + 1)
        for lid, p in zip(new_ids, new_positions, strict=True):
            made_at[lid], made_error[lid], made_from[lid] = np.asarray(p), error, np.asarray(robot_xy, float)
        return error

    last = 1
    for x in range(1, 9):                                # out along y = 0, a landmark at y = 1 per metre
        frame(np.array([float(x), 0.0]), [last], [last + 1], [np.array([float(x), 1.0])])
        last += 1
    for x in range(8, 0, -1):                            # back along y = −1, a landmark at y = −2 per metre
        frame(np.array([float(x), -1.0]), [last], [last + 1], [np.array([float(x), -2.0])])
        last += 1
    for k in range(10):                                  # A re-sighted with the two newest, the robot edging on
        robot_xy = np.array([1.0 - 0.1 * k, -1.0])
        error = frame(robot_xy, [0, last - 1, last])
        placements.append(error @ _h(a_pos, robot_xy).T)
    a_error = np.mean(placements, axis=0)
    return a_error, tracker.landmark_covariances(np.array([0]))[0, :2, :2]


def _nees(error: np.ndarray, cov: np.ndarray) -> np.ndarray:
    return np.einsum("ni,ni->n", error, np.linalg.solve(cov, error.T).T)


def test_a_landmark_resighted_from_a_drifted_pose_is_covered_by_the_relative_export():
    plain_error, plain_cov = _chain_then_return(False, 4000, np.random.default_rng(1))
    error, cov = _chain_then_return(True, 4000, np.random.default_rng(1))
    assert np.array_equal(plain_error, error)            # the truth does not depend on the export
    plain, relative = _nees(error, plain_cov), _nees(error, cov)
    # C_l alone is the creation pose's 1-2 cm: A's ~0.4 m shape error is far outside it
    assert np.mean(plain < CHI2_2_95) < 0.3
    # with the mean relative drift: covered (χ²₂: 95 %), and not by a cover that swamps it (median of χ²₂: 1.39;
    # the tracker's mean rule is wider than a pose held half-way, so somewhat under it)
    assert np.mean(relative < CHI2_2_95) >= 0.95
    assert 0.3 < np.median(relative) < 1.39
    # the shape part is the difference, and it is positive semi-definite
    assert np.all(np.linalg.eigvalsh(cov - plain_cov) > -1e-12)


def _spd(values) -> np.ndarray:
    a = np.array(values, float).reshape(3, 3)
    return a @ a.T + 1e-4 * np.eye(3)


@settings(max_examples=60, deadline=None)
@given(made=st.tuples(st.floats(-8, 8), st.floats(-8, 8)), creation=st.lists(st.floats(-0.5, 0.5), min_size=9,
                                                                            max_size=9),
       drift=st.lists(st.floats(-0.5, 0.5), min_size=9, max_size=9), n=st.integers(1, 12))
def test_sightings_sharing_one_drift_add_it_once_not_summed_nor_divided(made, creation, drift, n):
    # landmarks 0 (made at the origin with drift D_0) and 1 (made later from the same place with D_0 + Δ); then n
    # frames that see both from the same pose: every sighting of 0 has the same relative drift, so the shape part
    # is n/(n+1) of one sighting's (the creation sighting has none), however n grows: not n times it, nor 1/n
    d0, delta = _spd(creation), _spd(drift)
    t = ExportLeverDriftTracker(relative=True)
    landmarks = np.array([[*made, 0.0], [made[0] + 1.0, made[1], 0.0]])
    t.robot = d0
    t.update(np.zeros(0, np.int64), np.array([0]), landmarks[:1], np.zeros(3), np.zeros((3, 3)), 1)
    t.robot = d0 + delta
    t.update(np.zeros(0, np.int64), np.array([1]), landmarks[1:], np.zeros(3), np.zeros((3, 3)), 2)
    for _ in range(n):
        t.update(np.array([0, 1]), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(3), np.zeros((3, 3)), 2)
    # one sighting: the robot is held by the mean of the two, D_r = D_0 + Δ/2, relative to 0's creation Δ/2
    w = landmarks[0, :2]
    h = np.array([[1.0, 0.0, -w[1]], [0.0, 1.0, w[0]], [0.0, 0.0, 0.0]])
    one = h @ (delta / 2) @ h.T
    shape = t.relative_covariances(np.array([0]))[0]
    scale = 1.0 + np.abs(one).max()
    assert np.allclose(shape, n / (n + 1) * one, atol=1e-9 * scale)
    # landmark 1's own sightings are held partly by the older landmark 0: less drift than at its creation, no
    # shape part (the PSD part of a negative difference)
    assert np.allclose(t.relative_covariances(np.array([1]))[0], 0.0, atol=1e-9 * scale)
    # without ``relative`` nothing is added, and ``relative`` never narrows the export
    plain = ExportLeverDriftTracker()
    plain.robot = d0
    plain.update(np.zeros(0, np.int64), np.array([0]), landmarks[:1], np.zeros(3), np.zeros((3, 3)), 1)
    assert np.allclose(t.landmark_covariances(np.array([0]))[0] - shape, plain.landmark_covariances(np.array([0]))[0],
                       atol=1e-12 * scale)


def test_the_relative_export_changes_no_estimate():
    for seed in range(6):
        default, _ = turn_then_drive(seed, drift_export="lever+heading")
        relative, _ = turn_then_drive(seed, drift_export="lever+heading+relative")
        assert np.array_equal(default.trajectory(), relative.trajectory())
        a, b = default.best_map(min_count=1), relative.best_map(min_count=1)
        assert np.array_equal(a.positions, b.positions)
        # the export is the default's plus a positive semi-definite shape part
        extra = b.covariances[:, :2, :2] - a.covariances[:, :2, :2]
        assert np.all(np.linalg.eigvalsh(extra) > -1e-12)


def test_the_config_builds_the_relative_export_tracker():
    # range_bearing_config's known-ID export since session 14; "lever+heading" the one before it
    slam = FastSLAM(range_bearing_config(association="id"), np.random.default_rng(0))
    assert type(slam.drift) is ExportLeverDriftTracker and slam.drift.one_landmark_heading and slam.drift.relative
    before = FastSLAM(range_bearing_config(association="id", drift_export="lever+heading"), np.random.default_rng(0))
    assert before.drift.one_landmark_heading and not before.drift.relative
