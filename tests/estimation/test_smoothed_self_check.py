"""The self-check re-run along a smoothed trajectory (estimation.smoothed_self_check) on synthetic stereo logs.

A robot drives two laps of a circle inside a square room whose walls carry 3-D points; a point in the camera's view
is read with the sensor's own detection probability (so H0 holds exactly where the map is right). The association
(frame, reading, landmark row, inlier) is built as the smoothing's would be: a reading of a point the map already
holds goes to its landmark, a point first seen makes a new landmark (ids in the order they are made).
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from estimation.fastslam import FastSLAMConfig
from estimation.fastslam.existence import detection_probability_or_constant
from estimation.fastslam.self_check import SelfCheck
from estimation.geometry import compose
from estimation.landmark_map import LandmarkMap
from estimation.smoothed_self_check import (
    FILTER_KEY,
    SmoothedSelfCheckError,
    recheck,
    recheck_map,
    recheck_smoothed,
    rechecked_metadata,
)
from estimation.stereo_readings import SmoothedMap, StereoReadings
from fusion.split import split_id

CONFIG = FastSLAMConfig()
FRAMES_PER_LAP = 240
GAP = 300                      # the frame at which the second lap's trouble starts (lap 2 begins at 240)


def _room() -> np.ndarray:
    """(L, 3) points on the four walls of a 12 m square room, every 0.3 m along a wall, at five heights."""
    along = np.arange(-5.85, 6.0, 0.3)
    heights = np.linspace(0.3, 2.1, 5)
    a, h = np.meshgrid(along, heights)
    a, h = a.ravel(), h.ravel()
    six = np.full_like(a, 6.0)
    return np.vstack([np.column_stack(c) for c in ((a, six, h), (a, -six, h), (six, a, h), (-six, a, h))])


def _poses() -> np.ndarray:
    """(T, 3) two counter-clockwise laps of a 3 m circle about the room's centre, heading along the circle."""
    phi = np.linspace(0.0, 4 * np.pi, 2 * FRAMES_PER_LAP, endpoint=False)
    return np.column_stack([3 * np.cos(phi), 3 * np.sin(phi), phi + np.pi / 2])


def _in_camera(local: np.ndarray) -> np.ndarray:
    """(N,) bool: base_link points inside the camera's whole field of view and range (not only well inside)."""
    ox, oy, oz = CONFIG.sensor_offset
    depth, lateral, height = local[:, 0] - ox, local[:, 1] - oy, local[:, 2] - oz
    rng = np.sqrt(depth ** 2 + lateral ** 2 + height ** 2)
    return ((depth > CONFIG.min_range) & (np.abs(np.arctan2(lateral, depth)) < CONFIG.fov_horizontal / 2)
            & (np.abs(np.arctan2(height, depth)) < CONFIG.fov_vertical / 2) & (rng < CONFIG.max_range))


def _to_base(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    c, s = np.cos(pose[2]), np.sin(pose[2])
    d = points[:, :2] - pose[:2]
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], points[:, 2]])


def _to_world(pose: np.ndarray, local: np.ndarray) -> np.ndarray:
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return np.column_stack([pose[0] + c * local[:, 0] - s * local[:, 1],
                            pose[1] + s * local[:, 0] + c * local[:, 1], local[:, 2]])


def _log(seed: int, *, jump: float = 0.0, blind: int = 0, reobserve: bool = True) -> dict:
    """A synthetic smoothed log. ``jump`` (rad): from frame GAP on the estimated trajectory is turned by this much
    about the true pose there (the map lost its place: what it sees from then on it maps again, in the turned frame,
    and its old landmarks are predicted where nothing is seen); ``blind``: frames from GAP on whose readings no
    association holds (a stretch the filter's particles did not re-detect); ``reobserve``: after that stretch the
    readings of points the map already holds go to those landmarks (False: to new landmarks made again, the way
    the filter's particles made them)."""
    rng = np.random.default_rng(seed)
    world, truth = _room(), _poses()
    est = truth.copy()
    if jump:
        turn = np.array([0.0, 0.0, jump])
        for k in range(GAP, len(truth)):   # the same relative motion, from a turned pose at the gap
            est[k] = compose(compose(truth[GAP], turn), _relative(truth[GAP], truth[k]))
    landmark_of = np.full(len(world), -1, np.int64)         # the point's landmark row (the map's current one)
    positions, frames, readings, rows, points, counts = [], [], [], [], [], []
    renewed = np.zeros(len(world), bool)                    # made again after the gap
    n = 0
    for k, pose in enumerate(truth):
        local = _to_base(pose, world)
        r = np.linalg.norm(local - np.asarray(CONFIG.sensor_offset), axis=1)
        seen = np.flatnonzero(_in_camera(local) & (rng.random(len(world)) < detection_probability_or_constant(
            CONFIG, r)))
        z = local[seen] + 0.01 * rng.standard_normal((len(seen), 3))
        counts.append(len(seen))
        points.append(z)
        for i, p in enumerate(seen):
            if GAP <= k < GAP + blind:
                continue                                    # nothing associated in the blind stretch
            remake = k >= GAP and (jump or not reobserve) and not renewed[p]
            if landmark_of[p] < 0 or remake:
                landmark_of[p] = len(positions)
                renewed[p] = k >= GAP
                positions.append(_to_world(est[k], z[i:i + 1])[0])
            frames.append(k)
            readings.append(n + i)
            rows.append(landmark_of[p])
        n += len(seen)
    k = len(frames)
    return {"times": np.arange(len(truth)) / 3.75, "poses": est, "ids": np.arange(len(positions)),
            "positions": np.array(positions), "points": np.vstack(points), "counts": np.array(counts),
            "frames": np.array(frames), "readings": np.array(readings), "rows": np.array(rows),
            "inliers": np.ones(k, bool)}


