"""Everything the project sends to (and reads back from) Rerun. The ONLY module that imports ``rerun``.

Pinned to rerun-sdk 0.41. Every other module hands plain numpy data to :class:`MissionLog`, which owns an
explicitly passed ``rr.RecordingStream`` (tests use :func:`open_recording` with ``sink="memory"``).

Entity tree (one recording per mission, one subtree per robot; all 3-D entities in metres, REP-103)::

    world/building/walls                  static LineStrips3D, the floor plan (when known)
    world/<robot>                         Transform3D: the robot's map frame placed in the world
                                          (its true start pose on the mocks, else the fusion alignment)
    world/<robot>/pose, true_pose         Arrows3D: estimated (best particle) and true robot pose
    world/<robot>/trajectory/<k>, true_trajectory/<k>   LineStrips3D, the path in segments of
                                          TRAJECTORY_SEGMENT poses (a frame re-logs one short segment)
    world/<robot>/particles               Points3D, every particle's (x, y)
    world/<robot>/landmarks               Points3D + world/<robot>/landmarks/covariance Ellipsoids3D (2 σ)
    world/<robot>/sonar                   LineStrips3D, one segment per sonar ray
    world/<robot>/stereo                  Transform3D: the head on the estimated pose
    world/<robot>/stereo/{left,right}     Pinhole + Image (JPEG), .../features Points2D (matched corners)
    world/<robot>/stereo/pair             side-by-side Image with .../matches LineStrips2D
    world/fused                           Transform3D of the reference robot's frame
    world/fused/landmarks                 Points3D (+ /covariance), colour = how many robots saw each
    plots/<robot>/{ess,landmarks,observations,dropped}   Scalars
    plots/<robot>/time/<stage>            Scalars, milliseconds per call
    plots/fusion/{error_xy,error_theta,common,merged}    Scalars
    maps/<robot>, maps/fused              AnyValues: the map's arrays, so that ``p3at review`` rebuilds them
    fusion/alignment/<a>_<b>              AnyValues: the alignment result and its error against the truth
    mission/summary                       AnyValues (JSON) + TextDocument: the figures the demo prints

Timelines: ``sim_time`` (seconds since the mission started, the sensor timestamps) and ``frame`` (the
robot's stereo frame number). ``set_time`` is per thread in Rerun, so every method sets both before it logs.
"""
from __future__ import annotations

import json
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
import warnings
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from estimation.geometry import compose
from estimation.landmark_map import LandmarkMap

APPLICATION_ID = "p3at-fusion"
ROBOT_COLOURS = [(230, 80, 60), (60, 130, 230), (70, 180, 90), (200, 160, 40), (160, 80, 200), (40, 180, 180)]
FUSED_COLOUR = (240, 240, 240)


class RecordingReadError(ValueError):
    """A ``.rrd`` file is missing or holds no p3at-fusion mission; the message names the file."""


class ViewerError(RuntimeError):
    """A Rerun viewer could not be started."""


VIEWER_PORT = 9876  # Rerun's default, so `rerun --connect` and a viewer someone already opened find each other


def _listening(port: int) -> bool:
    with socket.socket() as probe:
        return probe.connect_ex(("127.0.0.1", port)) == 0


def spawn_viewer(port: int | None = None, timeout: float = 15.0) -> str:
    """Start a Rerun viewer listening on loopback (``port``, default ``VIEWER_PORT``) and return its URL; reuse
    one already listening there.

    ``rr.spawn`` would start it listening on every interface (the viewer's default bind is 0.0.0.0); a robot
    must not expose its data stream to the network unless asked. Raises ViewerError with the viewer's own
    reason (no display, no executable) when it does not come up.
    """
    port = VIEWER_PORT if port is None else port
    url = f"rerun+http://127.0.0.1:{port}/proxy"
    if _listening(port):
        return url
    executable = Path(sys.executable).with_name("rerun")
    if not executable.exists():
        found = shutil.which("rerun")
        if found is None:
            raise ViewerError("no rerun executable found (pip install rerun-sdk); use --rerun file instead")
        executable = Path(found)
    messages = tempfile.TemporaryFile()  # not a pipe: nobody reads it once the viewer runs
    viewer = subprocess.Popen([str(executable), "--bind", "127.0.0.1", "--port", str(port), "--memory-limit", "75%"],
                              stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=messages,
                              start_new_session=True)  # the viewer outlives the mission, as with rr.spawn
    with messages:
        deadline = time.monotonic() + timeout
        alive_since = None
        while time.monotonic() < deadline:
            if viewer.poll() is not None:
                messages.seek(0)
                reason = messages.read().decode(errors="replace").strip().splitlines()
                raise ViewerError(f"the Rerun viewer exited at start ({reason[-1] if reason else 'no message'}); "
                                  "on a machine without a display use --rerun file, or run `rerun` elsewhere and "
                                  "pass its rerun+http:// URL")
            if _listening(port):
                alive_since = alive_since or time.monotonic()
                if time.monotonic() - alive_since > 1.0:  # it listens before it opens its window, which may fail
                    return url
            time.sleep(0.1)
    viewer.kill()
    raise ViewerError(f"the Rerun viewer did not listen on 127.0.0.1:{port} within {timeout:g} s")


