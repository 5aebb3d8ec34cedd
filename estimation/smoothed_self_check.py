"""Does the smoothed map still know where it is? The filter's self-check re-run along the smoothed trajectory.

FastSLAM's self-check (:mod:`estimation.fastslam.self_check`) is a CUSUM on the re-detections of the old map's
landmarks predicted in view of the most probable particle, frame by frame, while the filter runs. A map smoothed
after the run (:mod:`estimation.stereo_smoothing`) is another estimate of the same log: another trajectory, other
landmark positions, and another association (each frame's readings re-associated to the filter's final map along the
final best particle's own poses, then the smoother's χ² cut). The filter's verdict is about the particle it had then;
where that particle failed to re-detect its old landmarks for a while (a turn on the spot facing unmapped walls) and
the final ancestry did re-observe them, the filter's alarm does not describe the smoothed map, and where the run
really lost its frame the smoothed trajectory inherits it (the smoother starts from the filter and cannot mend it).

This module answers the same question for the smoothed map with the same test: one :class:`SelfCheck` (the same H0
"the map is where the trajectory says" with the sensor's P_D(r), the same H1 chance re-detection, the same
lag-1 discount, over-dispersion φ estimated online from the frames in control, threshold h = ln(1/α) with the
config's ``self_check_false_alarm``), fed per frame with:

- *the pose*: the smoothed pose of the frame;
- *the landmarks that exist*: the smoothed map's landmarks whose first inlier reading came in an earlier frame
  (the smoothing's own evidence that the landmark was there then), at their smoothed positions, with as their count
  the inlier readings before this frame (confirmed: ≥ ``confirm_count``); each is *made* (:meth:`SelfCheck.made`,
  the range and bearing its descriptor was taken from) at its first inlier reading, from the smoothed pose;
- *re-detected*: the landmarks one of this frame's inlier readings is associated to; *missed*: the other existing
  landmarks; both only where the filter's own test predicts them well in view (``FastSLAM._well_in_view``: the
  config's field of view, ranges, sensor offset and ``miss_fov_margin``, within the frame's farthest reading);
- *a gap*: a frame with fewer than two inlier readings of existing landmarks (the filter's rule: two points fix a
  planar pose); the landmarks older than a gap are those with an id below the smallest id of the landmarks first seen
  in the gap's frame or later. FastSLAM numbers landmarks in the order it makes them, and the re-association can
  find a landmark in a frame before the filter made it, so this is the largest id bound under which every landmark
  was first seen before the gap: the verdict's ``first_id_after_gap`` splits the map as the filter's does
  (``fusion.split``).

The verdict (:func:`recheck`) has :meth:`SelfCheck.verdict`'s schema, so a smoothed map carries it as its
``metadata["self_check"]`` and the fusion splits (or not) on it unchanged; :func:`rechecked_metadata` keeps the
filter's as ``metadata["filter_self_check"]``.

What it cannot see: only the final map's landmarks are tested, so landmarks the filter's existence model removed
(missed in view too often) are not predicted here; a map that truly lost its place is then tested on the old
landmarks that survived in its view. Occlusion is not modelled, as in the filter (docs/fastslam.md, limits): an old
landmark behind a wall "in view" is a miss. The re-association finds fewer matches than the filter's particles did
in some turns (landmarks the filter matched then and later removed or merged are not in the final map), so the re-run
sees gaps where the filter saw none and tests stretches the filter never tested. No truth is read.

Session 50, rendered demo seeds 0–9 (``benchmarks/smoothed_self_check_eval.py`` on session 49's smoothed maps): the
filter flagged 4 of the 20 maps, 1 of them lost by the truth (seed 4's robot 1: heading +42 → +138 mrad); the re-run
flags 3: seed 4's robot 1 (the same loss, at 124.2 s), seed 8's robot 2 (as the filter, at 113.5 s: floor points
re-detected 3 of 60 times while the heading held, −3 → −4 mrad) and, newly, seed 0's robot 1 at 69.5 s (S 11.56
against 11.51: 0 of 32 old landmarks, all 32 behind a wall by ``world.raycast`` at the true pose). The filter's false
alarms on seeds 1 and 2 (robot 1) are answered: the smoothing's readings re-observe the old map there. A screen that
took out landmarks behind one of the frame's readings (within the readings' mean angular spacing, nearer than
``miss_fov_margin`` of the range) cleared seeds 0 and 8 but lost seed 4's true alarm and flagged seed 4's healthy robot
2; it was not kept.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from .fastslam.config import FastSLAMConfig
from .fastslam.filter import FastSLAM
from .fastslam.self_check import SelfCheck, slot_view

FILTER_KEY = "filter_self_check"   # where a re-checked map keeps the filter's own verdict


class SmoothedSelfCheckError(ValueError):
    """The inputs do not describe one smoothed log (shapes, indices, order)."""


class _View:
    """The filter's own "well in view" test (``FastSLAM._well_in_view``), on a config alone."""

    _ahead_in_view = FastSLAM._ahead_in_view
    _near_in_view = FastSLAM._near_in_view
    _well_in_view = FastSLAM._well_in_view

    def __init__(self, config: FastSLAMConfig) -> None:
        self.config = config


