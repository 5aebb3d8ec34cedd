"""A robot's stereo readings kept frame by frame, and the map after the mission smoothed from them (issue 13).

FastSLAM's map is its best particle's, made online. Once the mission is over, :mod:`estimation.stereo_smoothing`
finds every pose and landmark together (full SLAM) given each reading's landmark. This module holds what that needs
and is not the smoother's:

- :class:`ReadingsRecorder`: each processed frame's time, odometry pose and readings (points, covariances,
  descriptors, pixels), kept within a stated cap (:data:`MAX_FRAMES`, :data:`MAX_READINGS`). Past the cap it drops
  what it kept and keeps nothing more (``overflow`` says why): the smoother's reduced system is dense in the frames
  (3T × 3T), and a prefix of the run smoothed beside the filter's later poses would be no one map.
- :func:`associate`: each frame's readings re-associated to the filter's final exported map from the best particle's
  own pose at that frame (its trajectory, the ancestry), by the filter's rules: descriptor distance below
  ``descriptor_threshold``, the squared Mahalanobis distance under the landmark's covariance in that particle (not the
  exported mixture + drift) plus the reading's rotated covariance below ``mahalanobis_gate``, each reading and each
  landmark used once a frame, nearest first. (Not the filter's own record of the ancestry's matches: those live in
  every particle and are renamed by merges and removals; the best particle's map and its poses are consistent with
  each other, so its gate finds the readings it was made from, and a wrong one is left to the smoother's robust loss.)
- :func:`smoothed_map`: association, ``stereo_smoothing.smooth`` (Cauchy, then cut at χ²₃ 99 %) from the filter's
  trajectory and map with pose 0 fixed, and the smoothed :class:`LandmarkMap`: the filter's ids, descriptors, counts
  and metadata, with the smoothed positions, their marginal covariances, the smoothed trajectory, each landmark's
  drift (the smoothed pose's marginal where it was first seen) and its sighting spread; a landmark no inlier reading
  holds keeps the filter's values. The smoothed covariances carry the filter's observation floor
  (``observation_var_floor``) once more as an error shared by all of a landmark's readings (session 49: without it the
  landmarks' NEES fell to 68–94 % within χ²₃ 95 % on seeds 0, 5 and 6). Whatever cannot be smoothed raises
  :class:`SmoothingRefused` with one line saying why; the caller keeps the filter's map.
- The smoothed map's ``metadata["self_check"]`` is the filter's own self-check re-run along the smoothed poses with
  this association (:mod:`estimation.smoothed_self_check`); the filter's verdict is kept as ``filter_self_check``.
  The fusion splits a map at its self-check's alarm, so a filter's false alarm that the smoothing answers no longer
  costs the map (session 50: seeds 1 and 2's robot 1; seed 4's robot 1, truly lost, still flags).

Session 49 (benchmarks/demo_smoothing.py, rendered demo seeds 0–9): the demo's final fusion on the smoothed maps was
within 0.05 m / 0.01 rad on 8 of the 8 found seeds, none wrong (the filter's maps: 5 of 8).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .fastslam import FastSLAMConfig
from .fastslam.motion import increment_variance
from .geometry import between, rot_z
from .landmark_map import LandmarkMap
from .sighting_spread import sighting_covariances
from .smoothed_self_check import SmoothedSelfCheckError, recheck_smoothed, rechecked_metadata
from .stereo_smoothing import StereoLogProblem, StereoSmoothingError, smooth

# The cap on what a recorder keeps. Frames: the smoother's reduced system is a dense 3T × 3T matrix (T = 1000: 72 MB,
# a few copies during the solve and the marginals) and its cost grows as T³ (session 49: 750 frames took 72 s on a
# loaded 2-core machine); the rendered demo's 200 s at 3.75 Hz is at most 750 frames. Readings: each holds its point,
# covariance, 64-float descriptor and pixel (368 bytes): 100 000 are 37 MB (the demo's robots keep 24 000–42 000).
MAX_FRAMES = 1000
MAX_READINGS = 100_000
MIN_FRAMES = 2           # a smoothing needs an odometry factor


class SmoothingRefused(ValueError):
    """The map cannot be smoothed (too few readings, a cap passed, a map that does not match its particle...): the
    message is one line saying why; the filter's map stands."""