def _relative(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """b in a's frame."""
    c, s = np.cos(a[2]), np.sin(a[2])
    dx, dy = b[0] - a[0], b[1] - a[1]
    return np.array([c * dx + s * dy, -s * dx + c * dy, b[2] - a[2]])


def _verdict(log: dict) -> dict:
    return recheck(CONFIG, log["times"], log["poses"], log["ids"], log["positions"], log["points"], log["counts"],
                   log["frames"], log["readings"], log["rows"], log["inliers"])


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_map_that_truly_lost_its_frame_still_flags_along_the_smoothed_trajectory(seed):
    """Frame GAP starts a stretch the map did not hold (a gap) after which the trajectory is turned by 0.3 rad and
    everything is mapped again in the turned frame: its old landmarks, predicted in view where nothing is, are
    missed. The re-run flags it soon after, and its first_id_after_gap splits the old map from the new."""
    log = _log(seed, jump=0.3, blind=3)
    verdict = _verdict(log)
    assert verdict["lost"]
    alarm = verdict["alarms"][0]
    gap_t = log["times"][GAP]
    assert gap_t < alarm["t"] < gap_t + 10.0, alarm
    assert alarm["redetected"] <= 0.1 * alarm["predicted"]
    made_before = np.flatnonzero(np.isin(np.arange(len(log["ids"])), np.unique(
        log["rows"][log["frames"] < GAP])))
    assert alarm["first_id_after_gap"] == len(made_before)   # ids below it: exactly the landmarks made before


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_readings_that_re_observe_the_old_map_after_a_blind_stretch_do_not_flag(seed):
    """The same room and gap (a blind stretch of 3 frames at GAP), the trajectory right. If, after the stretch, the
    association made new landmarks for what it saw (the filter's particles, failing to re-detect), the old
    landmarks in view are missed and the test flags; the smoothing's association, whose readings re-observe them,
    answers it: no alarm."""
    filter_like = _verdict(_log(seed, blind=3, reobserve=False))
    assert filter_like["lost"]
    smoothed = _verdict(_log(seed, blind=3, reobserve=True))
    assert not smoothed["lost"], smoothed["alarms"]
    assert smoothed["frames_tested"] > 100           # it did test: the old map was in view after the gap
    assert smoothed["redetected"] > 0.3 * smoothed["predicted"]


def test_the_verdict_has_the_filters_schema_and_the_fusion_splits_on_it():
    log = _log(1, jump=0.3, blind=3)
    verdict = _verdict(log)
    assert set(verdict) == set(SelfCheck(CONFIG).verdict())
    json.dumps(verdict)
    traj = np.column_stack([np.r_[0.0, log["times"]], np.vstack([np.zeros(3), log["poses"]])])
    n = len(log["ids"])
    filter_verdict = {"version": 1, "lost": False, "alarms": []}
    m = LandmarkMap(log["positions"], np.tile(np.eye(3) * 1e-3, (n, 1, 1)), np.zeros((n, 0)), log["ids"], np.full(n, 5),
                    "robot1", trajectory=traj, metadata={"self_check": filter_verdict})
    again = recheck_map(m, CONFIG, log["points"], log["counts"], log["frames"], log["readings"], log["rows"],
                        log["inliers"])
    assert again == verdict
    n_r = len(log["points"])
    readings = StereoReadings(log["times"], log["poses"], log["counts"], log["points"], np.zeros((n_r, 3, 3)),
                              np.zeros((n_r, 0), np.float32), np.zeros((n_r, 2)))
    smoothed = SmoothedMap(m, {}, log["frames"], log["readings"], log["rows"], log["inliers"])
    assert recheck_smoothed(smoothed, readings, CONFIG) == verdict
    m.metadata = rechecked_metadata(m.metadata, again)
    assert m.metadata[FILTER_KEY] == filter_verdict and m.metadata["self_check"] == verdict
    assert split_id(m) == verdict["alarms"][0]["first_id_after_gap"]


def test_refuses_inputs_that_are_not_one_log():
    log = _log(1)
    args = [CONFIG] + [log[k] for k in ("times", "poses", "ids", "positions", "points", "counts", "frames",
                                        "readings", "rows", "inliers")]
    bad = list(args)
    bad[2] = log["poses"][:-1]
    with pytest.raises(SmoothedSelfCheckError, match="poses"):
        recheck(*bad)
    bad = list(args)
    bad[9] = log["rows"].copy()
    bad[9][0] = len(log["ids"])
    with pytest.raises(SmoothedSelfCheckError, match="does not exist"):
        recheck(*bad)
    bad = list(args)
    bad[8] = log["readings"].copy()
    bad[8][0] = log["counts"][0] + 5                 # a reading of another frame
    with pytest.raises(SmoothedSelfCheckError, match="not one of its frame"):
        recheck(*bad)
