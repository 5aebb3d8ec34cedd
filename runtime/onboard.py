"""The onboard runtime of one robot: drivers on their own threads, odometry at each frame, front end, FastSLAM.

Threads (all named, daemonic, joined on :meth:`Onboard.stop`)::

    driver reader (the driver's)  -> _on_odometry: buffer + sensor log, returns at once
    camera:<robot>                -> reads frames, logs them, offers them to a bounded queue (drops the oldest)
    slam:<robot>                  -> waits until odometry covers the frame's time, then front end + FastSLAM,
                                     Rerun, map snapshots published on the exchange every snapshot_interval
    control:<robot>               -> the motion controller at control_rate, sends (v, ω) to the robot

On the wall clock a stage that falls behind loses frames (counted as ``dropped_frames`` and logged), never
blocks a driver. On a lockstep clock (simulated time, ``mocks.simclock.SimClock``: anything with
``wait_for`` and ``sleep_until``) every thread is a participant that waits only through the clock: the
camera waits for room in the queue rather than dropping, the SLAM stage for its frame and its odometry, the
control loop for its next tick (half a SIP cycle after the SIPs); time waits for the slowest stage, so the
result does not depend on the machine's speed.

Supervision: every thread runs inside a guard; a stage that raises is reported at once (``on_event`` and the
Rerun event log, level ERROR), the robot's motors are stopped, its other stages end, and ``failure`` says
which stage failed and why (``on_failure`` is called), so a mission never runs on with a robot blind.

:class:`SlamCore` is the deterministic heart (no threads, no clock): the live runtime and ``p3at replay``
both feed it, so a replay of a sensor log with the same settings rebuilds the same map.
"""
from __future__ import annotations

import bisect
import contextlib
import queue
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from estimation.errors import MapFileError
from estimation.fastslam import FastSLAM, FastSLAMConfig
from estimation.frontend import FrontEnd, FrontEndConfig
from estimation.geometry import between, compose, wrap_angle
from estimation.landmark_map import LandmarkMap, check_map_bytes
from estimation.observations import OdometryIncrement, StereoObservations
from estimation.stereo_readings import KeyframeRule, ReadingsRecorder, SmoothedMap, SmoothingRefused, smoothed_map
from runtime import slam_frames
from runtime.exchange import MapExchange
from runtime.motion import Controller, NoMotion
from runtime.report import scales_text
from runtime.sensorlog import SensorLogError, SensorLogWriter
from runtime.trajectories import TrajectoryRecorder

Clock = Callable[[], float]

STAGE_END_TIMEOUT = 10.0   # seconds (on the clock) a stage thread has to end after the stop before it is a failure


def is_lockstep(clock: object) -> bool:
    """Does ``clock`` offer simulated-time waits (``wait_for``, ``sleep_until``, participants)?"""
    return all(callable(getattr(clock, name, None)) for name in ("wait_for", "sleep_until", "add_participant"))


@dataclass(frozen=True)
class StageFailure:
    """A runtime thread that raised: which robot, which stage, what error."""

    robot: str
    stage: str
    error: str
    t: float          # mission time, s

    def __str__(self) -> str:
        return f"{self.robot}: the {self.stage} stage failed at t={self.t:.2f} s: {self.error}"


# -- the runtime's own view of the sensors (adapters.py converts driver types into these) ------------------
@dataclass(frozen=True)
class OdometrySample:
    """One SIP as the runtime needs it. t: seconds (runtime clock); pose (3,) odometry frame (m, rad)."""

    t: float
    pose: np.ndarray
    v: float = 0.0
    w: float = 0.0
    stalled: bool = False
    sonar_ranges: np.ndarray = field(default_factory=lambda: np.zeros(0))      # (S,) m, nan = no reading
    sonar_poses: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (S, 3) in base_link
    raw: bytes = b""                                                           # the SIP payload, for logs


@dataclass(frozen=True)
class CameraFrame:
    """One stereo frame: t seconds (runtime clock), seq the camera's counter.

    Either a rectified pair ``left``/``right`` ((H, W) or (H, W, 3) uint8) or, from a synthetic camera,
    ready ``observations``.
    """

    t: float
    seq: int
    left: np.ndarray | None = None
    right: np.ndarray | None = None
    observations: StereoObservations | None = None


class RobotLink(Protocol):
    """What the runtime needs of a mobile base (adapters.P3ATLink wraps the ARCOS driver)."""

    def subscribe(self, callback: Callable[[OdometrySample], None]) -> None: ...
    def set_velocity(self, v: float, w: float) -> None: ...
    def enable_motors(self, on: bool) -> None: ...
    def close(self) -> None: ...


class Camera(Protocol):
    """What the runtime needs of a stereo head: blocking reads of the next frame."""

    def read(self, timeout: float) -> CameraFrame | None: ...   # None: nothing within timeout
    def close(self) -> None: ...