def open_recording(sink: str, *, mission_id: str | None = None, blueprint: rrb.Blueprint | None = None
                   ) -> rr.RecordingStream:
    """A new RecordingStream for one mission.

    ``sink``: a path ending in ``.rrd`` (saved file), ``"spawn"`` (start a viewer on loopback), ``"memory"`` (tests),
    ``"none"`` (disabled), or a ``rerun+http://host:port/proxy`` URL (connect to a running viewer).
    """
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=mission_id, default_enabled=(sink != "none"))
    if sink == "memory":
        rec.memory_recording()
    elif sink == "spawn":
        rec.connect_grpc(spawn_viewer(), default_blueprint=blueprint)
    elif sink.startswith(("rerun://", "rerun+http://", "rerun+https://", "http://")):
        rec.connect_grpc(sink, default_blueprint=blueprint)
    elif sink != "none":
        Path(sink).parent.mkdir(parents=True, exist_ok=True)
        rec.save(sink, default_blueprint=blueprint)
    return rec


def mission_blueprint(robots: Iterable[str]) -> rrb.Blueprint:
    """The layout: the 3-D world on the left, each robot's stereo pair, and the time series."""
    robots = list(robots)
    cameras = [rrb.Vertical(rrb.Spatial2DView(origin=f"world/{r}/stereo/pair", name=f"{r} stereo pair"),
                            rrb.Horizontal(rrb.Spatial2DView(origin=f"world/{r}/stereo/left", name=f"{r} left"),
                                           rrb.Spatial2DView(origin=f"world/{r}/stereo/right", name=f"{r} right")),
                            name=r) for r in robots]
    plots = [rrb.Vertical(rrb.TimeSeriesView(origin=f"plots/{r}", contents=[f"plots/{r}/ess", f"plots/{r}/landmarks"],
                                             name=f"{r} ESS and landmarks"),
                          rrb.TimeSeriesView(origin=f"plots/{r}/time", name=f"{r} ms per stage"), name=r)
             for r in robots]
    plots.append(rrb.TimeSeriesView(origin="plots/fusion", name="fusion"))
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="world", name="world"),
            rrb.Vertical(rrb.Tabs(*cameras), rrb.Tabs(*plots), row_shares=[1, 1]),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


