"""Replay a sensor log through the onboard pipeline, deterministically, with the same or other parameters.

The live runtime logs every SIP (``odometry``), every frame (``frames`` or, from a synthetic camera,
``observations``) and the frames its SLAM stage actually processed (``processed``). A replay feeds the same
frames, with the odometry interpolated from the logged SIPs exactly as the live SLAM thread did, through the
same :class:`~runtime.onboard.SlamCore`: with the logged settings it rebuilds the live map bit for bit; with
``every_frame`` or other settings it shows what they would have given.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimation.fastslam import FastSLAMConfig
from estimation.frontend import FrontEndConfig, HarrisConfig, StereoGeometry
from estimation.landmark_map import LandmarkMap
from estimation.observations import StereoObservations
from runtime.onboard import CameraFrame, OdometryBuffer, OnboardConfig, SlamCore
from runtime.sensorlog import SensorLog, SensorLogError


@dataclass
class ReplayResult:
    robot: str
    landmark_map: LandmarkMap
    frames: int
    skipped_without_odometry: int
    seconds: float                       # wall time of the replay
    log_span: float                      # seconds of sensor time replayed
    stage_seconds: dict[str, float]
    final_pose: np.ndarray
    missing_frames: int = 0              # frames the live run processed that the log does not hold (the writer
                                         # dropped them, or a crash cut them): the map then differs from live

    @property
    def speed(self) -> float:
        """How many times faster than real time the replay ran."""
        return self.log_span / self.seconds if self.seconds > 0 else float("inf")


def onboard_config_from_log(log: SensorLog, *, particles: int | None = None, seed: int | None = None,
                            fastslam_overrides: dict | None = None) -> OnboardConfig:
    """The settings the live run used (from the log's metadata), with any overrides."""
    meta = log.metadata
    try:
        fastslam = FastSLAMConfig.from_dict(dict(meta.get("fastslam") or {}))
        geometry = StereoGeometry.from_dict(meta["geometry"]) if meta.get("geometry") else None
        harris = meta.get("harris")
        harris = HarrisConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in harris.items()}) \
            if harris else HarrisConfig()
    except (KeyError, TypeError, ValueError) as e:
        raise SensorLogError(f"{log.folder}: metadata field 'settings' holds bad settings ({e})") from None
    changes = dict(fastslam_overrides or {})
    if particles is not None:
        changes["n_particles"] = particles
    if changes:
        try:
            fastslam = dataclasses.replace(fastslam, **changes)
        except TypeError as e:
            raise ValueError(f"unknown FastSLAM setting: {e}") from None
    frontend = FrontEndConfig(harris=harris, **({} if geometry is None else {"geometry": geometry}))
    return OnboardConfig(fastslam=fastslam, frontend=frontend, seed=int(meta.get("seed", 0) if seed is None else seed))


def _frames(log: SensorLog, descriptor_size: int):
    if log.count("observations"):
        for r in log.records("observations"):
            t = float(r["t"])
            if len(r["points"]) and r["descriptors"].shape[1] != descriptor_size:  # the filter's error named no file
                raise SensorLogError(f"{log.folder}: the observations at {t:.3f} s carry "
                                     f"{r['descriptors'].shape[1]}-element descriptors; the log's settings give "
                                     f"{descriptor_size}")
            yield CameraFrame(t, int(r["seq"]), observations=StereoObservations(
                np.asarray(r["points"], float).reshape(-1, 3), np.asarray(r["covariances"], float).reshape(-1, 3, 3),
                np.asarray(r["descriptors"], np.float32),
                np.asarray(r["pixels"], float).reshape(-1, 2), t))
    else:
        for r in log.records("frames"):
            yield CameraFrame(float(r["t"]), int(r["seq"]), np.asarray(r["left"]), np.asarray(r["right"]))


def core_and_odometry(log: SensorLog, config: OnboardConfig) -> tuple[SlamCore, OdometryBuffer]:
    """A fresh SlamCore for the log's robot (its true start, where the log has one, in the map's metadata) and the
    log's SIPs in an OdometryBuffer, from which each frame's odometry is interpolated as the live SLAM thread did."""
    core = SlamCore(str(log.metadata.get("robot", "robot")), config)
    if log.metadata.get("true_start_pose") is not None:
        core.metadata["true_start_pose"] = [float(v) for v in log.metadata["true_start_pose"]]
    odometry = OdometryBuffer(horizon=max(1, log.count("odometry")))
    for r in log.records("odometry"):
        odometry.add(float(r["t"]), np.array([float(r["x"]), float(r["y"]), float(r["theta"])]))
    return core, odometry


def replay_log(log: str | Path | SensorLog, config: OnboardConfig | None = None, *, every_frame: bool = False,
               on_frame=None) -> ReplayResult:
    """Run a sensor log (a path or an open :class:`SensorLog`) through a fresh SlamCore (``config``: default,
    the logged settings)."""
    log = log if isinstance(log, SensorLog) else SensorLog(log)
    config = config or onboard_config_from_log(log)
    core, odometry = core_and_odometry(log, config)
    processed = None if every_frame else {int(r["seq"]) for r in log.records("processed")}
    start = time.perf_counter()
    frames = skipped = 0
    replayed_seqs: set[int] = set()
    t_first = t_last = None
    pose = np.zeros(3)
    for frame in _frames(log, config.fastslam.descriptor_size):
        if processed is not None and frame.seq not in processed:
            continue
        replayed_seqs.add(frame.seq)
        odometry_pose = odometry.interpolate(frame.t)
        if odometry_pose is None:
            skipped += 1
            continue
        result = core.step(frame, odometry_pose)
        pose = result.best_pose
        frames += 1
        t_first = frame.t if t_first is None else t_first
        t_last = frame.t
        if on_frame is not None:
            on_frame(result)
    elapsed = time.perf_counter() - start
    span = 0.0 if t_first is None else t_last - t_first
    missing = 0 if processed is None else len(processed - replayed_seqs)
    return ReplayResult(core.robot, core.best_map(), frames, skipped, elapsed, span, dict(core.totals), pose, missing)




__all__ = ["ReplayResult", "core_and_odometry", "onboard_config_from_log", "replay_log"]
