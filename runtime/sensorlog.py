"""Sensor logs: one robot's raw streams as MCAP files with ROS 2 message types, for deterministic replay.

A log is a folder of segments, ``LOG/<LOG>_<k>.mcap`` (k = 0, 1, ...; the naming of ``ros2 bag``), each a
complete MCAP file (profile ``ros2``, CDR, zstd chunks) that Foxglove, ``ros2 bag``, Rerun's MCAP loader, the
``mcap`` CLI and ``rosbags`` open without this project. Topics, for robot ``R`` (frames ``R/odom``,
``R/base_link``, ``R/stereo_left_optical``, ``R/stereo_right_optical``, ``R/sonar_<i>``)::

    /R/sip                                  p3at_msgs/RawSip          every SIP: bytes + the runtime's odometry
    /R/odom                                 nav_msgs/Odometry         the same odometry, for other tools
    /tf                                     tf2_msgs/TFMessage        R/odom -> R/base_link at every SIP
    /tf_static                              tf2_msgs/TFMessage        camera and sonar mounts (each segment)
    /R/sonar/sonar_<i>                      sensor_msgs/Range         one per sonar per SIP (+inf: no echo)
    /R/stereo/{left,right}/image_rect/compressed  sensor_msgs/CompressedImage  lossless PNG of the rectified pair
    /R/stereo/{left,right}/camera_info      sensor_msgs/CameraInfo    the rectified geometry (right: P[3]=-fx·B)
    /R/stereo/frame                         p3at_msgs/FrameStamp      each frame's counter and exact stamp
    /R/stereo/observations                  p3at_msgs/StereoObservations   a synthetic camera's observations
    /R/slam/processed                       p3at_msgs/FrameStamp      the frames the live SLAM stage processed

Header stamps and MCAP log times are integer ns. In simulated time they are the runtime's clock (sim time from
0, as ROS's ``use_sim_time`` expects); on the wall clock (a real robot, ``--realtime``) they are on the epoch, as
ROS stamps: the runtime's clock plus ``epoch_offset_ns``, an offset read once when the writer starts (never again:
the epoch clock jumps) and recorded in the settings, so that ``log_time - epoch_offset_ns`` is the runtime's clock
in ns exactly. The custom types also carry the runtime's clock as float64 seconds, exactly as the runtime used it,
so that replay is bit-exact. The run's settings (robot, camera, geometry, FastSLAM, seed...) are an MCAP metadata
record ``p3at-sensor-log`` (key ``settings``, JSON).

Images are PNG, not JPEG: replay must feed the front end the very pixels the live run saw, and a lossy
image would give another map. Crash safety: the segment being written is ``<LOG>_<k>.mcap.part``; it is
closed, fsynced and renamed (then the folder fsynced) every ``segment_seconds`` of log time and at the end.
A ``.part`` left by a crash is itself read up to its last complete chunk (the writer flushes a chunk every
``flush_interval`` s of log time), so a SIGKILL loses at most the last ``flush_interval`` seconds.

Writing happens on the writer's own thread: a driver's callback only appends to a queue; records not yet on
disk are bounded in bytes (records beyond the budget are counted in ``dropped``, never block the caller).
The reader checks everything before use: record lengths against the file's size, chunk sizes against a bound
before decompressing, counts inside each message against its length, finiteness, image sizes before decoding.
"""
from __future__ import annotations

import io
import json
import math
import os
import queue
import re
import struct
import sys
import threading
import time
import zlib
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, fields, replace
from pathlib import Path

import cv2
import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.exceptions import EndOfFile, McapError, RecordLengthLimitExceeded
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter

from estimation.fastslam.config import FastSLAMConfig
from estimation.fastslam.motion import increment_variance, propagate_covariance
from estimation.frontend import StereoGeometry
from estimation.geometry import between
from runtime import ros2_messages as ros
from runtime.limits import MAX_PARTICLES
from runtime.textfile import not_a_file

METADATA_NAME = "p3at-sensor-log"
FORMAT_VERSION = 2                       # 1 was the npz-chunk folder (dropped)
MAX_CHUNK_BYTES = 64 << 20               # a decompressed chunk larger than this is refused (ours are ~1 MiB)
MAX_IMAGE_PIXELS = 4096 * 4096
MAX_OBSERVATIONS = 100_000
MAX_DESCRIPTOR = 4096
SONAR_FIELD_OF_VIEW = 0.26               # rad, the P3-AT's sonar cone (full width)
SONAR_MIN_RANGE, SONAR_MAX_RANGE = 0.1, 5.0   # m
STREAMS = ("odometry", "frames", "observations", "processed")


class SensorLogError(ValueError):
    """A sensor log is missing, malformed or of an unknown version; the message names the file and field."""


def _token(name: str) -> str:
    """A valid ROS name token (letters, digits, underscores; not starting with a digit)."""
    token = re.sub(r"[^A-Za-z0-9_]", "_", name) or "robot"
    return token if not token[0].isdigit() else "r" + token


def segment_name(folder: Path, index: int) -> str:
    return f"{folder.name}_{index}.mcap"


EPOCH_OFFSET_KEY = "epoch_offset_ns"     # the settings' key: stamps (ns) = the runtime's clock (ns) + this


def epoch_offset_ns(clock: Callable[[], float] = time.monotonic) -> int:
    """Nanoseconds that put a time of ``clock`` (seconds) on the epoch, ROS's clock for header stamps: the epoch
    read on either side of one read of ``clock``, their mean paired with it. Read it once per log: the epoch clock
    jumps (NTP, the user), a monotonic clock does not."""
    before = time.time_ns()
    now = clock()
    after = time.time_ns()
    return (before + after) // 2 - ros.stamp_ns(now)