def run(config: FastSLAMConfig, times: np.ndarray, poses: np.ndarray, ids: np.ndarray, positions: np.ndarray,
        points: np.ndarray, counts: np.ndarray, frames: np.ndarray, readings: np.ndarray, rows: np.ndarray,
        inliers: np.ndarray, keep_history: bool = False) -> SelfCheck:
    """The self-check of the module docstring, run over a smoothed log; returns the :class:`SelfCheck` after its
    last frame (``keep_history``: with each frame's evidence).

    ``times`` (T,) s and ``poses`` (T, 3) the smoothed pose of each frame (map frame); ``ids`` (L,) and
    ``positions`` (L, 3) the smoothed map's landmarks; ``points`` (R, 3) every reading in base_link, frame by frame,
    ``counts`` (T,) how many each frame has; ``frames``, ``readings``, ``rows``, ``inliers`` (K,) the association:
    the frame, the reading (an index into ``points``) and the landmark row of each, and whether the smoother kept it.
    """
    times = np.asarray(times, float).reshape(-1)
    poses = np.asarray(poses, float).reshape(-1, 3)
    ids = np.asarray(ids, np.int64).reshape(-1)
    positions = np.asarray(positions, float).reshape(-1, 3)
    points = np.asarray(points, float).reshape(-1, 3)
    counts = np.asarray(counts, np.int64).reshape(-1)
    frames, readings, rows = (np.asarray(a, np.int64).reshape(-1) for a in (frames, readings, rows))
    inliers = np.asarray(inliers, bool).reshape(-1)
    n_t, n_l = len(times), len(ids)
    if len(poses) != n_t or len(counts) != n_t:
        raise SmoothedSelfCheckError(f"{n_t} frame times but {len(poses)} poses and {len(counts)} reading counts")
    if len(positions) != n_l:
        raise SmoothedSelfCheckError(f"{n_l} landmark ids but {len(positions)} positions")
    if int(counts.sum()) != len(points) or np.any(counts < 0):
        raise SmoothedSelfCheckError(f"the frames' reading counts sum to {int(counts.sum())}, "
                                     f"not the {len(points)} readings")
    if not len(frames) == len(readings) == len(rows) == len(inliers):
        raise SmoothedSelfCheckError(f"association columns of {len(frames)}, {len(readings)}, {len(rows)} and "
                                     f"{len(inliers)} rows")
    if np.any(np.diff(times) < 0):
        raise SmoothedSelfCheckError("frame times must not decrease")
    if len(frames) and (frames.min() < 0 or frames.max() >= n_t or rows.min() < 0 or rows.max() >= n_l
                        or readings.min() < 0 or readings.max() >= len(points)):
        raise SmoothedSelfCheckError("an association names a frame, reading or landmark row that does not exist")
    offsets = np.r_[0, np.cumsum(counts)]
    if len(frames) and np.any((readings < offsets[frames]) | (readings >= offsets[frames + 1])):
        raise SmoothedSelfCheckError("an association's reading is not one of its frame's readings")
    f, j, lm = frames[inliers], readings[inliers], rows[inliers]
    order = np.lexsort((j, f))
    f, j, lm = f[order], j[order], lm[order]
    if len(np.unique(f * max(n_l, 1) + lm)) != len(f):
        raise SmoothedSelfCheckError("a landmark is associated to two readings of one frame")

    first = np.full(n_l, n_t, np.int64)               # each landmark's first inlier frame (n_t: never)
    np.minimum.at(first, lm, f)
    first_reading = np.full(n_l, -1, np.int64)
    at_first = f == first[lm]
    first_reading[lm[at_first]] = j[at_first]
    # the smallest id among the landmarks first seen in frame k or later (k = 0..T; beyond all: one past the largest)
    by_frame = np.full(n_t + 1, int(ids.max()) + 1 if n_l else 0, np.int64)
    np.minimum.at(by_frame, first, ids)
    id_bound = np.minimum.accumulate(by_frame[::-1])[::-1]

    check = SelfCheck(config, keep_history=keep_history)
    view = _View(config)
    offset = np.asarray(config.sensor_offset, float)
    seen = np.zeros(n_l, np.int64)                    # inlier readings before the frame: the landmarks' counts
    store = SimpleNamespace(flat_mean=positions, flat_lid=ids, flat_count=seen)
    bounds = np.searchsorted(f, np.arange(n_t + 1))
    made_by_frame = np.argsort(first, kind="stable")
    made_bounds = np.searchsorted(first[made_by_frame], np.arange(n_t + 1))
    for k in range(n_t):
        here = lm[bounds[k]:bounds[k + 1]]
        existing = first < k
        hit = here[existing[here]]                    # re-detected: landmarks made before this frame
        lost = np.flatnonzero(existing)
        lost = lost[~np.isin(lost, hit)]
        z = points[offsets[k]:offsets[k + 1]]
        reach = float(np.max(np.linalg.norm(z - offset, axis=1), initial=0.0))

        def in_view(x, y, zz, reach=reach):
            return view._well_in_view(x, y, zz, reach=reach)

        check.observe(times[k], slot_view(store, poses[k], hit, in_view, config.sensor_offset),
                      slot_view(store, poses[k], lost, in_view, config.sensor_offset), len(hit), int(id_bound[k]))
        new = made_by_frame[made_bounds[k]:made_bounds[k + 1]]
        if len(new):
            check.made(ids[new], points[first_reading[new]], poses[k])
        np.add.at(seen, here, 1)
    return check