class OdometryBuffer:
    """Thread-safe, time-ordered odometry samples with interpolation at any covered time."""

    def __init__(self, horizon: int = 3000) -> None:
        self._times: deque[float] = deque(maxlen=horizon)
        self._poses: deque[np.ndarray] = deque(maxlen=horizon)
        self._cond = threading.Condition()

    def add(self, t: float, pose: np.ndarray) -> None:
        """A sample stamped ``t``. Samples stamped alike came in one read (a driver that had fallen behind
        stamps a backlog with its read time): the newest is the pose at ``t``, the older ones are of earlier,
        unknown instants and are dropped. An out-of-order stamp is ignored."""
        with self._cond:
            if self._times and t < self._times[-1]:
                return
            if self._times and t == self._times[-1]:
                self._poses[-1] = np.asarray(pose, float)
            else:
                self._times.append(float(t))
                self._poses.append(np.asarray(pose, float))
            self._cond.notify_all()

    @property
    def latest_time(self) -> float:
        with self._cond:
            return self._times[-1] if self._times else -np.inf

    def wait_until(self, t: float, timeout: float) -> bool:
        """Block until a sample at or after ``t`` is in (True) or ``timeout`` seconds pass (False)."""
        with self._cond:
            return self._cond.wait_for(lambda: bool(self._times) and self._times[-1] >= t, timeout)

    def interpolate(self, t: float) -> np.ndarray | None:
        """Pose (3,) at time t, linear between the two samples around it; None if t is not covered."""
        with self._cond:
            times = list(self._times)
            if not times or t < times[0] or t > times[-1]:
                return None
            i = bisect.bisect_left(times, t)
            if times[i] == t:
                return self._poses[i].copy()
            t0, t1 = times[i - 1], times[i]
            p0, p1 = self._poses[i - 1], self._poses[i]
        s = (t - t0) / (t1 - t0)
        return np.array([p0[0] + s * (p1[0] - p0[0]), p0[1] + s * (p1[1] - p0[1]),
                         wrap_angle(p0[2] + s * wrap_angle(p1[2] - p0[2]))])


def log_step(logger, robot: str, t: float, frame: CameraFrame, result: StepResult, particle_poses: np.ndarray, *,
             true_pose: np.ndarray | None = None, head_mount=None, dropped: int = 0,
             landmarks: LandmarkMap | None = None, odometry_pose: np.ndarray | None = None,
             confirm_count: int | None = None) -> None:
    """What the runtime sends to Rerun for one processed frame (the Onboard and the pipeline benchmark share it).

    logger: a ``runtime.rerun_log.MissionLog``; t: seconds since the mission started (the mission's clock);
    particle_poses: (M, 3); true_pose, odometry_pose: (3,) in the map frame (the truth on mocks; odometry alone);
    landmarks: the best particle's map, provisional landmarks included, when it is due (every few frames only);
    confirm_count: FastSLAM's setting, which tells confirmed from provisional landmarks (default: FastSLAM's).
    """
    logger.log_pose(robot, t, frame.seq, result.best_pose, true_pose, head_mount, odometry=odometry_pose)
    logger.log_particles(robot, t, frame.seq, particle_poses)
    logger.log_scalars(robot, t, {
        "ess": result.ess, "landmarks/all": result.landmarks, "observations": result.n_observations,
        "dropped": dropped, **{f"time/{k}": 1000.0 * v for k, v in result.timings.items()}}, frame=frame.seq)
    if result.matches is not None:
        logger.log_stereo(robot, t, frame.seq, frame.left, frame.right, result.matches.left_pixels,
                          result.matches.right_pixels)
    if landmarks is not None:
        logger.log_robot_landmarks(robot, t, frame.seq, landmarks, confirm_count)


# -- the deterministic core ---------------------------------------------------------------------------------
P3AT_INSCRIBED_RADIUS_M = 0.2525      # half the P3-AT's 505 mm width (its length is 626 mm)


@dataclass(frozen=True)
class OnboardConfig:
    """Settings of one robot's pipeline (dumped with a sensor log so a replay can reuse or change them)."""

    fastslam: FastSLAMConfig = field(default_factory=FastSLAMConfig)
    frontend: FrontEndConfig = field(default_factory=FrontEndConfig)
    seed: int = 0
    snapshot_interval: float = 5.0     # s between map snapshots published on the exchange
    frame_queue: int = 2               # frames waiting for the SLAM stage before the oldest is dropped
    odometry_wait: float = 1.0         # s a frame waits for odometry covering its time before it is dropped
    control_rate: float = 10.0         # Hz
    landmarks_every: int = 5           # frames between landmark (+ellipsoid) logs to Rerun
    sonar_every: int = 3               # SIPs between sonar-ray logs
    steer_on_estimate: bool = False    # the controller gets FastSLAM's pose (odometry corrected at the last
                                       # frame) rather than raw odometry: for robots whose odometry drifts
    control_phase: float = 0.05        # s after the mission start of the first control tick (lockstep clock):
                                       # half a SIP cycle, so each command sees the newest SIP
    # the radius of the disc inscribed in the robot's footprint, written into the map (metadata footprint_radius_m)
    # for fusion's co-location test: a P3-AT is 626 x 505 mm (ARIA's p3at parameters,
    # /work/shared/reference/arcos-protocol.md), so 0.2525 m
    footprint_radius_m: float = P3AT_INSCRIBED_RADIUS_M
    # keep the readings of each keyframe (estimation.stereo_readings.ReadingsRecorder with KeyframeRule's 0.1 m /
    # 0.1 rad, within its cap of 1,000 keyframes) so that the map can be smoothed after the mission
    # (SlamCore.smoothed_map; p3at demo/run --smooth); off: nothing is kept
    keep_readings: bool = False


