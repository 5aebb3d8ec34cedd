"""Two robots cannot be in one place at one time (fusion/colocation.py; AlignmentConfig.colocation, session 12).

Through the public interface: ``colocation_test`` on two maps, ``CoLocation.admits`` / ``reason`` of a candidate
alignment, and ``align`` with the robust preset's option on.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from estimation.errors import MapFileError
from estimation.geometry import compose, inverse, transform_points
from estimation.landmark_map import LandmarkMap
from fusion import ROBUST, align
from fusion.alignment import alignment_error_xy_theta
from fusion.colocation import colocation_test
from fusion.errors import IncompatibleMapsError
from tests.hardening.foreign_map import save_unchecked

P3AT = 0.2525
NOISE = {"odom_xy_var_per_m": 0.0009, "odom_theta_var_per_rad": 0.0025, "odom_theta_var_per_m": 0.0004,
         "odom_var_floor": 1e-8}
PRECISE = {"odom_xy_var_per_m": 1e-6, "odom_theta_var_per_rad": 1e-7, "odom_theta_var_per_m": 1e-7,
           "odom_var_floor": 1e-10}
ON = dataclasses.replace(ROBUST, colocation=True)


def _path(rng, n: int, step: float) -> np.ndarray:
    """(n, 4) rows t, x, y, θ from the origin: a random smooth drive, 0.2 s a row, ``step`` metres a row."""
    theta = np.concatenate([[0.0], np.cumsum(rng.normal(0, 0.3, n - 1))])
    xy = np.vstack([[0.0, 0.0], np.cumsum(step * np.column_stack([np.cos(theta[:-1]), np.sin(theta[:-1])]), axis=0)])
    return np.column_stack([0.2 * np.arange(n), xy, theta])


def _map(trajectory, robot="robot1", clock="mission 1", radius=P3AT, noise=NOISE, n=6, seed=0, lost=False
         ) -> LandmarkMap:
    rng = np.random.default_rng(seed)
    meta = {"fastslam": dict(noise), "self_check": {"lost": lost}}
    if clock is not None:
        meta["clock"] = clock
    if radius is not None:
        meta["footprint_radius_m"] = radius
    return LandmarkMap(rng.uniform(-5, 5, (n, 3)), np.tile(np.eye(3) * 1e-3, (n, 1, 1)), rng.normal(size=(n, 8)),
                       robot=robot, trajectory=trajectory, metadata=meta)


def _world(pose, trajectory) -> np.ndarray:
    return transform_points(pose, np.column_stack([trajectory[:, 1:3], np.zeros(len(trajectory))]))[:, :2]


COV = np.diag([1e-4, 1e-4, 1e-5])

# -- the test on its own -----------------------------------------------------------------------------------------


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), k=st.integers(0, 39), bearing=st.floats(-np.pi, np.pi),
       theta=st.floats(-np.pi, np.pi))
def test_a_true_alignment_of_paths_that_keep_apart_never_fails(seed, k, bearing, theta):
    """Robot 2's start placed in a random frame so that its row k passes 0.6 m from robot 1's row k (a close pass,
    the bodies 0.1 m apart): the true alignment passes."""
    rng = np.random.default_rng(seed)
    t1, t2 = _path(rng, 40, 0.1), _path(rng, 40, 0.1)
    start1 = np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-np.pi, np.pi)])
    world1 = _world(start1, t1)
    c, s = np.cos(theta), np.sin(theta)
    at = world1[k] + 0.6 * np.array([np.cos(bearing), np.sin(bearing)])
    shift = at - np.array([[c, -s], [s, c]]) @ t2[k, 1:3]
    start2 = np.array([shift[0], shift[1], theta])
    assume(np.min(np.hypot(*(world1 - _world(start2, t2)).T)) >= 2 * P3AT + 0.01)
    test, why = colocation_test(_map(t1, noise=PRECISE), _map(t2, "robot2", noise=PRECISE))
    assert test is not None, why
    truth = compose(inverse(start1), start2)           # map 2's frame in map 1's
    assert test.admits(truth, COV)[0]
    assert test.reason(truth, COV) == ""


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), k=st.integers(0, 39), theta=st.floats(-np.pi, np.pi))
def test_a_transform_that_lays_one_path_onto_the_other_at_one_time_always_fails(seed, k, theta):
    rng = np.random.default_rng(seed)
    t1, t2 = _path(rng, 40, 0.1), _path(rng, 40, 0.1)
    c, s = np.cos(theta), np.sin(theta)
    shift = t1[k, 1:3] - np.array([[c, -s], [s, c]]) @ t2[k, 1:3]
    pose = np.array([shift[0], shift[1], theta])      # robot 2's row k lands on robot 1's row k
    test, why = colocation_test(_map(t1, noise=PRECISE), _map(t2, "robot2", noise=PRECISE))
    assert test is not None, why
    assert not test.admits(pose, COV)[0]
    reason = test.reason(pose, COV)
    assert reason.startswith("robot2 would overlap robot1 at t=") and "at least 0.505 m needed" in reason
    assert "\n" not in reason


def test_the_dead_reckoning_bound_forgives_an_overlap_late_in_a_long_drive():
    """The same overlap after 40 m of driving on the demo's noise model: the trajectories are no longer known well
    enough to call it (σ of metres), so the test does not fail it."""
    t1 = _path(np.random.default_rng(1), 500, 0.08)
    t2 = _path(np.random.default_rng(2), 500, 0.08)
    k = 499
    shift = t1[k, 1:3] - t2[k, 1:3]
    test, _ = colocation_test(_map(t1), _map(t2, "robot2"))
    assert test.admits(np.array([shift[0], shift[1], 0.0]), COV)[0]
    k = 1
    shift = t1[k, 1:3] - t2[k, 1:3]
    assert not test.admits(np.array([shift[0], shift[1], 0.0]), COV)[0]


@pytest.mark.parametrize("change, said", [
    ({"clock": None}, "does not name its trajectory's clock (metadata 'clock')"),
    ({"radius": None}, "does not give its robot's footprint (metadata 'footprint_radius_m')"),
    ({"clock": "mission 2"}, "different clocks"),
    ({"noise": {}}, "keeps no noise model"),
    ({"lost": True}, "flagged itself as lost"),
])
def test_without_a_shared_clock_or_a_footprint_there_is_no_test_and_the_fusion_says_why(change, said):
    t = _path(np.random.default_rng(0), 20, 0.05)
    m1 = _map(t)
    m2 = _map(t, "robot2", **change)
    test, why = colocation_test(m1, m2)
    assert test is None and said in why
    a = align(*_twin_maps(0, trajectories=False), ON, np.random.default_rng(0))
    assert a.statistics.colocation.startswith("no co-location test: the map of robot1 does not name")
    assert ROBUST.colocation is False and align(*_twin_maps(0), ROBUST).statistics.colocation == ""


@pytest.mark.parametrize("field, value", [("footprint_radius_m", float("nan")), ("footprint_radius_m", -0.2),
                                          ("footprint_radius_m", 0.0), ("footprint_radius_m", 1e9),
                                          ("footprint_radius_m", "wide"), ("clock", ""), ("clock", 7),
                                          ("clock", "x" * 300)])
def test_hostile_clock_or_footprint_is_a_one_line_error(tmp_path, field, value):
    m = _map(_path(np.random.default_rng(0), 5, 0.05))
    m.metadata[field] = value
    with pytest.raises(IncompatibleMapsError) as exc:
        colocation_test(m, _map(m.trajectory, "robot2"))
    assert field in str(exc.value) and "\n" not in str(exc.value)
    with pytest.raises(MapFileError) as exc:      # the writer refuses what its reader would refuse
        m.save(tmp_path / "m.npz")
    assert field in str(exc.value) and "\n" not in str(exc.value) and not (tmp_path / "m.npz").exists()
    save_unchecked(m, tmp_path / "m.npz")        # as another writer would leave it
    with pytest.raises(MapFileError) as exc:
        LandmarkMap.load(tmp_path / "m.npz")
    assert field in str(exc.value) and "\n" not in str(exc.value)


def test_clock_and_footprint_survive_a_file_round_trip(tmp_path):
    m = _map(_path(np.random.default_rng(0), 5, 0.05))
    m.save(tmp_path / "m.npz")
    back = LandmarkMap.load(tmp_path / "m.npz")
    assert back.metadata["clock"] == "mission 1" and back.metadata["footprint_radius_m"] == P3AT
    m.metadata.pop("clock")
    m.save(tmp_path / "m.npz")
    assert "clock" not in LandmarkMap.load(tmp_path / "m.npz").metadata


# -- in the pair's decision -----------------------------------------------------------------------------------------
TRUE_POSE = np.array([4.0, -1.0, 0.6])                  # robot 2's start in robot 1's frame, 4.1 m away
HALF_TURN = np.array([TRUE_POSE[0], TRUE_POSE[1], np.pi])   # a half turn about the two starts' midpoint
WRONG = compose(HALF_TURN, TRUE_POSE)                   # puts robot 2's start on robot 1's


def _unit(rng, n, d=32):
    v = rng.normal(size=(n, d))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _twin_maps(seed: int, common: int = 30, twins: int = 24, trajectories: bool = True):
    """A building symmetric under a half turn about the robots' starts' midpoint: map 1 holds ``common`` landmarks
    both saw and ``twins`` more; map 2 the common ones and a look-alike of each twin at its half-turned place.  Each
    robot waits 2 s at its start, then drives 2 m away from the other; both on one clock, P3-AT footprints."""
    rng = np.random.default_rng(seed)
    world_common = rng.uniform([-7, -3, 0.2], [11, 3, 2.5], (common, 3))
    world_twin = rng.uniform([-7, -3, 0.2], [11, 3, 2.5], (twins, 3))
    mirrored = transform_points(HALF_TURN, world_twin)
    d_common, d_twin = _unit(rng, common), _unit(rng, twins)
    sigma = 0.03
    p1 = np.vstack([world_common, world_twin]) + rng.normal(0, sigma, (common + twins, 3))
    p2 = transform_points(inverse(TRUE_POSE), np.vstack([world_common, mirrored])) + rng.normal(
        0, sigma, (common + twins, 3))
    cov = np.tile(np.eye(3) * sigma ** 2, (common + twins, 1, 1))
    desc2 = np.vstack([d_common, d_twin]) + rng.normal(0, 0.03, (common + twins, 32))
    perm = rng.permutation(common + twins)
    t = 0.2 * np.arange(60)
    away = np.clip(t - 2.0, 0, None) * 0.2              # metres along -x of each robot's own frame
    path = np.column_stack([t, -away, np.zeros_like(t), np.zeros_like(t)])
    meta = {"clock": "mission 7", "footprint_radius_m": P3AT, "fastslam": dict(NOISE)} if trajectories else {}
    return (LandmarkMap(p1, cov, np.vstack([d_common, d_twin]), robot="robot1", trajectory=path,
                        metadata=dict(meta)),
            LandmarkMap(p2[perm], cov, desc2[perm], robot="robot2", trajectory=path, metadata=dict(meta)))


@pytest.mark.parametrize("seed", [0, 1])
def test_a_half_turned_rival_that_would_stack_the_robots_no_longer_makes_the_pair_ambiguous(seed):
    m1, m2 = _twin_maps(seed)
    world1 = _world(np.zeros(3), m1.trajectory)
    world2 = _world(TRUE_POSE, m2.trajectory)
    assert np.min(np.hypot(*(world1 - world2).T)) > 1.0          # apart in truth
    plain = align(m1, m2, ROBUST, np.random.default_rng(seed))
    assert not plain.found and plain.reason.startswith("ambiguous")
    a = align(m1, m2, ON, np.random.default_rng(seed))
    assert a.found, a.reason
    assert alignment_error_xy_theta(a.pose, TRUE_POSE)[0] < 0.1
    assert a.statistics.colocation_removed_supports >= 15          # the half turn: removed, not a rival
    assert a.statistics.second_best_supports < 10
    assert a.statistics.colocation.startswith("co-location tested at 60 common times")


def test_a_best_alignment_that_stacks_the_robots_is_not_found_with_the_reason():
    """The twins outnumber the common landmarks: the evidence's best is the half turn, which puts robot 2 on
    robot 1 at t=0; with the option it is 'not found: contradicts co-location', never the loser in its place."""
    m1, m2 = _twin_maps(3, common=14, twins=36)
    plain = align(m1, m2, ROBUST, np.random.default_rng(3))
    assert plain.found and alignment_error_xy_theta(plain.pose, WRONG)[0] < 0.2
    a = align(m1, m2, ON, np.random.default_rng(3))
    assert not a.found
    assert "contradicts co-location: robot2 would overlap robot1 at t=0.0 s" in a.reason
    assert "at least 0.505 m needed, d²=" in a.reason and "\n" not in a.reason


def test_the_fusion_report_says_once_what_the_test_did_or_why_there_was_none():
    from runtime.fusion_report import fuse_maps

    m1, m2 = _twin_maps(0)
    pair = fuse_maps({"robot1": m1, "robot2": m2}, preset=ON).pairs[0]
    assert pair.aligned
    assert pair.colocation.startswith("co-location tested at 60 common times")
    assert pair.colocation.endswith("contradicts it and is no rival") and pair.colocation.count("co-location") == 1
    m1.metadata.pop("clock")
    pair = fuse_maps({"robot1": m1, "robot2": m2}, preset=ON).pairs[0]
    assert not pair.aligned and pair.note.startswith("ambiguous")
    assert pair.colocation == "no co-location test: the map of robot1 does not name its trajectory's clock " \
                              "(metadata 'clock')"
    assert fuse_maps({"robot1": m1, "robot2": m2}).pairs[0].colocation == ""