def recheck(config: FastSLAMConfig, times: np.ndarray, poses: np.ndarray, ids: np.ndarray, positions: np.ndarray,
            points: np.ndarray, counts: np.ndarray, frames: np.ndarray, readings: np.ndarray, rows: np.ndarray,
            inliers: np.ndarray) -> dict:
    """The smoothed map's verdict, in :meth:`SelfCheck.verdict`'s schema (arguments: :func:`run`)."""
    return run(config, times, poses, ids, positions, points, counts, frames, readings, rows, inliers).verdict()


def recheck_map(smoothed_map, config: FastSLAMConfig, points: np.ndarray, counts: np.ndarray, frames: np.ndarray,
                readings: np.ndarray, rows: np.ndarray, inliers: np.ndarray) -> dict:
    """:func:`recheck` on a smoothed ``LandmarkMap`` (its trajectory's rows after the first are the frames' smoothed
    poses, its landmark rows those the association names)."""
    traj = np.asarray(smoothed_map.trajectory, float) if smoothed_map.trajectory is not None else np.zeros((0, 4))
    if len(traj) != len(counts) + 1:
        raise SmoothedSelfCheckError(f"the map's trajectory has {len(traj)} rows for {len(counts)} frames "
                                     "(one more expected: the start)")
    return recheck(config, traj[1:, 0], traj[1:, 1:], smoothed_map.ids, smoothed_map.positions, points, counts,
                   frames, readings, rows, inliers)


def recheck_smoothed(smoothed, readings, config: FastSLAMConfig) -> dict:
    """:func:`recheck_map` on ``estimation.stereo_readings.smoothed_map``'s answer ``smoothed`` (a ``SmoothedMap``:
    its map and its association's frames, readings, rows and inliers) and the ``StereoReadings`` it was smoothed
    from (their points and per-frame counts), with the filter's ``config``."""
    return recheck_map(smoothed.landmark_map, config, readings.points, readings.counts, smoothed.frames,
                       smoothed.readings, smoothed.rows, smoothed.inliers)


def rechecked_metadata(metadata: dict, verdict: dict) -> dict:
    """A copy of a smoothed map's ``metadata`` with ``verdict`` as its ``self_check`` and the filter's verdict kept
    as ``filter_self_check`` (absent when the filter gave none)."""
    out = dict(metadata)
    if "self_check" in metadata and FILTER_KEY not in metadata:
        out[FILTER_KEY] = metadata["self_check"]
    out["self_check"] = verdict
    return out
