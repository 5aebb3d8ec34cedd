"""A robot's stereo readings kept frame by frame, and the map after the mission smoothed from them (issue 13).

FastSLAM's map is its best particle's, made online. Once the mission is over, :mod:`estimation.stereo_smoothing`
finds every pose and landmark together (full SLAM) given each reading's landmark. This module holds what that needs
and is not the smoother's:

- :class:`ReadingsRecorder`: each processed frame's time, odometry pose and readings (points, covariances,
  descriptors, pixels), kept within a stated cap (:data:`MAX_FRAMES`, :data:`MAX_READINGS`). Past the cap it drops
  what it kept and keeps nothing more (``overflow`` says why): the smoother's reduced system is dense in the frames
  (3T × 3T), and a prefix of the run smoothed beside the filter's later poses would be no one map. With a
  :class:`KeyframeRule` it keeps only keyframes (below), so that the cap is one of distance travelled, not of time.
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
  landmarks' NEES fell to 68–94 % within χ²₃ 95 % on seeds 0, 5 and 6), and are the white estimate's covariance under
  the error shared by a landmark's readings from about one view (``view_model="sandwich"`` at the same floor, session
  51: the estimate unchanged; pose NEES ≥ 90 % on 13 of the demo's 20 maps against 7). Whatever cannot be smoothed
  raises :class:`SmoothingRefused` with one line saying why; the caller keeps the filter's map.
- The smoothed map's ``metadata["self_check"]`` is the filter's own self-check re-run along the smoothed poses with
  this association (:mod:`estimation.smoothed_self_check`); the filter's verdict is kept as ``filter_self_check``.
  The fusion splits a map at its self-check's alarm, so a filter's false alarm that the smoothing answers no longer
  costs the map (session 50: seeds 1 and 2's robot 1; seed 4's robot 1, truly lost, still flags).

Session 49 (benchmarks/demo_smoothing.py, rendered demo seeds 0–9): the demo's final fusion on the smoothed maps was
within 0.05 m / 0.01 rad on 8 of the 8 found seeds, none wrong (the filter's maps: 5 of 8).

*Keyframes* (session 51; ``ReadingsRecorder(keyframes=KeyframeRule(), config=...)``, off by default). As mature
smoothers do (RTAB-Map's linear/angular update of 0.1 m / 0.1 rad, ORB-SLAM's "the frame tracks too few of the
reference keyframe's points"), a frame's readings are kept when, since the last kept frame, its odometry pose moved
``distance`` (0.1 m) or turned ``angle`` (0.1 rad), or fewer than ``overlap`` (half) of its readings have a reading of
the last keyframe within the filter's ``descriptor_threshold`` in descriptor space (it sees what the last keyframe did
not: a doorway passed, a corner turned by little motion). The first frame is always kept (the map's origin); a
frame without readings is never kept by the view. Decided online, frame by frame; besides the kept rows the recorder
holds the last frame's odometry pose and time, the last keyframe's descriptors and a 3 × 3 covariance.

The odometry between keyframes is their odometry poses' increment (exactly the frames' increments composed), with
the covariance of that composition under the filter's own motion model: each frame's increment independent, with
``motion.increment_variance``'s diagonal variances in its start frame, composed to first order
(:func:`compose_increment`; what FastSLAM's ``sample_motion`` draws frame after frame, and what the chain of
per-frame odometry factors gives once the poses between are marginalised). Checked, not assumed, against one
increment over the whole: the model is a random walk in the distance *driven* and the angle *turned* (each frame's
|Δθ|), not in the net increment, and the heading's errors carry into later positions. So along a straight line or
on the spot the x and θ variances are one increment's over the total (plus the floor once a frame); y gains
Σ var_θk · r_k² (lateral error growing as distance³) and a y-θ covariance; a path back and forth or a wiggle costs
the distance and angle driven (on the demo's logs the one-increment variance would be up to 480 times too small in x
where a robot jittered in place, 8.8 times in θ). ``tests/estimation/test_stereo_keyframes.py`` checks the
composition against the chain's Jacobian on random paths and against the filter's own sampling. The smoother's
odometry factors are diagonal, so :func:`smoothed_map` passes the composed diagonal and leaves out the x-θ and y-θ
covariances: on the demo's logs with the default rule |ρ_yθ| is at most 0.27 (95 % below 0.07), |ρ_xθ| below 0.02.

:func:`smoothed_map` then takes the filter's trajectory at the keyframes (``StereoReadings.frame_index``) and gives
the smoothed map a trajectory at every frame again (the fusion's colocation test interpolates trajectories only
between rows 0.5 s apart): a frame between keyframes is the filter's pose moved by the smoothing's correction
(the map-frame transform from the filter's pose to the smoothed one) interpolated in time between the keyframes
around it. The self-check re-run walks the keyframes, whose readings it has.

Session 51 (``benchmarks/demo_keyframes.py`` on session 49's logs of demo seeds 0–9, 20 maps; every frame → keyframes
with the default rule): 60 % of the frames and readings kept (the view rule adds 37 keyframes of 6 558; none of the
1 183 frames standing still is kept), smoothing seconds 106 → 43 in all, the final fusion within 0.05 m / 0.01 rad on
9 of 9 found seeds either way (median error 0.024 → 0.032 m), landmark NEES ≥ 90 % on 18 of 20 either way (seed 9's
robot 1 76 → 86 %: fewer readings from one view share its error), ATE median 0.028 m either way; the re-run
self-check keeps seed 4's robot 1's true alarm and loses seed 0's robot 1's false one. Against exact marginalisation
(the same keyframe readings with every frame's pose in the odometry chain) the composed diagonal factors move the
landmarks by 0.1–0.2 mm (median; Mahalanobis ≤ 0.4). ``p3at run`` at 15 Hz (robot 1's route, 118 s, 1 767 frames,
refused without keyframes at frame 1 001): 389 keyframes, ATE 0.064 → 0.027 m; the cap then comes after ~300 s or
~74 m of that route (13.6 keyframes a metre driven with its turns). A coarser rule (0.25 m / 0.2 rad) keeps 34 % of
the demo's frames and 19 of 20 maps ≥ 90 %, but the re-run self-check then misses seed 4's true loss.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from .fastslam import FastSLAMConfig
from .fastslam.motion import increment_variance, propagate_covariance
from .geometry import between, compose, interpolate_poses, inverse, rot_z
from .landmark_map import LandmarkMap
from .sighting_spread import sighting_covariances
from .smoothed_self_check import SmoothedSelfCheckError, recheck_map, rechecked_metadata
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
    frame_index: np.ndarray | None = None             # (T,) each kept frame's index among the frames the recorder
    #                                                   was given (keyframes); None: every frame was kept
    increment_covariances: np.ndarray | None = None   # (T − 1, 3, 3) the composed odometry increments' covariances
    #                                                   (keyframes); None: one increment a frame, by the filter's model

    @property
    def frames(self) -> int:
        return len(self.times)

    @property
    def offsets(self) -> np.ndarray:
        """(T + 1,) where each frame's readings start (and the last ends)."""
        return np.r_[0, np.cumsum(self.counts)].astype(np.int64)


