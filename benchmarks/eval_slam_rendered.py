"""FastSLAM on rendered frames through the real front end: offline, deterministic, no drivers or threads.

Run from the repository root:

    .venv/bin/python -m benchmarks.eval_slam_rendered [--seconds 60] [--robots robot1,robot2] [--seed 0]
        [--frame-rate 5] [--max-corners 150] [--particles 100] [--diagnose] [--json] [--set key=value ...]
        [--frames-cache DIR] [--descriptor-depth M]

Each robot drives its world route (moved to the right of travel as the mission does) with
``runtime.slam_sim.simulate`` in simulated time and the synthetic odometry's realistic errors (2 % distance,
3 % turning scale, random walk); its observer renders the virtual head's raw stereo pair at the true pose
(``mocks.stereo_head.renderer.StereoRenderer``, radiance ×255 + σ = 1 DN noise), rectifies it and runs the real
front end (``estimation.frontend.FrontEnd``, Harris + U-SURF) to get ``StereoObservations``.

Ground truth for the observations: the world point behind each observation's left pixel
(``StereoRenderer.true_points``). Each observation is tagged with the index of its nearest *surface point
cluster* (the first true point seen within 5 cm), so the map's duplicates (landmarks minus distinct true points
they stand for) and landmark errors are scored by ``simulate`` as for the synthetic sensor.

Prints per robot: ATE and final position error of FastSLAM beside dead reckoning, map size and duplicates,
landmark error, CPU time per update; with ``--json`` also the best particle's matches that joined two true points
(``slam_consistency.association_scores``), overall and by the range ratio to the landmark's first sighting, and
the exported map's merges of coincident landmarks (``export_merges``; ``export_merges_wrong``: the true points behind
the two first sightings > 10 cm apart; ``FastSLAMConfig.export_merge_coincident``).
``--diagnose`` adds: observations per frame, the share that re-associate to an existing landmark in the best
particle, the observations' 3-D NEES against their covariances, and the descriptor distance between
observations of the same true point at different viewing distances.
The filter is configured as the runtime's (``runtime.mission.MissionConfig``): every reading of a frame
(``max_observations=0``), not FastSLAMConfig's own cap of the 40 nearest, so the figures are the demo's robots'.
(Until session 18 the cap applied here, and the rendered NEES and duplicates in docs/fastslam-history.md's tables of
sessions 17–18 were measured with it: ``--set max_observations=40`` gives them again.)
``--set`` overrides any FastSLAMConfig field (e.g. ``--set descriptor_threshold=0.7``).
``--frames-cache DIR`` keeps each robot's observations (and their true points) in DIR the first time and replays
them afterwards: the observer's frames depend only on the true route and the seed, not on the filter, so a
replay gives the same scores as rendering, minutes faster (a replay checks every frame's pose and time).
``--descriptor-depth M`` (an experiment on the front end, off by default): every observation is described again
with U-SURF at s = scale · M / z, z its depth, i.e. a window of fixed physical size instead of fixed pixels.
"""
from __future__ import annotations

import argparse
import io
import json
import sys
import time
import zipfile
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

import runtime.slam_sim as slam_sim
from benchmarks.config_overrides import config_overrides
from benchmarks.slam_consistency import association_scores, landmark_scores, merge_scores
from drivers.fileio import atomic_write_bytes
from estimation.fastslam import FastSLAM, FastSLAMConfig
from estimation.frontend import FrontEndConfig, HarrisConfig
from estimation.geometry import between, compose
from estimation.observations import StereoObservations
from runtime.commands.features import front_end_from_calibration
from runtime.commands.options import non_negative_float, non_negative_int, particle_count, positive_float, positive_int
from runtime.mission import MissionConfig
from runtime.motion import keep_right

ROOT = Path(__file__).resolve().parents[1]
CALIBRATION = ROOT / "mocks" / "stereo_head" / "data" / "sth_mdcs2_default.ini"
SNAP = 0.05  # m: true points closer than this on a grid count as the same physical point


