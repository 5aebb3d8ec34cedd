"""Keyframes in the smoothing's readings recorder (estimation.stereo_readings.ReadingsRecorder(keyframes=...)).

The rule (a frame is kept when it moved or turned enough since the last kept frame, or sees enough the last kept
frame did not), the odometry between kept frames (the composed increment and its covariance under the filter's
motion model, checked against the chain's Jacobian, the filter's own sampling and the one-increment model where they
must agree), and that without keyframes the recorder's output and the smoothed map are what they were.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.fastslam import FastSLAMConfig
from estimation.fastslam.motion import increment_variance, sample_motion
from estimation.geometry import between, compose
from estimation.landmark_map import LandmarkMap
from estimation.stereo_readings import KeyframeRule, ReadingsRecorder, StereoReadings, smoothed_map

CONFIG = FastSLAMConfig()
D = CONFIG.descriptor_size
FAR = 1e6                  # a threshold no test path reaches


class _Obs(SimpleNamespace):
    def __len__(self) -> int:
        return len(self.points)


def _descriptors(n: int, seed: int) -> np.ndarray:
    d = np.random.default_rng(seed).standard_normal((n, D)).astype(np.float32)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _obs(n: int = 5, seed: int = 0, descriptors: np.ndarray | None = None) -> _Obs:
    rng = np.random.default_rng(1000 + seed)
    return _Obs(points=rng.uniform(1.0, 4.0, (n, 3)), covariances=np.tile(np.eye(3) * 1e-4, (n, 1, 1)),
                descriptors=_descriptors(n, seed) if descriptors is None else descriptors,
                pixels=rng.uniform(0.0, 600.0, (n, 2)))


def _recorder(distance: float = FAR, angle: float = FAR, overlap: float = 0.0, config=CONFIG) -> ReadingsRecorder:
    return ReadingsRecorder(D, keyframes=KeyframeRule(distance, angle, overlap), config=config)


def _fold(steps: np.ndarray) -> np.ndarray:
    out = np.zeros(3)
    for s in steps:
        out = compose(out, s)
    return out


# -- the rule ---------------------------------------------------------------------------------------------------
def test_a_frame_moved_less_than_the_distance_is_not_kept_and_one_moved_more_is():
    rec = _recorder(distance=0.1)
    same = _obs(seed=1)
    assert rec.add(0.0, [2.0, 1.0, 0.3], same)                          # the first frame is always a keyframe
    assert not rec.add(0.1, compose([2.0, 1.0, 0.3], [0.06, 0.0, 0.0]), same)
    assert not rec.add(0.2, compose([2.0, 1.0, 0.3], [0.09, 0.01, 0.0]), same)
    assert rec.add(0.3, compose([2.0, 1.0, 0.3], [0.10, 0.01, 0.0]), same)
    assert not rec.add(0.4, compose([2.0, 1.0, 0.3], [0.15, 0.01, 0.0]), same)   # 0.05 from the new keyframe
    kept = rec.readings_kept()
    assert rec.frames == 2 and rec.frames_seen == 5 and rec.readings == 10 and rec.readings_seen == 25
    np.testing.assert_array_equal(kept.frame_index, [0, 3])
    np.testing.assert_array_equal(kept.times, [0.0, 0.3])


def test_a_turn_less_than_the_angle_is_not_kept_and_one_more_is():
    rec = _recorder(angle=0.1)
    same = _obs(seed=2)
    assert rec.add(0.0, [0.0, 0.0, 3.1], same)
    assert not rec.add(0.1, [0.0, 0.0, 3.1 + 0.09], same)            # across ±π: still 0.09 rad
    assert rec.add(0.2, [0.0, 0.0, 3.1 + 0.11], same)
    np.testing.assert_array_equal(rec.readings_kept().frame_index, [0, 2])


def test_a_frame_that_sees_what_the_last_keyframe_did_not_is_kept_without_moving():
    rec = _recorder(overlap=0.5)
    old = _descriptors(10, 3)
    new = _descriptors(10, 4)
    assert rec.add(0.0, [0.0, 0.0, 0.0], _obs(10, descriptors=old))
    assert not rec.add(0.1, [0.0, 0.0, 0.0], _obs(10, descriptors=old))                      # all seen before
    assert not rec.add(0.2, [0.0, 0.0, 0.0], _obs(10, descriptors=np.vstack([old[:5], new[:5]])))  # half
    assert rec.add(0.3, [0.0, 0.0, 0.0], _obs(10, descriptors=np.vstack([old[:4], new[:6]])))      # 4 of 10
    assert not rec.add(0.4, [0.0, 0.0, 0.0], _obs(0))                                       # nothing to add
    assert not rec.add(0.5, [0.0, 0.0, 0.0], _obs(10, descriptors=np.vstack([old[:4], new[:6]])))
    np.testing.assert_array_equal(rec.readings_kept().frame_index, [0, 3])


def test_the_rule_and_the_recorder_refuse_what_they_cannot_use():
    for bad in ({"distance": 0.0}, {"angle": -1.0}, {"distance": np.nan}, {"overlap": 1.5},
                {"descriptor_threshold": 0.0}):
        with pytest.raises(ValueError, match="KeyframeRule"):
            KeyframeRule(**bad)
    with pytest.raises(ValueError, match="config"):
        ReadingsRecorder(D, keyframes=KeyframeRule())


def test_the_cap_counts_keyframes_not_frames():
    rec = ReadingsRecorder(D, max_frames=3, keyframes=KeyframeRule(0.1, FAR, 0.0), config=CONFIG)
    for k in range(12):                                    # 0.03 m a frame: keyframes at frames 0, 4 and 8
        rec.add(0.1 * k, [0.03 * k, 0.0, 0.0], _obs(seed=5))
    assert rec.overflow is None and rec.frames == 3 and rec.frames_seen == 12
    assert not rec.add(1.2, [0.36, 0.0, 0.0], _obs(seed=5))    # the fourth keyframe passes the cap
    assert rec.overflow is not None and rec.frames == 0


# -- the odometry between keyframes ----------------------------------------------------------------------------------
def _feed(rec: ReadingsRecorder, start: np.ndarray, steps: np.ndarray, dt: float = 0.1) -> list[np.ndarray]:
    """Odometry poses start ⊕ steps[0] ⊕ ... given one a frame, the last frame's readings all new (a keyframe by
    the view when overlap > 0)."""
    poses = [np.asarray(start, float)]
    for s in steps:
        poses.append(compose(poses[-1], s))
    for k, p in enumerate(poses):
        last = k == len(poses) - 1
        rec.add(dt * k, p, _obs(6, seed=7 if not last else 8))
    return poses


def test_the_composed_increment_is_the_direct_one_and_the_fold_of_the_frames():
    rng = np.random.default_rng(11)
    steps = np.column_stack([rng.uniform(0.0, 0.04, 40), rng.uniform(-0.005, 0.005, 40), rng.uniform(-0.03, 0.05, 40)])
    rec = _recorder(distance=0.12, angle=0.15)
    poses = _feed(rec, [1.0, -2.0, 2.5], steps)
    kept = rec.readings_kept()
    idx = kept.frame_index
    assert 3 < len(idx) < len(poses)
    np.testing.assert_array_equal(kept.odometry, np.array(poses)[idx])
    inc = between(kept.odometry[:-1], kept.odometry[1:])
    for k, (a, b) in enumerate(zip(idx[:-1], idx[1:], strict=True)):
        np.testing.assert_allclose(inc[k], between(poses[a], poses[b]), atol=1e-12)
        np.testing.assert_allclose(inc[k], _fold(steps[a:b]), atol=1e-12)


def _composed(steps: np.ndarray, config=CONFIG, dt: float = 0.1) -> np.ndarray:
    """The covariance the recorder gives the increment over ``steps`` (one keyframe at each end)."""
    rec = _recorder(overlap=0.5, config=config)
    _feed(rec, [0.3, 0.2, -1.0], steps, dt)
    kept = rec.readings_kept()
    np.testing.assert_array_equal(kept.frame_index, [0, len(steps)])
    return kept.increment_covariances[0]


def test_straight_on_or_turning_on_the_spot_the_composition_is_one_increment_over_the_total():
    """The model is a random walk in distance and angle: along a straight line the x and θ variances of n frames
    composed are one increment's over the whole distance (plus the floor once a frame); y also holds the heading's
    errors carried across the rest of the way (Σ var_θk · r_k²: lateral error grows as distance³), which one increment
    does not; on the spot all three are the one increment's."""
    n, step = 10, 0.03
    cov = _composed(np.tile([step, 0.0, 0.0], (n, 1)))
    one = increment_variance(np.array([n * step, 0.0, 0.0]), CONFIG, n * 0.1)
    floors = (n - 1) * CONFIG.odom_var_floor
    per_step = increment_variance(np.array([step, 0.0, 0.0]), CONFIG, 0.1)
    lever = per_step[2] * np.sum((step * np.arange(n - 1, -1, -1)) ** 2)
    np.testing.assert_allclose(np.diag(cov), one + floors + [0.0, lever, 0.0], rtol=1e-12)
    assert lever > 0.01 * one[1]                        # not negligible: the test sees it
    np.testing.assert_allclose(cov[1, 2], per_step[2] * np.sum(step * np.arange(n - 1, -1, -1)), rtol=1e-12)
    spin = _composed(np.tile([0.0, 0.0, 0.04], (n, 1)))
    np.testing.assert_allclose(spin, np.diag(increment_variance(np.array([0.0, 0.0, n * 0.04]), CONFIG, 1.0)
                                             + floors), rtol=1e-12, atol=1e-18)


