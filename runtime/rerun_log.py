"""What the project logs to Rerun during a mission: :class:`MissionLog`, and the entities it writes.

Pinned to rerun-sdk 0.41 (``rerun`` itself is imported by runtime/rerun_sdk.py). Every other module hands plain numpy
data to :class:`MissionLog`, which owns an explicitly passed ``rr.RecordingStream``
(:func:`runtime.rerun_sink.open_recording` opens one; tests pass ``sink="memory"``); colours, legends and layouts are
runtime/rerun_style.py's, the per-frame rows reach the stream through runtime/rerun_rows.py (held and sent as
columns for a saved file), and runtime/rerun_read.py reads a saved recording back. What a reader sees, and why, is in
docs/recording.md.

Entity tree (one recording per mission, one subtree per robot; metres, radians, REP-103)::

    world/building/walls                  static LineStrips3D, the floor plan (when known)
    world/<robot>                         Transform3D: the robot's map frame placed in the world
                                          (its true start pose on the mocks, else the identity)
    world/<robot>/base_link[/body]        Transform3D of the estimated pose, Boxes3D of the P3-AT in its colour
    world/<robot>/pose, true_pose         Arrows3D: estimated (best particle) and true robot pose
    world/<robot>/trajectory/<k>, true_trajectory/<k>   LineStrips3D, the path in segments of
                                          TRAJECTORY_SEGMENT poses (a frame re-logs one short segment)
    world/<robot>/particles               Points3D, every particle's (x, y)
    world/<robot>/landmarks               Points3D, confirmed bright, provisional dim and small
    world/<robot>/landmarks/covariance    Ellipsoids3D (1 σ) of the last snapshot; hidden by the blueprint
    world/<robot>/true_landmarks          Points3D, a data set's true landmarks (static, labelled)
    world/<robot>/sonar                   LineStrips3D, one segment per sonar ray
    world/<robot>/stereo                  Transform3D: the head on the estimated pose
    world/<robot>/stereo/{left,right}     Pinhole, .../features Points2D (matched corners); a lone left image
    world/fused/landmarks[/covariance]    Points3D coloured by robot (white: seen by several), Ellipsoids3D 1 σ;
                                          world/fused placed at the fused map's true_start_pose when it has one
    images/<robot>/pair[/matches]         side-by-side Image and LineStrips2D: 2-D, outside the 3-D world
    map/<key>                             static Transform3D flipping y: the 2-D maps are drawn y up
    map/<robot>/building                  LineStrips2D, the walls in the robot's start frame (when known)
    map/<robot>/trajectory/{estimated,odometry,true}/<k>   LineStrips2D segments, as in the 3-D world
    map/<robot>/pose[/heading], true_pose Points2D (labelled) + Arrows2D
    map/<robot>/particles                 Points2D
    map/<robot>/landmarks/{confirmed,provisional}          Points2D
    map/<robot>/true_landmarks[/ids]      Points2D, a data set's true landmarks (static), and their ids shown
                                          TRUE_LABEL_OFFSET_M below them (a label box hid the estimate)
    map/<robot>/frame_tie[/ray]           Points2D (labelled) + LineStrips2D: a data set run's sighting its frame
                                          rests on, unchecked (estimation.frame_reliability), and its ray
    map/<robot>/naming_tie/<k>[/start]    LineStrips2D + Points2D (labelled): the path a chain's naming its frame or
                                          path rests on, unchecked, was seen from (estimation.naming_reliability)
    map/fused/building                    the walls in the fused map's frame (the reference robot's start)
    map/fused/<robot>                     Transform3D: the robot's frame as the fusion aligned it
    map/fused/<robot>/{trajectory,pose}   its path from its last map snapshot
    map/fused/landmarks                   Points2D of the merged map, coloured as in the 3-D world
    plots/<robot>/{ess,observations,dropped}, plots/<robot>/landmarks/{all,confirmed,provisional}   Scalars
    plots/<robot>/time/<stage>            Scalars, milliseconds per call
    plots/<robot>/self_check[/threshold]  Scalars, the map's self-check CUSUM and its threshold (per snapshot)
    plots/<robot>/pose_nees               Scalars, a data set run's pose NEES against its ground truth
    plots/fusion/{error_xy,error_theta,common,merged}    Scalars (m, rad, counts)
    maps/<robot>, maps/fused              AnyValues: the map's arrays, so that ``p3at review`` rebuilds them
    fusion/alignment/<a>_<b>              AnyValues: the alignment result and its error against the truth
    fusion/status                         TextDocument (Markdown): each pair's last fusion, aligned or why not, with
                                          its supports, P(chance), 1 σ and error; shown beside the fused map;
                                          at t = 0 (two robots or more) NO_FUSION_YET
    mission/events                        TextLog: warnings and notices (fusion candidates, splits, contacts...)
    mission/summary                       AnyValues (JSON) + TextDocument: the figures the demo prints, as it
                                          prints them (the layout's summary tab)
    mission/closed                        static AnyValues, logged last by ``close``: the writer closed the stream
                                          (a file saved without Rerun's footer has no end-of-stream message)

Every series has its legend name with its unit (SERIES), logged once as a static SeriesLines. ``world`` carries
ViewCoordinates RIGHT_HAND_Z_UP (REP-103: x forward, y left, z up), so the 3-D view's up is +z whatever a viewer
would guess.

Timelines: ``sim_time`` (seconds since the mission started, the sensor timestamps: the mission's clock) and
``frame`` (the robot's stereo frame number). ``set_time`` is per thread in Rerun, so every method sets both before
it logs.
"""
from __future__ import annotations

import json
import sys
import threading
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field

import cv2
import numpy as np

from estimation.fastslam.config import FastSLAMConfig
from estimation.geometry import between, compose
from estimation.landmark_map import LandmarkMap
from runtime.report import alignment_status, candidate_text, format_summary
from runtime.rerun_map_format import CLOSED_ENTITY, OPTIONAL_MAP_ARRAYS, map_arrays, map_checksum
from runtime.rerun_rows import RowSender
from runtime.rerun_sdk import rr
from runtime.rerun_sink import (
    SAVED_STREAMS,
    WRITERS,
    finish_live,
    finish_saved,
    live_url,
    release_saved,
    viewer_lost,
    writer_failure,
)
from runtime.rerun_style import (
    EVENTS,
    FRAME_TIE_COLOUR,
    FUSION_STATUS,
    SHARED_COLOUR,
    SPARSE_SERIES,
    SUMMARY,
    TRUE_COLOUR,
    WALL_COLOUR,
    dimmed,
    mission_blueprint,
    robot_colour,
    series_style,
)