@dataclass
class StepResult:
    """What one frame did: observations count, timings (s) per stage, the filter's state after it."""

    seq: int
    t: float
    n_observations: int
    ess: float
    landmarks: int
    best_pose: np.ndarray
    timings: dict[str, float]
    matches: object | None = None     # the front end's StereoMatches (pixels for Rerun), if images were given


class SlamCore:
    """Front end + FastSLAM on a stream of (frame, odometry pose at the frame's time). No threads, no clock.

    The map frame is the robot's start frame: the first frame's odometry pose is its origin.
    """

    def __init__(self, robot: str, config: OnboardConfig, front_end: FrontEnd | None = None,
                 timer: Clock = time.perf_counter) -> None:
        self.robot = robot
        self.config = config
        self.front_end = front_end if front_end is not None else FrontEnd(config.frontend)
        self.slam = FastSLAM(config.fastslam, np.random.default_rng(config.seed))
        self.timer = timer
        self.previous_odometry: np.ndarray | None = None
        self.first_odometry: np.ndarray | None = None     # the odometry pose at the map frame's origin
        self.frames = 0
        self.totals: dict[str, float] = {"frontend": 0.0, "predict": 0.0, "update": 0.0}
        self.metadata: dict = {}
        # each frame's readings for the smoothing after the mission (config.keep_readings), None when off
        # keyframes, not every frame: at 15 Hz every frame would pass the dense smoother's 1,000-frame cap after
        # ~67 s; at 0.1 m / 0.1 rad it lasts ~300 s of the demo's routes (session 51)
        self.readings = (ReadingsRecorder(config.fastslam.descriptor_size, keyframes=KeyframeRule(),
                                          config=config.fastslam) if config.keep_readings else None)
        # why the readings stopped being kept during the run (an error in keeping them), None while they are kept
        self.readings_failure: str | None = None
        self.frames_too_near = 0   # frames the front end dropped: a scene nearer than the head can measure

    def step(self, frame: CameraFrame, odometry_pose: np.ndarray) -> StepResult:
        timings: dict[str, float] = {}
        t0 = self.timer()
        matches = None
        if frame.observations is not None:
            observations = frame.observations
        else:
            matches = self.front_end.match(frame.left, frame.right)
            observations = matches.to_observations(frame.t)
            # a frame facing a surface nearer than the head measures gives no reading (the filter only predicts)
            self.frames_too_near += bool(matches.near_scene)
        t1 = self.timer()
        timings["frontend"] = t1 - t0
        if self.previous_odometry is not None:
            dx, dy, dtheta = between(self.previous_odometry, odometry_pose)
            increment_t0 = frame.t if self.frames == 0 else self._last_t
            self.slam.predict(OdometryIncrement(float(dx), float(dy), float(dtheta), increment_t0, frame.t))
        self.previous_odometry = np.asarray(odometry_pose, float)
        if self.first_odometry is None:
            self.first_odometry = self.previous_odometry
        t2 = self.timer()
        timings["predict"] = t2 - t1
        report = self.slam.update(observations)
        t3 = self.timer()
        timings["update"] = t3 - t2
        if self.readings is not None:
            try:
                self.readings.add(frame.t, odometry_pose, observations)
            except Exception as exc:  # noqa: BLE001 - keeping the smoothing's readings must not end the robot's run
                # nothing more is kept (a log with a hole would be no one map) and the smoothing is refused with this
                self.readings_failure = (f"keeping the readings failed at frame {self.frames + 1}: "
                                         f"{type(exc).__name__}: {' '.join(str(exc).split())}")
                self.readings = None
        self._last_t = frame.t
        self.frames += 1
        for k, v in timings.items():
            self.totals[k] += v
        landmarks = int(self.slam.particle_landmark_count()[self.slam.best_index])
        return StepResult(frame.seq, frame.t, len(observations), float(report.ess), landmarks,
                          self.slam.best_pose(), timings, matches)

    def best_map(self) -> LandmarkMap:
        return self.slam.best_map(robot=self.robot, metadata=self.metadata)

    def smoothed_map(self, exported: LandmarkMap) -> SmoothedMap:
        """``exported`` (this core's :meth:`best_map`, as the caller made it) smoothed over the readings kept
        (estimation.stereo_readings.smoothed_map). Raises SmoothingRefused (one line) when it cannot be: readings
        not kept, the cap passed, too few frames, no reading matching the map..."""
        if self.readings is None:
            raise SmoothingRefused(self.readings_failure or "no readings were kept (keep_readings is off)")
        kept = self.readings.readings_kept()
        particle = self.slam.best_map(robot=self.robot, metadata=self.metadata, covariance="particle")
        # the odometry's distance and turn scales estimated with the poses (Kümmerle et al. 2011): wheel odometry's
        # errors are systematic (tyre wear, a skid-steer's effective track), and the smoother's random-walk
        # increments alone followed a turn on the spot measured 4 % short (session 52: the demo's keyframe heading
        # error 10.4 -> 6.5 mrad median; the mock's 0.99 / 0.961 recovered within σ on 20 of 20 maps)
        return smoothed_map(kept, self.slam.trajectory(), exported, particle.positions, particle.covariances,
                            self.config.fastslam, calibrate_odometry=True)

    def dead_reckoning_pose(self) -> np.ndarray | None:
        """Odometry alone at the last frame, in the map frame (3,): what FastSLAM improves on."""
        if self.first_odometry is None:
            return None
        return between(self.first_odometry, self.previous_odometry)