@dataclass(frozen=True)
class KeyframeRule:
    """Which frames' readings a :class:`ReadingsRecorder` keeps when given one (module docstring, *Keyframes*): the
    first frame, then a frame whose odometry pose is ``distance`` m or more from the last kept frame's, or turned
    ``angle`` rad or more from it, or whose readings the last kept frame's readings match (descriptor distance below
    ``descriptor_threshold``, None: the filter's) fewer than ``overlap`` of (a share, 0–1; 0: never by the view)."""

    distance: float = 0.1
    angle: float = 0.1
    overlap: float = 0.5
    descriptor_threshold: float | None = None

    def __post_init__(self) -> None:
        for name in ("distance", "angle"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"KeyframeRule.{name} must be finite and > 0, not {v}")
        if not (math.isfinite(self.overlap) and 0.0 <= self.overlap <= 1.0):
            raise ValueError(f"KeyframeRule.overlap must be a share in [0, 1], not {self.overlap}")
        if self.descriptor_threshold is not None and not (math.isfinite(self.descriptor_threshold)
                                                          and self.descriptor_threshold > 0.0):
            raise ValueError(f"KeyframeRule.descriptor_threshold must be finite and > 0, not "
                             f"{self.descriptor_threshold}")


def compose_increment(covariance: np.ndarray, so_far: np.ndarray, step: np.ndarray,
                      step_variance: np.ndarray) -> np.ndarray:
    """(3, 3) the covariance of ``so_far ⊕ step`` to first order: ``so_far`` (3,) an increment with ``covariance``
    (3, 3), ``step`` (3,) the next one with independent diagonal ``step_variance`` (3,) in its own start frame (the
    filter's motion model: each frame's increment drawn with its own variances and composed, motion.sample_motion):
    the filter's own propagation (motion.propagate_covariance) of one pose."""
    return propagate_covariance(np.asarray(so_far, float).reshape(1, 3), np.asarray(covariance, float)[None],
                                np.asarray(step, float), np.asarray(step_variance, float))[0]