def test_a_path_back_and_forth_composes_the_distance_driven_not_the_net_one():
    """What one increment over the net motion would understate: forward 0.15 m and back costs 0.3 m of x variance."""
    cov = _composed(np.array([[0.05, 0.0, 0.0]] * 3 + [[-0.05, 0.0, 0.0]] * 3))
    assert cov[0, 0] == pytest.approx(CONFIG.odom_xy_var_per_m * 0.3 + 6 * CONFIG.odom_var_floor, rel=1e-12)


def _jacobian_covariance(steps: np.ndarray, config, dt: float) -> np.ndarray:
    """J diag(v) Jᵀ with J the central-difference Jacobian of steps[0] ⊕ ... ⊕ steps[-1] in every step."""
    v = increment_variance(steps, config, np.full(len(steps), dt)).ravel()
    x0 = steps.ravel()
    h = 1e-6
    jac = np.zeros((3, len(x0)))
    for i in range(len(x0)):
        e = np.zeros(len(x0))
        e[i] = h
        jac[:, i] = (_fold((x0 + e).reshape(-1, 3)) - _fold((x0 - e).reshape(-1, 3))) / (2 * h)
    return (jac * v) @ jac.T


_step = st.tuples(st.floats(-0.05, 0.08), st.floats(-0.02, 0.02), st.floats(-0.2, 0.2))