@dataclass
class StereoReadings:
    """T frames, N readings: times (T,) s; odometry (T, 3) the odometry pose at each frame (odometry frame); counts
    (T,) readings per frame; points (N, 3) base_link, covariances (N, 3, 3) as the front end gave them (before the
    filter's scale and floor); descriptors (N, D) float32; pixels (N, 2) left-image pixels."""

    times: np.ndarray
    odometry: np.ndarray
    counts: np.ndarray
    points: np.ndarray
    covariances: np.ndarray
    descriptors: np.ndarray
    pixels: np.ndarray

    @property
    def frames(self) -> int:
        return len(self.times)

    @property
    def offsets(self) -> np.ndarray:
        """(T + 1,) where each frame's readings start (and the last ends)."""
        return np.r_[0, np.cumsum(self.counts)].astype(np.int64)


class ReadingsRecorder:
    """Each processed frame's readings, within :data:`MAX_FRAMES` and :data:`MAX_READINGS` (module docstring)."""

    def __init__(self, descriptor_size: int, max_frames: int | None = None, max_readings: int | None = None) -> None:
        self.descriptor_size = int(descriptor_size)
        self.max_frames = MAX_FRAMES if max_frames is None else int(max_frames)
        self.max_readings = MAX_READINGS if max_readings is None else int(max_readings)
        self.overflow: str | None = None     # why nothing is kept (past the cap), None while it keeps
        self.frames_seen = 0
        self.readings_seen = 0
        self._rows: list[tuple] = []
        self._kept = 0

    @property
    def frames(self) -> int:
        return len(self._rows)

    @property
    def readings(self) -> int:
        return self._kept

    def add(self, t: float, odometry_pose: np.ndarray, observations) -> bool:
        """Keep one frame's readings (a ``StereoObservations``); False once past the cap (nothing is kept then)."""
        n = len(observations)
        self.frames_seen += 1
        self.readings_seen += n
        if self.overflow is not None:
            return False
        if self.frames + 1 > self.max_frames or self._kept + n > self.max_readings:
            self.overflow = (f"past the smoothing's cap of {self.max_frames} frames and {self.max_readings} readings "
                             f"at frame {self.frames_seen} ({self.readings_seen} readings): the readings kept are "
                             "dropped and no more are kept")
            self._rows.clear()
            self._kept = 0
            return False
        self._rows.append((float(t), np.asarray(odometry_pose, float).copy(), n,
                           np.asarray(observations.points, float).reshape(n, 3).copy(),
                           np.asarray(observations.covariances, float).reshape(n, 3, 3).copy(),
                           np.asarray(observations.descriptors, np.float32).reshape(n, self.descriptor_size).copy(),
                           np.asarray(observations.pixels, float).reshape(n, 2).copy()))
        self._kept += n
        return True

    def readings_kept(self) -> StereoReadings:
        """What was kept, as arrays (raises SmoothingRefused past the cap)."""
        if self.overflow is not None:
            raise SmoothingRefused(self.overflow)
        rows = self._rows
        d = self.descriptor_size
        return StereoReadings(np.array([r[0] for r in rows], float),
                              np.array([r[1] for r in rows], float).reshape(-1, 3),
                              np.array([r[2] for r in rows], np.int64),
                              np.concatenate([r[3] for r in rows]) if rows else np.zeros((0, 3)),
                              np.concatenate([r[4] for r in rows]) if rows else np.zeros((0, 3, 3)),
                              np.concatenate([r[5] for r in rows]) if rows else np.zeros((0, d), np.float32),
                              np.concatenate([r[6] for r in rows]) if rows else np.zeros((0, 2)))


