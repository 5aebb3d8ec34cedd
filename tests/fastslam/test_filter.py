"""FastSLAM behaviour through its public interface: convergence, association, provisional landmarks."""
from __future__ import annotations

import numpy as np
import pytest

from estimation.fastslam import FastSLAM, FastSLAMConfig, range_bearing_config, range_bearing_observations
from estimation.geometry import compose, transform_points
from estimation.observations import OdometryIncrement, StereoObservations


def _unit(rng, n=1, d=64):
    v = rng.standard_normal((n, d))
    return (v / np.linalg.norm(v, axis=1, keepdims=True)).astype(np.float32)


def _obs(points, descriptors, sigma=0.03):
    points = np.asarray(points, float).reshape(-1, 3)
    cov = np.tile(np.eye(3) * sigma**2, (len(points), 1, 1))
    return StereoObservations(points, cov, np.asarray(descriptors, np.float32).reshape(len(points), -1))


def _landmark_ids(slam, particle=0):
    return set(slam.particle_map(particle, min_count=1).ids.tolist())


@pytest.mark.parametrize("version", [1, 2])
def test_straight_run_with_known_landmarks_converges(drive, version):
    slam = FastSLAM(FastSLAMConfig(n_particles=20, version=version), np.random.default_rng(2))
    truth, dead, features, feature_of = drive(slam, seed=11, frames=70)
    estimate = slam.trajectory()[1:, 1:]
    err = np.linalg.norm(estimate[:, :2] - truth[:, :2], axis=1)
    dead_err = np.linalg.norm(dead[:, :2] - truth[:, :2], axis=1)
    assert dead_err[-1] > 0.25                        # 4 % odometry scale error over 8 m
    assert err[-1] < 0.5 * dead_err[-1] and err.max() < 0.2  # the map pins the pose down
    landmark_map = slam.best_map()
    assert len(landmark_map) > 50
    truth_pos = features[[feature_of[int(i)] for i in landmark_map.ids]]
    errors = np.linalg.norm(landmark_map.positions - truth_pos, axis=1)
    assert np.median(errors) < 0.15
    # each landmark stands for one feature: no doubling on a simple straight run
    assert len(set(feature_of[int(i)] for i in landmark_map.ids)) >= 0.97 * len(landmark_map)


def test_map_is_in_the_start_frame(straight_run_v2):
    slam, truth, *_ = straight_run_v2
    traj = slam.trajectory()
    assert np.allclose(traj[0, 1:], 0.0)
    assert traj.shape == (len(truth) + 1, 4)
    assert np.all(np.diff(traj[:, 0]) > 0)


def test_association_rejects_similar_descriptor_in_the_wrong_place():
    rng = np.random.default_rng(0)
    slam = FastSLAM(FastSLAMConfig(n_particles=10), np.random.default_rng(1))
    desc = _unit(rng)
    slam.update(_obs([[4.0, 0.5, 1.0]], desc))
    (first,) = _landmark_ids(slam)
    near_copy = desc + 0.01 * _unit(rng)  # the same-looking corner ...
    report = slam.update(_obs([[4.0, 1.3, 1.0]], near_copy))  # ... 0.8 m away: a different landmark
    assert report.best_matches[0] == -1 and report.new_landmark_ids[0] >= 0
    assert _landmark_ids(slam) == {first, int(report.new_landmark_ids[0])}
    # the same place with the same descriptor is the old landmark again
    report = slam.update(_obs([[4.02, 0.5, 1.0]], near_copy))
    assert report.best_matches[0] == first
    # the same place but a different-looking corner is not
    report = slam.update(_obs([[4.0, 0.5, 1.0]], _unit(rng)))
    assert report.best_matches[0] == -1


def test_one_landmark_per_observation_within_a_frame():
    rng = np.random.default_rng(0)
    slam = FastSLAM(FastSLAMConfig(n_particles=5), np.random.default_rng(1))
    desc = _unit(rng)
    slam.update(_obs([[4.0, 0.5, 1.0]], desc))
    report = slam.update(_obs([[4.0, 0.5, 1.0], [4.05, 0.5, 1.0]], np.vstack([desc, desc])))
    assert np.sum(report.best_matches >= 0) == 1        # one of the two claims the landmark
    assert np.all(report.new_landmark_ids == -1)        # the loser is ambiguous, not a new landmark
    assert report.matched == 1.0