class _Segment:
    """One MCAP file being written under a temporary name."""

    TYPES = ros.TYPES

    def __init__(self, path: Path, settings: Mapping, chunk_size: int) -> None:
        self.path = path
        self.part = path.with_name(path.name + ".part")
        self._file = open(self.part, "wb")  # noqa: SIM115 - closed in close()
        self.writer = McapWriter(self._file, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self.writer.start(profile="ros2", library="p3at-fusion sensorlog")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self.writer.add_metadata(METADATA_NAME, {"settings": json.dumps(dict(settings)),
                                                 "version": str(FORMAT_VERSION)})
        self.writer.add_metadata(*ros.ROSBAG2_METADATA)   # rosbag2 then reads the channels' QoS as integers (v8)
        self.t0: float | None = None
        self.static_written: bool | None = None   # None: no mounts written yet; False: camera only; True: all

    def write(self, topic: str, type_name: str, ns: int, data: bytes) -> None:
        channel = self._channels.get(topic)
        if channel is None:
            schema = self._schemas.get(type_name)
            if schema is None:
                schema = self.writer.register_schema(ros.schema_name(type_name), "ros2msg",
                                                     ros.message_definition(type_name).encode())
                self._schemas[type_name] = schema
            channel = self.writer.register_channel(topic, "cdr", schema, metadata=ros.channel_metadata(topic))
            self._channels[topic] = channel
        self.writer.add_message(channel, log_time=max(0, ns), publish_time=max(0, ns), data=data, sequence=0)

    def flush(self) -> None:
        self.writer.flush()

    def close(self) -> None:
        """Finish the file, fsync it, give it its final name, fsync the folder."""
        self.writer.finish()
        self._file.flush()
        os.fsync(self._file.fileno())
        self._file.close()
        os.replace(self.part, self.path)
        _fsync_folder(self.path.parent)


def _fsync_folder(folder: Path) -> None:
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


UNUSED_AXIS_VARIANCE = 1e6   # m², rad², (m/s)², (rad/s)²: z, roll, pitch and their rates (OdometryCovariance)
NOMINAL_SIP_PERIOD = 0.1     # s, ARCOS's default SIP cycle: the period of a log's first odometry record
ODOMETRY_NOISE_KEYS = ("odom_xy_var_per_m", "odom_theta_var_per_rad", "odom_theta_var_per_m", "odom_var_floor",
                       "odom_turn_xy_inflation")


class OdometryCovariance:
    """The covariances of the ``/R/odom`` messages (nav_msgs/Odometry), from the robot's odometry noise model.

    The noise model is the random walk FastSLAM moves its particles with (estimation/fastslam/motion.py): an
    increment (dx, dy, dθ) between two odometry poses has variances ``xy_var_per_m``·d on x and y,
    ``theta_var_per_rad``·|dθ| + ``theta_var_per_m``·d on θ (d its length), plus ``var_floor``, the x/y ones of an
    increment in a turn multiplied by ``turn_xy_inflation`` (1 unless the noise model fitted it). Its values are the
    log's own settings (metadata ``fastslam``: what the robot's filter used), else FastSLAMConfig's defaults
    (= estimation.noise_model.P3AT_VIDERE_DEFAULT's odometry: NOT measured on a P3-AT, see its ``source``).

    Pose (odometry frame): the covariance of the integrated odometry, propagated increment by increment from the
    log's first record exactly as the filter propagates a pose (``propagate_covariance``: a heading error turns into
    a cross-track error as the robot drives on), so it grows with the distance driven and the angle turned. The
    log's first pose counts as known (its floor only): the runtime starts its log when the robot connects, where
    the odometry frame has its origin; a log started later gives a lower bound.

    Twist (base_link): each SIP carries its velocities, not an increment's error, so the variance written is that
    of the mean velocity over the period since the previous SIP that the increment's random walk implies:
    var(v) = var(dx) / dt², var(ω) = var(dθ) / dt² (dt of the log's first record: NOMINAL_SIP_PERIOD). At rest that
    is the floor (1e-8 / 0.1² = 1e-6: σ 1 mm/s), never 0.

    Axes a planar robot does not measure (z, roll, pitch; their rates) get UNUSED_AXIS_VARIANCE, a variance so large
    that a filter fusing the message learns nothing on them, not 0 (which tells robot_localization and every other
    consumer that the value is perfectly known) and not -1: -1 in element 0 is sensor_msgs/Imu's marker for a whole
    estimate missing; geometry_msgs/PoseWithCovariance and TwistWithCovariance define no such marker, and a negative
    variance makes the matrix invalid for a consumer that reads it as a covariance. 1e6 is what ROS drivers of
    planar bases write there (e.g. the TurtleBot 2 / Kobuki-style ``covariances.py``: 1e6 on z, roll, pitch).
    Row-major 6×6 over (x, y, z, rotation about X, Y, Z), REP-103 units.
    """

    def __init__(self, xy_var_per_m: float, theta_var_per_rad: float, theta_var_per_m: float,
                 var_floor: float, turn_xy_inflation: float = 1.0) -> None:
        values = (xy_var_per_m, theta_var_per_rad, theta_var_per_m, var_floor, turn_xy_inflation)
        if not all(math.isfinite(v) and v >= 0 for v in values):
            raise ValueError(f"odometry noise must be finite and >= 0, not {values}")
        # the filter's own settings with these values (FastSLAMConfig checks them too: the turns' inflation >= 1), so
        # estimation.fastslam.motion reads here whatever it reads in the filter
        self.noise = replace(FastSLAMConfig(), **dict(zip(ODOMETRY_NOISE_KEYS, map(float, values), strict=True)))
        self._t: float | None = None
        self._pose: np.ndarray | None = None
        self._cov = np.zeros((3, 3))

    @classmethod
    def from_settings(cls, fastslam: Mapping | None) -> OdometryCovariance:
        """From a log's ``fastslam`` settings (FastSLAMConfig.to_dict); a missing value (or None): the default.

        A value given is checked where the filter's are, not here: the constructor's (finite, >= 0) and
        FastSLAMConfig's own (the turns' inflation >= 1), so a value the filter would refuse is refused here with
        the same ``ValueError``, never replaced by the default."""
        default = FastSLAMConfig()
        given = fastslam if isinstance(fastslam, Mapping) else {}
        values = []
        for key in ODOMETRY_NOISE_KEYS:
            v = given.get(key)
            if v is None:
                v = getattr(default, key)
            elif isinstance(v, bool) or not isinstance(v, int | float):
                raise ValueError(f"{key} must be a number, not {v!r}")
            values.append(float(v))
        return cls(*values)

    def update(self, t: float, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(pose covariance (6, 6), twist covariance (6, 6)) at the odometry pose (x, y, θ) of time ``t``."""
        pose = np.asarray(pose, float)
        previous = pose if self._pose is None else self._pose
        delta = between(previous, pose)
        dt = NOMINAL_SIP_PERIOD if self._t is None or not t > self._t else t - self._t
        variance = increment_variance(delta, self.noise)
        cov = propagate_covariance(previous[None], self._cov[None], delta, variance)[0]
        self._cov = (cov + cov.T) / 2.0     # exactly symmetric, as a consumer may check
        self._t, self._pose = float(t), pose
        planar = [0, 1, 5]     # x, y, rotation about Z in the 6×6
        pose_cov = np.diag(np.full(6, UNUSED_AXIS_VARIANCE))
        pose_cov[np.ix_(planar, planar)] = self._cov
        twist_cov = np.diag(np.full(6, UNUSED_AXIS_VARIANCE))
        twist_cov[np.ix_(planar, planar)] = np.diag(variance) / dt ** 2
        return pose_cov, twist_cov


class SensorLogWriter:
    """Writes records to a log folder from any thread without blocking it (a bounded queue, own thread).

    Records (what ``runtime.onboard`` hands over; t in seconds on the runtime clock):
    ``odometry`` t, x, y, theta, v, w, stalled, sonar (S,), sonar_poses (S, 3), raw (SIP bytes);
    ``frames`` t, seq, left, right (rectified uint8 (H, W) or (H, W, 3)); ``observations`` t, seq, points,
    covariances, descriptors, pixels; ``processed`` t, seq.
    """

    def __init__(self, folder: str | os.PathLike, metadata: Mapping | None = None, *, segment_seconds: float = 30.0,
                 flush_interval: float = 2.0, chunk_size: int = 1 << 20, png_compression: int = 1,
                 queue_size: int = 2000, max_queued_bytes: int = 256 << 20,
                 epoch_offset: int | None = None) -> None:
        """``epoch_offset``: on the wall clock, :func:`epoch_offset_ns` of the runtime's clock, read once at the
        start; header stamps and log times are then the runtime's clock plus it (the epoch, as ROS stamps), and the
        settings record it (key ``epoch_offset_ns``). None (simulated time): they are the runtime's clock."""
        self.folder = Path(folder)
        self.metadata = dict(metadata or {})
        if EPOCH_OFFSET_KEY in self.metadata:
            raise ValueError(f"the settings' {EPOCH_OFFSET_KEY!r} is the writer's: pass epoch_offset instead")
        if epoch_offset is not None:
            if isinstance(epoch_offset, bool) or not isinstance(epoch_offset, int):
                raise ValueError(f"epoch_offset must be whole nanoseconds, not {epoch_offset!r}")
            self.metadata[EPOCH_OFFSET_KEY] = epoch_offset
        self.epoch_offset = 0 if epoch_offset is None else epoch_offset
        # Settings are checked before the folder is made: a refused log leaves nothing behind.
        self._odometry_covariance = OdometryCovariance.from_settings(self.metadata.get("fastslam"))
        self.folder.mkdir(parents=True, exist_ok=True)
        if any(self.folder.glob("*.mcap*")) or (self.folder / "index.json").exists():
            raise SensorLogError(f"{self.folder}: already holds a sensor log (choose a new folder)")
        self.robot = _token(str(self.metadata.get("robot", "robot")))
        self.segment_seconds, self.flush_interval, self.chunk_size = segment_seconds, flush_interval, chunk_size
        self.png_compression = png_compression
        self.geometry = self.metadata.get("geometry") or None
        self.segments: list[Path] = []
        self._segment: _Segment | None = None
        self._last_flush = -math.inf
        self._sonar_poses: np.ndarray | None = None
        self._queue: queue.Queue = queue.Queue(maxsize=queue_size)
        self.max_queued_bytes = max_queued_bytes
        self._queued_bytes = 0
        self._bytes_lock = threading.Lock()
        self.dropped = 0
        self.error: BaseException | None = None
        self._closed = False
        self._thread = threading.Thread(target=self._run, name=f"sensorlog:{self.folder.name}", daemon=True)
        self._thread.start()

    def write(self, stream: str, record: Mapping) -> None:
        """Queue one record (must hold ``t``); never blocks: if the disk cannot keep up it counts a drop."""
        if self._closed:
            return
        if stream not in STREAMS:
            raise ValueError(f"unknown sensor-log stream {stream!r} (one of {', '.join(STREAMS)})")
        if "t" not in record:
            raise ValueError("a sensor-log record needs a time field 't'")
        size = sum(getattr(v, "nbytes", 8) for v in record.values())
        with self._bytes_lock:
            if self._queued_bytes + size > self.max_queued_bytes:
                self.dropped += 1  # images arriving faster than the disk takes them: bounded memory
                return
            self._queued_bytes += size
        try:
            self._queue.put_nowait((stream, dict(record), size))
        except queue.Full:
            with self._bytes_lock:
                self._queued_bytes -= size
            self.dropped += 1

    def flush(self) -> None:
        """Write every queued record and the chunk in progress to the file now (blocks until done)."""
        done = threading.Event()
        self._queue.put(("__flush__", done, 0))
        done.wait()

    def close(self) -> None:
        """Write everything and close the last segment under its final name. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        self._queue.put(("__close__", None, 0))
        self._thread.join()
        if self.error is not None:
            raise SensorLogError(f"{self.folder}: writing the log failed ({self.error})")

    def __enter__(self) -> SensorLogWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- the writer thread ------------------------------------------------------------------------------
    def _run(self) -> None:
        while True:
            stream, item, size = self._queue.get()
            try:
                if stream == "__flush__":
                    if self._segment is not None:
                        self._segment.flush()
                    item.set()
                    continue
                if stream == "__close__":
                    if self._segment is not None:
                        self._close_segment()
                    return
                try:
                    self._write_record(stream, item)
                finally:
                    with self._bytes_lock:
                        self._queued_bytes -= size
            except BaseException as e:  # keep running: a logging fault must not stop the robot
                # the first fault is the cause (a full disk, a removed folder); later ones are its consequences
                # ("write to closed file" once the segment's file is gone)
                self.error = self.error or e
                if stream == "__flush__":
                    item.set()
                elif stream == "__close__":
                    return

    def _open_segment(self, t: float) -> _Segment:
        path = self.folder / segment_name(self.folder, len(self.segments))
        self._segment = _Segment(path, {**self.metadata, "format_version": FORMAT_VERSION}, self.chunk_size)
        self._segment.t0 = t
        self._last_flush = t
        return self._segment

    def _close_segment(self) -> None:
        self._segment.close()
        self.segments.append(self._segment.path)
        self._segment = None

    def _write_record(self, stream: str, r: dict) -> None:
        t = float(r["t"])
        segment = self._segment
        if segment is not None and t - segment.t0 >= self.segment_seconds:
            self._close_segment()
            segment = None
        if segment is None:
            segment = self._open_segment(t)
        if stream == "odometry" and self._sonar_poses is None:
            self._sonar_poses = np.asarray(r.get("sonar_poses", np.zeros((0, 3))), float).reshape(-1, 3)
        if segment.static_written is not (self._sonar_poses is not None):  # the mounts, again once sonars are known
            self._write_static(segment, t)
        getattr(self, f"_write_{stream}")(segment, t, r)
        if t - self._last_flush >= self.flush_interval:
            segment.flush()  # a chunk on disk: what a crash can lose is bounded by flush_interval
            self._last_flush = t

    def _frame(self, name: str) -> str:
        return f"{self.robot}/{name}"

    def _ns(self, t: float) -> int:
        """A record's header stamp and log time (ns): its runtime-clock time, on the epoch on the wall clock."""
        return ros.stamp_ns(t) + self.epoch_offset

    def _write_static(self, segment: _Segment, t: float) -> None:
        transforms = []
        if self.geometry is not None:
            g = StereoGeometry.from_dict(self.geometry)
            left = g.left_camera_to_base()
            right_in_left = np.eye(4)
            right_in_left[0, 3] = g.baseline
            transforms += [(self._frame("base_link"), self._frame("stereo_left_optical"), left),
                           (self._frame("stereo_left_optical"), self._frame("stereo_right_optical"), right_in_left)]
        if self._sonar_poses is not None:
            for i, (x, y, yaw) in enumerate(self._sonar_poses):
                T = np.eye(4)
                T[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]]
                T[:2, 3] = x, y
                transforms.append((self._frame("base_link"), self._frame(f"sonar_{i}"), T))
        if transforms:
            segment.write("/tf_static", "tf2_msgs/TFMessage", self._ns(t), ros.encode_transforms(
                self._ns(t), transforms))
        segment.static_written = self._sonar_poses is not None

    def _write_odometry(self, segment: _Segment, t: float, r: dict) -> None:
        ns = self._ns(t)
        x, y, theta = float(r["x"]), float(r["y"]), float(r["theta"])
        raw = np.asarray(r.get("raw", np.zeros(0, np.uint8)), np.uint8).tobytes()
        odom, base = self._frame("odom"), self._frame("base_link")
        segment.write(f"/{self.robot}/sip", "p3at_msgs/RawSip", ns, ros.encode_raw_sip(
            ns, odom, t, raw, x, y, theta, float(r.get("v", 0.0)), float(r.get("w", 0.0)), bool(r.get("stalled"))))
        pose_cov, twist_cov = self._odometry_covariance.update(t, np.array([x, y, theta]))
        segment.write(f"/{self.robot}/odom", "nav_msgs/Odometry", ns, ros.encode_odometry(
            ns, odom, base, x, y, theta, float(r.get("v", 0.0)), float(r.get("w", 0.0)), pose_cov, twist_cov))
        T = np.eye(4)
        T[:3, :3] = [[np.cos(theta), -np.sin(theta), 0.0], [np.sin(theta), np.cos(theta), 0.0], [0.0, 0.0, 1.0]]
        T[:2, 3] = x, y
        segment.write("/tf", "tf2_msgs/TFMessage", ns, ros.encode_transforms(ns, [(odom, base, T)]))
        for i, value in enumerate(np.asarray(r.get("sonar", ()), float).reshape(-1)):
            segment.write(f"/{self.robot}/sonar/sonar_{i}", "sensor_msgs/Range", ns, ros.encode_range(
                ns, self._frame(f"sonar_{i}"), SONAR_FIELD_OF_VIEW, SONAR_MIN_RANGE, SONAR_MAX_RANGE,
                math.inf if not np.isfinite(value) else float(value)))

    def _camera_info(self, segment: _Segment, ns: int, width: int, height: int) -> None:
        if self.geometry is None:
            return
        g = self.geometry
        K = np.array([[g["fx"], 0.0, g["cx"]], [0.0, g["fy"], g["cy"]], [0.0, 0.0, 1.0]])
        for side, tx in (("left", 0.0), ("right", -g["fx"] * g["baseline"])):
            P = np.column_stack([K, [tx, 0.0, 0.0]])
            segment.write(f"/{self.robot}/stereo/{side}/camera_info", "sensor_msgs/CameraInfo", ns,
                          ros.encode_camera_info(ns, self._frame(f"stereo_{side}_optical"), width, height, K, P))

    def _write_frames(self, segment: _Segment, t: float, r: dict) -> None:
        ns = self._ns(t)
        left, right = np.asarray(r["left"], np.uint8), np.asarray(r["right"], np.uint8)
        for side, image in (("left", left), ("right", right)):
            ok, png = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, self.png_compression])
            if not ok:
                raise ValueError(f"PNG encoding of a {image.shape} image failed")
            segment.write(f"/{self.robot}/stereo/{side}/image_rect/compressed", "sensor_msgs/CompressedImage", ns,
                          ros.encode_compressed_image(ns, self._frame(f"stereo_{side}_optical"), "png", png.tobytes()))
        self._camera_info(segment, ns, left.shape[1], left.shape[0])
        segment.write(f"/{self.robot}/stereo/frame", "p3at_msgs/FrameStamp", ns, ros.encode_frame_stamp(
            ns, self._frame("stereo_left_optical"), int(r["seq"]), t))

    def _write_observations(self, segment: _Segment, t: float, r: dict) -> None:
        ns = self._ns(t)
        segment.write(f"/{self.robot}/stereo/observations", "p3at_msgs/StereoObservations", ns,
                      ros.encode_observations(ns, self._frame("base_link"), int(r["seq"]), t, r["points"],
                                              r["covariances"], r["descriptors"], r["pixels"]))

    def _write_processed(self, segment: _Segment, t: float, r: dict) -> None:
        ns = self._ns(t)
        segment.write(f"/{self.robot}/slam/processed", "p3at_msgs/FrameStamp", ns, ros.encode_frame_stamp(
            ns, self._frame("base_link"), int(r["seq"]), t))


