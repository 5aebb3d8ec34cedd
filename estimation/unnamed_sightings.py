"""Sightings no name holds, named by the final map when exactly one name explains them.

The chain of names leaves some sightings unlinked, and the leave-out steps (:mod:`estimation.name_leave_out`) unname
others. On a map tight enough to end the merges, the smoother's own outlier test can name them: at the smoothed pose
of its time, a sighting whose residual against exactly one name is within the bound beyond which the smoother drops
a sighting takes that name (:func:`unnamed_names`); the map is smoothed again with them (:func:`name_unnamed`).
Session 29 (lead), robot 5 seed 2: the chain left 18 sightings of the first 10 s unlinked, and without them the map's
frame (pose 0 is the first named sighting's) turned 0.025 rad from the start pose.

Measured in ``benchmarks/mrclam_constellation.py`` (its docstring, step 9; docs/fastslam-history.md, "Session 29:
sightings the chain left unnamed ... (lead)"). Moved here from the benchmark in session 36 (lead), unchanged; the
benchmark scores the names given by the barcodes, these functions never see them.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from estimation.datasets import RangeBearingLog
from estimation.geometry import wrap_angle
from estimation.landmark_smoother import OUTLIER_CHI2
from estimation.name_leave_out import detected_in_frames
from estimation.name_merging import NamedSmoother, poses_at, resmoothed
from estimation.named_smoothing import MergeRound
from estimation.noise_model import NoiseModel

# a visit: one name's sightings less than this apart (the offset group of a sighting named late)
VISIT_GAP_S = 5.0


def unnamed_names(log: RangeBearingLog, current: MergeRound, noise: NoiseModel, offset_sigma_m: float = 0.0
                  ) -> dict[int, int]:
    """{log row: name} for the sightings no name holds (the chain left them unlinked, or a leave-out step left them
    out) that the final map names unambiguously, by the smoother's own outlier test: at the smoothed pose of its
    time, a sighting's normalised residual (range and bearing, each in its σ) against exactly one name is within
    χ²₂ 99 % (the bound beyond which the smoother drops a sighting), with the name's position covariance and a
    sighting offset's prior (σ ``offset_sigma_m`` per axis) added. With a second name within it, or only a name
    already detected in that frame, the sighting stays unnamed. The pose's own uncertainty is left out: on a map
    tight enough to end the rounds it is centimetres against the sensor's decimetres at range."""
    rows = np.flatnonzero(current.names < 0)
    solution, named = current.solution, current.named
    seen = np.isfinite(solution.landmark_covariances.reshape(len(named.names), -1)).all(axis=1)
    if not len(rows) or not seen.any():
        return {}
    sensor = noise.range_bearing
    inflate_r, inflate_b = (float(np.sqrt(f)) for f in sensor.variance_inflation())
    ranges, bearings = sensor.corrected(log.ranges[rows], log.bearings[rows])
    sigma_r = sensor.range_sigma(ranges) * inflate_r
    sigma_b = np.full(len(rows), sensor.bearing_sigma_rad * inflate_b)
    poses = poses_at(log, current, noise, log.sighting_times[rows])
    offset_var = offset_sigma_m ** 2
    delta = solution.landmarks[None, :, :] - poses[:, None, :2]                 # (R, L, 2)
    r_hat = np.hypot(delta[..., 0], delta[..., 1])
    b_hat = np.arctan2(delta[..., 1], delta[..., 0]) - poses[:, None, 2]
    # ∂(r, φ)/∂m: the landmark's (and its offset's) uncertainty in range and bearing
    jac = np.stack([delta / r_hat[..., None], np.stack([-delta[..., 1], delta[..., 0]], -1) / r_hat[..., None] ** 2],
                   axis=-2)                                                     # (R, L, 2, 2)
    cov_m = np.nan_to_num(solution.landmark_covariances) + offset_var * np.eye(2)
    s = jac @ cov_m[None] @ np.swapaxes(jac, -1, -2)
    s[..., 0, 0] += sigma_r[:, None] ** 2
    s[..., 1, 1] += sigma_b[:, None] ** 2
    e = np.stack([r_hat - ranges[:, None], wrap_angle(b_hat - bearings[:, None])], -1)
    d2 = np.einsum("rli,rli->rl", e, np.linalg.solve(s, e[..., None])[..., 0])
    # a name already detected in the sighting's frame cannot be its name
    frame_of = {float(t): i for i, t in enumerate(named.frame_times)}
    detected = detected_in_frames(current)
    out: dict[int, int] = {}
    taken: dict[tuple[float, int], list[int]] = {}
    for i, row in enumerate(rows):
        within = np.flatnonzero(seen & (d2[i] < OUTLIER_CHI2))
        frame = frame_of.get(float(log.sighting_times[row]))
        if frame is not None:
            within = within[~detected[frame, within]]
        if len(within) == 1:
            out[int(row)] = int(named.names[within[0]])
            taken.setdefault((float(log.sighting_times[row]), int(within[0])), []).append(int(row))
    for rows_of_one in taken.values():          # two sightings of one frame cannot both be one name
        if len(rows_of_one) > 1:
            for row in rows_of_one:
                out.pop(row)
    return out


def visits(rows: np.ndarray, names: np.ndarray, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``rows`` ordered by name, then time, and each one's visit, numbered from 1: a visit is one name's sightings
    less than :data:`VISIT_GAP_S` apart (the offset group of the sightings a step names late)."""
    order = rows[np.lexsort((times[rows], names[rows]))]
    fresh = np.r_[True, (names[order][1:] != names[order][:-1]) | (np.diff(times[order]) > VISIT_GAP_S)]
    return order, np.cumsum(fresh)


def name_unnamed(smoother: NamedSmoother, current: MergeRound
                 ) -> tuple[MergeRound, dict[int, int], NamedSmoother]:
    """The sightings :func:`unnamed_names` names are given their names and the map re-smoothed (new frames start at
    the nearest old pose moved by the odometry); the smoother's outlier test then judges them with the rest (one it
    drops keeps its name, unused, like any sighting it drops). With sighting offsets, each newly named sighting gets
    an offset group of its own visit (its name, sightings less than :data:`VISIT_GAP_S` apart). Returns the new state
    (``current`` when nothing is named), the names given ({log row: name}) and the smoother with those groups."""
    log = smoother.log
    offset = smoother.sighting_offset
    proposed = unnamed_names(log, current, smoother.noise, offset.sigma_m if offset is not None else 0.0)
    if not proposed:
        return current, proposed, smoother
    names = current.names.copy()
    rows = np.array(sorted(proposed))
    names[rows] = [proposed[r] for r in rows]
    if offset is not None and smoother.offset_names is not None:
        groups = smoother.offset_names.copy()
        order, visit = visits(rows, names, log.sighting_times)
        groups[order] = int(max(groups.max(), names.max())) + visit
        smoother = dataclasses.replace(smoother, offset_names=groups)
    return resmoothed(smoother, current, names), proposed, smoother
