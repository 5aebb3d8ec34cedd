"""Association by identity ("id" mode, with outlier rejection) and landmark existence in log-odds."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.fastslam import FastSLAM, FastSLAMConfig, range_bearing_config, range_bearing_observations
from estimation.geometry import compose, transform_points
from estimation.landmark_map import LandmarkMap
from estimation.observations import OdometryIncrement, StereoObservations


def _square_run(slam, rng, landmarks, ids, *, outlier_every=0, legs=4, max_range=8.0):
    """A square loop among point landmarks, range-bearing readings carrying ``ids``; every
    ``outlier_every``-th frame one reading is moved 2 m (a misread barcode / a reflection)."""
    pose, dead, errors, dead_errors, frame = np.zeros(3), np.zeros(3), [], [], 0
    readings = planted = 0
    for _leg in range(legs):
        for i in range(40):
            step = np.array([0.25, 0.0, np.pi / 2 if i == 39 else 0.0])
            pose = compose(pose, step)
            noisy = step * [1.05, 1.0, 1.03] + rng.normal(0, [0.01, 0.01, 0.005])
            dead = compose(dead, noisy)
            slam.predict(OdometryIncrement(*noisy))
            local = transform_points(np.array([0.0, 0.0, -pose[2]]), landmarks - [pose[0], pose[1], 0.0])
            r, b = np.hypot(local[:, 0], local[:, 1]), np.arctan2(local[:, 1], local[:, 0])
            seen = np.flatnonzero(r < max_range)
            r_seen = r[seen] + rng.normal(0, 0.05, len(seen))
            frame += 1
            readings += len(seen)
            if outlier_every and frame % outlier_every == 0 and len(seen):
                r_seen[0] += 2.0
                planted += 1
            slam.update(range_bearing_observations(r_seen, b[seen] + rng.normal(0, 0.01, len(seen)), 0.05, 0.01,
                                                   ids=ids[seen]))
            errors.append(np.hypot(*(slam.best_pose()[:2] - pose[:2])))
            dead_errors.append(np.hypot(*(dead[:2] - pose[:2])))
    return np.array(errors), np.array(dead_errors), readings, planted


@pytest.mark.parametrize("version", [1, 2])
def test_id_association_builds_one_landmark_per_identity_and_rejects_outliers(version):
    rng = np.random.default_rng(7)
    landmarks = np.column_stack([rng.uniform(-5, 15, 30), rng.uniform(-5, 15, 30), np.zeros(30)])
    ids = np.arange(100, 130)          # external identities (barcodes), not the filter's own numbering
    slam = FastSLAM(range_bearing_config(n_particles=20, version=version, max_range=8.0, association="id"),
                    np.random.default_rng(8))
    errors, dead_errors, readings, planted = _square_run(slam, rng, landmarks, ids, outlier_every=5)
    assert errors[-1] < 0.3 and np.mean(errors) < 0.5 * np.mean(dead_errors)
    landmark_map = slam.best_map(min_count=1)
    external = slam.external_ids(landmark_map.ids)
    assert len(set(external.tolist())) == len(external)            # one landmark per identity, no duplicates
    assert set(external.tolist()) <= set(ids.tolist())
    truth = landmarks[external - 100]
    assert np.median(np.linalg.norm(landmark_map.positions[:, :2] - truth[:, :2], axis=1)) < 0.3   # as unknown ids
    # the 2 m misreadings are rejected in (nearly) every particle; beyond them, only the gate's 1 % and the
    # particles whose pose is off (1.0 samples the motion model: its cloud is wider) reject a reading
    assert slam.stats.id_outliers >= 0.9 * planted * 20
    assert slam.stats.id_outliers - planted * 20 < 0.12 * readings * 20


def test_id_mode_ignores_observations_without_identity_and_repeats_of_one():
    slam = FastSLAM(range_bearing_config(n_particles=5, association="id"), np.random.default_rng(0))
    obs = range_bearing_observations([2.0, 3.0, 3.0, 4.0], [0.0, 0.5, 0.5, -0.5], 0.05, 0.01, ids=[-1, 7, 7, 9])
    report = slam.update(obs)
    assert report.new_landmark_ids[0] == -1 and report.new_landmark_ids[2] == -1
    assert report.new_landmark_ids[1] >= 0 and report.new_landmark_ids[3] >= 0
    assert sorted(slam.external_ids(slam.particle_map(0).ids).tolist()) == [7, 9]
    assert len(slam.particle_map(0)) == 2


def test_id_mode_finds_a_named_landmark_however_far_the_particle_drifted():
    # a landmark seen once, then the odometry claims a 40 m jump: the landmark is far outside the view's
    # footprint, but its identity still names it; the gate rejects the now-impossible reading instead of
    # making a second landmark with the same identity
    slam = FastSLAM(range_bearing_config(n_particles=5, association="id"), np.random.default_rng(0))
    slam.update(range_bearing_observations([2.0], [0.0], 0.05, 0.01, ids=[3]))
    slam.predict(OdometryIncrement(40.0, 0.0, 0.0))
    slam.update(range_bearing_observations([2.0], [0.0], 0.05, 0.01, ids=[3]))
    assert len(slam.particle_map(0)) == 1
    assert slam.stats.id_outliers == 5


def _stereo(points, desc, sigma=0.03):
    points = np.asarray(points, float).reshape(-1, 3)
    return StereoObservations(points, np.tile(np.eye(3) * sigma**2, (len(points), 1, 1)),
                              np.asarray(desc, np.float32).reshape(len(points), -1))


def test_existence_rises_with_detections_and_falls_with_misses_in_view():
    rng = np.random.default_rng(0)
    desc = rng.standard_normal((2, 64)).astype(np.float32)
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    cfg = FastSLAMConfig(n_particles=4, max_observations=0)
    slam = FastSLAM(cfg, np.random.default_rng(1))
    near, far = [3.0, 0.0, 0.8], [5.0, 0.5, 1.0]
    for _ in range(6):                 # both seen 6 times: established (existence at its clamp)
        slam.update(_stereo([near, far], desc))
    established = slam.particle_map(0)
    assert len(established) == 2
    # now only "near" is seen; "far" is well in view and missed every frame: it goes, but only after
    # (existence_max - existence_remove) / -existence_miss frames, not at the first miss
    needed = int(np.ceil((cfg.existence_max - cfg.existence_remove) / -cfg.existence_miss))
    for _ in range(needed - 1):
        slam.update(_stereo([near], desc[:1]))
    assert len(slam.particle_map(0)) == 2
    slam.update(_stereo([near], desc[:1]))
    assert len(slam.particle_map(0)) == 1
    assert slam.stats.landmarks_removed == 4   # in each of the 4 particles


def test_a_capped_frame_is_no_evidence_against_landmarks_beyond_its_reach():
    # "nearest" keeps the near observations: a far landmark that was not kept must not be counted as missed
    rng = np.random.default_rng(0)
    desc = rng.standard_normal((6, 64)).astype(np.float32)
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    points = [[2.0, -0.3, 0.6], [2.2, 0.3, 0.6], [2.4, 0.0, 0.8], [2.6, 0.2, 0.5], [2.8, -0.2, 0.7], [8.0, 0.0, 1.5]]
    cov = np.array([np.eye(3) * (0.01 * (1 + i)) ** 2 for i in range(6)])
    slam = FastSLAM(FastSLAMConfig(n_particles=4, max_observations=0), np.random.default_rng(1))
    slam.update(StereoObservations(np.array(points), cov, desc))
    capped = FastSLAM(FastSLAMConfig(n_particles=4, max_observations=5), np.random.default_rng(1))
    capped.update(StereoObservations(np.array(points), cov, desc))          # 6 > 5: the far one is left out
    slam_far = FastSLAM(FastSLAMConfig(n_particles=4, max_observations=6), np.random.default_rng(1))
    slam_far.update(StereoObservations(np.array(points), cov, desc))
    for _ in range(10):
        slam_far.update(StereoObservations(np.array(points), cov, desc))
        capped.update(StereoObservations(np.array(points), cov, desc))
    assert len(slam_far.particle_map(0)) == 6
    assert len(capped.particle_map(0)) == 5      # never created, never wrongly removed either
    assert capped.stats.landmarks_removed == 0


@pytest.mark.parametrize("merge_gate", [0.0, 7.815])
def test_duplicates_are_merged_only_when_statistically_one_point_and_alike(merge_gate):
    # a corner whose look changed beyond the association gate (0.5) but not beyond a merge threshold of 0.8 is made
    # again at the same place: a duplicate, merged; a different-looking corner 5 cm away is not merged, nor
    # a same-looking one 0.5 m away (20 σ)
    rng = np.random.default_rng(3)
    base = rng.standard_normal(64)
    base /= np.linalg.norm(base)
    other = rng.standard_normal(64)
    other -= (other @ base) * base
    other /= np.linalg.norm(other)
    drifted = np.cos(0.6) * base + np.sin(0.6) * other          # distance 2 sin(0.3) ≈ 0.59 from base
    unrelated = rng.standard_normal(64)
    unrelated /= np.linalg.norm(unrelated)
    slam = FastSLAM(FastSLAMConfig(n_particles=5, merge_gate=merge_gate, merge_every=1, max_observations=0,
                                   merge_descriptor_threshold=0.8),
                    np.random.default_rng(4))
    corner, beside, far = [4.0, 0.5, 1.0], [4.0, 0.55, 1.0], [4.0, 1.0, 1.0]
    slam.update(_stereo([corner, beside, far], [base, unrelated, base]))
    slam.update(_stereo([corner, beside, far], [drifted, unrelated, base]))
    kept = slam.particle_map(0)
    if merge_gate == 0:
        assert len(kept) == 4 and slam.stats.landmarks_merged == 0
    else:
        assert len(kept) == 3 and slam.stats.landmarks_merged == 5   # one merge in each particle
        merged = kept.positions[np.argmin(np.linalg.norm(kept.positions - corner, axis=1))]
        assert np.linalg.norm(merged - corner) < 0.02
        assert kept.counts.max() == 2


def test_a_named_landmark_whose_readings_are_rejected_is_not_taken_for_missing():
    # the identity was read, so the landmark is there: a reading the gate rejects is an outlier, not a miss
    slam = FastSLAM(range_bearing_config(n_particles=5, association="id", max_range=10.0), np.random.default_rng(0))
    slam.update(range_bearing_observations([3.0], [0.0], 0.05, 0.01, ids=[5]))
    for _ in range(20):
        slam.update(range_bearing_observations([5.0], [0.0], 0.05, 0.01, ids=[5]))   # 2 m off: rejected
    assert slam.stats.id_outliers == 20 * 5
    assert slam.stats.landmarks_removed == 0 and len(slam.particle_map(0)) == 1
    for _ in range(3):                   # truly not seen while in view: now it is negative evidence
        slam.update(range_bearing_observations([2.0], [0.3], 0.05, 0.01, ids=[6]))
    assert 5 not in slam.external_ids(slam.particle_map(0).ids).tolist()


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), pose=st.tuples(st.floats(-5, 5), st.floats(-5, 5), st.floats(-3.1, 3.1)))
def test_a_frame_misses_exactly_the_landmarks_well_inside_the_view(seed, pose):
    """One frame that detects nothing: every landmark predicted inside ``miss_fov_margin`` of the field of view and
    of the range takes one miss, and no other. Checked against the geometry written out here (angles by atan2), on
    landmarks all around the robot, above and below the view, near and far; one miss removes a landmark (a miss worth
    −6 from the prior map's clamp of 4 falls below existence_remove)."""
    rng = np.random.default_rng(seed)
    cfg = FastSLAMConfig(n_particles=1, max_observations=0, existence_miss=-6.0)
    local = np.column_stack([rng.uniform(-14, 14, 400), rng.uniform(-14, 14, 400), rng.uniform(-4, 5, 400)])
    depth, lateral, height = (local - np.asarray(cfg.sensor_offset)).T
    margin, max_range = cfg.miss_fov_margin, cfg.max_range
    bounds = (depth - cfg.min_range, depth, 0.5 * margin * cfg.fov_horizontal - np.abs(np.arctan2(lateral, depth)),
              0.5 * margin * cfg.fov_vertical - np.abs(np.arctan2(height, np.maximum(depth, 1e-9))),
              margin * max_range - np.sqrt(depth ** 2 + lateral ** 2 + height ** 2))
    clear = np.all([np.abs(b) > 1e-6 for b in bounds], axis=0)     # none on a boundary, where rounding decides
    local, inside = local[clear], np.all([b > 0 for b in bounds], axis=0)[clear]
    c, s = np.cos(pose[2]), np.sin(pose[2])
    world = np.column_stack([pose[0] + c * local[:, 0] - s * local[:, 1], pose[1] + s * local[:, 0] + c * local[:, 1],
                             local[:, 2]])
    n = len(world)
    slam = FastSLAM(cfg, np.random.default_rng(0), initial_pose=pose)
    ids = slam.load_prior_map(LandmarkMap(world, np.tile(0.01 * np.eye(3), (n, 1, 1)), np.zeros((n, 64), np.float32),
                                          counts=np.full(n, 5)))
    slam.update(StereoObservations(np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 64), np.float32)))
    kept = slam.particle_map(0, 1)
    assert set(kept.ids.tolist()) == set(ids[~inside].tolist())
    assert slam.stats.landmarks_removed == int(inside.sum())