# == reading =================================================================================================
@dataclass(frozen=True)
class LoggedMessage:
    """One message of a log: its topic, ROS type (``pkg/msg/Type``), log time (ns), CDR bytes and file."""

    topic: str
    type: str
    log_time: int
    data: bytes
    file: Path


def _segment_files(path: Path) -> list[Path]:
    if path.is_file():
        return [path]
    if not path.is_dir():
        raise SensorLogError(f"{path}: {not_a_file(path, 'sensor log')}; a sensor log is a folder of .mcap segments "
                             "or one .mcap file")
    numbered = []
    for p in path.iterdir():
        found = re.fullmatch(r".*_(\d{1,9})\.mcap(\.part)?", p.name)
        if found and p.is_file():
            numbered.append((int(found.group(1)), p.name.endswith(".part"), p))
    numbered.sort()
    for (k, _, a), (k_next, _, b) in zip(numbered, numbered[1:], strict=False):
        if k == k_next:   # the writer numbers one log's segments 0, 1, ...: two logs (or a copy) share the folder
            raise SensorLogError(f"{path}: two segments numbered {k} ({a.name}, {b.name}): a sensor log folder holds "
                                 "one log; give each log its own folder")
    if not numbered:
        if (path / "index.json").exists():
            raise SensorLogError(f"{path}: an npz-chunk sensor log (format 1), which this version no longer reads; "
                                 "record it again with --log-sensors")
        raise SensorLogError(f"{path}: no sensor log here (no <name>_<k>.mcap segment)")
    return [p for _, _, p in sorted(numbered)]


