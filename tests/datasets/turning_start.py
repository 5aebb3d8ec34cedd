"""The synthetic log the frame tests of data set runs share (tests/datasets/test_frame_reliability_run.py,
test_checked_frame.py, test_chain_reliability.py, tests/runtime/test_dataset_frame_tie.py): MRCLAM robot 1's start, a
robot that turns on the spot before it drives, so that its map's frame rests on what it saw before and during the
turn; MRCLAM-like noise for the runs."""
from __future__ import annotations

import numpy as np

from estimation.datasets import RangeBearingLog
from estimation.geometry import wrap_angle
from estimation.noise_model import NoiseModel, OdometryNoise, RangeBearingNoise
from tests.estimation.frame_helpers import seen_from, unicycle

LANDMARKS = np.array([[3.0, 0.2], [-2.0, 2.5], [-2.5, -2.0], [0.5, 3.5], [1.5, -3.0], [4.0, 3.0]])
RANGE_SIGMA, BEARING_SIGMA = 0.03, 0.017
NOISE = NoiseModel(OdometryNoise(0.003, 0.0087, 1e-4),
                   RangeBearingNoise(RANGE_SIGMA, 0.0, BEARING_SIGMA, fov_rad=np.radians(120.0), max_range_m=6.0))
GLIMPSE_EVERY = 75      # 0.02 s steps between two glimpses of the turn: 1.5 s


def turning_start_log(first_landmarks: int = 1, with_truth: bool = True, *,
                      glimpses_in_turn: bool = False) -> RangeBearingLog:
    """A robot still at the origin for 1 s sees ``first_landmarks`` landmarks at 1 s (the first sighting: the map's
    frame), turns on the spot by 3 rad at 0.4 rad/s seeing nothing or (``glimpses_in_turn``) the one landmark nearest
    its heading every 1.5 s, each glimpse the lone tie of its pose, then drives a 1.5 m circle at 0.2 m/s seeing
    every landmark within 60° and 6 m every 0.25 s. Exact data (what the tests find is the design's, not the
    noise's)."""
    dt = 0.02
    t = np.arange(0.0, 60.0, dt)
    w = np.where((t >= 1.0) & (t < 8.5), 0.4, np.where(t >= 8.5, 0.2 / 1.5, 0.0))
    v = np.where(t >= 8.5, 0.2, 0.0)
    x, y, theta = unicycle(v, w, dt)
    poses = np.column_stack([t, x, y, wrap_angle(theta)])
    times, ids, ranges, bearings = [], [], [], []
    first, turning = 50, int(8.5 / dt)
    for k in range(first, len(t), 12):
        in_turn = first < k < turning
        if in_turn and not (glimpses_in_turn and (k - first) % GLIMPSE_EVERY == 0):
            continue
        r, b = seen_from(LANDMARKS, x[k], y[k], theta[k])
        if k == first:
            seen = np.argsort(np.abs(b))[:first_landmarks]
        elif in_turn:
            seen = np.argsort(np.abs(b))[:1]
        else:
            seen = np.flatnonzero((np.abs(b) < 1.0) & (r < 6))
        times += [t[k]] * len(seen)
        ids += list(seen + 6)
        ranges += list(r[seen])
        bearings += list(b[seen])
    truth = (poses, np.arange(6, 6 + len(LANDMARKS)), LANDMARKS) if with_truth else ()
    name = "synthetic-turning-start" if glimpses_in_turn else "synthetic-first-sighting"
    return RangeBearingLog(name, poses, np.array(times), np.array(ranges), np.array(bearings),
                           np.array(ids, np.int64), *truth)