def associate(readings: StereoReadings, trajectory: np.ndarray, exported: LandmarkMap,
              particle_covariances: np.ndarray, config: FastSLAMConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(frame index, reading index, landmark row) of each association of a reading to the exported map from the best
    particle's pose at its frame (module docstring). ``trajectory`` (T + 1, 4): the best particle's rows (t, x, y, θ),
    its start and one per frame; ``particle_covariances`` (L, 3, 3): the exported landmarks' covariances in that
    particle."""
    from scipy.spatial import cKDTree

    times = readings.times
    if len(trajectory) != len(times) + 1 or not np.allclose(trajectory[1:, 0], times):
        raise SmoothingRefused(f"the filter's trajectory has {len(trajectory)} rows for {len(times)} frames kept")
    if not len(exported):
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)
    desc_map = exported.descriptors.astype(np.float64)
    tree = cKDTree(exported.positions[:, :2])
    offsets = readings.offsets
    eye = np.eye(3)
    out_f, out_j, out_l = [], [], []
    for k in range(len(times)):
        a, b = offsets[k], offsets[k + 1]
        if a == b:
            continue
        x, y, th = trajectory[k + 1, 1:]
        R = rot_z(th)
        z = readings.points[a:b]
        q = config.observation_cov_scale * readings.covariances[a:b] + config.observation_var_floor * eye
        world = z @ R.T + np.array([x, y, 0.0])
        qw = R @ q @ R.T
        near = tree.query_ball_point(world[:, :2], r=1.5)
        jj = np.repeat(np.arange(b - a), [len(n) for n in near])
        ll = np.fromiter((v for n in near for v in n), np.int64, len(jj))
        if not len(jj):
            continue
        dd = readings.descriptors[a:b][jj].astype(np.float64) - desc_map[ll]
        ok = np.einsum("ij,ij->i", dd, dd) < config.descriptor_threshold ** 2
        jj, ll = jj[ok], ll[ok]
        e = world[jj] - exported.positions[ll]
        d2 = np.einsum("ni,ni->n", e, np.linalg.solve(particle_covariances[ll] + qw[jj], e[:, :, None])[:, :, 0])
        ok = d2 < config.mahalanobis_gate
        jj, ll, d2 = jj[ok], ll[ok], d2[ok]
        used_j, used_l = set(), set()
        for i in np.argsort(d2, kind="stable"):
            if jj[i] in used_j or ll[i] in used_l:
                continue
            used_j.add(jj[i])
            used_l.add(ll[i])
            out_f.append(k)
            out_j.append(a + jj[i])
            out_l.append(ll[i])
    return np.array(out_f, np.int64), np.array(out_j, np.int64), np.array(out_l, np.int64)


@dataclass
class SmoothedMap:
    """:func:`smoothed_map`'s answer: the map, its figures (frames, readings, associated, inliers, chi2_per_dof,
    iterations, landmarks, held, associate_s, smooth_s) and each association (frame, reading, landmark row, inlier)."""

    landmark_map: LandmarkMap
    figures: dict
    frames: np.ndarray
    readings: np.ndarray
    rows: np.ndarray
    inliers: np.ndarray


def smoothed_map(readings: StereoReadings, trajectory: np.ndarray, exported: LandmarkMap,
                 particle_positions: np.ndarray, particle_covariances: np.ndarray, config: FastSLAMConfig,
                 landmark_floor: float | None = None) -> SmoothedMap:
    """The filter's exported map ``exported`` smoothed over ``readings`` (module docstring). ``trajectory``: the best
    particle's (T + 1, 4) rows; ``particle_positions`` (L, 3), ``particle_covariances`` (L, 3, 3): the same export
    with the particle's own covariances (``best_map(covariance="particle")``); ``landmark_floor`` m² (None: the
    filter's ``observation_var_floor``).
    Raises :class:`SmoothingRefused` (one line) when it cannot."""
    if readings.frames < MIN_FRAMES:
        raise SmoothingRefused(f"{readings.frames} frame{'s' if readings.frames != 1 else ''} kept; the smoothing "
                               f"needs at least {MIN_FRAMES}")
    if len(particle_positions) != len(exported) or not np.allclose(particle_positions, exported.positions):
        raise SmoothingRefused("the map's export with the particle's own covariances differs from the exported map")
    if not len(exported):
        raise SmoothingRefused("the filter's map holds no landmark")
    start = time.perf_counter()
    f, j, lm = associate(readings, trajectory, exported, particle_covariances, config)
    t_assoc = time.perf_counter() - start
    if not len(f):
        raise SmoothingRefused(f"none of the {int(readings.counts.sum())} readings kept matches the filter's map")
    odo, times = readings.odometry, readings.times
    inc = between(odo[:-1], odo[1:])
    var = increment_variance(inc, config, np.maximum(np.diff(times), 0.0))
    q = config.observation_cov_scale * readings.covariances[j] + config.observation_var_floor * np.eye(3)
    poses0 = trajectory[1:, 1:].copy()
    if np.abs(poses0[0]).max() > 1e-9:
        raise SmoothingRefused(f"the first frame's pose is {np.round(poses0[0], 6).tolist()} in the map frame, not "
                               "its origin")
    t0 = time.perf_counter()
    floor = config.observation_var_floor if landmark_floor is None else landmark_floor
    try:
        problem = StereoLogProblem(inc, var, f, lm, readings.points[j], q, len(exported))
        sol = smooth(problem, poses0, exported.positions, landmark_floor=floor)
    except (StereoSmoothingError, np.linalg.LinAlgError) as exc:
        raise SmoothingRefused(f"the smoother refused: {exc}") from None
    t_smooth = time.perf_counter() - t0
    held = sol.held
    if not (np.all(np.isfinite(sol.poses)) and np.all(np.isfinite(sol.landmarks[held]))
            and np.all(np.isfinite(sol.landmark_covariances[held]))):
        raise SmoothingRefused("the smoothing gave non-finite poses or landmarks")
    positions = np.where(held[:, None], sol.landmarks, exported.positions)
    covariances = np.where(held[:, None, None], sol.landmark_covariances, exported.covariances)
    first = np.full(len(exported), -1, np.int64)        # each landmark's first inlier reading's frame
    for k, row in zip(f[sol.inliers][::-1], lm[sol.inliers][::-1], strict=True):
        first[row] = k
    drift_cov = exported.drift_covariances.copy() if exported.drift_covariances is not None else \
        np.tile(np.eye(3) * 1e-6, (len(exported), 1, 1))
    drift_org = exported.drift_origins.copy() if exported.drift_origins is not None else positions[:, :2].copy()
    ok = first >= 0
    drift_cov[ok] = sol.pose_covariances[first[ok]]
    drift_org[ok] = sol.poses[first[ok], :2]
    smoothed_trajectory = np.vstack([trajectory[:1], np.column_stack([times, sol.poses])])
    meta = dict(exported.metadata)
    meta["smoothed"] = {"readings": int(len(f)), "inliers": int(sol.inliers.sum()),
                        "chi2_per_dof": sol.chi2_per_dof, "landmarks_held": int(held.sum())}
    m = LandmarkMap(positions, covariances, exported.descriptors, exported.ids, exported.counts, exported.robot,
                    exported.frame, list(exported.robots), exported.seen_by, smoothed_trajectory, meta, drift_cov,
                    drift_org)
    if exported.sighting_covariances is not None:
        keep = sol.inliers
        m.sighting_covariances = sighting_covariances(m, times[f[keep]], readings.points[j[keep]],
                                                      exported.ids[lm[keep]])
    figures = {"frames": int(len(times)), "readings": int(readings.counts.sum()), "associated": int(len(f)),
               "inliers": int(sol.inliers.sum()), "chi2_per_dof": float(sol.chi2_per_dof),
               "iterations": int(sol.iterations), "landmarks": len(exported), "held": int(held.sum()),
               "associate_s": t_assoc, "smooth_s": t_smooth}
    smoothed = SmoothedMap(m, figures, f, j, lm, sol.inliers)
    # the map's self-check re-run along the smoothed poses with the smoothing's association (estimation.
    # smoothed_self_check): the fusion splits the smoothed map by its own verdict, the filter's kept beside; a re-run
    # that cannot be made leaves the filter's verdict, the cautious one
    try:
        m.metadata = rechecked_metadata(m.metadata, recheck_smoothed(smoothed, readings, config))
    except SmoothedSelfCheckError:
        pass
    return smoothed


__all__ = ["MAX_FRAMES", "MAX_READINGS", "ReadingsRecorder", "SmoothedMap", "SmoothingRefused", "StereoReadings",
           "associate", "smoothed_map"]