class RenderedObserver:
    """``observe(pose, t) -> (StereoObservations, point_index)`` from rendered frames through the front end.

    point_index (N,) indexes ``self.points`` (K, 3), the distinct true world points seen so far (snapped to a
    ``SNAP`` grid); -1 where the pixel's ray meets nothing. Records per-frame diagnostics when ``diagnose``.
    """

    def __init__(self, world, rng: np.random.Generator, max_corners: int = 150, noise_dn: float = 1.0,
                 diagnose: bool = False, latency: float = 0.0, descriptor_depth: float = 0.0) -> None:
        from drivers.videre import calibration
        from mocks.stereo_head.renderer import StereoRenderer

        calib = calibration.load(CALIBRATION)
        self.renderer = StereoRenderer(world, calib)
        self.front_end = front_end_from_calibration(
            calib, FrontEndConfig(harris=HarrisConfig(max_corners=max_corners)))
        self.rng = rng
        self.noise_dn = noise_dn
        self.diagnose = diagnose
        self._cell_index: dict[tuple[int, int, int], list[int]] = {}
        self._points: list[np.ndarray] = []
        self.frames: list[dict] = []          # per frame: n, nees (N,), depth (N,), index (N,), desc (N, D)
        self.indices: list[np.ndarray] = []   # per frame: the true point index of each observation
        self.frontend_seconds = 0.0
        self.latency = latency
        self.descriptor_depth = descriptor_depth
        self._previous: tuple[float, np.ndarray] | None = None

    @property
    def points(self) -> np.ndarray:
        return np.array(self._points, float).reshape(-1, 3)

    def _point_index(self, p: np.ndarray) -> int:
        """Index of the known true point within SNAP of p (the nearest), or of p added as a new one."""
        cell = np.floor(p / SNAP).astype(int)
        best, best_d = -1, SNAP
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for dz in (-1, 0, 1):
                    for i in self._cell_index.get((cell[0] + dx, cell[1] + dy, cell[2] + dz), ()):
                        d = float(np.linalg.norm(self._points[i] - p))
                        if d < best_d:
                            best, best_d = i, d
        if best < 0:
            best = len(self._points)
            self._points.append(p)
            self._cell_index.setdefault(tuple(int(c) for c in cell), []).append(best)
        return best

    def _described_at_depth(self, left: np.ndarray, right: np.ndarray, obs: StereoObservations) -> StereoObservations:
        """The frame's observations re-described with U-SURF at s = scale · descriptor_depth / z (z the point's depth
        in the camera): a window of fixed physical size, so a point looks the same from any distance as far as the
        images resolve it. Corners whose window leaves the image are dropped (as the front end drops them)."""
        from estimation.frontend.pipeline import rectify_pair
        from estimation.frontend.usurf import usurf_descriptors

        rectified, _ = rectify_pair(left, right, self.front_end.rectification)
        depth = self.front_end.last_matches.points_camera[:, 2]
        scale = np.round(4.0 * np.clip(self.front_end.config.scale * self.descriptor_depth / depth, 1.0, 8.0)) / 4.0
        desc = np.zeros((len(obs), np.asarray(obs.descriptors).shape[1]), np.float32)
        described = np.zeros(len(obs), bool)
        for s in np.unique(scale):               # U-SURF describes at one scale a call: a quarter-pixel grid of s
            group = np.flatnonzero(scale == s)
            d, ok = usurf_descriptors(rectified, obs.pixels[group], float(s))
            desc[group[ok]], described[group[ok]] = d, True
        return StereoObservations(obs.points[described], obs.covariances[described], desc[described],
                                  obs.pixels[described], obs.timestamp)

    def observe(self, pose, timestamp: float = 0.0):
        pose = np.asarray(pose, float)
        truth_pose = pose
        if self.latency > 0 and self._previous is not None:
            # the image was taken ``latency`` s before its time stamp: the pose on the way from the last frame
            t_prev, p_prev = self._previous
            f = max(0.0, 1.0 - self.latency / max(timestamp - t_prev, 1e-9))
            step = between(p_prev, pose)
            pose = compose(p_prev, step * f)
        self._previous = (float(timestamp), truth_pose)
        left, right = (np.clip(np.rint(im * 255.0 + self.rng.normal(0.0, self.noise_dn, im.shape)), 0, 255)
                       .astype(np.uint8) for im in self.renderer.render(pose))
        t0 = time.process_time()
        obs = self.front_end.process(left, right, float(timestamp))
        if self.descriptor_depth > 0:
            obs = self._described_at_depth(left, right, obs)
        self.frontend_seconds += time.process_time() - t0
        truth = self.renderer.true_points(pose, obs.pixels, "left", rectified=True)
        index = np.full(len(obs), -1, np.int64)
        for j, p in enumerate(truth):
            if np.all(np.isfinite(p)):
                index[j] = self._point_index(p)
        self.indices.append(index)
        if self.diagnose:
            c, s = np.cos(pose[2]), np.sin(pose[2])
            d = truth - np.array([pose[0], pose[1], 0.0])
            truth_base = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]])
            err = obs.points - truth_base
            ok = np.all(np.isfinite(err), axis=1)
            nees = np.full(len(obs), np.nan)
            if ok.any():
                solved = np.linalg.solve(obs.covariances[ok], err[ok][..., None])[..., 0]
                nees[ok] = np.einsum("ni,ni->n", err[ok], solved)
            self.frames.append({"n": len(obs), "nees": nees, "depth": obs.points[:, 0].copy(), "index": index,
                                "desc": np.asarray(obs.descriptors, np.float32).copy(),
                                "err": np.linalg.norm(err, axis=1)})
        return obs, index