@settings(max_examples=60, deadline=None)
@given(st.lists(_step, min_size=1, max_size=12), st.floats(0.0, 1e-3), st.floats(1.0, 3.0))
def test_the_composed_covariance_is_the_chains_first_order_one_on_any_path(steps, per_s, inflation):
    config = FastSLAMConfig(odom_theta_var_per_s=per_s, odom_turn_xy_inflation=inflation)
    steps = np.array(steps, float)
    cov = _composed(steps, config, dt=0.2)
    want = _jacobian_covariance(steps, config, 0.2)
    np.testing.assert_allclose(cov, want, rtol=1e-5, atol=1e-13)
    assert np.all(np.linalg.eigvalsh(cov) > 0)


def test_the_composed_covariance_is_the_filters_own_sampling_of_the_frames():
    """The filter predicts each frame by sample_motion with increment_variance; 20 000 particles driven through a
    curving path's 12 frames spread as the recorder's composed covariance says (whitened, fixed seed)."""
    rng = np.random.default_rng(5)
    steps = np.column_stack([np.full(12, 0.06), np.zeros(12), np.linspace(0.02, 0.12, 12)])
    cov = _composed(steps)
    particles = np.zeros((20_000, 3))
    for s in steps:
        particles = sample_motion(particles, s, increment_variance(s, CONFIG, 0.1), rng)
    e = particles - _fold(steps)
    w = np.linalg.cholesky(np.linalg.inv(cov))
    white = np.cov((e @ w).T)
    np.testing.assert_allclose(white, np.eye(3), atol=0.05)