def test_provisional_landmark_dropped_when_not_seen_where_it_should_be():
    rng = np.random.default_rng(0)
    cfg = FastSLAMConfig(n_particles=5, confirm_count=3, max_misses=3)
    slam = FastSLAM(cfg, np.random.default_rng(1))
    ghost, solid = _unit(rng, 2)
    slam.update(_obs([[4.0, 0.3, 0.8], [5.0, -0.3, 0.9]], np.vstack([ghost, solid])))
    for _ in range(2):  # the solid one is seen twice more: confirmed
        slam.update(_obs([[5.0, -0.3, 0.9]], solid[None]))
    assert len(_landmark_ids(slam)) == 2
    for _ in range(cfg.max_misses):  # neither is seen now, both are in view
        slam.update(StereoObservations.empty())
    survivors = slam.particle_map(0, min_count=1)
    assert len(survivors) == 1 and survivors.counts[0] == 3


def test_landmark_out_of_view_is_kept():
    rng = np.random.default_rng(0)
    slam = FastSLAM(FastSLAMConfig(n_particles=5), np.random.default_rng(1))
    slam.update(_obs([[4.0, 0.3, 0.8]], _unit(rng)))
    slam.predict(OdometryIncrement(0.0, 0.0, np.pi))  # turn round: the landmark is behind
    for _ in range(5):
        slam.update(StereoObservations.empty())
    assert len(_landmark_ids(slam)) == 1


def test_determinism_given_a_seed(drive):
    maps = []
    for seed in (4, 4, 5):
        slam = FastSLAM(FastSLAMConfig(n_particles=10), np.random.default_rng(seed))
        drive(slam, seed=3, frames=25)
        maps.append(slam.best_map())
    assert np.array_equal(maps[0].positions, maps[1].positions)
    assert np.array_equal(maps[0].ids, maps[1].ids)
    assert np.array_equal(maps[0].trajectory, maps[1].trajectory)
    assert not np.array_equal(maps[0].trajectory, maps[2].trajectory)


def test_wrong_descriptor_size_is_a_clear_error():
    slam = FastSLAM(FastSLAMConfig(n_particles=3), np.random.default_rng(0))
    with pytest.raises(ValueError, match="descriptor_size=64"):
        slam.update(_obs([[3.0, 0.0, 1.0]], np.ones((1, 32))))


@pytest.mark.parametrize(("version", "max_landmarks"), [(1, 40), (2, 30)])
def test_range_bearing_landmarks(version, max_landmarks):
    """Classic 2-D landmark SLAM: a square loop among 30 point landmarks with range-bearing readings."""
    rng = np.random.default_rng(7)
    landmarks = np.column_stack([rng.uniform(-5, 15, 30), rng.uniform(-5, 15, 30), np.zeros(30)])
    slam = FastSLAM(range_bearing_config(n_particles=20, version=version, max_range=8.0),
                    np.random.default_rng(8))
    pose, dead = np.zeros(3), np.zeros(3)
    errors, dead_errors = [], []
    for _leg in range(4):
        for i in range(40):
            step = np.array([0.25, 0.0, np.pi / 2 if i == 39 else 0.0])
            pose = compose(pose, step)
            noisy = step * [1.05, 1.0, 1.03] + rng.normal(0, [0.01, 0.01, 0.005])
            dead = compose(dead, noisy)
            slam.predict(OdometryIncrement(*noisy))
            rel = transform_points(compose(np.zeros(3), [-pose[0], -pose[1], 0.0]), landmarks)  # translate
            c, s = np.cos(pose[2]), np.sin(pose[2])
            local = np.column_stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]])
            r, b = np.hypot(local[:, 0], local[:, 1]), np.arctan2(local[:, 1], local[:, 0])
            seen = r < 8.0
            slam.update(range_bearing_observations(r[seen] + rng.normal(0, 0.05, seen.sum()),
                                                   b[seen] + rng.normal(0, 0.01, seen.sum()), 0.05, 0.01))
            errors.append(np.hypot(*(slam.best_pose()[:2] - pose[:2])))
            dead_errors.append(np.hypot(*(dead[:2] - pose[:2])))
    assert dead_errors[-1] > 0.5
    assert errors[-1] < 0.3 and np.mean(errors) < np.mean(dead_errors)
    landmark_map = slam.best_map(min_count=3)
    nearest = np.min(np.linalg.norm(landmark_map.positions[:, None, :2] - landmarks[None, :, :2], axis=2), axis=1)
    assert np.median(nearest) < 0.3 and len(landmark_map) <= max_landmarks  # 1.0 doubles a few