def landmark_confirmed(landmark_map: LandmarkMap, confirm_count: int | None = None) -> np.ndarray:
    """(N,) bool: which landmarks are confirmed (the rest are provisional).

    Confirmed: observed at least ``confirm_count`` times (what FastSLAM's exported maps keep; the setting comes
    from the caller, else the map's recorded FastSLAM settings, else FastSLAM's default), and, when the map carries
    an existence probability per landmark (an ``existence`` array (N,) in [0, 1]), at least 0.5 likely to exist.
    A field that is missing, or of the wrong shape or range, is ignored rather than trusted.
    """
    n = len(landmark_map)
    if confirm_count is None:
        recorded = (landmark_map.metadata or {}).get("fastslam", {})
        confirm_count = recorded.get("confirm_count") if isinstance(recorded, dict) else None
        if not isinstance(confirm_count, int):
            confirm_count = FastSLAMConfig().confirm_count
    confirmed = np.asarray(landmark_map.counts).reshape(-1) >= confirm_count
    existence = getattr(landmark_map, "existence", None)
    if existence is not None:
        try:
            existence = np.asarray(existence, float).reshape(-1)
        except (TypeError, ValueError):
            return confirmed
        if existence.shape == (n,) and np.all((existence >= 0) & (existence <= 1)):
            confirmed &= existence >= 0.5
    return confirmed