class SensorLog:
    """Reads a sensor log (a segment folder, or one ``.mcap`` file) written by :class:`SensorLogWriter`.

    Opening scans every segment once (counts per topic, metadata, validation of the container); ``messages``
    and ``records`` then stream, holding one chunk at a time. ``truncated`` names a segment that ended early (a
    crash): its complete chunks are read, the rest is reported in ``warnings``.
    """

    def __init__(self, path: str | os.PathLike, allow_truncated: bool = False) -> None:
        """``allow_truncated``: read a complete-named ``.mcap`` that ends early (copied or written in part) as a
        crash's ``.part`` is read, up to its last complete chunk, with a warning; by default it is refused."""
        self.folder = Path(path)
        self.allow_truncated = allow_truncated
        self.files = _segment_files(self.folder)
        self.metadata: dict = {}
        self.counts: dict[str, int] = {}
        self.types: dict[str, str] = {}
        self.truncated: list[Path] = []
        self.warnings: list[str] = []
        self.t_first = self.t_last = None
        previous: tuple[Path, int] | None = None   # the last segment with a message, and its last log time
        for f in self.files:
            self._file_settings = None
            last = None
            for m in self._read_file(f, scan=True):
                self.counts[m.topic] = self.counts.get(m.topic, 0) + 1
                self.types.setdefault(m.topic, m.type)
                self.t_first = m.log_time if self.t_first is None else min(self.t_first, m.log_time)
                self.t_last = m.log_time if self.t_last is None else max(self.t_last, m.log_time)
                last = m.log_time if last is None else max(last, m.log_time)
            if self._file_settings is not None and self._file_settings != self.metadata:
                raise SensorLogError(f"{f}: its settings differ from those of {self.files[0].name}: a segment of "
                                     "another log (a sensor log folder holds one log)")
            # A segment is closed when a record comes 30 s after its first: the next one ends later. One that ends
            # no later than the segment before it is a copy or another log's, and would replay time backwards.
            if last is not None:
                if previous is not None and last <= previous[1]:
                    raise SensorLogError(f"{f}: ends at log time {last} ns, no later than {previous[0].name} before "
                                         "it: not the next segment of the same log (a copy, or another log's)")
                previous = (f, last)
        self.closed = not any(f.name.endswith(".part") for f in self.files) and not self.truncated
        robot = self.metadata.get("robot", "robot")
        if not isinstance(robot, str):
            raise SensorLogError(f"{self.files[0]}: metadata field 'robot' is not a string")
        self.robot = _token(robot)
        # log times minus this are the runtime's clock (ns): 0 in simulated time and in logs written before the
        # offset was recorded (their wall-clock stamps were the monotonic clock itself)
        self.epoch_offset: int = self.metadata.get(EPOCH_OFFSET_KEY, 0)

    # -- the container ---------------------------------------------------------------------------------
    def _read_file(self, path: Path, scan: bool = False) -> Iterator[LoggedMessage]:
        try:
            size = path.stat().st_size
            stream = open(path, "rb")  # noqa: SIM115 - closed below
        except OSError as e:
            raise SensorLogError(f"{path}: cannot read ({e.strerror})") from None
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        partial = path.name.endswith(".part") or self.allow_truncated
        try:
            reader = StreamReader(_Bounded(stream, size), emit_chunks=True, record_size_limit=size)
            for record in reader.records:
                if isinstance(record, Chunk):
                    inner = _chunk_records(path, record)
                else:
                    inner = [record]
                for rec in inner:
                    if isinstance(rec, Schema):
                        schemas[rec.id] = rec
                    elif isinstance(rec, Channel):
                        if rec.schema_id not in schemas or rec.message_encoding != "cdr":
                            raise SensorLogError(f"{path}: channel '{rec.topic}' has no ROS 2 CDR schema")
                        if schemas[rec.schema_id].encoding != "ros2msg":
                            raise SensorLogError(f"{path}: channel '{rec.topic}' schema is not ros2msg")
                        channels[rec.id] = rec
                    elif isinstance(rec, Message):
                        channel = channels.get(rec.channel_id)
                        if channel is None:
                            raise SensorLogError(f"{path}: a message refers to unknown channel {rec.channel_id}")
                        yield LoggedMessage(channel.topic, schemas[channel.schema_id].name, rec.log_time, rec.data,
                                            path)
                    elif isinstance(rec, Metadata) and scan and rec.name == METADATA_NAME:
                        self._file_settings = _settings(path, rec.metadata)
                        if not self.metadata:
                            self.metadata = self._file_settings
        except SensorLogError:
            raise
        except (McapError, EOFError, struct.error, ValueError, OSError, UnicodeDecodeError, MemoryError) as e:
            # mcap's stream reader raises EndOfFile (an McapError) at a cut; a crash leaves a cut in the .part file
            if not partial and size == 0:
                raise SensorLogError(f"{path}: an empty file, not an MCAP log") from None
            if not partial and isinstance(e, EndOfFile | EOFError | RecordLengthLimitExceeded | struct.error):
                # what a file that ends inside a record gives (a segment copied or written in part)
                raise SensorLogError(f"{path}: cut short or damaged ({size} bytes; {str(e) or 'no MCAP footer'}): "
                                     "--allow-truncated reads it up to its last complete chunk") from None
            if not partial:
                raise SensorLogError(f"{path}: not a readable MCAP file ({type(e).__name__}: {e})") from None
            if scan:
                self.truncated.append(path)
                why = "cut short by a crash" if path.name.endswith(".part") else "cut short"
                self.warnings.append(f"{path}: {why}; read up to its last complete chunk")
        finally:
            stream.close()

    def messages(self, topics: set[str] | None = None) -> Iterator[LoggedMessage]:
        """Every message (of ``topics``) in the order it was written."""
        for f in self.files:
            for m in self._read_file(f):
                if topics is None or m.topic in topics:
                    yield m

    # -- the runtime's streams -------------------------------------------------------------------------
    def topic(self, suffix: str) -> str:
        return f"/{self.robot}/{suffix}"

    def streams(self) -> list[str]:
        return [s for s in STREAMS if self.count(s)]

    def count(self, stream: str) -> int:
        topic = {"odometry": "sip", "frames": "stereo/frame", "observations": "stereo/observations",
                 "processed": "slam/processed"}[stream]
        return self.counts.get(self.topic(topic), 0)

    def time_span(self) -> tuple[float, float]:
        """The first and last log time, in seconds on the runtime's clock (the epoch offset taken off)."""
        if self.t_first is None:
            return 0.0, 0.0
        return (self.t_first - self.epoch_offset) / 1e9, (self.t_last - self.epoch_offset) / 1e9

    def records(self, stream: str) -> Iterator[dict]:
        """The runtime's records of ``stream`` (see :class:`SensorLogWriter`), validated, in the order written."""
        if stream == "odometry":
            for m in self.messages({self.topic("sip")}):
                yield _decode(m, _raw_sip)
        elif stream == "processed":
            for m in self.messages({self.topic("slam/processed")}):
                yield _decode(m, _frame_stamp)
        elif stream == "observations":
            for m in self.messages({self.topic("stereo/observations")}):
                yield _decode(m, _observations)
        elif stream == "frames":
            yield from self._frames()
        else:
            raise ValueError(f"unknown stream {stream!r}")

    def _frames(self) -> Iterator[dict]:
        left, right, stamp = (self.topic(f"stereo/{s}") for s in ("left/image_rect/compressed",
                                                                   "right/image_rect/compressed", "frame"))
        pending: dict[int, dict] = {}
        for m in self.messages({left, right, stamp}):
            if m.topic == stamp:
                r = _decode(m, _frame_stamp)
                pending.setdefault(m.log_time, {}).update(r)
            else:
                pending.setdefault(m.log_time, {})["left" if m.topic == left else "right"] = _decode(m, _png_image)
            entry = pending[m.log_time]
            if {"t", "left", "right"} <= set(entry):
                del pending[m.log_time]
                if entry["left"].shape[:2] != entry["right"].shape[:2]:   # the front end refused it, naming no file
                    raise SensorLogError(f"{m.file}: the frame at {m.log_time} ns: its left image is "
                                         f"{entry['left'].shape[1]}x{entry['left'].shape[0]} pixels, its right one "
                                         f"{entry['right'].shape[1]}x{entry['right'].shape[0]}")
                yield entry
            while len(pending) > 8:  # a frame missing a part (a crash between its messages): skip it
                pending.pop(next(iter(pending)))