class RecordingRenderedObserver:
    """Wraps a :class:`RenderedObserver`; keeps every frame's observations, true-point index, pose and time."""

    def __init__(self, observer: RenderedObserver) -> None:
        self.observer = observer
        self.frames: list[tuple[float, np.ndarray, StereoObservations, np.ndarray]] = []

    @property
    def points(self) -> np.ndarray:
        return self.observer.points

    @property
    def indices(self) -> list[np.ndarray]:
        return self.observer.indices

    @property
    def frontend_seconds(self) -> float:
        return self.observer.frontend_seconds

    def observe(self, pose, timestamp: float = 0.0):
        obs, index = self.observer.observe(pose, timestamp)
        self.frames.append((float(timestamp), np.asarray(pose, float).copy(), obs, index))
        return obs, index

    def save(self, path: Path) -> None:
        """All frames in one .npz (plain arrays, concatenated with per-frame counts), written atomically."""
        def cat(field: str, shape: tuple[int, ...]) -> np.ndarray:   # in the front end's own dtype
            parts = [np.asarray(getattr(f[2], field)).reshape(-1, *shape) for f in self.frames]
            return np.concatenate(parts) if parts else np.zeros((0, *shape))
        arrays = {
            "t": np.array([f[0] for f in self.frames]), "pose": np.array([f[1] for f in self.frames]).reshape(-1, 3),
            "count": np.array([len(f[2]) for f in self.frames], np.int64),
            "points": cat("points", (3,)), "covariances": cat("covariances", (3, 3)),
            "descriptors": cat("descriptors", (self.frames[0][2].descriptors.shape[1],) if self.frames else (0,)),
            "pixels": cat("pixels", (2,)),
            "index": np.concatenate([f[3] for f in self.frames]).astype(np.int64),
            "true_points": self.points}
        buffer = io.BytesIO()
        np.savez(buffer, **arrays)
        atomic_write_bytes(path, buffer.getvalue())


class ReplayObserver:
    """Replays a :class:`RecordingRenderedObserver`'s file; ``observe`` checks that the pose and time match."""

    def __init__(self, path: Path) -> None:
        try:
            with np.load(path, allow_pickle=False) as data:
                arrays = {k: data[k] for k in data.files}
            arrays["count"], arrays["t"], arrays["pose"]   # noqa: B018 - the fields a replay needs first
        except (OSError, ValueError, KeyError, zipfile.BadZipFile) as error:
            raise SystemExit(f"{path}: not a frames cache ({error}); delete it to render again") from None
        self._arrays = arrays
        self._starts = np.concatenate([[0], np.cumsum(arrays["count"])])
        self._frame = 0
        self.indices: list[np.ndarray] = []
        self.frontend_seconds = 0.0
        self.points = arrays["true_points"].reshape(-1, 3)

    def observe(self, pose, timestamp: float = 0.0):
        a, i = self._arrays, self._frame
        if i >= len(a["t"]) or abs(a["t"][i] - timestamp) > 1e-9 or not np.allclose(a["pose"][i], pose, atol=1e-9):
            raise SystemExit(f"frames cache: frame {i} does not match the route (delete the cache file)")
        lo, hi = self._starts[i], self._starts[i + 1]
        self._frame += 1
        index = a["index"][lo:hi]
        self.indices.append(index)
        return StereoObservations(a["points"][lo:hi], a["covariances"][lo:hi], a["descriptors"][lo:hi],
                                  a["pixels"][lo:hi], float(timestamp)), index