# -- off: unchanged ----------------------------------------------------------------------------------------------
def _frames(n: int = 30, seed: int = 0) -> list[tuple[float, np.ndarray, _Obs]]:
    rng = np.random.default_rng(seed)
    pose = np.zeros(3)
    out = []
    for k in range(n):
        pose = compose(pose, [rng.uniform(0.0, 0.05), 0.0, rng.uniform(-0.05, 0.05)])
        out.append((0.25 * k, pose.copy(), _obs(int(rng.integers(0, 7)), seed=100 + k)))
    return out


def test_without_keyframes_the_recorder_keeps_every_frame_as_it_came():
    frames = _frames()
    rec = ReadingsRecorder(D)
    assert all(rec.add(t, p, o) for t, p, o in frames)
    kept = rec.readings_kept()
    assert kept.frame_index is None and kept.increment_covariances is None
    np.testing.assert_array_equal(kept.times, [f[0] for f in frames])
    np.testing.assert_array_equal(kept.odometry, np.array([f[1] for f in frames]))
    np.testing.assert_array_equal(kept.counts, [len(f[2]) for f in frames])
    for name in ("points", "covariances", "descriptors", "pixels"):
        np.testing.assert_array_equal(getattr(kept, name), np.concatenate([getattr(f[2], name) for f in frames]))
    assert kept.descriptors.dtype == np.float32


def test_keyframes_that_keep_every_frame_give_the_same_readings_and_the_filters_own_variances():
    frames = _frames()
    off, on = ReadingsRecorder(D), _recorder(distance=1e-9)
    for t, p, o in frames:
        off.add(t, p, o)
        assert on.add(t, p, o)
    a, b = off.readings_kept(), on.readings_kept()
    for name in ("times", "odometry", "counts", "points", "covariances", "descriptors", "pixels"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    np.testing.assert_array_equal(b.frame_index, np.arange(len(frames)))
    v = increment_variance(between(a.odometry[:-1], a.odometry[1:]), CONFIG, np.diff(a.times))
    np.testing.assert_array_equal(np.diagonal(b.increment_covariances, axis1=1, axis2=2), v)
    assert np.all(b.increment_covariances[:, [0, 0, 1, 1, 2, 2], [1, 2, 0, 2, 0, 1]] == 0.0)


# -- the smoothed map from keyframes ------------------------------------------------------------------------------
def _world(seed: int = 0) -> dict:
    """A robot driving a 2 m arc past 60 landmarks on two walls, its filter's trajectory (the truth bent by 0.02 rad
    a metre) and map (the truth with 2 cm noise), and every frame's readings (1 cm noise)."""
    rng = np.random.default_rng(seed)
    xs = np.linspace(-1.0, 5.0, 30)
    world = np.vstack([np.column_stack([xs, np.full(30, 2.5), rng.uniform(0.3, 1.5, 30)]),
                       np.column_stack([xs, np.full(30, -2.5), rng.uniform(0.3, 1.5, 30)])])
    desc = _descriptors(len(world), 77)
    n = 60
    truth = np.column_stack([np.linspace(0, 3.0, n), 0.3 * np.sin(np.linspace(0, 3, n)), np.linspace(0, 0.3, n)])
    truth = np.vstack([np.zeros(3), truth[1:]])
    bent = truth.copy()
    bent[:, 2] += 0.02 * truth[:, 0]
    times = 0.25 * np.arange(1, n + 1)
    frames = []
    for k, pose in enumerate(truth):
        c, s = np.cos(pose[2]), np.sin(pose[2])
        d = world[:, :2] - pose[:2]
        local = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], world[:, 2]])
        seen = np.flatnonzero((local[:, 0] > 0.5) & (np.abs(np.arctan2(local[:, 1], local[:, 0])) < 0.7))
        z = local[seen] + 0.01 * rng.standard_normal((len(seen), 3))
        frames.append((times[k], truth[k], _Obs(points=z, covariances=np.tile(np.eye(3) * 1e-4, (len(seen), 1, 1)),
                                                descriptors=desc[seen], pixels=np.zeros((len(seen), 2)))))
    positions = world + 0.02 * rng.standard_normal(world.shape)
    covariances = np.tile(np.eye(3) * 4e-4, (len(world), 1, 1))
    exported = LandmarkMap(positions, covariances, desc, np.arange(len(world)), np.full(len(world), 5),
                           "robot1", trajectory=np.vstack([[0.0, 0.0, 0.0, 0.0],
                                                           np.column_stack([times, bent])]))
    return {"frames": frames, "map": exported, "truth": truth, "trajectory": exported.trajectory}