def test_bad_input_is_refused_and_leaves_the_filter_unchanged():
    rng = np.random.default_rng(0)
    slam = FastSLAM(FastSLAMConfig(n_particles=4), np.random.default_rng(1))
    slam.update(_obs([[4.0, 0.5, 1.0]], _unit(rng)))
    poses, ids = slam.poses.copy(), _landmark_ids(slam)
    with pytest.raises(ValueError, match="not finite"):
        slam.predict(OdometryIncrement(float("nan"), 0.0, 0.0))
    with pytest.raises(ValueError, match="non-finite"):
        slam.update(_obs([[np.inf, 0.0, 1.0]], _unit(rng)))
    bad = _obs([[3.0, 0.0, 1.0]], _unit(rng))
    with pytest.raises(ValueError, match="positive definite"):
        slam.update(StereoObservations(bad.points, -np.eye(3)[None], bad.descriptors))
    with pytest.raises(ValueError, match="base_link"):
        slam.update(StereoObservations(bad.points, bad.covariances, bad.descriptors, frame="left_camera"))
    assert np.array_equal(slam.poses, poses) and _landmark_ids(slam) == ids


def test_history_pruning_keeps_every_live_trajectory(drive, monkeypatch):
    import estimation.fastslam.filter as filter_module

    runs = []
    for every in (7, 10**9):  # prune often, and never
        monkeypatch.setattr(filter_module, "PRUNE_HISTORY_EVERY", every)
        slam = FastSLAM(FastSLAMConfig(n_particles=8, version=1), np.random.default_rng(6))
        drive(slam, seed=3, frames=30)
        runs.append(slam)
    pruned, full = runs
    assert sum(len(p) for _, p, _ in pruned._history) < sum(len(p) for _, p, _ in full._history)
    for m in range(8):
        assert np.array_equal(pruned.trajectory(m), full.trajectory(m))


def _great_circle(a, b, steps):
    """``steps`` + 1 unit descriptors from a to b (orthonormal) along the great circle (a look that drifts)."""
    angles = np.linspace(0.0, np.pi / 2, steps + 1)[:, None]
    return (np.cos(angles) * a + np.sin(angles) * b).astype(np.float32)


@pytest.mark.parametrize("refresh", [True, False])
def test_landmark_descriptor_follows_a_gradually_changing_look(refresh):
    # (merge_gate=0 would leave the corner doubled without refresh: see test_duplicates_are_merged_...)
    # the same corner approached step by step: its fixed-scale descriptor drifts a little each frame
    rng = np.random.default_rng(3)
    config = FastSLAMConfig(n_particles=10, refresh_descriptors=refresh, merge_every=1, merge_descriptor_threshold=0.8)
    slam = FastSLAM(config, np.random.default_rng(4))
    a = _unit(rng)[0]
    b = _unit(rng)[0]
    b = (b - (a @ b) * a) / np.linalg.norm(b - (a @ b) * a)
    looks = _great_circle(a, b, 6)             # 15° (0.26) per frame, 90° (1.41) from first to last
    for desc in looks:
        slam.update(_obs([[4.0, 0.5, 1.0]], desc))
    assert np.linalg.norm(looks[-1] - looks[0]) > slam.config.descriptor_threshold  # the first look no longer gates
    ids = _landmark_ids(slam)
    if refresh:
        assert len(ids) == 1                                  # every frame re-associated to the one landmark
        assert np.allclose(slam.best_map().descriptors[0], looks[-1])
    else:   # kept as first seen: a later look makes a second landmark at the same point, which is merged back
        assert len(ids) == 1 and slam.stats.landmarks_merged > 0


def test_observation_cap_keeps_the_most_precise():
    rng = np.random.default_rng(5)
    slam = FastSLAM(FastSLAMConfig(n_particles=5, max_observations=3), np.random.default_rng(6))
    points = np.column_stack([np.arange(1.0, 9.0), np.zeros(8), np.ones(8)])
    sigmas = np.array([0.08, 0.01, 0.05, 0.02, 0.09, 0.03, 0.07, 0.06])
    cov = np.array([np.eye(3) * s**2 for s in sigmas])
    report = slam.update(StereoObservations(points, cov, _unit(rng, 8)))
    used = np.flatnonzero(report.new_landmark_ids >= 0)
    assert report.n_observations == 3 and len(report.new_landmark_ids) == 8
    assert used.tolist() == [1, 3, 5]                         # σ = 0.01, 0.02, 0.03
    assert np.all(report.best_matches == -1)
    assert len(_landmark_ids(slam)) == 3