class ReadingsRecorder:
    """Each processed frame's readings, within :data:`MAX_FRAMES` and :data:`MAX_READINGS` (module docstring).

    ``keyframes`` (a :class:`KeyframeRule`, None: every frame) keeps only the keyframes' readings, the odometry
    between them composed with its covariance under ``config``'s motion model (a ``FastSLAMConfig``, needed then);
    the caps then count keyframes. The decision is online, frame by frame; what it holds besides the kept rows is
    the last frame's odometry pose and time, the last keyframe's descriptors and the composed covariance."""

    def __init__(self, descriptor_size: int, max_frames: int | None = None, max_readings: int | None = None, *,
                 keyframes: KeyframeRule | None = None, config: FastSLAMConfig | None = None) -> None:
        self.descriptor_size = int(descriptor_size)
        self.max_frames = MAX_FRAMES if max_frames is None else int(max_frames)
        self.max_readings = MAX_READINGS if max_readings is None else int(max_readings)
        if keyframes is not None and config is None:
            raise ValueError("ReadingsRecorder: keyframes need the filter's config (its motion model composes the "
                             "odometry between them)")
        self.keyframes = keyframes
        self.config = config
        self.overflow: str | None = None     # why nothing is kept (past the cap), None while it keeps
        self.frames_seen = 0
        self.readings_seen = 0
        self._rows: list[tuple] = []
        self._kept = 0
        # keyframes: the last frame's odometry pose and time, the last keyframe's odometry pose and descriptors,
        # the composed increment from it to the last frame and that increment's covariance
        self._previous: tuple[float, np.ndarray] | None = None
        self._key_pose = np.zeros(3)
        self._key_descriptors = np.zeros((0, self.descriptor_size), np.float32)
        self._covariance = np.zeros((3, 3))

    @property
    def frames(self) -> int:
        return len(self._rows)

    @property
    def readings(self) -> int:
        return self._kept

    def add(self, t: float, odometry_pose: np.ndarray, observations) -> bool:
        """Keep one frame's readings (a ``StereoObservations``); False when the frame is not kept (not a keyframe,
        or past the cap: nothing is kept then)."""
        n = len(observations)
        index = self.frames_seen
        self.frames_seen += 1
        self.readings_seen += n
        if self.overflow is not None:
            return False
        pose = np.asarray(odometry_pose, float).reshape(3).copy()
        covariance = None
        if self.keyframes is not None:
            descriptors = np.asarray(observations.descriptors, np.float32).reshape(n, self.descriptor_size)
            key = self._keyframe(float(t), pose, descriptors)
            if not key:
                return False
            covariance = self._covariance
        if self.frames + 1 > self.max_frames or self._kept + n > self.max_readings:
            self.overflow = (f"past the smoothing's cap of {self.max_frames} frames and {self.max_readings} readings "
                             f"at frame {self.frames_seen} ({self.readings_seen} readings): the readings kept are "
                             "dropped and no more are kept")
            self._rows.clear()
            self._kept = 0
            return False
        row = (float(t), pose, n,
               np.asarray(observations.points, float).reshape(n, 3).copy(),
               np.asarray(observations.covariances, float).reshape(n, 3, 3).copy(),
               np.asarray(observations.descriptors, np.float32).reshape(n, self.descriptor_size).copy(),
               np.asarray(observations.pixels, float).reshape(n, 2).copy())
        if self.keyframes is not None:
            row = row + (index, covariance)
            self._key_pose = pose
            self._key_descriptors = row[5]
            self._covariance = np.zeros((3, 3))
        self._rows.append(row)
        self._kept += n
        return True

    def _keyframe(self, t: float, pose: np.ndarray, descriptors: np.ndarray) -> bool:
        """Whether this frame is a keyframe (:class:`KeyframeRule`); composes the odometry's covariance since the
        last keyframe up to it either way."""
        previous, self._previous = self._previous, (t, pose)
        if previous is None:
            return True
        rule, config = self.keyframes, self.config
        t0, pose0 = previous
        step = between(pose0, pose)
        variance = increment_variance(step, config, max(t - t0, 0.0))
        self._covariance = compose_increment(self._covariance, between(self._key_pose, pose0), step, variance)
        moved = between(self._key_pose, pose)
        if math.hypot(moved[0], moved[1]) >= rule.distance or abs(moved[2]) >= rule.angle:
            return True
        if not len(descriptors) or rule.overlap <= 0.0:
            return False
        if not len(self._key_descriptors):
            return True
        threshold = config.descriptor_threshold if rule.descriptor_threshold is None else rule.descriptor_threshold
        a = descriptors.astype(np.float64)
        b = self._key_descriptors.astype(np.float64)
        d2 = np.einsum("ij,ij->i", a, a)[:, None] + np.einsum("ij,ij->i", b, b)[None, :] - 2.0 * a @ b.T
        matched = np.count_nonzero(d2.min(axis=1) < threshold ** 2)
        return matched < rule.overlap * len(descriptors)

    def readings_kept(self) -> StereoReadings:
        """What was kept, as arrays (raises SmoothingRefused past the cap)."""
        if self.overflow is not None:
            raise SmoothingRefused(self.overflow)
        rows = self._rows
        d = self.descriptor_size
        out = StereoReadings(np.array([r[0] for r in rows], float),
                             np.array([r[1] for r in rows], float).reshape(-1, 3),
                             np.array([r[2] for r in rows], np.int64),
                             np.concatenate([r[3] for r in rows]) if rows else np.zeros((0, 3)),
                             np.concatenate([r[4] for r in rows]) if rows else np.zeros((0, 3, 3)),
                             np.concatenate([r[5] for r in rows]) if rows else np.zeros((0, d), np.float32),
                             np.concatenate([r[6] for r in rows]) if rows else np.zeros((0, 2)))
        if self.keyframes is not None:
            out.frame_index = np.array([r[7] for r in rows], np.int64)
            out.increment_covariances = np.array([r[8] for r in rows[1:]], float).reshape(-1, 3, 3)
        return out


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
    iterations, landmarks, held, associate_s, smooth_s; with ``calibrate_odometry`` also odometry_scales (s_d, s_θ)
    and odometry_scale_sd, their marginal σ), each association (frame, reading, landmark row, inlier) and the
    smoothed frames' (keyframes') pose marginals (T, 3, 3)."""

    landmark_map: LandmarkMap
    figures: dict
    frames: np.ndarray
    readings: np.ndarray
    rows: np.ndarray
    inliers: np.ndarray
    pose_covariances: np.ndarray | None = None


def smoothed_map(readings: StereoReadings, trajectory: np.ndarray, exported: LandmarkMap,
                 particle_positions: np.ndarray, particle_covariances: np.ndarray, config: FastSLAMConfig,
                 landmark_floor: float | None = None, calibrate_odometry: bool = False) -> SmoothedMap:
    """The filter's exported map ``exported`` smoothed over ``readings`` (module docstring). ``trajectory``: the best
    particle's (T + 1, 4) rows; ``particle_positions`` (L, 3), ``particle_covariances`` (L, 3, 3): the same export
    with the particle's own covariances (``best_map(covariance="particle")``); ``landmark_floor`` m² (None: the
    filter's ``observation_var_floor``); ``calibrate_odometry`` (off by default): the smoother also estimates the
    odometry's distance and turn scales (``stereo_smoothing.smooth(calibrate_odometry=True)``; the map's
    ``metadata["smoothed"]`` and the figures then hold them and their σ).
    Raises :class:`SmoothingRefused` (one line) when it cannot."""
    if readings.frames < MIN_FRAMES:
        raise SmoothingRefused(f"{readings.frames} frame{'s' if readings.frames != 1 else ''} kept; the smoothing "
                               f"needs at least {MIN_FRAMES}")
    if len(particle_positions) != len(exported) or not np.allclose(particle_positions, exported.positions):
        raise SmoothingRefused("the map's export with the particle's own covariances differs from the exported map")
    if not len(exported):
        raise SmoothingRefused("the filter's map holds no landmark")
    full = trajectory
    if readings.frame_index is not None:        # keyframes: the filter's rows at the frames kept
        index = np.asarray(readings.frame_index, np.int64)
        if len(index) != readings.frames or (len(index) and (index.min() < 0 or index.max() + 1 >= len(full))):
            raise SmoothingRefused(f"the filter's trajectory has {len(full)} rows, too few for the keyframes kept "
                                   f"(the last is frame {int(index.max()) if len(index) else -1})")
        trajectory = np.vstack([full[:1], full[1:][index]])
    start = time.perf_counter()
    f, j, lm = associate(readings, trajectory, exported, particle_covariances, config)
    t_assoc = time.perf_counter() - start
    if not len(f):
        raise SmoothingRefused(f"none of the {int(readings.counts.sum())} readings kept matches the filter's map")
    odo, times = readings.odometry, readings.times
    inc = between(odo[:-1], odo[1:])
    if readings.increment_covariances is None:
        var = increment_variance(inc, config, np.maximum(np.diff(times), 0.0))
    else:   # keyframes: the composed increments' variances (their x-θ, y-θ covariances are left out: the smoother's
        #     odometry factors are diagonal; module docstring, *Keyframes*)
        var = np.diagonal(readings.increment_covariances, axis1=1, axis2=2).copy()
    q = config.observation_cov_scale * readings.covariances[j] + config.observation_var_floor * np.eye(3)
    poses0 = trajectory[1:, 1:].copy()
    if np.abs(poses0[0]).max() > 1e-9:
        raise SmoothingRefused(f"the first frame's pose is {np.round(poses0[0], 6).tolist()} in the map frame, not "
                               "its origin")
    t0 = time.perf_counter()
    floor = config.observation_var_floor if landmark_floor is None else landmark_floor
    try:
        problem = StereoLogProblem(inc, var, f, lm, readings.points[j], q, len(exported))
        # the white model's estimate, its covariance under the error a landmark's readings from about one view share
        # (the sandwich at the filter's observation floor; stereo_smoothing's docstring, *The sandwich*, session 51)
        sol = smooth(problem, poses0, exported.positions, landmark_floor=floor,
                     view_floor=config.observation_var_floor, view_model="sandwich",
                     calibrate_odometry=calibrate_odometry)
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
    key_trajectory = smoothed_trajectory
    if readings.frame_index is not None:
        smoothed_trajectory = _every_frame(full, readings.frame_index, sol.poses)
    meta = dict(exported.metadata)
    meta["smoothed"] = {"readings": int(len(f)), "inliers": int(sol.inliers.sum()),
                        "chi2_per_dof": sol.chi2_per_dof, "landmarks_held": int(held.sum())}
    scale_figures = {}
    if sol.odometry_scales is not None:
        scale_figures = {"odometry_scales": [float(v) for v in sol.odometry_scales],
                         "odometry_scale_sd": [float(v) for v in np.sqrt(np.diag(sol.odometry_scale_covariance))]}
        meta["smoothed"] |= scale_figures
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
               "associate_s": t_assoc, "smooth_s": t_smooth} | scale_figures
    smoothed = SmoothedMap(m, figures, f, j, lm, sol.inliers, sol.pose_covariances)
    # the map's self-check re-run along the smoothed poses with the smoothing's association (estimation.
    # smoothed_self_check): the fusion splits the smoothed map by its own verdict, the filter's kept beside; a re-run
    # that cannot be made leaves the filter's verdict, the cautious one
    try:
        walked = m   # along the frames smoothed, whose readings it has: with keyframes, the keyframes' trajectory
        if readings.frame_index is not None:
            walked = m.subset(slice(None))
            walked.trajectory = key_trajectory
        verdict = recheck_map(walked, config, readings.points, readings.counts, f, j, lm, sol.inliers)
        m.metadata = rechecked_metadata(m.metadata, verdict)
    except SmoothedSelfCheckError:
        pass
    return smoothed


def _every_frame(trajectory: np.ndarray, index: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """The smoothed trajectory at every frame the filter's ``trajectory`` (T + 1, 4) holds, from the keyframes'
    smoothed ``poses`` (K, 3) at its frames ``index`` (K,): each frame is the filter's pose moved by the smoothing's
    correction (the map-frame transform taking the filter's pose to the smoothed one), interpolated in time between
    the keyframes around it (after the last: the last's). The keyframes' rows are their smoothed poses."""
    out = np.asarray(trajectory, float).copy()
    rows = out[1:]
    key = rows[index]
    correction = compose(poses, inverse(key[:, 1:]))
    c = interpolate_poses(np.column_stack([key[:, 0], correction]), rows[:, 0])
    rows[:, 1:] = compose(c, rows[:, 1:])
    rows[index, 1:] = poses
    return out


__all__ = ["MAX_FRAMES", "MAX_READINGS", "KeyframeRule", "ReadingsRecorder", "SmoothedMap", "SmoothingRefused",
           "StereoReadings", "associate", "compose_increment", "smoothed_map"]