def runtime_config(particles: int = 100, version: int = 2) -> FastSLAMConfig:
    """The filter the robots run (``runtime.mission``): every reading of a frame (``MissionConfig.max_observations``),
    not FastSLAMConfig's own cap of the 40 nearest."""
    return FastSLAMConfig(n_particles=particles, version=version, max_observations=MissionConfig.max_observations)


def replay_default_run(world, robot: str, seed: int, frame_rate: float, frames_cache: Path
                       ) -> tuple[ReplayObserver, np.ndarray, np.ndarray]:
    """The diagnostics' replay of one robot's default run (150 corners, no latency, 300 s) from the frames cache:
    (observer, its kept-right route, its true start pose); a one-line exit when the cache was never made."""
    cache = frames_cache / f"{robot}-seed{seed}-{frame_rate:g}hz-150c-0s-300s.npz"
    if not cache.exists():
        raise SystemExit(f"{cache}: no frames cache (make it with eval_slam_rendered --frames-cache)")
    return (ReplayObserver(cache), keep_right(np.asarray(world.routes[robot], float)),
            np.asarray(world.start_poses[robot], float))


def replay_through(filter_class, world, robot: str, seed: int, frame_rate: float, frames_cache: Path,
                   config: FastSLAMConfig):
    """The default run of ``robot`` replayed from the frames cache through ``filter_class`` (a FastSLAM subclass
    that records what the diagnosis needs and keeps its last instance as ``filter_class.last``):
    (observer, true start pose, the simulation's result, the filter)."""
    observer, route, start = replay_default_run(world, robot, seed, frame_rate, frames_cache)
    original = slam_sim.FastSLAM
    slam_sim.FastSLAM = filter_class   # simulate() builds its filter by this name
    try:
        result = slam_sim.simulate(_PointWorld(world, observer), start_pose=start, route=route, seconds=300.0,
                                   seed=seed, config=config, robot=robot, frame_rate=frame_rate, observer=observer)
    finally:
        slam_sim.FastSLAM = original
    return observer, start, result, filter_class.last


class _PointWorld:
    """The world as ``simulate`` scores it, with ``features`` = the observer's distinct true points."""

    def __init__(self, world, observer: RenderedObserver) -> None:
        self._world, self._observer = world, observer

    @property
    def features(self) -> np.ndarray:
        return self._observer.points

    def __getattr__(self, name):
        return getattr(self._world, name)


class _TimedFastSLAM(FastSLAM):
    """FastSLAM that records the CPU time and the report of every update (for the diagnostics)."""

    instances: list[_TimedFastSLAM] = []
    observer = None   # the run's observer (set by run_robot): its ``indices[-1]`` is the current frame's truth

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.update_seconds: list[float] = []
        self.reports = []
        self.ranges: list[np.ndarray] = []   # per update: each observation's range from the sensor (m)
        _TimedFastSLAM.instances.append(self)

    def update(self, observations):
        t0 = time.process_time()
        report = super().update(observations)
        self.update_seconds.append(time.process_time() - t0)
        self.reports.append(report)
        self.ranges.append(np.linalg.norm(np.asarray(observations.points) - self.config.sensor_offset, axis=1))
        return report