def _unreadable(m: LandmarkMap, source: str) -> str | None:
    """Why the map's reader would refuse ``m`` (the check :meth:`LandmarkMap.save` makes before it writes), in one
    line beginning ``source``; None if it would not."""
    try:
        check_map_bytes(m.archive_bytes(), source)
    except MapFileError as exc:
        return str(exc)
    return None


# -- the live runtime ---------------------------------------------------------------------------------------
@dataclass
class OnboardStats:
    frames_received: int = 0
    frames_processed: int = 0
    dropped_frames: int = 0          # the SLAM stage was behind: the oldest waiting frame was discarded
    frames_without_odometry: int = 0
    odometry_samples: int = 0
    snapshots: int = 0
    map_landmarks: int = 0           # in the last snapshot: the exported map (the best particle's confirmed
    #                                  landmarks, coincident ones merged: FastSLAM.best_map), as saved
    camera_errors: int = 0
    stage_seconds: dict[str, float] = field(default_factory=dict)


@dataclass
class SmoothingOutcome:
    """:meth:`Onboard.smooth_final_map`'s answer: the filter's final map, the smoothed one (None: not smoothed) and
    the figures (frames/readings kept, readings seen, matched, inliers, cut, χ²/dof, landmarks held, seconds;
    ``smoothed`` and ``reason``: why not)."""

    filter_map: LandmarkMap
    smoothed: LandmarkMap | None
    figures: dict