def _smooth(w: dict, rec: ReadingsRecorder):
    for t, p, o in w["frames"]:
        rec.add(t, p, o)
    m = w["map"]
    return smoothed_map(rec.readings_kept(), w["trajectory"], m, m.positions, m.covariances, CONFIG)


def test_the_smoothed_map_from_keyframes_has_every_frames_trajectory_and_mends_the_filters_bend():
    w = _world()
    every = _smooth(w, ReadingsRecorder(D))
    key = _smooth(w, _recorder(distance=0.2, angle=0.1))
    kept = key.figures["frames"]
    assert kept < len(w["frames"]) / 2
    t_every, t_key = every.landmark_map.trajectory, key.landmark_map.trajectory
    np.testing.assert_array_equal(t_key[:, 0], t_every[:, 0])           # a row at every frame, the same times
    truth = w["truth"]
    filt = np.abs(w["trajectory"][1:, 3] - truth[:, 2]).max()
    for t in (t_every, t_key):
        assert np.abs(t[1:, 3] - truth[:, 2]).max() < filt / 3
        assert np.abs(t[1:, 1:3] - truth[:, :2]).max() < 0.03
    # the landmarks the readings hold: the keyframes' smoothed ones are the every-frame ones' within their own σ
    held = np.any(every.landmark_map.positions != w["map"].positions, axis=1)
    assert held.sum() >= 15
    e = key.landmark_map.positions[held] - every.landmark_map.positions[held]
    assert 0.0 < np.median(np.linalg.norm(e, axis=1)) < 0.01
    sigma = np.sqrt(np.trace(key.landmark_map.covariances[held], axis1=1, axis2=2))
    assert np.all(np.linalg.norm(e, axis=1) < sigma)
    assert key.landmark_map.metadata["self_check"] is not None


def test_keyframes_that_keep_every_frame_smooth_to_the_same_map():
    w = _world(1)
    a = _smooth(w, ReadingsRecorder(D)).landmark_map
    b = _smooth(w, _recorder(distance=1e-9)).landmark_map
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.covariances, b.covariances)
    np.testing.assert_array_equal(a.trajectory, b.trajectory)
    np.testing.assert_array_equal(a.drift_covariances, b.drift_covariances)
    assert a.metadata == b.metadata


def test_readings_built_by_hand_without_keyframe_fields_smooth_as_before():
    """The benchmark's StereoReadings (seven arrays, no keyframe fields) and the recorder's without keyframes are one
    input to smoothed_map."""
    w = _world(2)
    rec = ReadingsRecorder(D)
    for t, p, o in w["frames"]:
        rec.add(t, p, o)
    r = rec.readings_kept()
    by_hand = StereoReadings(r.times, r.odometry, r.counts, r.points, r.covariances, r.descriptors, r.pixels)
    m = w["map"]
    a = smoothed_map(r, w["trajectory"], m, m.positions, m.covariances, CONFIG).landmark_map
    b = smoothed_map(by_hand, w["trajectory"], m, m.positions, m.covariances, CONFIG).landmark_map
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.trajectory, b.trajectory)