class _Bounded:
    """A file whose ``read(n)`` never asks for more than the file holds: a length field inside a record
    (a string, a map) claiming gigabytes must not make the reader allocate them."""

    def __init__(self, stream, size: int) -> None:
        self._stream, self._left = stream, size

    def read(self, n: int = -1) -> bytes:
        data = self._stream.read(self._left if n < 0 else min(n, self._left))
        self._left -= len(data)
        return data


# bounds on what a log's settings may ask of a replay: FastSLAM's particles as `--particles` takes them, descriptor
# lengths far above any descriptor's (U-SURF 64, SIFT 128), block sizes and descriptor slots far above the defaults
# (a block of 10^9 landmarks asked numpy for 1 TiB), corners per image, and every number's magnitude in the
# settings of the filter, the front end and the geometry (1e308 overflowed FastSLAM's field of view, exit 70)
MAX_LOGGED_DESCRIPTOR = 4096
MAX_LOGGED_CORNERS = 1_000_000
MAX_LOGGED_BLOCK = 4096        # landmarks per copy-on-write block (64 by default)
MAX_LOGGED_SLOTS = 64          # descriptors a landmark keeps (1 by default)
MAX_LOGGED_MAGNITUDE = 1e9
MAX_EPOCH_OFFSET = 10 ** 19    # ns (317 years): beyond any epoch a monotonic clock is from; stamps are uint64 ns
_SECTIONS = ("fastslam", "geometry", "harris")