class Onboard:
    """One robot's runtime. ``start()``, then ``stop()`` (idempotent: motors stopped, threads joined, files
    flushed). ``logger`` is a :class:`runtime.rerun_log.MissionLog` or None; ``truth`` returns the robot's
    true world pose (mocks only); ``t0`` is the mission's start on the clock.
    """

    def __init__(self, robot: str, link: RobotLink, camera: Camera, config: OnboardConfig, *,
                 exchange: MapExchange | None = None, controller: Controller | None = None,
                 logger=None, sensor_log: SensorLogWriter | None = None, clock: Clock = time.monotonic,
                 t0: float | None = None, truth: Callable[[], np.ndarray] | None = None,
                 true_start: np.ndarray | None = None, head_mount: tuple[float, float, float] | None = None,
                 on_event: Callable[[str], None] | None = None, front_end: FrontEnd | None = None,
                 on_failure: Callable[[StageFailure], None] | None = None, time_base: str | None = None) -> None:
        self.robot, self.link, self.camera, self.config = robot, link, camera, config
        self.exchange, self.logger, self.sensor_log = exchange, logger, sensor_log
        self.controller = controller or NoMotion()
        self.clock = clock
        self.lockstep = is_lockstep(clock)
        self.on_failure = on_failure or (lambda failure: None)
        self.failure: StageFailure | None = None
        self.t0 = clock() if t0 is None else t0
        self.truth, self.true_start = truth, true_start
        self.head_mount = head_mount
        self.on_event = on_event or (lambda text: None)
        self.core = SlamCore(robot, config, front_end)
        if true_start is not None:
            self.core.metadata["true_start_pose"] = [float(v) for v in true_start]
        # what fusion's co-location test needs (fusion/colocation.py): the body, and the name of the clock the frames
        # (so the map's trajectory) are stamped on, when the caller knows other robots share it (a mission's robots)
        self.core.metadata["footprint_radius_m"] = float(config.footprint_radius_m)
        if time_base is not None:
            self.core.metadata["clock"] = str(time_base)
        # estimated, odometry and (mocks) true pose per processed frame, for the TUM files beside the map
        self.trajectories = TrajectoryRecorder(true_start if truth is not None else None)
        self.odometry = OdometryBuffer()
        self.stats = OnboardStats()
        self.route_done = threading.Event()
        self._recoveries_seen = self._skipped_seen = 0  # the controller's counts already reported
        self._frames: queue.Queue[CameraFrame] = queue.Queue(maxsize=max(1, config.frame_queue))
        self._stop = threading.Event()
        self._latest: OdometrySample | None = None
        self._latest_lock = threading.Lock()
        self._core_lock = threading.Lock()
        self._threads: list[tuple[str, threading.Thread, object]] = []   # (stage, thread, participant or None)
        self._last_snapshot = -np.inf
        self._stopped = False
        self._stop_time: float | None = None   # mission time at request_stop (None: not requested)
        self._anchor: np.ndarray | None = None            # best pose at the last frame (map frame) ...
        self._anchor_odometry: np.ndarray | None = None   # ... and the odometry pose it corresponds to
        self.errors: list[str] = []
        self.final_true_pose: np.ndarray | None = None   # the truth when stopped (mocks only)
        self._readings_overflow_said = False

    # -- lifecycle -------------------------------------------------------------------------------------
    def start(self) -> None:
        self.link.subscribe(self._on_odometry)
        self.link.enable_motors(True)
        for name, target in (("camera", self._camera_loop), ("slam", self._slam_loop),
                             ("control", self._control_loop)):
            self._spawn(name, target)

    def _spawn(self, stage: str, target: Callable[[], None]) -> None:
        """A named daemon thread running ``target`` under supervision (and as a participant of a lockstep clock,
        registered now so that simulated time cannot pass its first action)."""
        # the camera thread only carries frames from the sensor to the queue: a part of the (virtual) world that
        # reads nothing the runtime has received, so it may render while a SIP is still on its way
        token = self.clock.add_participant(f"{stage}:{self.robot}", world=stage == "camera") if self.lockstep \
            else None

        def run() -> None:
            with self.clock.participant(token) if token is not None else contextlib.nullcontext():
                try:
                    target()
                except BaseException as exc:  # noqa: BLE001 - the supervisor reports it and stops the robot
                    self._fail(stage, exc)

        thread = threading.Thread(target=run, name=f"{stage}:{self.robot}", daemon=True)
        try:
            thread.start()
        except BaseException:
            if token is not None:
                self.clock.discard(token)
            raise
        self._threads.append((stage, thread, token))

    def _fail(self, stage: str, exc: BaseException) -> None:
        """A stage raised: report it at once, stop this robot (motors first), tell the owner."""
        if self.failure is not None:
            return
        self.failure = StageFailure(self.robot, stage, f"{type(exc).__name__}: {exc}", self.mission_time)
        self._event(f"the {stage} stage failed: {type(exc).__name__}: {exc}; stopping the robot", "ERROR")
        self._stop.set()
        self._halt_motors()
        self.on_failure(self.failure)

    def request_stop(self) -> None:
        """Stop the motors and tell every thread to end (returns at once; idempotent). On a lockstep clock,
        call it from a participant: every thread then ends at this simulated instant."""
        if self._stop_time is not None:
            return
        self._stop_time = self.mission_time
        self._stop.set()
        self._halt_motors()
        if self.truth is not None:
            try:
                self.final_true_pose = np.asarray(self.truth(), float)
            except LookupError:  # the virtual robot is already gone
                pass

    def stop(self) -> None:
        """Stop the motors first, then the threads; publish a last snapshot; flush the sensor log.

        On a lockstep clock, call it from a participant (the mission's): the stages then end at the stop's
        simulated instant, the wait for the robot to stand still and the sensor log's last records are the same
        however busy the machine is. A stage that has not ended :data:`STAGE_END_TIMEOUT` seconds after the stop
        is a failure (``on_failure``), and the stop goes on without it."""
        if self._stopped:
            return
        self._stopped = True
        self.request_stop()
        self._join_stages()
        self._halt_motors()
        self._wait_until_still(timeout=3.0)
        self.publish_snapshot(force=True)
        if self.sensor_log is not None:
            try:
                self.sensor_log.close()
            except SensorLogError as exc:
                # its last records could not be written (a full disk): a failure of the log, as one during the run
                # is, not an exception that would lose the rest of the stop and the mission's end
                failure = StageFailure(self.robot, "sensor log", str(exc), self.mission_time)
                self.failure = self.failure or failure
                self.on_failure(failure)

    def _join_stages(self) -> None:
        """Wait for every stage thread to end, each for up to :data:`STAGE_END_TIMEOUT` s. On a lockstep clock the
        wait is for its participant to be discarded (the clock sees that at a simulated instant: the thread's
        last act as a participant) and only then for the thread itself, which has nothing left but to return; a
        wait for the thread alone would let simulated time run while it returns, longer the busier the machine."""
        late = []
        for stage, thread, token in self._threads:
            if token is not None:
                self.clock.wait_for(lambda token=token: token.discarded, timeout=STAGE_END_TIMEOUT)
            thread.join(timeout=STAGE_END_TIMEOUT if token is None or token.discarded else 0.0)
            if thread.is_alive():
                late.append(stage)
        if late:
            failure = StageFailure(self.robot, late[0], f"did not end within {STAGE_END_TIMEOUT:g} s of the stop "
                                   f"({', '.join(late)} still running)", self.mission_time)
            self.failure = self.failure or failure
            self._event(f"the {' and '.join(late)} stage{'s' if len(late) > 1 else ''} did not end within "
                        f"{STAGE_END_TIMEOUT:g} s of the stop; stopping without {'them' if len(late) > 1 else 'it'}",
                        "ERROR")
            self.on_failure(failure)

    def _wait_until_still(self, timeout: float) -> bool:
        """Wait until the robot reports it stands still, so the logs end with the stop."""
        def still() -> bool:
            sample = self.latest()
            return sample is None or (abs(sample.v) < 0.01 and abs(sample.w) < 0.01)
        if self.lockstep:
            return self.clock.wait_for(still, timeout=timeout)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if still():
                return True
            time.sleep(0.05)
        return False

    def _pause(self, seconds: float) -> bool:
        """Wait ``seconds`` (on the clock) unless stopped; True if stopped."""
        if self.lockstep:
            return self.clock.wait_for(self._stop.is_set, timeout=seconds)
        return self._stop.wait(seconds)

    def _halt_motors(self) -> None:
        try:
            self.link.set_velocity(0.0, 0.0)
            self.link.enable_motors(False)
        except Exception as e:  # a vanished link: nothing more can be sent; the robot's watchdog stops it
            self.errors.append(f"stopping the motors failed: {e}")

    @property
    def mission_time(self) -> float:
        return self.clock() - self.t0

    def latest(self) -> OdometrySample | None:
        with self._latest_lock:
            return self._latest

    def pose_estimate(self) -> np.ndarray | None:
        """The pose (3,) in the map frame now: the filter's estimate at the last frame moved on by odometry since
        (None before the first frame); safe from any thread."""
        latest = self.latest()
        return None if latest is None else self._map_pose(latest.pose)

    # -- driver callbacks (the driver's thread: must return at once) ---------------------------------------
    def _on_odometry(self, sample: OdometrySample) -> None:
        try:
            self._take_odometry(sample)
        except Exception as exc:  # noqa: BLE001 - the driver would only log it; the supervisor stops the robot
            self._fail("odometry", exc)

    def _take_odometry(self, sample: OdometrySample) -> None:
        with self._latest_lock:
            self._latest = sample
        self.odometry.add(sample.t, sample.pose)
        if self.truth is not None:
            self.trajectories.add_truth(sample.t, self.truth)
        self.stats.odometry_samples += 1
        if self.sensor_log is not None:
            self.sensor_log.write("odometry", odometry_record(sample))
        # the recording ends with the mission: a SIP of the shutdown (the joins take wall time, and simulated time
        # runs on meanwhile: more of it the busier the machine) is in the sensor log, not in the recording
        if self.logger is not None and self.stats.odometry_samples % self.config.sonar_every == 0 \
                and len(sample.sonar_ranges) and (self._stop_time is None or sample.t - self.t0 <= self._stop_time):
            pose = self._map_pose(sample.pose)
            if pose is not None:
                ranges = np.nan_to_num(sample.sonar_ranges, nan=0.0)
                self.logger.log_sonar(self.robot, sample.t - self.t0, pose, sample.sonar_poses, ranges)

    def _map_pose(self, odometry_pose: np.ndarray) -> np.ndarray | None:
        """An odometry pose in the map frame, through the filter's estimate at the last frame (for display)."""
        with self._latest_lock:
            anchor, anchor_odometry = self._anchor, self._anchor_odometry
        if anchor is None:
            return None
        return compose(anchor, between(anchor_odometry, odometry_pose))

    # -- camera thread -------------------------------------------------------------------------------------
    def _camera_loop(self) -> None:
        while not self._stop.is_set():
            try:
                frame = self.camera.read(timeout=0.5)
            except Exception as e:  # a camera error must not take the robot down; count, report, retry
                self.stats.camera_errors += 1
                self._event(f"camera error: {e}", "WARN")
                self._pause(0.5)
                continue
            if frame is None or self._stop.is_set():
                continue
            self.stats.frames_received += 1
            if self.sensor_log is not None:
                self.sensor_log.write(*frame_record(frame))
            if self.lockstep:  # simulated time waits for the SLAM stage: no frame is ever dropped
                self.clock.wait_for(lambda: self._stop.is_set() or not self._frames.full())
                if not self._stop.is_set():
                    self._frames.put_nowait(frame)
                continue
            try:
                self._frames.put_nowait(frame)
            except queue.Full:
                try:
                    old = self._frames.get_nowait()
                    self.stats.dropped_frames += 1
                    if self.stats.dropped_frames in (1, 10, 100) or self.stats.dropped_frames % 500 == 0:
                        self._event(f"SLAM stage behind: dropped frame {old.seq} "
                                    f"({self.stats.dropped_frames} so far)", "WARN")
                except queue.Empty:
                    pass
                self._frames.put_nowait(frame)

    # -- SLAM thread ---------------------------------------------------------------------------------------
    def _next_frame(self) -> CameraFrame | None:
        if self.lockstep:
            self.clock.wait_for(lambda: self._stop.is_set() or not self._frames.empty())
            return None if self._stop.is_set() else self._frames.get_nowait()
        try:
            return self._frames.get(timeout=0.2)
        except queue.Empty:
            return None

    def _odometry_covers(self, t: float) -> bool:
        if self.lockstep:
            return self.clock.wait_for(lambda: self._stop.is_set() or self.odometry.latest_time >= t,
                                       timeout=self.config.odometry_wait) and not self._stop.is_set()
        return self.odometry.wait_until(t, self.config.odometry_wait)

    def _slam_loop(self) -> None:
        while not self._stop.is_set():
            frame = self._next_frame()
            if frame is None:
                continue
            if not self._odometry_covers(frame.t) or self._stop.is_set():
                if not self._stop.is_set():
                    self.stats.frames_without_odometry += 1
                    self._event(f"frame {frame.seq}: no odometry at t={frame.t:.3f}, dropped", "WARN")
                continue
            pose = self.odometry.interpolate(frame.t)
            if pose is None:
                self.stats.frames_without_odometry += 1
                continue
            self.process(frame, pose)

    def process(self, frame: CameraFrame, odometry_pose: np.ndarray) -> StepResult:
        """Run one frame through the core and report it (also the entry point of tests and replay)."""
        with self._core_lock:
            result = self.core.step(frame, odometry_pose)
        readings = self.core.readings
        why = self.core.readings_failure if readings is None else readings.overflow   # the readings no longer kept
        if why is not None and not self._readings_overflow_said:
            self._readings_overflow_said = True
            self._event(f"smoothing: {why}; the filter's map will stand", "WARN")
        self.trajectories.add_frame(frame.t, result.best_pose, self.core.dead_reckoning_pose())
        with self._latest_lock:
            self._anchor = result.best_pose
            self._anchor_odometry = np.asarray(odometry_pose, float)
        self.stats.frames_processed += 1
        for k, v in result.timings.items():
            self.stats.stage_seconds[k] = self.stats.stage_seconds.get(k, 0.0) + v
        if self.sensor_log is not None:
            self.sensor_log.write("processed", {"t": frame.t, "seq": frame.seq})
        self._report(frame, result)
        if frame.t - self.t0 - self._last_snapshot >= self.config.snapshot_interval:
            self.publish_snapshot()
        return result

    def _best_map(self) -> LandmarkMap:
        """The best particle's map with the frame counts of the moment (runtime/slam_frames.py); the caller
        holds the core lock."""
        self.core.metadata[slam_frames.KEY] = slam_frames.frame_counts(self.stats)
        return self.core.best_map()

    def current_map(self) -> LandmarkMap | None:
        """The best particle's map now (None before the first frame); safe from any thread."""
        with self._core_lock:
            return self._best_map() if self.core.frames else None

    def final_map(self) -> LandmarkMap:
        """The best particle's map, also before the first frame (an empty map): what the mission saves at its end."""
        with self._core_lock:
            return self._best_map()

    def smooth_final_map(self) -> SmoothingOutcome:
        """After :meth:`stop`: the best particle's map smoothed over the readings kept (``keep_readings``), published
        on the exchange in place of the filter's last snapshot and logged to Rerun, with one event line saying what
        was done; when it cannot be smoothed (or the smoothing raises), one line saying why, and the filter's map
        stands. Never raises."""
        start = time.perf_counter()
        t = self.mission_time if self._stop_time is None else self._stop_time
        with self._core_lock:
            filter_map = self._best_map()
            kept = self.core.readings
            figures: dict = {"frames_kept": 0 if kept is None else kept.frames,
                             "frames_seen": 0 if kept is None else kept.frames_seen,
                             "readings_kept": 0 if kept is None else kept.readings,
                             "readings_seen": 0 if kept is None else kept.readings_seen}
            try:
                smoothed = self.core.smoothed_map(filter_map)
            except SmoothingRefused as exc:
                reason = str(exc)
            except Exception as exc:  # noqa: BLE001 - a smoothing that fails must not take the mission's end down
                reason = f"the smoothing failed: {type(exc).__name__}: {exc}"
            else:
                # a smoothed map its reader would refuse would fail the map save (OUT/<robot>.npz not written, the
                # mission failed) where the filter's map is at hand: not taken
                reason = _unreadable(smoothed.landmark_map, "the smoothed map would not be readable")
        figures["seconds"] = time.perf_counter() - start
        if reason is not None:
            reason = " ".join(reason.split())   # one line, whatever the error's message was
            self._event(f"the map was not smoothed: {reason}; the filter's map stands", "WARN", t)
            return SmoothingOutcome(filter_map, None, figures | {"smoothed": False, "reason": reason})
        figures |= smoothed.figures
        figures["cut"] = figures["associated"] - figures["inliers"]
        m = smoothed.landmark_map
        self._event(f"the final map is smoothed: {figures['frames']} keyframes of {figures['frames_seen']} frames, "
                    f"{figures['readings']} readings kept, "
                    f"{figures['associated']} matched to the map, {figures['cut']} cut, χ²/dof "
                    f"{figures['chi2_per_dof']:.2f}, {figures['held']} of {figures['landmarks']} landmarks held by "
                    f"readings, {scales_text(figures)}{figures['seconds']:.1f} s", t=t)
        if self.exchange is not None:
            self.exchange.publish(self.robot, m, stamp=t)
        if self.logger is not None:
            self.logger.log_map(self.robot, t, m)
        return SmoothingOutcome(filter_map, m, figures | {"smoothed": True, "reason": None})

    def publish_snapshot(self, force: bool = False) -> LandmarkMap | None:
        if self.core.frames == 0:
            return None
        # after the stop the map is the one of the stop's instant (every stage ended then): stamped so, not with
        # the end of the joins, which on a simulated clock comes later the busier the machine is
        t = self.mission_time if self._stop_time is None else self._stop_time
        with self._core_lock:
            snapshot = self._best_map()
        self._last_snapshot = t
        self.stats.snapshots += 1
        self.stats.map_landmarks = len(snapshot)
        if self.exchange is not None:
            self.exchange.publish(self.robot, snapshot, stamp=t)
        if self.logger is not None:
            self.logger.log_map(self.robot, t, snapshot)
            # the count the progress line, the fleet status and the summary give (the exported map: confirmed,
            # coincident landmarks merged), beside the per-frame counts of the filter's best particle
            self.logger.log_scalars(self.robot, t, {"landmarks/map": len(snapshot)})
        return snapshot

    def _report(self, frame: CameraFrame, result: StepResult) -> None:
        if self.logger is None:
            return
        true_pose = None
        if self.truth is not None and self.true_start is not None:
            true_pose = between(self.true_start, self.truth())
        landmarks = None
        if self.core.frames % self.config.landmarks_every == 0:
            with self._core_lock:
                landmarks = self.core.slam.particle_map(self.core.slam.best_index, 1, self.robot)
        log_step(self.logger, self.robot, frame.t - self.t0, frame, result, self.core.slam.poses,
                 true_pose=true_pose, head_mount=self.head_mount, dropped=self.stats.dropped_frames,
                 landmarks=landmarks, odometry_pose=self.core.dead_reckoning_pose(),
                 confirm_count=self.config.fastslam.confirm_count)

    # -- control thread ------------------------------------------------------------------------------------
    def _ticks(self):
        """Control ticks: every 1/control_rate s; on a lockstep clock at fixed instants after t0."""
        period = 1.0 / self.config.control_rate
        k = 0
        while True:
            if self.lockstep:
                stopped = self.clock.wait_for(self._stop.is_set, until=self.t0 + self.config.control_phase
                                              + k * period)
            else:
                stopped = self._stop.wait(period)
            if stopped:
                return
            k += 1
            yield

    def _control_loop(self) -> None:
        for _ in self._ticks():
            sample = self.latest()
            if sample is None:
                continue
            pose = sample.pose
            if self.config.steer_on_estimate:
                estimate = self._map_pose(sample.pose)
                if estimate is not None and self.core.first_odometry is not None:
                    pose = compose(self.core.first_odometry, estimate)  # back in the odometry frame's origin
            try:
                command = self.controller.command(pose, sample.sonar_poses, sample.sonar_ranges)
                self._report_recoveries()
                if command.done:
                    self.link.set_velocity(0.0, 0.0)
                    if not self.route_done.is_set():
                        self._event("route finished")
                        self.route_done.set()
                    continue
                self.link.set_velocity(command.v, command.w)
            except Exception as e:
                self._event(f"control error: {e}", "WARN")

    def _report_recoveries(self) -> None:
        """Say when the controller backed off an obstacle it was stuck on, or gave a waypoint up."""
        recoveries, skipped = getattr(self.controller, "recoveries", 0), getattr(self.controller, "skipped", 0)
        if recoveries > self._recoveries_seen:
            self._event("stuck (driving, not moving): backing off and trying again", "WARN")
        if skipped > self._skipped_seen:
            self._event("gave a waypoint up after getting stuck on the way to it several times", "WARN")
        self._recoveries_seen, self._skipped_seen = recoveries, skipped

    def _event(self, text: str, level: str = "INFO", t: float | None = None) -> None:
        message = f"{self.robot}: {text}"
        self.on_event(message)
        if self.logger is not None:
            self.logger.log_event(self.mission_time if t is None else t, message, level)


def odometry_record(sample: OdometrySample) -> dict:
    return {"t": sample.t, "x": float(sample.pose[0]), "y": float(sample.pose[1]), "theta": float(sample.pose[2]),
            "v": sample.v, "w": sample.w, "stalled": int(sample.stalled),
            "sonar": np.asarray(sample.sonar_ranges, float), "sonar_poses": np.asarray(sample.sonar_poses, float),
            "raw": np.frombuffer(sample.raw, np.uint8)}


def frame_record(frame: CameraFrame) -> tuple[str, dict]:
    if frame.observations is not None:
        o = frame.observations
        return "observations", {"t": frame.t, "seq": frame.seq, "points": o.points, "covariances": o.covariances,
                                "descriptors": o.descriptors, "pixels": o.pixels}
    return "frames", {"t": frame.t, "seq": frame.seq, "left": frame.left, "right": frame.right}