def run_robot(world, robot: str, *, seconds: float, seed: int, config: FastSLAMConfig, frame_rate: float,
              max_corners: int, diagnose: bool, latency: float = 0.0, frames_cache: Path | None = None,
              descriptor_depth: float = 0.0, filter_class: type[_TimedFastSLAM] | None = None) -> dict:
    """One robot's run; returns the scores (and diagnostics). ``filter_class``: a subclass of the timed filter
    (diagnostics that look at the truth while the filter runs, e.g. ``benchmarks.merge_oracle``)."""
    filter_class = filter_class or _TimedFastSLAM
    cache = None
    if frames_cache is not None:
        depth = f"-desc{descriptor_depth:g}m" if descriptor_depth > 0 else ""
        name = f"{robot}-seed{seed}-{frame_rate:g}hz-{max_corners}c-{latency:g}s-{seconds:g}s{depth}"
        cache = frames_cache / f"{name}.npz"
    if cache is not None and cache.exists():
        if diagnose:
            raise SystemExit("--diagnose needs the rendered frames' truth: run it without --frames-cache")
        observer = ReplayObserver(cache)
    else:
        observer = RenderedObserver(world, np.random.default_rng([seed, 1]), max_corners, diagnose=diagnose,
                                    latency=latency, descriptor_depth=descriptor_depth)
        if cache is not None:
            observer = RecordingRenderedObserver(observer)
    route = keep_right(np.asarray(world.routes[robot], float))
    start = np.asarray(world.start_poses[robot], float)
    original = slam_sim.FastSLAM
    slam_sim.FastSLAM = filter_class   # simulate() builds its filter by this name; measure its updates
    filter_class.observer = observer
    try:
        _TimedFastSLAM.instances.clear()
        result = slam_sim.simulate(_PointWorld(world, observer), start_pose=start, route=route, seconds=seconds,
                                   seed=seed, config=config, robot=robot, frame_rate=frame_rate,
                                   observer=observer)
    finally:
        slam_sim.FastSLAM = original
    if isinstance(observer, RecordingRenderedObserver):
        cache.parent.mkdir(parents=True, exist_ok=True)
        observer.save(cache)
        observer = observer.observer
    slam = _TimedFastSLAM.instances[-1]
    m = result.metrics
    times = np.array(slam.update_seconds) * 1e3
    out = {"robot": robot, **{k: m[k] for k in (
        "seconds", "frames", "ate_m", "dead_reckoning_ate_m", "final_position_error_m",
        "dead_reckoning_final_position_error_m", "landmarks", "distinct_features", "duplicate_landmarks",
        "landmark_median_error_m", "landmark_rms_error_m")},
        "update_ms_median": float(np.median(times)), "update_ms_mean": float(np.mean(times)),
        "update_ms_p90": float(np.percentile(times, 90)),
        **{k: v for k, v in landmark_scores(result.map, start, observer.points, slam.reports, observer.indices).items()
           if k != "landmark_nees"},
        "pose_nees_median": m["pose_nees_median"], "pose_nees_within_bound": m["pose_nees_within_chi2_95"],
        "pose_nees_drift_median": m["pose_nees_drift_median"],
        "pose_nees_drift_within_bound": m["pose_nees_drift_within_chi2_95"],
        "stats": vars(slam.stats).copy() if hasattr(slam, "stats") else {},
        **merge_scores(getattr(slam, "merged_pairs", []), observer.points, slam.reports, observer.indices),
        **{f"export_{k}": v for k, v in merge_scores(
            [(a, b, False) for a, b in result.map.metadata.get("merged_at_export", [])], observer.points,
            slam.reports, observer.indices).items() if "covisibility" not in k},
        **association_scores(slam.reports, observer.indices, observer.points, slam.ranges),
        "frontend_ms_mean": 1e3 * observer.frontend_seconds / max(1, m["frames"]),
        "observations_per_frame": float(np.mean([r.n_observations for r in slam.reports]))}
    if diagnose:
        out["diagnostics"] = _diagnostics(observer, slam)
    return out