def _settings(path: Path, metadata: Mapping[str, str]) -> dict:
    text = metadata.get("settings", "{}")
    try:
        value = json.loads(text)
    except json.JSONDecodeError as e:
        raise SensorLogError(f"{path}: metadata '{METADATA_NAME}' field 'settings' is not JSON ({e})") from None
    except RecursionError:
        raise SensorLogError(f"{path}: metadata '{METADATA_NAME}' field 'settings' is nested too deeply") from None
    if not isinstance(value, dict):
        raise SensorLogError(f"{path}: metadata '{METADATA_NAME}' field 'settings' is not a JSON object")
    problem = _settings_problem(value)
    if problem is not None:
        raise SensorLogError(f"{path}: metadata field 'settings' holds bad settings ({problem})")
    return value


def _numbers(value, where: str) -> Iterator[tuple[str, float]]:
    """Every number inside a JSON value, with where it is (``fastslam.max_range``, ``geometry.head_pose[2]``)."""
    if isinstance(value, bool):
        return
    if isinstance(value, int | float):
        yield where, value
    elif isinstance(value, dict):
        for key, item in value.items():
            yield from _numbers(item, f"{where}.{key}")
    elif isinstance(value, list):
        for k, item in enumerate(value):
            yield from _numbers(item, f"{where}[{k}]")