# -- geometry helpers -------------------------------------------------------------------------------------
def _arrow(poses: np.ndarray, length: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    poses = np.atleast_2d(poses)
    origins = np.column_stack([poses[:, 0], poses[:, 1], np.zeros(len(poses))])
    vectors = length * np.column_stack([np.cos(poses[:, 2]), np.sin(poses[:, 2]), np.zeros(len(poses))])
    return origins, vectors


def _xyzw_z(theta: float) -> list[float]:
    """The quaternion (x, y, z, w) of a rotation by ``theta`` about z."""
    return [0.0, 0.0, float(np.sin(theta / 2)), float(np.cos(theta / 2))]


def _quaternion_z(theta: float) -> rr.Quaternion:
    return rr.Quaternion(xyzw=_xyzw_z(theta))


def _ellipsoids(covariances: np.ndarray, sigmas: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
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
# The logger keeps only the open segment: its memory does not grow with the mission.
TRAJECTORY_SEGMENT = 150
SNAPSHOT_TRAJECTORY_POINTS = 1000   # a map snapshot's trajectory drawn in the fused view is thinned to this


@dataclass
class _Strip:
    points: list = field(default_factory=list)
    segment: int = 0

    def add(self, point: list[float]) -> tuple[int, np.ndarray]:
        """Append a point; returns the open segment's number and its (n, 2) points (it starts where the last
        one ended, so the path stays connected)."""
        if len(self.points) >= TRAJECTORY_SEGMENT:
            self.points = self.points[-1:]
            self.segment += 1
        self.points.append(point)
        return self.segment, np.array(self.points, float)


@dataclass
class _Track:
    estimated: _Strip = field(default_factory=_Strip)
    odometry: _Strip = field(default_factory=_Strip)
    true: _Strip = field(default_factory=_Strip)


def _with_z(points: np.ndarray, z: float) -> np.ndarray:
    return np.column_stack([points[:, :2], np.full(len(points), z)])


def _jpeg(image: np.ndarray, quality: int = 75) -> rr.EncodedImage:
    """A (H, W) mono or (H, W, 3) BGR uint8 image as JPEG. OpenCV's encoder is ~4x faster than
    ``rr.Image.compress`` here (0.4 vs 1.5 ms for 640x480 on one core) and takes BGR as the heads deliver it."""
    ok, data = cv2.imencode(".jpg", np.ascontiguousarray(image), [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError(f"could not JPEG-encode an image of shape {image.shape} and type {image.dtype}")
    return rr.EncodedImage(contents=data.tobytes(), media_type="image/jpeg")


TRUE_LABEL_OFFSET_M = 0.3  # m below a true landmark in the 2-D map where its id is shown (clear of the map's landmark)
P3AT_HALF_SIZE = (0.32, 0.25, 0.14)  # m: the Pioneer 3-AT's body, drawn at the estimated pose in the 3-D view
Y_UP = np.diag([1.0, -1.0, 1.0])     # 2-D views draw +y down; the maps are REP-103 (x forward, y left): flip once


# frames logged (log_pose, log_scalars and log_event calls) between two looks at a saved file's writer
# (runtime.rerun_sink.writer_failure, ~15 us): a count, not a clock, so that a mission in simulated time sees a dead
# writer at the same point of the mission however busy the machine (15 Hz, one robot: a look every ~0.5 s)
WRITER_LOOK_CALLS = 16


# the fusion status before the first fusion (fusion/status at t = 0)
NO_FUSION_YET = ("**No fusion yet.** The robots' maps have not been aligned and merged yet (a mission fuses them every "
                 "--fusion-interval s and at its end); the fused map stays empty until the first fusion, and each "
                 "pair's last fusion is then said here (aligned or why not).")


class RecordingError(RuntimeError):
    """The saved recording is incomplete: its writer stopped, or its file was removed (the text says which)."""


def _warn_on_stderr(text: str) -> None:
    print(f"warning: {text}", file=sys.stderr, flush=True)


class MissionLog:
    """Logs one mission to the RecordingStream it is given. Thread-safe: robots log from their own threads.

    Times ``t`` are seconds since the mission started; ``frame`` is the robot's stereo frame number. What the
    logger keeps between calls is bounded whatever the mission's length: the open trajectory segment of each
    robot, each robot's last snapshot trajectory (thinned to SNAPSHOT_TRAJECTORY_POINTS) and placement, one
    style per plotted series, the entity last styled of each per-frame family, and (saved files) each entity's held
    rows (at most HELD_ROWS_MAX, at most FILE_FLUSH_TICK s: :class:`runtime.rerun_rows.RowSender`, through which the
    per-frame rows and their times go).

    A saved file whose writer stops (a full disk, a file-size limit) or which is removed while it is written is seen
    within WRITER_LOOK_CALLS frames logged after it (:func:`runtime.rerun_sink.writer_failure`: nothing is
    asked of Rerun): ``recording_failure`` then says why, ``on_recording_failure`` is called once with one line naming
    the file (default: the line on stderr), and the logger goes on (Rerun drops the rows; the mission's own files are
    not its). :meth:`close` then raises :class:`RecordingError` instead of waiting on a dead writer.

    A live stream to a viewer URL whose viewer goes away (:func:`runtime.rerun_sink.viewer_lost`, looked at as often)
    is said once the same way (``live_view_lost`` keeps why) and the mission goes on; :meth:`flush` and :meth:`close`
    wait for its last rows a bounded time (:func:`runtime.rerun_sink.finish_live`) and raise nothing: the live view
    is not one of the mission's files.

    ``records_fusion=False``: the logger of one robot's process of a fleet whose processes share one recording (``p3at
    run --recording-id``, each robot of ``p3at demo --processes``). The fleet's fusion is the fusion node's, logged in
    the node's file on the entities above (fusion/**, maps/fused, world/fused/**, map/fused/**, plots/fusion/**);
    the fusion such a robot makes of the maps it receives (at its end, or as it hears its peers) is then not logged
    at all (:meth:`log_alignment`, :meth:`log_map` of "fused" and the fused frame's placement log nothing). Logged on
    the same entities, it replaced the node's fusion in the view that opens the files together (the latest row of
    either wins: robot2's own "9 needed" at t = 141 s over the node's "8 needed", session 50); under an entity root
    of its own, nothing would show it (such a robot sends no layout, the node's has no place for it) and no reader
    reads it (``p3at review`` reads the node's fusion and each robot's map). The robot's own fusion is still in its
    summary and its fused map file.
    """

    def __init__(self, rec: rr.RecordingStream, robots: Iterable[str] = (), *, image_interval: float = 0.5,
                 blueprint: bool = True, hold_rows: bool | None = None,
                 on_recording_failure: Callable[[str], None] | None = None, records_fusion: bool = True) -> None:
        self.rec = rec
        self.records_fusion = bool(records_fusion)   # False: a fleet's robot process (the class's docstring)
        self.recording_failure: str | None = None   # why the saved file stopped being written, once seen
        self.live_view_lost: str | None = None      # why the viewer URL stopped taking the stream, once seen
        self._on_recording_failure = on_recording_failure or _warn_on_stderr
        self._calls = 0                              # calls of _watch: every WRITER_LOOK_CALLS-th looks
        self._last_t = 0.0                           # the mission time of the last frame looked at
        # a saved file: the per-frame rows of each entity are held up to FILE_FLUSH_TICK s and sent as columns
        # (RowSender.emit); a live stream gets each row as it is logged. None: hold when open_recording saves ``rec``
        self._rows = RowSender(rec, rec in SAVED_STREAMS if hold_rows is None else bool(hold_rows))
        self.robots = list(robots)
        self.image_interval = float(image_interval)   # s between logged stereo pairs of one robot (file size)
        self._last_image: dict[str, float] = {}
        self._tracks: dict[str, _Track] = {}
        self._lock = threading.Lock()
        self._once: set[str] = set()                 # static things logged once: series styles, map roots, bodies
        self._walls: np.ndarray | None = None        # (W, 2, 2) wall end points in the world
        self._placements: dict[str, np.ndarray] = {}  # map key -> its frame's pose in the world (x, y, θ)
        self._snapshot_paths: dict[str, np.ndarray] = {}  # robot -> (T, 2) path of its last map snapshot
        self._aligned: dict[str, np.ndarray] = {}     # robot -> its frame in the fused map's frame (x, y, θ)
        self._styled: dict[str, str] = {}             # family -> the entity whose style was last logged static
        self._status: dict[tuple[str, str], str] = {}  # (reference, other) -> its last fusion in words
        # the layout, again whenever a robot is first seen (a fleet's fusion node learns its robots from their maps;
        # the last blueprint received wins); a disabled stream ("none") refuses blueprints
        self._send_layout = bool(blueprint) and rec.is_enabled()
        if self._send_layout and self.robots:
            rec.send_blueprint(mission_blueprint(self.robots))
        # REP-103 in the 3-D view: z up (without it a viewer guesses the up axis from what it is shown)
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        if len(self.robots) >= 2:
            self._no_fusion_yet()

    # -- helpers --------------------------------------------------------------------------------------
    @property
    def hold_rows(self) -> bool:
        """Whether the per-frame rows are held and sent as columns (a saved file), not logged one by one."""
        return self._rows.hold

    def colour(self, robot: str) -> tuple[int, int, int]:
        """The robot's colour; a robot first seen here joins the layout."""
        if robot not in self.robots:
            second = False
            with self._lock:  # sent under the lock: the layouts go out in the order the robots came
                if robot not in self.robots:
                    self.robots.append(robot)
                    if self._send_layout:
                        self.rec.send_blueprint(mission_blueprint(self.robots))
                    second = len(self.robots) == 2
            if second:   # a fusion node that learns its robots from their maps (p3at fuse --live)
                self._no_fusion_yet()
        return robot_colour(robot)

    def _no_fusion_yet(self) -> None:
        """The fusion status before the first fusion, at t = 0: the status panel beside the (still empty) fused map
        said "(empty)" for the mission's first 20 s, which reads as a recording that lost its fusion. Logged by a
        logger of two robots or more (a robot's own process of a fleet logs none: the fusion node's is the one shown).
        The time this thread logs at is kept."""
        if not self.records_fusion or not self._first_time(FUSION_STATUS):
            return
        now = self._rows.current_time()
        self._rows.set_time(0.0)
        self.rec.log(FUSION_STATUS, rr.TextDocument(NO_FUSION_YET, media_type="text/markdown"))
        if now is not None:
            self._rows.set_time(*now)

    def _first_time(self, key: str) -> bool:
        """True the first time ``key`` is asked (thread-safe): for static things logged once."""
        with self._lock:
            if key in self._once:
                return False
            self._once.add(key)
            return True

    def _log_styled(self, path: str, archetype, data: dict, style: dict, *, family: str | None = None) -> None:
        """What ``rec.log(path, archetype(**data, **style))`` shows a viewer, for what is logged every frame: the
        styling fields (colours, radii, draw order, labels: the same every call for one ``family``) are logged once
        per entity, static, and each call logs only ``data``.

        A viewer resolves each component of an entity at the time it shows by a latest-at query, static data
        included (Rerun's data model: static data belongs to every timeline and shadows temporal data of the same
        component; its own "incremental logging" example logs colours and radii once). So every frame draws as
        before, while a call converts and sends fewer component arrays (Rerun's ``log_arrow_msg`` costs about as
        much per array as per call). Static, not at the first frame's time: a viewer's memory limit drops old
        temporal rows, never static ones, so later frames cannot lose their style. ``family``: for an entity logged
        in numbered segments, its path with the segment number left out (``world/robot1/trajectory``; default
        ``path``): the logger keeps the one entity of each family whose style it logged last, so a new segment gets
        its own and nothing grows with the mission.
        """
        family = path if family is None else family
        with self._lock:
            fresh = self._styled.get(family) != path
            if fresh:
                self._styled[family] = path
        if fresh:
            self.rec.log(path, archetype.from_fields(**style), static=True)
        self._rows.emit(path, archetype, data)

    def _map_root(self, key: str) -> str:
        """map/<key>, with the y-up flip logged once (static)."""
        root = f"map/{key}"
        if self._first_time(root):
            self.rec.log(root, rr.Transform3D(mat3x3=Y_UP), static=True)
        return root

    def _watch(self, t: float) -> None:
        """Look at the saved file's writer every WRITER_LOOK_CALLS calls (a count otherwise); the first failure seen
        is kept and said once, with ``t``, the mission time it was seen at."""
        self._last_t = t
        self._calls += 1   # robots' threads may race here: a look then comes a call early or late
        if self._calls % WRITER_LOOK_CALLS or self.recording_failure is not None or self.live_view_lost is not None:
            return
        failure = writer_failure(self.rec)
        if failure is not None:
            self._failed(failure, say=True)
        elif (lost := viewer_lost(self.rec)) is not None:
            self._view_lost(lost)

    def _view_lost(self, why: str) -> None:
        """Keep and say (once) why the viewer URL stopped taking the stream."""
        with self._lock:
            if self.live_view_lost is not None:
                return
            self.live_view_lost = f"{why}, seen at t = {self._last_t:.1f} s"
        self._on_recording_failure(f"the live view at {live_url(self.rec)} is lost: {self.live_view_lost}; the "
                                   "mission goes on (its maps and trajectory files are written as before)")

    def _failed(self, failure: str, say: bool) -> None:
        """Keep the first failure of the saved file (with the mission time it was seen at); ``say``: and say it."""
        with self._lock:
            if self.recording_failure is not None:
                return
            self.recording_failure = f"{failure}, seen at t = {self._last_t:.1f} s"
        if say:
            watch = WRITERS.get(self.rec)
            where = watch.current_path() if watch is not None else "the saved recording"
            self._on_recording_failure(f"the Rerun recording {where} is incomplete: {self.recording_failure}; the "
                                       "mission goes on (its maps and trajectory files are written as before)")

    def _finish(self, say: bool) -> None:
        """Send what is held and flush; a saved file that is not whole raises RecordingError (never waits on a
        writer that has stopped: runtime.rerun_sink.finish_saved)."""
        self._rows.send_held_rows()
        if live_url(self.rec) is not None:   # a viewer URL: waited for a bounded time, its loss said, never raised
            if (lost := finish_live(self.rec)) is not None:
                self._view_lost(lost)
            return
        failure = finish_saved(self.rec)
        if failure is not None:
            self._failed(failure, say)
            raise RecordingError(f"incomplete: {self.recording_failure}")

    def flush(self) -> None:
        """Send every row to the sink; a saved file found incomplete is said (once) and raises RecordingError."""
        self._finish(say=True)

    def close(self) -> None:
        """Flush and detach every sink (the .rrd file is complete afterwards). Safe to call twice. A saved file that
        is not whole raises RecordingError (detached, unless a flush of it is stranded: runtime.rerun_sink's
        release_saved)."""
        if getattr(self, "_closed", False):
            return
        self._closed = True
        self._rows.closed = True   # its rows are sent here, not at exit
        if not self.rec.is_enabled():
            return
        self.rec.log(CLOSED_ENTITY, rr.AnyValues(closed=True), static=True)
        try:
            self._finish(say=False)   # the caller reports what close raises: one line, not two
        finally:
            release_saved(self.rec)

    # -- static scene ---------------------------------------------------------------------------------
    def log_building(self, walls: np.ndarray, heights: np.ndarray) -> None:
        """walls (W, 4) x0, y0, x1, y1; heights (W,): each wall as a closed vertical rectangle in the 3-D world,
        and as a line in every 2-D map whose frame's place in the world is known."""
        walls = np.asarray(walls, float).reshape(-1, 4)
        heights = np.broadcast_to(np.asarray(heights, float), (len(walls),))
        strips = [[[x0, y0, 0], [x1, y1, 0], [x1, y1, h], [x0, y0, h], [x0, y0, 0]]
                  for (x0, y0, x1, y1), h in zip(walls, heights, strict=True)]
        self.rec.log("world/building/walls", rr.LineStrips3D(strips, radii=0.01, colors=(150, 150, 150)),
                     static=True)
        self._walls = walls.reshape(-1, 2, 2)
        for key, placement in list(self._placements.items()):
            self._log_walls_2d(key, placement)

    def _log_walls_2d(self, key: str, placement: np.ndarray) -> None:
        if self._walls is None or not len(self._walls):
            return
        ends = self._walls.reshape(-1, 2)
        local = between(placement, np.column_stack([ends, np.zeros(len(ends))]))[:, :2].reshape(-1, 2, 2)
        self.rec.log(f"{self._map_root(key)}/building", rr.LineStrips2D(local, radii=-1.0, colors=WALL_COLOUR,
                                                                         draw_order=0.0), static=True)

    def log_robot_frame(self, robot: str, placement: np.ndarray, t: float | None = None) -> None:
        """Place the robot's map frame in the world: placement (3,) = (x, y, θ) of its origin (its true start on
        the mocks). Key "fused": the fused map's frame. The 2-D map of that frame gets the building's walls."""
        if robot == "fused" and not self.records_fusion:
            return
        if t is not None:
            self._rows.set_time(t)
        placement = np.asarray(placement, float).reshape(3)
        x, y, theta = placement
        self.rec.log(f"world/{robot}", rr.Transform3D(translation=[x, y, 0.0], quaternion=_quaternion_z(theta)),
                     static=t is None)
        self._placements[robot] = placement
        self._log_walls_2d(robot, placement)

    def log_camera_model(self, robot: str, fx: float, fy: float, cx: float, cy: float, width: int, height: int,
                         baseline: float) -> None:
        """The stereo head's pinholes (static); the right camera sits ``baseline`` m along the left's +x."""
        for side, offset in (("left", 0.0), ("right", baseline)):
            path = f"world/{robot}/stereo/{side}"
            self.rec.log(path, rr.Transform3D(translation=[offset, 0, 0]), static=True)
            self.rec.log(path, rr.Pinhole(focal_length=[fx, fy], principal_point=[cx, cy], width=width,
                                          height=height, camera_xyz=rr.ViewCoordinates.RDF,
                                          image_plane_distance=0.3), static=True)

    def log_disc_body(self, robot: str, radius: float, height: float = 0.1) -> None:
        """Draw the robot as a disc of ``radius`` m (e.g. MRCLAM's iRobot Creates) instead of the P3-AT's box: call
        before its first :meth:`log_pose`."""
        if self._first_time(f"world/{robot}/base_link/body"):
            self.rec.log(f"world/{robot}/base_link/body", rr.Cylinders3D(
                lengths=[height], radii=[radius], centers=[[0, 0, height / 2]], colors=self.colour(robot),
                fill_mode=rr.components.FillMode.Solid), static=True)

    def log_true_landmarks(self, robot: str, positions: np.ndarray, labels: Iterable[str] = ()) -> None:
        """The true landmarks (N, 2) in the robot's map frame (a data set's ground truth; static), labelled, in the
        3-D world and in the robot's 2-D map, drawn under its estimated landmarks."""
        positions = np.asarray(positions, float).reshape(-1, 2)
        labels = [str(label) for label in labels] or None
        self.rec.log(f"world/{robot}/true_landmarks", rr.Points3D(_with_z(positions, 0.0), radii=0.05,
                                                                  colors=TRUE_COLOUR, labels=labels), static=True)
        # A point's label box is drawn over the point, on top of everything: on the true landmark it hid the map's
        # own landmark, a few pixels off (MRCLAM's median error 0.09 m), which is what the view is for. The ids are
        # shown on points of no size TRUE_LABEL_OFFSET_M below each (the map is drawn y up), the landmark itself
        # keeps its id for hovering.
        root = self._map_root(robot)
        self.rec.log(f"{root}/true_landmarks", rr.Points2D(positions, radii=-5.0, colors=TRUE_COLOUR, labels=labels,
                                                           show_labels=False, draw_order=4.0), static=True)
        if labels:
            self.rec.log(f"{root}/true_landmarks/ids",
                         rr.Points2D(positions - [0.0, TRUE_LABEL_OFFSET_M], radii=0.0, colors=TRUE_COLOUR,
                                     labels=labels, show_labels=True, draw_order=4.0), static=True)

    # -- per robot, per frame -------------------------------------------------------------------------
    def log_pose(self, robot: str, t: float, frame: int | None, estimated: np.ndarray,
                 true: np.ndarray | None = None, head_mount: np.ndarray | None = None,
                 odometry: np.ndarray | None = None) -> None:
        """Estimated (and true, and odometry-only) pose (3,) in the robot's map frame; the trajectories grow with
        each call, in the 3-D world and in the robot's 2-D map.

        head_mount: (x, y, z) of the left camera in base_link; places world/<robot>/stereo (optical frame).
        """
        self._watch(t)
        self._rows.set_time(t, frame)
        colour = self.colour(robot)
        estimated = np.asarray(estimated, float).reshape(3)
        strips = {}
        with self._lock:
            track = self._tracks.setdefault(robot, _Track())
            strips["estimated"] = track.estimated.add(estimated[:2].tolist())
            if true is not None:
                true = np.asarray(true, float).reshape(3)
                strips["true"] = track.true.add(true[:2].tolist())
            if odometry is not None:
                odometry = np.asarray(odometry, float).reshape(3)
                strips["odometry"] = track.odometry.add(odometry[:2].tolist())
        # 3-D world
        origins, vectors = _arrow(estimated)
        self._log_styled(f"world/{robot}/pose", rr.Arrows3D,
                         {"vectors": vectors, "origins": origins}, {"colors": colour, "radii": 0.03})
        if self._first_time(f"world/{robot}/base_link/body"):
            self.rec.log(f"world/{robot}/base_link/body", rr.Boxes3D(
                half_sizes=[P3AT_HALF_SIZE], centers=[[0, 0, P3AT_HALF_SIZE[2]]], colors=colour,
                fill_mode=rr.components.FillMode.Solid), static=True)
        self._rows.emit(f"world/{robot}/base_link", rr.Transform3D,
                   {"translation": [[estimated[0], estimated[1], 0.0]], "quaternion": [_xyzw_z(estimated[2])]})
        segment, points = strips["estimated"]
        self._log_styled(f"world/{robot}/trajectory/{segment:04d}", rr.LineStrips3D,
                         {"strips": [_with_z(points, 0.02)]}, {"colors": colour, "radii": 0.02},
                         family=f"world/{robot}/trajectory")
        if true is not None:
            origins, vectors = _arrow(true)
            self._log_styled(f"world/{robot}/true_pose", rr.Arrows3D,
                             {"vectors": vectors, "origins": origins}, {"colors": TRUE_COLOUR, "radii": 0.02})
            segment, points = strips["true"]
            self._log_styled(f"world/{robot}/true_trajectory/{segment:04d}", rr.LineStrips3D,
                             {"strips": [_with_z(points, 0.01)]}, {"colors": TRUE_COLOUR, "radii": 0.01},
                             family=f"world/{robot}/true_trajectory")
        if head_mount is not None:
            hx, hy, hz = head_mount
            x, y, theta = compose(estimated, [hx, hy, 0.0])
            # optical frame (x right, y down, z forward) -> base_link: columns are the optical axes
            c, s = np.cos(theta), np.sin(theta)
            mat = np.array([[s, 0, c], [-c, 0, s], [0, -1, 0]])
            self._rows.emit(f"world/{robot}/stereo", rr.Transform3D, {"translation": [[x, y, hz]], "mat3x3": [mat]})
        # 2-D map: truth thin and light, odometry dim, the estimate bright and on top
        root = self._map_root(robot)
        styles = {"true": (TRUE_COLOUR, -1.0, 1.0), "odometry": (dimmed(colour), -1.5, 2.0),
                  "estimated": (colour, -2.0, 3.0)}
        for kind, (segment, points) in strips.items():
            line_colour, width, order = styles[kind]
            self._log_styled(f"{root}/trajectory/{kind}/{segment:04d}", rr.LineStrips2D, {"strips": [points]},
                             {"colors": line_colour, "radii": width, "draw_order": order},
                             family=f"{root}/trajectory/{kind}")
        heading = 0.6 * np.array([np.cos(estimated[2]), np.sin(estimated[2])])
        self._log_styled(f"{root}/pose", rr.Points2D, {"positions": [estimated[:2]]},
                         {"radii": -7.0, "colors": colour, "labels": [robot], "show_labels": True,
                          "draw_order": 10.0})
        self._log_styled(f"{root}/pose/heading", rr.Arrows2D,
                         {"vectors": [heading], "origins": [estimated[:2]]},
                         {"radii": -2.0, "colors": colour, "draw_order": 10.0})
        if true is not None:
            self._log_styled(f"{root}/true_pose", rr.Points2D, {"positions": [true[:2]]},
                             {"radii": -4.0, "colors": TRUE_COLOUR, "draw_order": 9.0})

    def log_particles(self, robot: str, t: float, frame: int | None, poses: np.ndarray) -> None:
        """poses (M, 3) of every particle in the robot's map frame."""
        self._rows.set_time(t, frame)
        poses = np.asarray(poses, float).reshape(-1, 3)
        colour = self.colour(robot)
        self._log_styled(f"world/{robot}/particles", rr.Points3D,
                         {"positions": _with_z(poses, 0.03)}, {"radii": 0.015, "colors": colour})
        path = f"{self._map_root(robot)}/particles"
        self._log_styled(path, rr.Points2D, {"positions": poses[:, :2]},
                         {"radii": -1.5, "colors": dimmed(colour), "draw_order": 8.0})

    def log_landmarks(self, robot: str, t: float, frame: int | None, positions: np.ndarray,
                      covariances: np.ndarray | None = None, path: str | None = None,
                      colours: np.ndarray | None = None, sigmas: float = 1.0) -> None:
        """positions (N, 3), covariances (N, 3, 3): 3-D points and their ``sigmas``-σ ellipsoids (at .../covariance,
        which the blueprint hides for the robots' maps)."""
        self._rows.set_time(t, frame)
        path = path or f"world/{robot}/landmarks"
        positions = np.asarray(positions, float).reshape(-1, 3)
        colour = colours if colours is not None else self.colour(robot)
        self.rec.log(path, rr.Points3D(positions, radii=0.03, colors=colour))
        if covariances is not None:
            self._log_ellipsoids(f"{path}/covariance", positions, covariances, colour, sigmas)

    def _log_ellipsoids(self, path: str, positions: np.ndarray, covariances: np.ndarray, colour,
                        sigmas: float = 1.0) -> None:
        if not len(positions):
            self.rec.log(path, rr.Clear(recursive=False))
            return
        half_sizes, quaternions = _ellipsoids(np.asarray(covariances, float).reshape(-1, 3, 3), sigmas)
        self.rec.log(path, rr.Ellipsoids3D(centers=positions, half_sizes=half_sizes, quaternions=quaternions,
                                           colors=colour, line_radii=0.004))

    def log_robot_landmarks(self, robot: str, t: float, frame: int | None, landmark_map: LandmarkMap,
                            confirm_count: int | None = None) -> tuple[int, int]:
        """The best particle's landmarks (all of them, provisional ones included), coloured by state: confirmed in
        the robot's colour, provisional dimmed and smaller, in the 3-D world and in the robot's 2-D map; their
        counts are plotted. Returns (confirmed, provisional)."""
        self._rows.set_time(t, frame)
        colour = self.colour(robot)
        positions = np.asarray(landmark_map.positions, float).reshape(-1, 3)
        confirmed = landmark_confirmed(landmark_map, confirm_count)
        colours = np.where(confirmed[:, None], np.array(colour), np.array(dimmed(colour)))
        radii = np.where(confirmed, 0.04, 0.02)
        self.rec.log(f"world/{robot}/landmarks", rr.Points3D(positions, radii=radii, colors=colours))
        root = self._map_root(robot)
        self.rec.log(f"{root}/landmarks/confirmed", rr.Points2D(positions[confirmed, :2], radii=-3.0, colors=colour,
                                                                draw_order=6.0))
        self.rec.log(f"{root}/landmarks/provisional", rr.Points2D(positions[~confirmed, :2], radii=-2.0,
                                                                  colors=dimmed(colour), draw_order=5.0))
        counts = (int(confirmed.sum()), int((~confirmed).sum()))
        self.log_scalars(robot, t, {"landmarks/confirmed": counts[0], "landmarks/provisional": counts[1]}, frame)
        return counts

    def log_sonar(self, robot: str, t: float, pose: np.ndarray, sonar_poses: np.ndarray, ranges: np.ndarray,
                  max_range: float = 5.0) -> None:
        """Sonar rays: sonar_poses (S, 3) in base_link, ranges (S,) metres, drawn from ``pose`` (map frame)."""
        self._rows.set_time(t)
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
        A pair is logged once, side by side (images/<robot>/pair, a 2-D entity outside the 3-D world, with the
        match lines): logging each image again under its pinhole would double the recording's largest part. The
        matched corners sit under the pinholes (world/<robot>/stereo/{left,right}/features); a lone left image too.
        """
        if t - self._last_image.get(robot, -np.inf) < self.image_interval:
            return
        self._last_image[robot] = t
        self._rows.set_time(t, frame)
        left_pixels = np.asarray(left_pixels, float).reshape(-1, 2)
        colour = self.colour(robot)
        base = f"world/{robot}/stereo"
        self.rec.log(f"{base}/left/features", rr.Points2D(left_pixels, radii=2.0, colors=colour))
        if right_pixels is not None:
            right_pixels = np.asarray(right_pixels, float).reshape(-1, 2)
            self.rec.log(f"{base}/right/features", rr.Points2D(right_pixels, radii=2.0, colors=colour))
        if left is not None and right is not None:
            width = left.shape[1]
            self.rec.log(f"images/{robot}/pair", _jpeg(np.hstack([left, right])))
            if right_pixels is not None and len(right_pixels) == len(left_pixels):
                shifted = right_pixels + [width, 0]
                self.rec.log(f"images/{robot}/pair/matches",
                             rr.LineStrips2D(np.stack([left_pixels, shifted], axis=1), radii=0.7, colors=colour))
        elif left is not None:
            self.rec.log(f"{base}/left", _jpeg(left))

    def log_scalars(self, robot: str, t: float, values: Mapping[str, float], frame: int | None = None) -> None:
        """Time series under plots/<robot>/<name> (a name may hold '/', e.g. 'time/frontend'); each series gets
        its legend name (with its unit, from SERIES) and colour once."""
        self._watch(t)
        self._rows.set_time(t, frame)
        for name, value in values.items():
            if value is None or not np.isfinite(value):
                continue
            path = f"plots/{robot}/{name}"
            if self._first_time(path):
                label, colour = series_style(name)
                self.rec.log(path, rr.SeriesLines(names=label, colors=colour, widths=1.5), static=True)
                if name in SPARSE_SERIES:  # a line needs two values: a marker shows a fusion's first and only one
                    self.rec.log(path, rr.SeriesPoints(names=label, colors=colour, marker_sizes=5.0), static=True)
            self._rows.emit(path, rr.Scalars, {"scalars": [float(value)]})

    def log_event(self, t: float, text: str, level: str = "INFO") -> None:
        self._watch(t)
        self._rows.set_time(t)
        self.rec.log(EVENTS, rr.TextLog(text, level=level))

    def log_frame_tie(self, robot: str, t: float, pose: np.ndarray, landmark: np.ndarray | None, label: str) -> None:
        """The sighting a map's frame rests on (:mod:`estimation.frame_reliability`): a ring on the pose it was taken
        from and, when its landmark is in the map, the ray to it, labelled, in the robot's 2-D map (drawn from ``t``,
        the sighting's time, in the final estimate's place)."""
        self._rows.set_time(t)
        root = self._map_root(robot)
        pose = np.asarray(pose, float).reshape(-1)[:2]
        self.rec.log(f"{root}/frame_tie", rr.Points2D([pose], radii=-9.0, colors=FRAME_TIE_COLOUR, labels=[label],
                                                    show_labels=True, draw_order=11.0))
        if landmark is not None:
            ray = np.array([pose, np.asarray(landmark, float).reshape(-1)[:2]])
            self.rec.log(f"{root}/frame_tie/ray", rr.LineStrips2D([ray], radii=-2.0, colors=FRAME_TIE_COLOUR,
                                                                draw_order=11.0))

    def log_naming_tie(self, robot: str, key: str, t: float, path: np.ndarray, label: str) -> None:
        """A run of sightings whose naming a chain's map rests on, untested (:mod:`estimation.naming_reliability`):
        the stretch of the estimated path ``path`` (N, 2) it was seen from, thick and labelled at its start, in the
        robot's 2-D map under naming_tie/<key> (drawn from ``t``, the run's first time)."""
        self._rows.set_time(t)
        root = self._map_root(robot)
        path = np.asarray(path, float).reshape(-1, 2)
        self.rec.log(f"{root}/naming_tie/{key}", rr.LineStrips2D([path], radii=-5.0, colors=FRAME_TIE_COLOUR,
                                                               draw_order=11.0))
        self.rec.log(f"{root}/naming_tie/{key}/start", rr.Points2D(path[:1], radii=-7.0, colors=FRAME_TIE_COLOUR,
                                                                   labels=[label], show_labels=True, draw_order=11.0))

    # -- maps, fusion and the summary -----------------------------------------------------------------
    def log_map(self, key: str, t: float, landmark_map: LandmarkMap, *, draw: bool = True,
                placement_path: str | None = None) -> None:
        """The map's arrays under maps/<key> (for :func:`read_recording`), and what a reader sees of it.

        key: a robot's name (a snapshot it published) or "fused". A robot's snapshot gives its landmarks' 1-σ
        ellipsoids in the 3-D world (hidden by default) and, once the fusion placed its frame, its path in the fused
        map. The fused map is drawn in the 3-D world and in the fused 2-D map, each landmark in the colour of the
        robot that saw it, white when several did. A logger that does not record fusions logs no "fused" map.
        """
        if key == "fused" and not self.records_fusion:
            return
        self._rows.set_time(t)
        m = landmark_map
        optional = {name: getattr(m, name) for name in OPTIONAL_MAP_ARRAYS if getattr(m, name) is not None}
        # which optional arrays the snapshot holds is said in its metadata (AnyValues does not store an empty
        # array, so a map of no landmarks could not tell "none" from "empty" otherwise); absent in older recordings
        meta = json.dumps({"robot": m.robot, "frame": m.frame, "robots": m.robots, "metadata": m.metadata,
                           **({"optional": sorted(optional)} if optional else {})})
        arrays = map_arrays(m.positions, m.covariances, m.descriptors, m.ids, m.counts, m.seen_by, m.trajectory,
                            **optional)
        self.rec.log(f"maps/{key}", rr.AnyValues(
            **{name: a.ravel() for name, a in arrays.items()}, descriptor_size=int(m.descriptor_size),
            meta=meta, size=len(m), t=float(t), checksum=map_checksum(arrays, meta)))
        if not draw:
            return
        if key == "fused":
            self._place_fused_frame(m.metadata)
            colours = self._seen_by_colours(m)
            self.log_landmarks("fused", t, None, m.positions, m.covariances, path="world/fused/landmarks",
                               colours=colours)
            shared = m.seen_by.sum(axis=1) > 1 if len(m) else np.zeros(0, bool)
            self.rec.log(f"{self._map_root('fused')}/landmarks",
                         rr.Points2D(m.positions[:, :2], radii=np.where(shared, -4.0, -2.5), colors=colours,
                                     draw_order=6.0))
            return
        self.colour(key)
        self._log_self_check(key, t, m.metadata)
        self._log_ellipsoids(f"world/{key}/landmarks/covariance", m.positions, m.covariances, dimmed(robot_colour(key)))
        path = m.trajectory[:, 1:3]
        if len(path) > SNAPSHOT_TRAJECTORY_POINTS:
            path = path[np.linspace(0, len(path) - 1, SNAPSHOT_TRAJECTORY_POINTS).astype(int)]
        self._snapshot_paths[key] = path
        if key in self._aligned:
            self._log_fused_path(key)

    def _place_fused_frame(self, metadata: Mapping) -> None:
        """Place the fused map's frame (world/fused, and the walls of its 2-D map) where the map says it is: its
        ``true_start_pose``, the reference robot's true start (mocks, simulations). A caller places "fused" at its own
        first robot's start (runtime/mission.py), which is the reference only in the process that logs every robot: a
        fleet's robot2 process placed it at robot2's start, and its fused map, in robot1's frame, was drawn 180° about
        in the 3-D world and over walls 24 m off in its 2-D map. A map without a valid one leaves the placement as it
        is."""
        try:
            start = np.asarray((metadata or {}).get("true_start_pose"), float).reshape(3)
        except (TypeError, ValueError):
            return
        placed = self._placements.get("fused")
        if np.isfinite(start).all() and (placed is None or not np.allclose(placed, start)):
            self.log_robot_frame("fused", start)

    def _log_self_check(self, robot: str, t: float, metadata: Mapping) -> None:
        """A snapshot's self-check (runtime/map_self_check.py): its CUSUM beside its threshold under
        plots/<robot>/self_check, and a warning event the first time the map says it lost its place."""
        from runtime.map_self_check import lost_text, read_self_check

        try:
            verdict = read_self_check(metadata)
        except ValueError as e:
            if self._first_time(f"self_check/bad/{robot}"):
                self.log_event(t, f"{robot}: {e}", "WARN")
            return
        if verdict is None:
            return
        self.log_scalars(robot, t, {"self_check": verdict["statistic"], "self_check/threshold": verdict["threshold"]})
        text = lost_text(verdict)
        if text is not None and self._first_time(f"self_check/lost/{robot}"):
            self.log_event(t, f"{robot}: map {text}", "WARN")

    def _seen_by_colours(self, m: LandmarkMap) -> np.ndarray:
        """(N, 3) uint8: the colour of the only robot that saw each landmark, white if several did."""
        if not len(m):
            return np.zeros((0, 3), np.uint8)
        palette = np.array([robot_colour(r) for r in m.robots] + [SHARED_COLOUR], np.uint8)
        seen = m.seen_by
        which = np.where(seen.sum(axis=1) == 1, np.argmax(seen, axis=1), len(m.robots))
        return palette[which]

    def _log_fused_path(self, robot: str) -> None:
        path = self._snapshot_paths.get(robot)
        if path is None or len(path) < 2:
            return
        self.rec.log(f"{self._map_root('fused')}/{robot}/trajectory",
                     rr.LineStrips2D([path], colors=robot_colour(robot), radii=-2.0, draw_order=3.0))
        self.rec.log(f"map/fused/{robot}/pose", rr.Points2D([path[-1]], radii=-6.0, colors=robot_colour(robot),
                                                            labels=[robot], show_labels=True, draw_order=10.0))

    def log_alignment(self, t: float, reference: str, other: str, result: Mapping) -> None:
        """One pairwise alignment: ``result`` is plain JSON-able data (tx, ty, theta of ``other``'s frame in
        ``reference``'s, supports, errors...). An alignment found places ``other``'s path in the fused map. Nothing
        from a logger that does not record fusions."""
        if not self.records_fusion:
            return
        self._rows.set_time(t)
        self.rec.log(f"fusion/alignment/{reference}_{other}", rr.AnyValues(json=json.dumps(dict(result))))
        with self._lock:  # one paragraph per pair (bounded by the pairs), the document re-logged whole
            self._status[(reference, other)] = alignment_status(t, {"reference": reference, "other": other,
                                                                    **result})
            document = "\n\n".join(self._status[key] for key in sorted(self._status))
        self.rec.log(FUSION_STATUS, rr.TextDocument(document, media_type="text/markdown"))
        values = {k: result.get(k) for k in ("error_xy", "error_theta", "common", "merged")}
        values = {k: v for k, v in values.items() if isinstance(v, int | float) and not isinstance(v, bool)}
        self.log_scalars("fusion", t, values)
        candidate = candidate_text({"reference": reference, "other": other, **result})  # found once, unconfirmed
        if candidate is not None:
            self.log_event(t, f"fusion: {candidate}", "INFO")
        split = result.get("self_check")   # a flagged map split at its alarm (fusion/split.py): once per decision
        if split and self._first_time(f"fusion/split/{reference}_{other}/{result.get('split_decision')}"):
            self.log_event(t, f"fusion: {split}", "INFO" if result.get("split_decision") == "whole" else "WARN")
        pose = np.array([result.get(k, np.nan) for k in ("tx", "ty", "theta")], float)
        if result.get("aligned", True) and np.isfinite(pose).all():
            root = self._map_root("fused")
            for robot, placement in ((reference, np.zeros(3)), (other, pose)):
                self._aligned[robot] = placement
                self.rec.log(f"{root}/{robot}", rr.Transform3D(translation=[placement[0], placement[1], 0.0],
                                                               quaternion=_quaternion_z(placement[2])))
                self._log_fused_path(robot)

    def log_summary(self, summary: Mapping) -> None:
        """The mission's figures, as JSON (read back by :func:`read_recording`) and as a text panel (the layout's
        summary tab): a mission's summary as the command printed it (runtime.report.format_summary's tables: robots'
        landmarks, frames, errors and times, each pair's alignment with its supports, P(chance), 1 σ and error, the
        merged map), any other (a data set's run, a fusion node's) as a table of its figures (:func:`_figures_table`;
        the JSON keeps every digit)."""
        text = json.dumps(dict(summary), indent=2, default=float)
        self.rec.log(SUMMARY, rr.AnyValues(json=text), static=True)
        try:
            shown = f"```\n{format_summary(dict(summary))}\n```"
        except Exception:   # not a mission's summary (a view never fails the mission that logs it)
            shown = _figures_table(summary)
        self.rec.log(SUMMARY, rr.TextDocument(shown, media_type="text/markdown"), static=True)


def _figures_table(summary: Mapping) -> str:
    """A summary's figures as a Markdown table, one row per key: numbers to 4 significant digits (a data set run's
    JSON shows 0.08796996940001048 m), yes/no, lists joined by '; ', anything else as compact JSON."""
    def shown(value) -> str:
        if isinstance(value, bool):
            return "yes" if value else "no"
        if isinstance(value, float):
            return f"{value:.4g}"
        if isinstance(value, list | tuple) and all(isinstance(v, str) for v in value):
            return "; ".join(value) or "none"
        if isinstance(value, str):
            return value
        return json.dumps(value, default=float)

    def cell(text: str) -> str:
        return " ".join(text.split()).replace("|", "\\|")

    rows = [f"| {cell(str(key))} | {cell(shown(value))} |" for key, value in summary.items()]
    return "\n".join(["| figure | value |", "|---|---|", *rows])


__all__ = ["NO_FUSION_YET", "WRITER_LOOK_CALLS", "MissionLog", "RecordingError", "landmark_confirmed"]