def test_spread_selection_keeps_far_and_wide_observations():
    from estimation.fastslam.selection import select_observations

    rng = np.random.default_rng(3)
    # 60 points: 40 near (1.5–3 m) and 20 far (7–11 m), bearings across ±25°; the near ones are the most precise
    depth = np.r_[rng.uniform(1.5, 3.0, 40), rng.uniform(7.0, 11.0, 20)]
    bearing = rng.uniform(-0.45, 0.45, 60)
    points = np.column_stack([depth * np.cos(bearing), depth * np.sin(bearing), np.full(60, 1.0)])
    cov = np.array([np.eye(3) * (0.01 * d) ** 2 for d in depth])
    nearest = select_observations(points, cov, 30, "nearest")
    spread = select_observations(points, cov, 30, "spread", (0.12, 0.0, 0.5), 1.1)
    assert np.all(depth[nearest] < 3.0)                     # the old rule drops every far point
    assert np.sum(depth[spread] > 7.0) >= 8                   # a third of the cells are the far tercile
    assert len(np.unique(spread)) == 30 and np.all(np.diff(spread) > 0)
    for side in (bearing[spread] < -0.2, bearing[spread] > 0.2):
        assert side.sum() >= 5                                # both edges of the image are represented
    with pytest.raises(ValueError, match="observation_selection"):
        FastSLAMConfig(observation_selection="random")


@pytest.mark.parametrize("anchor", [False, True])
def test_first_frame_anchors_the_map_at_the_mean_pose(anchor):
    """The frame that starts the map fixes its gauge: anchored, every particle keeps the odometry's mean there."""
    rng = np.random.default_rng(0)
    slam = FastSLAM(FastSLAMConfig(n_particles=30, anchor_first_frame=anchor), np.random.default_rng(1))
    delta = np.array([0.5, 0.05, 0.3])
    slam.predict(OdometryIncrement(*delta, 0.0, 1.0))
    slam.update(_obs([[4.0, 0.3, 0.8], [5.0, -0.3, 0.9]], _unit(rng, 2)))
    spread = np.ptp(slam.poses, axis=0)
    if anchor:
        np.testing.assert_allclose(slam.poses, np.tile(delta, (30, 1)), atol=1e-12)
        landmarks = slam.particle_map(7, min_count=1).positions
        np.testing.assert_allclose(landmarks, transform_points(delta, [[4.0, 0.3, 0.8], [5.0, -0.3, 0.9]]))
    else:
        assert spread[2] > 0.01 and spread[0] > 0.01
    # once the map exists the proposal samples again: the next frame spreads the particles
    slam.predict(OdometryIncrement(0.5, 0.0, 0.2, 1.0, 2.0))
    slam.update(_obs([[3.0, 1.0, 0.8]], _unit(rng)))
    assert np.ptp(slam.poses[:, 2]) > 0.01


def test_observation_covariance_scale_widens_new_landmarks():
    rng = np.random.default_rng(0)
    descriptor = _unit(rng)
    covariances = []
    for scale in (1.0, 4.0):
        slam = FastSLAM(FastSLAMConfig(n_particles=3, observation_cov_scale=scale, observation_var_floor=0.0),
                        np.random.default_rng(1))
        slam.update(_obs([[4.0, 0.3, 0.8]], descriptor, sigma=0.05))
        covariances.append(slam.particle_map(0, min_count=1).covariances[0])
    np.testing.assert_allclose(covariances[1], 4.0 * covariances[0], rtol=1e-9)
    with pytest.raises(ValueError, match="observation_cov_scale"):
        FastSLAMConfig(observation_cov_scale=0.0)


@pytest.mark.parametrize("unmatched", [False, True])
def test_a_frame_without_matches_keeps_the_mean_pose_when_asked(unmatched):
    rng = np.random.default_rng(0)
    cfg = FastSLAMConfig(n_particles=30, anchor_first_frame=True, anchor_unmatched=unmatched)
    slam = FastSLAM(cfg, np.random.default_rng(1))
    slam.update(_obs([[4.0, 0.3, 0.8]], _unit(rng)))
    slam.predict(OdometryIncrement(0.5, 0.0, 0.3, 0.0, 1.0))
    slam.update(_obs([[2.0, -1.0, 0.5]], _unit(rng)))      # a new look, nothing to match
    assert (np.ptp(slam.poses[:, 2]) < 1e-12) == unmatched