def _section_defaults(section: str) -> dict:
    """The default value of every field a settings section may hold (a field whose default is None is unchecked)."""
    from estimation.frontend import HarrisConfig

    if section == "fastslam":
        return FastSLAMConfig().to_dict()
    if section == "harris":
        return {f.name: getattr(HarrisConfig(), f.name) for f in fields(HarrisConfig)}
    return StereoGeometry().to_dict()


def _same_kind(value, default) -> bool:
    """Whether a JSON value has the kind of a setting's default: a flag, a whole number, a number, a word, or a list
    (of numbers when the default's are; as many as the default's when it holds some: a pose, an offset)."""
    if isinstance(default, bool):
        return isinstance(value, bool)
    if isinstance(default, int):
        return isinstance(value, int) and not isinstance(value, bool)
    if isinstance(default, float):
        return isinstance(value, int | float) and not isinstance(value, bool)
    if isinstance(default, str):
        return isinstance(value, str)
    if isinstance(default, list | tuple):
        numbers = all(isinstance(v, int | float) and not isinstance(v, bool) for v in default)
        return isinstance(value, list) and (not numbers or all(_same_kind(v, 0.0) for v in value)) \
            and (not numbers or not default or len(value) == len(default))
    return True


def _kind_name(default) -> str:
    for kind, name in ((bool, "true or false"), (int, "a whole number"), (float, "a number"), (str, "a string")):
        if isinstance(default, kind):
            return name
    if isinstance(default, list | tuple):
        return f"a list of {len(default)} numbers" if default else "a list of numbers"
    return type(default).__name__


def _whole(value, low: int, high: float) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and low <= value <= high


def _settings_problem(settings: dict) -> str | None:
    """Why a log's settings cannot drive a replay (None when they can): a section of the wrong type, a number that
    is not finite or beyond MAX_LOGGED_MAGNITUDE in a section, a seed that is no whole number >= 0, more particles
    than MAX_PARTICLES, a true start pose that is no three finite numbers. Before, such settings ended in exit 70
    (MemoryError, OverflowError, AttributeError) or exit 1, or a replay of NaN gates that 'succeeded'."""
    for where, number in _numbers(settings, "settings"):
        if isinstance(number, int) and abs(number) > sys.float_info.max:   # JSON's integers have no bound
            return f"{where.removeprefix('settings.')} is a {len(str(abs(number)))}-digit number, beyond any float"
        if not math.isfinite(number):
            return f"{where.removeprefix('settings.')} is {number}"
    for section in _SECTIONS:
        if settings.get(section) is not None and not isinstance(settings[section], dict):
            return f"{section} is not an object"
        defaults = _section_defaults(section)
        for key, value in (settings.get(section) or {}).items():
            default = defaults.get(key)
            if default is not None and not _same_kind(value, default):
                return f"{section}.{key} is {json.dumps(value)[:40]}, not {_kind_name(default)}"
        for where, number in _numbers(settings.get(section), section):
            if abs(number) > MAX_LOGGED_MAGNITUDE:
                return f"{where} is {number:g}, beyond ±{MAX_LOGGED_MAGNITUDE:g}"
    if "seed" in settings and not _whole(settings["seed"], 0, math.inf):
        return f"seed must be a whole number >= 0, not {json.dumps(settings['seed'])[:40]}"
    fastslam = settings.get("fastslam") or {}
    # the settings that size FastSLAM's arrays (particles x blocks of landmarks x descriptor slots x descriptor)
    for key, low, high in (("n_particles", 1, MAX_PARTICLES), ("descriptor_size", 0, MAX_LOGGED_DESCRIPTOR),
                           ("block_size", 1, MAX_LOGGED_BLOCK), ("descriptor_slots", 1, MAX_LOGGED_SLOTS)):
        if key in fastslam and not _whole(fastslam[key], low, high):
            return f"fastslam.{key} must be a whole number from {low} to {high}"
    harris = settings.get("harris") or {}
    if "max_corners" in harris and not _whole(harris["max_corners"], 1, MAX_LOGGED_CORNERS):
        return f"harris.max_corners must be a whole number from 1 to {MAX_LOGGED_CORNERS}"
    if "grid" in harris and not (isinstance(harris["grid"], list) and len(harris["grid"]) == 2
                                 and all(_whole(v, 1, 1000) for v in harris["grid"])):
        return "harris.grid must be two whole numbers from 1 to 1000"
    offset = settings.get(EPOCH_OFFSET_KEY)
    if EPOCH_OFFSET_KEY in settings and not _whole(offset, -MAX_EPOCH_OFFSET, MAX_EPOCH_OFFSET):
        return f"{EPOCH_OFFSET_KEY} must be a whole number of ns within ±{MAX_EPOCH_OFFSET:.0e}"
    start = settings.get("true_start_pose")
    if start is not None and not (isinstance(start, list) and len(start) == 3
                                  and all(isinstance(v, int | float) and not isinstance(v, bool) for v in start)):
        return "true_start_pose must be three numbers (x, y, yaw) or null"
    return None