def _diagnostics(observer: RenderedObserver, slam: _TimedFastSLAM) -> dict:
    frames = observer.frames
    reports = slam.reports
    n = np.array([f["n"] for f in frames])
    matched = np.array([np.mean(r.best_matches >= 0) if r.n_observations else np.nan for r in reports])
    # an observation of a true point seen before (in an earlier frame) should re-associate
    seen: set[int] = set()
    reobs, reobs_matched = 0, 0
    for f, r in zip(frames, reports, strict=True):
        for j, idx in enumerate(f["index"]):
            if idx < 0:
                continue
            if idx in seen:
                reobs += 1
                reobs_matched += int(r.best_matches[j] >= 0)
        seen.update(int(i) for i in f["index"] if i >= 0)
    # association truth: the true point behind a matched observation vs behind the landmark's first sighting
    points = observer.points
    origin: dict[int, int] = {}
    slide = []
    for f, r in zip(frames, reports, strict=True):
        for j in np.flatnonzero(r.best_matches >= 0):
            first_point = origin.get(int(r.best_matches[j]), -1)
            if first_point >= 0 and f["index"][j] >= 0:
                slide.append(float(np.linalg.norm(points[f["index"][j]] - points[first_point])))
        for j in np.flatnonzero(r.new_landmark_ids >= 0):
            origin[int(r.new_landmark_ids[j])] = int(f["index"][j])
    slide = np.array(slide)
    nees = np.concatenate([f["nees"] for f in frames])
    nees = nees[np.isfinite(nees)]
    err = np.concatenate([f["err"] for f in frames])
    depth = np.concatenate([f["depth"] for f in frames])
    ok = np.isfinite(err)
    # descriptor distance between the first sighting of a true point and later sightings, by depth ratio
    first: dict[int, tuple[np.ndarray, float]] = {}
    pairs = []
    for f in frames:
        for j, idx in enumerate(f["index"]):
            if idx < 0:
                continue
            if idx not in first:
                first[int(idx)] = (f["desc"][j], f["depth"][j])
            else:
                d0, z0 = first[int(idx)]
                pairs.append((float(np.linalg.norm(f["desc"][j] - d0)), f["depth"][j] / z0))
    pairs = np.array(pairs).reshape(-1, 2)
    by_ratio = {}
    for lo, hi in ((0.0, 0.8), (0.8, 0.95), (0.95, 1.05), (1.05, 1.25), (1.25, 1e9)):
        sel = (pairs[:, 1] >= lo) & (pairs[:, 1] < hi)
        if sel.any():
            d = pairs[sel, 0]
            by_ratio[f"{lo:.2f}-{hi:.2f}"] = {"n": int(sel.sum()), "median": float(np.median(d)),
                                              "p90": float(np.percentile(d, 90)),
                                              "below_0.5": float(np.mean(d < 0.5))}
    # random (different point) descriptor distances for comparison
    desc = np.concatenate([f["desc"] for f in frames[:: max(1, len(frames) // 20)]])
    rng = np.random.default_rng(0)
    a, b = rng.integers(0, len(desc), (2, 2000))
    random_d = np.linalg.norm(desc[a] - desc[b], axis=1)
    bins = [(0, 2), (2, 4), (4, 6), (6, 13)]
    err_by_depth = {f"{lo}-{hi} m": {"n": int(((depth >= lo) & (depth < hi) & ok).sum()),
                                    "median_err_m": float(np.median(err[ok & (depth >= lo) & (depth < hi)]))
                                    if ((depth >= lo) & (depth < hi) & ok).any() else float("nan")}
                    for lo, hi in bins}
    return {
        "observations_per_frame": float(n.mean()),
        "best_particle_matched_share": float(np.nanmean(matched)),
        "new_landmarks_per_frame_mean_over_particles": float(np.mean([r.new_landmarks for r in reports])),
        "reobservations": reobs, "reobservations_matched_share": reobs_matched / max(1, reobs),
        "matches_true_point_offset_median_m": float(np.median(slide)) if len(slide) else float("nan"),
        "matches_true_point_offset_p90_m": float(np.percentile(slide, 90)) if len(slide) else float("nan"),
        "matches_wrong_share_over_0.2m": float(np.mean(slide > 0.2)) if len(slide) else float("nan"),
        "obs_nees_median": float(np.median(nees)), "obs_nees_mean": float(np.mean(nees)),
        "obs_nees_below_7.81": float(np.mean(nees < 7.815)), "obs_nees_p90": float(np.percentile(nees, 90)),
        "obs_err_median_m": float(np.median(err[ok])), "obs_err_p90_m": float(np.percentile(err[ok], 90)),
        "obs_err_by_depth": err_by_depth,
        "descriptor_distance_same_point_by_depth_ratio": by_ratio,
        "descriptor_distance_random_pairs": {"median": float(np.median(random_d)),
                                             "p10": float(np.percentile(random_d, 10)),
                                             "below_0.5": float(np.mean(random_d < 0.5))},
        "ess_median": float(np.median([r.ess for r in reports])),
        "resampled_share": float(np.mean([r.resampled for r in reports])),
    }


# The printed table, one (header, cell) pair per column: the header and the rows cannot disagree on the columns.
COLUMNS: tuple[tuple[str, Callable[[dict], str]], ...] = (
    ("robot", lambda r: f"{r['robot']}"),
    ("s", lambda r: f"{r['seconds']:.0f}"),
    ("ATE (m)", lambda r: f"{r['ate_m']:.3f}"),
    ("DR ATE (m)", lambda r: f"{r['dead_reckoning_ate_m']:.3f}"),
    ("final err (m)", lambda r: f"{r['final_position_error_m']:.3f}"),
    ("DR final (m)", lambda r: f"{r['dead_reckoning_final_position_error_m']:.3f}"),
    ("landmarks", lambda r: f"{r['landmarks']}"),
    ("distinct points", lambda r: f"{r['distinct_features']}"),
    ("duplicates", lambda r: f"{r['duplicate_landmarks']}"),
    ("landmark median / RMS err (m)",
     lambda r: f"{r['landmark_median_error_m']:.3f} / {r['landmark_rms_error_m']:.3f}"),
    ("obs/frame", lambda r: f"{r['observations_per_frame']:.1f}"),
    ("update ms median / p90", lambda r: f"{r['update_ms_median']:.1f} / {r['update_ms_p90']:.1f}"),
    ("duplicate fraction", lambda r: f"{100 * r['duplicate_fraction']:.1f} %"),
    ("landmark NEES median / < χ²₃ 95 %",
     lambda r: f"{r['landmark_nees_median']:.1f} / {100 * r['landmark_nees_within_bound']:.0f} %"),
    ("pose NEES median / < χ²₃ 95 %",
     lambda r: f"{r['pose_nees_median']:.1f} / {100 * r['pose_nees_within_bound']:.0f} %"),
    ("merges (co-visibility)", lambda r: f"{r['merges']} ({r['merges_by_covisibility']})"),
    ("merged 5-10 cm / wrong > 10 cm", lambda r: f"{r['merges_5_to_10cm']} / {r['merges_wrong']}"),
)


def table(rows: list[dict]) -> list[str]:
    """The Markdown table of run_robot's rows: header, separator and one line per row, all from COLUMNS."""
    def line(cells) -> str:
        return "| " + " | ".join(cells) + " |"

    return [line(h for h, _ in COLUMNS), "|" + "---|" * len(COLUMNS), *(line(f(r) for _, f in COLUMNS) for r in rows)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=positive_float, default=300.0,
                        help="simulated time limit (the route ends first)")
    parser.add_argument("--robots", default="robot1,robot2", help="comma-separated world route names")
    parser.add_argument("--seed", type=non_negative_int, default=0)
    parser.add_argument("--frame-rate", type=positive_float, default=5.0)
    parser.add_argument("--max-corners", type=positive_int, default=150, help="Harris corners per image (runtime: 150)")
    parser.add_argument("--particles", type=particle_count, default=100)
    parser.add_argument("--fastslam", type=positive_int, choices=(1, 2), default=2)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a FastSLAMConfig field")
    parser.add_argument("--latency", type=non_negative_float, default=0.0,
                        help="s between the image and its time stamp (the pose is interpolated; default 0)")
    parser.add_argument("--diagnose", action="store_true", help="association and noise diagnostics")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--frames-cache", type=Path, default=None, metavar="DIR",
                        help="keep the rendered observations in DIR and replay them on later runs (same scores)")
    parser.add_argument("--descriptor-depth", type=non_negative_float, default=0.0, metavar="M",
                        help="experiment: re-describe every observation with U-SURF at scale·M/depth (a window of "
                             "fixed physical size) instead of the front end's fixed scale; 0 (default): off")
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    from mocks.world import World

    world = World.load()
    config = replace(runtime_config(args.particles, args.fastslam), **config_overrides(args.set))
    rows = [run_robot(world, robot, seconds=args.seconds, seed=args.seed, config=config,
                      frame_rate=args.frame_rate, max_corners=args.max_corners, diagnose=args.diagnose,
                      latency=args.latency, frames_cache=args.frames_cache, descriptor_depth=args.descriptor_depth)
            for robot in args.robots.split(",")]
    if args.json:
        print(json.dumps({"config": config.to_dict(), "rows": rows}, indent=2))
        return 0
    print(f"FastSLAM {args.fastslam}.0, {args.particles} particles, rendered frames at {args.frame_rate:g} Hz, "
          f"{args.max_corners} corners, seed {args.seed}")
    print("\n".join(table(rows)))
    for r in rows:
        if "diagnostics" in r:
            print(f"\n{r['robot']} diagnostics:")
            print(json.dumps(r["diagnostics"], indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