def _arrow(poses: np.ndarray, length: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    poses = np.atleast_2d(poses)
    origins = np.column_stack([poses[:, 0], poses[:, 1], np.zeros(len(poses))])
    vectors = length * np.column_stack([np.cos(poses[:, 2]), np.sin(poses[:, 2]), np.zeros(len(poses))])
    return origins, vectors


def _quaternion_z(theta: float) -> rr.Quaternion:
    return rr.Quaternion(xyzw=[0.0, 0.0, float(np.sin(theta / 2)), float(np.cos(theta / 2))])


def _ellipsoids(covariances: np.ndarray, sigmas: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """Half sizes (N, 3) and xyzw quaternions (N, 4) of the ``sigmas``-σ ellipsoids of covariances (N, 3, 3)."""
    eigenvalues, eigenvectors = np.linalg.eigh(0.5 * (covariances + np.swapaxes(covariances, -1, -2)))
    half_sizes = sigmas * np.sqrt(np.clip(eigenvalues, 1e-12, None))
    r = eigenvectors.copy()
    r[np.linalg.det(r) < 0, :, 2] *= -1  # a proper rotation
    # rotation matrix -> quaternion (xyzw), vectorised, robust branch on the largest diagonal term
    m = r
    trace = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    q = np.empty((len(m), 4))
    w = np.sqrt(np.clip(1.0 + trace, 0, None)) / 2
    safe = w > 1e-3
    q[:, 3] = w
    q[:, 0] = (m[:, 2, 1] - m[:, 1, 2]) / np.where(safe, 4 * w, 1)
    q[:, 1] = (m[:, 0, 2] - m[:, 2, 0]) / np.where(safe, 4 * w, 1)
    q[:, 2] = (m[:, 1, 0] - m[:, 0, 1]) / np.where(safe, 4 * w, 1)
    for i in np.flatnonzero(~safe):  # rare: rotations by about π
        k = int(np.argmax(np.diag(m[i])))
        a, b = (k + 1) % 3, (k + 2) % 3
        s = np.sqrt(max(1.0 + m[i, k, k] - m[i, a, a] - m[i, b, b], 1e-12)) * 2
        q[i, k] = s / 4
        q[i, a] = (m[i, a, k] + m[i, k, a]) / s
        q[i, b] = (m[i, b, k] + m[i, k, b]) / s
        q[i, 3] = (m[i, b, a] - m[i, a, b]) / s
    return half_sizes, q


# Poses per trajectory entity. Re-logging the whole path every frame would make each frame cost O(path) and
# the recording O(path^2) (a 10-minute run at 15 Hz: ~1 GB); closed segments stay as they were last logged.
TRAJECTORY_SEGMENT = 150


@dataclass
class _Strip:
    points: list = field(default_factory=list)
    segment: int = 0

    def add(self, point: list[float]) -> tuple[int, np.ndarray]:
        """Append a point; returns the open segment's number and its (n, 3) points (it starts where the last
        one ended, so the path stays connected)."""
        if len(self.points) >= TRAJECTORY_SEGMENT:
            self.points = self.points[-1:]
            self.segment += 1
        self.points.append(point)
        return self.segment, np.array(self.points)


@dataclass
class _Track:
    estimated: _Strip = field(default_factory=_Strip)
    true: _Strip = field(default_factory=_Strip)


def _jpeg(image: np.ndarray, quality: int = 75) -> rr.EncodedImage:
    """A (H, W) mono or (H, W, 3) BGR uint8 image as JPEG. OpenCV's encoder is ~4x faster than
    ``rr.Image.compress`` here (0.4 vs 1.5 ms for 640x480 on one core) and takes BGR as the heads deliver it."""
    ok, data = cv2.imencode(".jpg", np.ascontiguousarray(image), [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError(f"could not JPEG-encode an image of shape {image.shape} and type {image.dtype}")
    return rr.EncodedImage(contents=data.tobytes(), media_type="image/jpeg")


class MissionLog:
    """Logs one mission to the RecordingStream it is given. Thread-safe: robots log from their own threads.

    Times ``t`` are seconds since the mission started; ``frame`` is the robot's stereo frame number.
    """

    def __init__(self, rec: rr.RecordingStream, robots: Iterable[str] = (), *, image_interval: float = 0.5,
                 blueprint: bool = True) -> None:
        self.rec = rec
        self.robots = list(robots)
        self.image_interval = float(image_interval)   # s between logged stereo pairs of one robot (file size)
        self._last_image: dict[str, float] = {}
        self._tracks: dict[str, _Track] = {}
        self._lock = threading.Lock()
        if blueprint and self.robots:
            rec.send_blueprint(mission_blueprint(self.robots))

    # -- helpers --------------------------------------------------------------------------------------
    def colour(self, robot: str) -> tuple[int, int, int]:
        if robot not in self.robots:
            self.robots.append(robot)
        return ROBOT_COLOURS[self.robots.index(robot) % len(ROBOT_COLOURS)]

    def _time(self, t: float, frame: int | None = None) -> None:
        self.rec.set_time("sim_time", duration=float(t))
        if frame is not None:
            self.rec.set_time("frame", sequence=int(frame))
        else:  # set_time is sticky per thread: do not stamp this row with an older frame number
            self.rec.disable_timeline("frame")

    def flush(self) -> None:
        self.rec.flush()

    def close(self) -> None:
        """Flush and detach every sink (the .rrd file is complete afterwards). Safe to call twice."""
        if getattr(self, "_closed", False):
            return
        self._closed = True
        self.rec.flush()
        self.rec.disconnect()

    # -- static scene ---------------------------------------------------------------------------------
    def log_building(self, walls: np.ndarray, heights: np.ndarray) -> None:
        """walls (W, 4) x0, y0, x1, y1; heights (W,): each wall as a closed vertical rectangle."""
        walls = np.asarray(walls, float).reshape(-1, 4)
        heights = np.broadcast_to(np.asarray(heights, float), (len(walls),))
        strips = [[[x0, y0, 0], [x1, y1, 0], [x1, y1, h], [x0, y0, h], [x0, y0, 0]]
                  for (x0, y0, x1, y1), h in zip(walls, heights, strict=True)]
        self.rec.log("world/building/walls", rr.LineStrips3D(strips, radii=0.01, colors=(150, 150, 150)),
                     static=True)

    def log_robot_frame(self, robot: str, placement: np.ndarray, t: float | None = None) -> None:
        """Place the robot's map frame in the world: placement (3,) = (x, y, θ) of its origin."""
        if t is not None:
            self._time(t)
        x, y, theta = np.asarray(placement, float)
        self.rec.log(f"world/{robot}", rr.Transform3D(translation=[x, y, 0.0], quaternion=_quaternion_z(theta)),
                     static=t is None)

    def log_camera_model(self, robot: str, fx: float, fy: float, cx: float, cy: float, width: int, height: int,
                         baseline: float) -> None:
        """The stereo head's pinholes (static); the right camera sits ``baseline`` m along the left's +x."""
        for side, offset in (("left", 0.0), ("right", baseline)):
            path = f"world/{robot}/stereo/{side}"
            self.rec.log(path, rr.Transform3D(translation=[offset, 0, 0]), static=True)
            self.rec.log(path, rr.Pinhole(focal_length=[fx, fy], principal_point=[cx, cy], width=width,
                                          height=height, camera_xyz=rr.ViewCoordinates.RDF,
                                          image_plane_distance=0.3), static=True)

    # -- per robot, per frame -------------------------------------------------------------------------
    def log_pose(self, robot: str, t: float, frame: int | None, estimated: np.ndarray,
                 true: np.ndarray | None = None, head_mount: np.ndarray | None = None) -> None:
        """Estimated (and true) pose (3,) in the robot's map frame; the trajectories grow with each call.

        head_mount: (x, y, z) of the left camera in base_link; places world/<robot>/stereo (optical frame).
        """
        self._time(t, frame)
        colour = self.colour(robot)
        with self._lock:
            track = self._tracks.setdefault(robot, _Track())
            segment, estimated_strip = track.estimated.add([estimated[0], estimated[1], 0.02])
            if true is not None:
                true_segment, true_strip = track.true.add([true[0], true[1], 0.01])
        origins, vectors = _arrow(np.asarray(estimated, float))
        self.rec.log(f"world/{robot}/pose", rr.Arrows3D(vectors=vectors, origins=origins, colors=colour, radii=0.03))
        self.rec.log(f"world/{robot}/trajectory/{segment:04d}",
                     rr.LineStrips3D([estimated_strip], colors=colour, radii=0.02))
        if true is not None:
            origins, vectors = _arrow(np.asarray(true, float))
            self.rec.log(f"world/{robot}/true_pose", rr.Arrows3D(vectors=vectors, origins=origins,
                                                                 colors=(255, 255, 255), radii=0.02))
            self.rec.log(f"world/{robot}/true_trajectory/{true_segment:04d}",
                         rr.LineStrips3D([true_strip], colors=(200, 200, 200), radii=0.01))
        if head_mount is not None:
            hx, hy, hz = head_mount
            x, y, theta = compose(estimated, [hx, hy, 0.0])
            # optical frame (x right, y down, z forward) -> base_link: columns are the optical axes
            c, s = np.cos(theta), np.sin(theta)
            mat = np.array([[s, 0, c], [-c, 0, s], [0, -1, 0]])
            self.rec.log(f"world/{robot}/stereo", rr.Transform3D(translation=[x, y, hz], mat3x3=mat))

    def log_particles(self, robot: str, t: float, frame: int | None, poses: np.ndarray) -> None:
        """poses (M, 3) of every particle in the robot's map frame."""
        self._time(t, frame)
        poses = np.asarray(poses, float).reshape(-1, 3)
        pts = np.column_stack([poses[:, :2], np.full(len(poses), 0.03)])
        self.rec.log(f"world/{robot}/particles", rr.Points3D(pts, radii=0.015, colors=self.colour(robot)))

    def log_landmarks(self, robot: str, t: float, frame: int | None, positions: np.ndarray,
                      covariances: np.ndarray | None = None, path: str | None = None,
                      colours: np.ndarray | None = None) -> None:
        """positions (N, 3), covariances (N, 3, 3): points and their 2-σ ellipsoids."""
        self._time(t, frame)
        path = path or f"world/{robot}/landmarks"
        positions = np.asarray(positions, float).reshape(-1, 3)
        colour = colours if colours is not None else self.colour(robot)
        self.rec.log(path, rr.Points3D(positions, radii=0.03, colors=colour))
        if covariances is not None and len(positions):
            half_sizes, quaternions = _ellipsoids(np.asarray(covariances, float).reshape(-1, 3, 3))
            self.rec.log(f"{path}/covariance", rr.Ellipsoids3D(centers=positions, half_sizes=half_sizes,
                                                               quaternions=quaternions, colors=colour,
                                                               line_radii=0.004))

    def log_sonar(self, robot: str, t: float, pose: np.ndarray, sonar_poses: np.ndarray, ranges: np.ndarray,
                  max_range: float = 5.0) -> None:
        """Sonar rays: sonar_poses (S, 3) in base_link, ranges (S,) metres, drawn from ``pose`` (map frame)."""
        self._time(t)
        sonar_poses = np.asarray(sonar_poses, float).reshape(-1, 3)
        ranges = np.minimum(np.asarray(ranges, float).reshape(-1), max_range)
        starts = compose(np.asarray(pose, float), sonar_poses)
        ends = starts[:, :2] + ranges[:, None] * np.column_stack([np.cos(starts[:, 2]), np.sin(starts[:, 2])])
        z = np.full((len(ranges), 1), 0.25)
        strips = np.stack([np.hstack([starts[:, :2], z]), np.hstack([ends, z])], axis=1)
        self.rec.log(f"world/{robot}/sonar", rr.LineStrips3D(strips, radii=0.005, colors=(255, 200, 0)))

    def log_stereo(self, robot: str, t: float, frame: int, left: np.ndarray | None, right: np.ndarray | None,
                   left_pixels: np.ndarray, right_pixels: np.ndarray | None = None) -> None:
        """The current pair (at most one per ``image_interval`` s) with its matched corners and match lines.

        left/right: (H, W) or (H, W, 3) uint8 rectified images; left_pixels, right_pixels: (N, 2) (u, v).
        """
        if t - self._last_image.get(robot, -np.inf) < self.image_interval:
            return
        self._last_image[robot] = t
        self._time(t, frame)
        left_pixels = np.asarray(left_pixels, float).reshape(-1, 2)
        colour = self.colour(robot)
        base = f"world/{robot}/stereo"
        if left is not None:
            self.rec.log(f"{base}/left", _jpeg(left))
        self.rec.log(f"{base}/left/features", rr.Points2D(left_pixels, radii=2.0, colors=colour))
        if right_pixels is not None:
            right_pixels = np.asarray(right_pixels, float).reshape(-1, 2)
            self.rec.log(f"{base}/right/features", rr.Points2D(right_pixels, radii=2.0, colors=colour))
        if left is not None and right is not None:
            self.rec.log(f"{base}/right", _jpeg(right))
            width = left.shape[1]
            self.rec.log(f"{base}/pair", _jpeg(np.hstack([left, right])))
            if right_pixels is not None and len(right_pixels) == len(left_pixels):
                shifted = right_pixels + [width, 0]
                self.rec.log(f"{base}/pair/matches",
                             rr.LineStrips2D(np.stack([left_pixels, shifted], axis=1), radii=0.7, colors=colour))

    def log_scalars(self, robot: str, t: float, values: Mapping[str, float], frame: int | None = None) -> None:
        """Time series under plots/<robot>/<name> (a name may hold '/', e.g. 'time/frontend')."""
        self._time(t, frame)
        for name, value in values.items():
            if value is not None and np.isfinite(value):
                self.rec.log(f"plots/{robot}/{name}", rr.Scalars(float(value)))

    def log_event(self, t: float, text: str, level: str = "INFO") -> None:
        self._time(t)
        self.rec.log("mission/events", rr.TextLog(text, level=level))

    # -- maps, fusion and the summary -----------------------------------------------------------------
    def log_map(self, key: str, t: float, landmark_map: LandmarkMap, *, draw: bool = True,
                placement_path: str | None = None) -> None:
        """The map's arrays under maps/<key> (for :func:`read_recording`), and its landmarks drawn in the world.

        key: the robot's name, or "fused". Drawn under world/<key>/landmarks.
        """
        self._time(t)
        m = landmark_map
        meta = {"robot": m.robot, "frame": m.frame, "robots": m.robots, "metadata": m.metadata}
        self.rec.log(f"maps/{key}", rr.AnyValues(
            positions=m.positions.ravel(), covariances=m.covariances.ravel(),
            descriptors=m.descriptors.astype(np.float32).ravel(), descriptor_size=int(m.descriptor_size),
            ids=m.ids, counts=m.counts, seen_by=m.seen_by.astype(np.uint8).ravel(),
            trajectory=m.trajectory.ravel(), meta=json.dumps(meta), size=len(m), t=float(t)))
        if draw:
            colours = None
            if key == "fused":
                shares = m.seen_by.sum(axis=1) if len(m) else np.zeros(0)
                colours = np.where((shares > 1)[:, None], np.array([255, 255, 0]), np.array(FUSED_COLOUR))
            self.log_landmarks(key, t, None, m.positions, m.covariances,
                               path=f"world/{key}/landmarks", colours=colours)

    def log_alignment(self, t: float, reference: str, other: str, result: Mapping) -> None:
        """One pairwise alignment: ``result`` is plain JSON-able data (tx, ty, theta, supports, errors...)."""
        self._time(t)
        self.rec.log(f"fusion/alignment/{reference}_{other}", rr.AnyValues(json=json.dumps(dict(result))))
        values = {k: result.get(k) for k in ("error_xy", "error_theta", "common", "merged")}
        values = {k: v for k, v in values.items() if isinstance(v, int | float)}
        self.log_scalars("fusion", t, values)

    def log_summary(self, summary: Mapping) -> None:
        """The mission's figures, as JSON (read back by :func:`read_recording`) and as a text panel."""
        text = json.dumps(dict(summary), indent=2, default=float)
        self.rec.log("mission/summary", rr.AnyValues(json=text), static=True)
        self.rec.log("mission/summary", rr.TextDocument(f"```json\n{text}\n```", media_type="text/markdown"),
                     static=True)


# -- reading a recording back -------------------------------------------------------------------------------
@dataclass
class RecordingContents:
    """What :func:`read_recording` finds in a mission's ``.rrd``."""

    path: Path
    robots: list[str]
    duration: float                       # seconds of sim_time covered
    maps: dict[str, LandmarkMap]          # the last logged map of each robot, and "fused"
    alignments: dict[str, dict]           # "a_b" -> the last alignment result logged for that pair
    summary: dict | None                  # the mission summary, when the mission finished
    entity_count: int


def _last_values(rows: list[dict], key: str):
    for row in reversed(rows):
        value = row.get(key)
        if value is not None and value != []:
            return value
    return None


def read_recording(path: str | Path) -> RecordingContents:
    """Read a mission's ``.rrd`` (rerun 0.41 ``rerun.chunk.RrdReader``) and rebuild its maps and figures."""
    import rerun.chunk as rrchunk  # only used for reading

    path = Path(path)
    if not path.is_file():
        raise RecordingReadError(f"{path}: no such recording")
    try:
        with warnings.catch_warnings():  # files saved by a viewer or `rerun --save` have no footer: read by scanning
            warnings.filterwarnings("ignore", message=".*no footer/manifest.*")
            reader = rrchunk.RrdReader(path)
        if not reader.recordings():
            raise RecordingReadError(f"{path}: holds no recording")
        # the maps, fusion results, summary and time series; not the images and point clouds
        chunks = list(reader.stream().filter(content=["+ /maps/**", "+ /fusion/**", "+ /mission/**", "+ /plots/**"]))
    except RecordingReadError:
        raise
    except Exception as e:  # the bindings raise several untyped errors on corrupt files
        raise RecordingReadError(f"{path}: not a readable Rerun recording ({e})") from None
    rows_by_entity: dict[str, list[tuple[float, int, dict]]] = {}
    t_min, t_max = np.inf, -np.inf
    entities: set[str] = set()
    wanted = ("maps/", "fusion/alignment/", "mission/summary")
    for order, chunk in enumerate(chunks):
        entity = chunk.entity_path.lstrip("/")
        entities.add(entity)
        batch = chunk.to_record_batch()
        names = batch.schema.names
        if "sim_time" in names:  # a duration column, nanoseconds
            times = batch.column("sim_time").cast("int64").to_numpy(zero_copy_only=False) / 1e9
            if len(times):
                t_min, t_max = min(t_min, float(times.min())), max(t_max, float(times.max()))
        else:
            times = np.full(chunk.num_rows, -np.inf)
        if not entity.startswith(wanted):
            continue
        columns = {k: batch.column(k).to_pylist() for k in names
                   if k not in ("log_time", "sim_time", "frame") and not k.startswith("rerun.")}
        for i in range(chunk.num_rows):
            row = {k: v[i] for k, v in columns.items()}
            rows_by_entity.setdefault(entity, []).append((float(times[i]), order, row))
    maps: dict[str, LandmarkMap] = {}
    alignments: dict[str, dict] = {}
    summary = None
    for entity, rows in rows_by_entity.items():
        rows.sort(key=lambda r: (r[0], r[1]))
        plain = [r[2] for r in rows]
        if entity.startswith("maps/"):
            maps[entity.removeprefix("maps/")] = _map_from_row(path, entity, plain)
        elif entity.startswith("fusion/alignment/"):
            text = _last_values(plain, "json")
            if text:
                alignments[entity.removeprefix("fusion/alignment/")] = json.loads(_scalar(text))
        elif entity == "mission/summary":
            text = _last_values(plain, "json")
            if text:
                summary = json.loads(_scalar(text))
    robots = sorted({e.split("/")[1] for e in entities if e.startswith("plots/") and e.count("/") >= 2}
                    - {"fusion"} | {k for k in maps if k != "fused"})
    robots = [r for r in robots if r]
    duration = float(t_max - t_min) if np.isfinite(t_min) else 0.0
    return RecordingContents(path, robots, duration, maps, alignments, summary, len(entities))


def _scalar(value):
    while isinstance(value, list) and len(value) == 1:
        value = value[0]
    return value


def _map_from_row(path: Path, entity: str, rows: list[dict]) -> LandmarkMap:
    # empty arrays are not stored by AnyValues: only the scalars are sure to be there
    row = next((r for r in reversed(rows) if all(r.get(f) is not None for f in ("meta", "descriptor_size", "size"))),
               None)
    if row is None:
        raise RecordingReadError(f"{path}: entity '{entity}' does not hold a complete map")

    def array(name: str, dtype) -> np.ndarray:
        value = row.get(name)
        return np.asarray(value if value is not None else [], dtype)

    try:
        meta = json.loads(_scalar(row["meta"]))
        d = int(_scalar(row["descriptor_size"]))
        n = int(_scalar(row["size"]))
        robots = [str(r) for r in meta.get("robots") or [meta.get("robot", "robot")]]
        return LandmarkMap(
            array("positions", float).reshape(n, 3), array("covariances", float).reshape(n, 3, 3),
            array("descriptors", np.float32).reshape(n, d), array("ids", np.int64).reshape(n),
            array("counts", np.int64).reshape(n), str(meta.get("robot", "robot")), str(meta.get("frame", "map")),
            robots, array("seen_by", np.uint8).reshape(n, len(robots)).astype(bool),
            array("trajectory", float).reshape(-1, 4), dict(meta.get("metadata", {})))
    except (ValueError, TypeError, KeyError, json.JSONDecodeError) as e:
        raise RecordingReadError(f"{path}: entity '{entity}' holds a malformed map ({e})") from None


__all__ = ["MissionLog", "RecordingContents", "RecordingReadError", "mission_blueprint", "open_recording",
           "read_recording"]