def _chunk_records(path: Path, chunk: Chunk) -> list:
    """The records inside a chunk, decompressed with a bound (a chunk's stated size is not trusted)."""
    if chunk.uncompressed_size > MAX_CHUNK_BYTES:
        raise SensorLogError(f"{path}: a chunk claims {chunk.uncompressed_size} bytes (at most {MAX_CHUNK_BYTES})")
    if chunk.compression == "zstd":
        import zstandard

        pieces, total = [], 0
        try:  # piece by piece: memory grows with what the data really holds, not with what a field claims
            with zstandard.ZstdDecompressor().stream_reader(io.BytesIO(chunk.data)) as reader:
                while total <= chunk.uncompressed_size and (piece := reader.read(1 << 20)):
                    pieces.append(piece)
                    total += len(piece)
        except zstandard.ZstdError as e:
            raise SensorLogError(f"{path}: a chunk does not decompress ({e})") from None
        data = b"".join(pieces)
    elif chunk.compression == "":
        data = chunk.data
    else:
        raise SensorLogError(f"{path}: chunk compression {chunk.compression!r} is not supported (zstd or none)")
    if len(data) != chunk.uncompressed_size:
        raise SensorLogError(f"{path}: a chunk holds {len(data)} bytes, its header says {chunk.uncompressed_size}")
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise SensorLogError(f"{path}: a chunk fails its CRC check (damaged)")
    stream = ReadDataStream(io.BytesIO(data))
    records: list = []
    while stream.count < len(data):
        opcode = stream.read1()
        length = stream.read8()
        if length > len(data) - stream.count:
            raise SensorLogError(f"{path}: a record inside a chunk runs past the chunk's end")
        start = stream.count
        if opcode == Opcode.CHANNEL:
            records.append(Channel.read(stream))
        elif opcode == Opcode.MESSAGE:
            records.append(Message.read(stream, length))
        elif opcode == Opcode.SCHEMA:
            records.append(Schema.read(stream))
        else:
            stream.read(length)
        if stream.count - start != length:
            raise SensorLogError(f"{path}: a record inside a chunk has the wrong length")
    return records


# -- message decoders (validated) -----------------------------------------------------------------------------
def _decode(m: LoggedMessage, decoder) -> dict:
    expected = decoder.type_name
    if m.type != ros.schema_name(expected):
        raise SensorLogError(f"{m.file}: topic {m.topic}: type {m.type}, expected {ros.schema_name(expected)}")
    try:
        return decoder(ros.CdrReader(m.data))
    except ros.CdrError as e:
        raise SensorLogError(f"{m.file}: topic {m.topic}, message at {m.log_time} ns: {e}") from None


def _finite(topic: str, **values) -> None:
    for name, v in values.items():
        if not np.all(np.isfinite(v)):
            raise ros.CdrError(f"field '{name}' is not finite")


def _raw_sip(c: ros.CdrReader) -> dict:
    c.header()
    t = c.float64()
    payload = c.raw_bytes()
    x, y, theta, v, w = (c.float64() for _ in range(5))
    stalled = c.uint8()
    _finite("sip", t=t, x=x, y=y, theta=theta, v=v, w=w)
    return {"t": t, "x": x, "y": y, "theta": theta, "v": v, "w": w, "stalled": stalled, "raw": payload}


def _frame_stamp(c: ros.CdrReader) -> dict:
    c.header()
    seq, t = c.uint64(), c.float64()
    _finite("frame", t=t)
    return {"t": t, "seq": seq}


def _observations(c: ros.CdrReader) -> dict:
    c.header()
    seq, t, n, d = c.uint64(), c.float64(), c.uint32(), c.uint32()
    if n > MAX_OBSERVATIONS or d > MAX_DESCRIPTOR:
        raise ros.CdrError(f"{n} observations of descriptor size {d} exceed the bounds")
    points, covariances, descriptors, pixels = c.array("<f8"), c.array("<f8"), c.array("<f4"), c.array("<f8")
    for name, array, size in (("points", points, 3 * n), ("covariances", covariances, 9 * n),
                              ("descriptors", descriptors, d * n), ("pixels", pixels, 2 * n)):
        if len(array) != size:
            raise ros.CdrError(f"field '{name}' holds {len(array)} numbers, count {n} needs {size}")
    _finite("observations", t=t, points=points, covariances=covariances, descriptors=descriptors, pixels=pixels)
    covariances = covariances.reshape(n, 3, 3)
    if n:   # FastSLAM refused one with "an observation covariance is not positive definite", naming no file (exit 1)
        eigenvalues = np.linalg.eigvalsh(0.5 * (covariances + np.swapaxes(covariances, 1, 2)))
        worst = int(np.argmin(eigenvalues[:, 0]))
        if eigenvalues[worst, 0] < -1e-9 * max(1.0, float(np.abs(eigenvalues[worst]).max())):
            raise ros.CdrError(f"observation {worst}'s covariance is not positive semi-definite (eigenvalue "
                               f"{eigenvalues[worst, 0]:.3g})")
    return {"t": t, "seq": seq, "points": points.reshape(n, 3), "covariances": covariances,
            "descriptors": descriptors.reshape(n, d), "pixels": pixels.reshape(n, 2)}


def _png_image(c: ros.CdrReader) -> np.ndarray:
    c.header()
    fmt = c.string()
    data = c.raw_bytes()
    if fmt.split(";")[0].strip() != "png" or len(data) < 24 or data[:8] != b"\x89PNG\r\n\x1a\n":
        raise ros.CdrError(f"an image is not PNG (format {fmt!r})")
    width, height = struct.unpack(">II", data[16:24])  # the IHDR chunk: checked before anything is allocated
    if width * height > MAX_IMAGE_PIXELS or width == 0 or height == 0:
        raise ros.CdrError(f"an image of {width}x{height} pixels exceeds the bound")
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None or image.dtype != np.uint8:
        raise ros.CdrError("an image's PNG data does not decode to 8-bit pixels")
    return image


_raw_sip.type_name = "p3at_msgs/RawSip"
_frame_stamp.type_name = "p3at_msgs/FrameStamp"
_observations.type_name = "p3at_msgs/StereoObservations"
_png_image.type_name = "sensor_msgs/CompressedImage"

__all__ = ["FORMAT_VERSION", "LoggedMessage", "SensorLog", "SensorLogError", "SensorLogWriter", "segment_name"]
