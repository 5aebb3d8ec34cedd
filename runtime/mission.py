"""The multi-robot mission: N virtual P3-ATs explore the simulated building, each maps it on board, maps fused.

Each robot is a wire-level virtual P3-AT (``mocks.p3at``) driven by the real ARCOS driver, with a stereo
head (the rendering virtual head through the real Videre driver, or the fast synthetic observer), running
its own :class:`~runtime.onboard.Onboard`. The robots start at the world's start poses, which none of them
knows; they share maps only through the :class:`~runtime.exchange.MapExchange`. A fusion stage (what a base
station or any robot would run) reads the exchange every ``fusion_interval`` seconds and at the end, aligns
every map to the first robot's, merges them, and scores each alignment against the true start poses that
simulated maps carry in their metadata.

Clock: on the virtual hardware the mission runs in simulated time by default (``mocks.simclock.SimClock``,
lockstep: time advances only when every participant has done its part, so a slow or busy machine makes the
mission take longer, never gives it another answer; see docs/runtime.md for who waits for whom).
``realtime=True`` keeps the wall clock (hardware-in-the-loop timing; the virtual heads then drop the frames
they cannot deliver on time). A real robot always runs on the wall clock.

Supervision: a stage that raises ends the mission (motors stopped, an event, a row in the summary's
``failures``); every robot's map is also written to ``OUT/<robot>.npz`` every ``map_save_interval``
simulated seconds, atomically, so a hard kill leaves readable maps.
"""
from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import os
import signal
import threading
import time
import uuid
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from estimation.errors import MapFileError
from estimation.fastslam import FastSLAMConfig
from estimation.frontend import FrontEndConfig, HarrisConfig
from estimation.geometry import between
from estimation.landmark_map import LandmarkMap
from runtime.exchange import InProcessExchange, MapExchange
from runtime.fleet.status import publish_robot_status
from runtime.fusion_report import FusionReport, alignment_cache, fuse_maps, keep_latest_map
from runtime.limits import CAMERAS, MOTIONS  # the spellings the command line offers (runtime/mission_cli.py)
from runtime.motion import NoMotion, PurePursuit, WallFollower, keep_right
from runtime.onboard import Clock, Onboard, OnboardConfig, StageFailure, is_lockstep
from runtime.report import fusion_event_line, fusion_progress_part, start_prior_line


class MissionError(RuntimeError):
    """The mission could not be set up (a mock would not start, a world file is bad...)."""


@dataclass(frozen=True)
class MissionConfig:
    robots: int = 2
    seconds: float = 90.0             # at most; the mission ends earlier when every route is finished
    seed: int = 0
    camera: str = "mock"              # "mock": rendered frames through the Videre driver; "synthetic": observer
    camera_rate: float = 15.0         # Hz
    camera_latency: float | None = None  # s from exposure to arrival (None: the virtual head's; 0 for a real one)
    particles: int = 100
    max_corners: int = 150            # Harris corners per image: fewer observations, faster FastSLAM updates
    max_observations: int = 0         # FastSLAM's cap per frame (0: every observation the front end gives)
    motion: str = "route"             # the world's named routes, the sonar wall follower, or none
    speed: float = 0.35               # m/s along routes
    fusion_interval: float = 20.0     # s between fusions during the mission (0: only at the end)
    preset: str = "robust"            # fusion preset: "robust" or "paper"
    method: int = 1                   # common landmarks: 1 (RANSAC supports, descriptor-checked) or 2 (position)
    snapshot_interval: float = 5.0
    out: Path = Path("p3at-mission")
    rerun: str = "file"               # "file" (OUT/mission.rrd), "spawn", "none", or a rerun+http:// URL
    log_sensors: bool = False         # raw SIPs and frames to OUT/<robot>-log/
    world: Path | None = None
    robot_url: str = "mock"           # "mock" (virtual P3-ATs in the world), or one real robot's URL
    route_file: Path | None = None    # a route (in the robot's odometry frame) instead of the world's routes
    time_scale: float = 1.0           # virtual robots, realtime only: simulated seconds per wall-clock second
    odometry: str = "exact"           # virtual robots' wheel odometry: "exact" or "realistic" (1 % scale, 3 % track)
    robot_name: str | None = None     # this robot's name in a fleet; virtual: the world robot run alone
    realtime: bool = False            # virtual robots: the wall clock instead of simulated time (lockstep)
    robot_process: bool = True        # realtime: serve the virtual robots from their own process (SIP timing)
    map_save_interval: float = 10.0   # s between atomic writes of OUT/<robot>.npz during the mission (0: end only)
    recording_id: str | None = None   # a fleet's processes share one Rerun recording (None: a new one)
    # (σ xy m, σ yaw rad): give the fusion the robots' configured start poses as a rough prior on their relative start
    # (fusion/prior.py); None (the default): the robots are unknown to each other
    start_prior: tuple[float, float] | None = None
    # at the mission's end each robot's map is smoothed over the readings it kept (estimation.stereo_readings) and the
    # final fusion uses the smoothed maps; OUT/<robot>.npz holds the smoothed map, OUT/<robot>-filter.npz the filter's
    smooth: bool = False

    @property
    def on_mocks(self) -> bool:
        return self.robot_url == "mock"

    @property
    def lockstep(self) -> bool:
        """Simulated time: the virtual hardware unless --realtime."""
        return self.on_mocks and not self.realtime

    def __post_init__(self) -> None:
        if self.robots < 1:
            raise ValueError(f"--robots must be at least 1, not {self.robots}")
        if self.camera not in CAMERAS:
            raise ValueError(f"--camera must be one of {', '.join(CAMERAS)}, not {self.camera!r}")
        if self.motion not in MOTIONS:
            raise ValueError(f"--motion must be one of {', '.join(MOTIONS)}, not {self.motion!r}")
        if self.seconds <= 0 or self.camera_rate <= 0 or self.particles < 1:
            raise ValueError("--seconds, --camera-rate and --particles must be positive")
        if not self.on_mocks and self.robots != 1:
            raise ValueError("a real robot URL runs exactly one robot (--robots 1)")
        if not self.on_mocks and self.camera != "usb":
            raise ValueError(f"--robot {self.robot_url}: a robot given by URL needs a real stereo head (--camera usb); "
                             "the virtual heads (mock, synthetic) ride only on the virtual robots (--robot mock)")
        if self.camera_latency is not None and not 0.0 <= self.camera_latency < 1.0:
            raise ValueError(f"--camera-latency must be in [0, 1) s, not {self.camera_latency!r}")
        if self.odometry not in ("exact", "realistic"):
            raise ValueError(f"--odometry must be exact or realistic, not {self.odometry!r}")
        if self.on_mocks and self.camera == "usb":
            raise ValueError("--camera usb needs a real robot (--robot URL); the virtual robots use mock or synthetic")
        if self.time_scale != 1.0 and self.lockstep:
            raise ValueError("--time-scale needs --realtime (simulated time already runs as fast as the machine "
                             "allows)")
        if not self.time_scale > 0:
            raise ValueError(f"--time-scale must be positive, not {self.time_scale!r}")
        if not self.map_save_interval >= 0:
            raise ValueError(f"--map-save-interval must be >= 0, not {self.map_save_interval!r}")
        if self.start_prior is not None and not self.on_mocks:
            raise ValueError("--start-prior gives the fusion the virtual robots' configured start poses; a real robot "
                             "has none")


@dataclass
class RobotSetup:
    name: str
    onboard: Onboard
    true_start: np.ndarray


@dataclass
class MissionResult:
    summary: dict
    maps: dict[str, LandmarkMap]
    fused: LandmarkMap | None
    recording: Path | None
    fusion_history: list[FusionReport] = field(default_factory=list)
    failures: list[StageFailure] = field(default_factory=list)


def _time_base(config: MissionConfig, lockstep: bool) -> str:
    """The name of the one clock this mission's robots stamp their frames on (the maps' metadata 'clock',
    fusion/colocation.py).  Simulated time repeats with the settings (one seed gives identical map files), so it is
    named by them (the output folder aside); a wall-clock run by a fresh id, so maps of two runs, or of robots on
    other hosts (one robot per mission off the mocks), are never taken as sharing it."""
    if not lockstep:
        return f"mission {uuid.uuid4().hex[:12]} (monotonic clock)"
    # the smoothing comes after the clock's last tick: it does not name another clock
    settings = {k: v for k, v in dataclasses.asdict(config).items() if k not in ("out", "smooth")}
    digest = hashlib.sha256(json.dumps(settings, sort_keys=True, default=str).encode()).hexdigest()[:12]
    return f"mission {digest} (simulated clock)"


class Mission:
    """Set up with a config, ``run()`` until the time is up, the routes are done, or ``stop()`` is called."""

    def __init__(self, config: MissionConfig, *, clock: Clock | None = None,
                 progress: Callable[[str], None] | None = None, events: Callable[[str], None] | None = None,
                 exchange: MapExchange | None = None, warnings: Callable[[str], None] | None = None) -> None:
        self.config = config
        if clock is None and config.lockstep:
            from mocks.simclock import SimClock

            clock = SimClock()
            self._own_clock = True
        else:
            self._own_clock = False
        self.clock = clock if clock is not None else time.monotonic
        self.lockstep = is_lockstep(self.clock)
        self.time_base = _time_base(config, self.lockstep)
        self.progress = progress or (lambda line: None)
        self.events = events or (lambda line: None)
        self.warnings = warnings   # lines said at once, also under --quiet (None: MissionLog's own, on stderr)
        self.exchange = exchange if exchange is not None else InProcessExchange()
        self._stop = threading.Event()
        self.robots: list[RobotSetup] = []
        self._virtual_heads: dict = {}  # robot -> its VirtualStereoHead (mock cameras), for the late-frame count
        self.fusion_history: list[FusionReport] = []
        # alignments of maps unchanged since an earlier fusion; a live fusion's found is a candidate until the next
        # one agrees (fusion/confirmation.py); the final fusion after every route is done is decided on the maps alone
        self.fusion_cache = alignment_cache(confirm_after=self.config.fusion_interval or None)
        self.logger = None
        self.recording_path: Path | None = None
        # an earlier run's OUT/mission.rrd is replaced only once every robot is set up: until then the new recording
        # is written beside it (a run that fails at start must not leave an empty recording in its place)
        self._recording_pending: Path | None = None
        self.failures: list[StageFailure] = []
        self._servers: dict = {}   # robot -> its virtual P3-AT's server (mocks)
        self._robot_process = None  # realtime: the process serving the virtual robots (mocks.p3at.RobotProcess)
        self._drivers: dict = {}   # robot -> its ARCOS driver
        self._end_time: float | None = None
        self._wall_start = time.monotonic()
        # on the wall clock, what puts the runtime's clock on the epoch for the sensor logs' stamps: read once, for
        # every robot's log (runtime.sensorlog.epoch_offset_ns)
        self._epoch_offset: int | None = None
        self._link_lost_since: dict[str, float] = {}
        self.smoothing: dict = {}   # robot -> runtime.onboard.SmoothingOutcome (--smooth, after the stop)
        self._touching: dict[str, str | None] = {}  # virtual robots: what each was last seen pressed against

    def stop(self) -> None:
        """Ask the mission to end (thread- and signal-safe)."""
        self._stop.set()

    # -- setup --------------------------------------------------------------------------------------------
    def _open_logger(self, names: list[str], world) -> None:
        from runtime.rerun_log import MissionLog
        from runtime.rerun_sink import open_recording
        from runtime.rerun_style import mission_blueprint

        cfg = self.config
        sink = cfg.rerun
        if sink == "file":
            self.recording_path = cfg.out / "mission.rrd"
            sink = str(self.recording_path)
            if self.recording_path.exists():
                self._recording_pending = cfg.out / f".mission.rrd.{os.getpid()}.starting"
                sink = str(self._recording_pending)
        # one process of a fleet's shared recording sends no layout: the fusion node's (it knows every robot) wins
        layout = None if cfg.recording_id else mission_blueprint(names)
        rec = open_recording(sink, recording_id=cfg.recording_id, blueprint=layout)
        # open_recording sent the layout (active); a writer that dies is said at once, the mission goes on
        # one robot's process of a fleet's shared recording logs no fusion of its own: the fusion node's is the fleet's
        self.logger = MissionLog(rec, names, blueprint=False, on_recording_failure=self.warnings,
                                 records_fusion=cfg.recording_id is None or len(names) > 1)
        if world is not None:
            self.logger.log_building(world.walls, world.wall_heights)

    def _commit_recording(self) -> None:
        """The robots are up: the new recording takes mission.rrd's name (Rerun's file sink writes on through the
        rename, which is atomic on one file system)."""
        if self._recording_pending is not None:
            os.replace(self._recording_pending, self.recording_path)
            self._recording_pending = None

    def _discard_pending_recording(self) -> None:
        """The run failed before its robots were up: the earlier mission.rrd stays, the new one goes."""
        if self._recording_pending is not None:
            self._recording_pending.unlink(missing_ok=True)
            self._recording_pending = None

    def _robot(self, stack: ExitStack, world, index: int, name: str, t0: float) -> RobotSetup:
        from drivers.arcos.robot import P3AT
        from mocks.p3at import serve_tcp
        from runtime.adapters import P3ATLink, left_camera_mount
        from runtime.sensorlog import SensorLogWriter, epoch_offset_ns

        cfg = self.config
        if cfg.on_mocks:
            pose = np.asarray(world.start_poses[name], float)
            if self._robot_process is not None:  # served from their own process (see _serve_robots_apart)
                server = self._robot_process.servers[name]
            else:
                server = serve_tcp(world, name, pose, host="127.0.0.1", port=0, clock=self.clock,
                                   time_scale=cfg.time_scale, seed=cfg.seed + 100 * index,
                                   odometry=self._odometry_errors())
                stack.callback(server.close)
            self._servers[name] = server
            url = server.url
        else:
            server, pose, url = None, None, cfg.robot_url
        driver = P3AT(url, clock=self.clock)
        stack.callback(driver.close)
        self._drivers[name] = driver
        if self.lockstep and server is not None:
            # the server is runnable while the driver's bytes are on their way; time moves during the handshake
            # only from OPEN to the first SIP (the driver waits for one), so setup takes the same simulated time
            server.client_sent = lambda: driver.bytes_written
            model = server.model
            with self.clock.gate(lambda: model.is_open and model.stats.sips == 0):
                driver.connect()
        else:
            driver.connect()
        link = P3ATLink(driver)
        if self.lockstep and server is not None:
            remove = self.clock.add_quiescence(f"{name}: SIPs reach the runtime",
                                               lambda: link.delivered(server.last_sip_sent))
            stack.callback(remove)
            link.on_delivered = self.clock.notify  # the coordinator looks again at once, not at its next poll
        camera, geometry = self._camera(stack, world, index, name)
        frontend = FrontEndConfig(geometry=geometry, harris=HarrisConfig(max_corners=cfg.max_corners))
        fastslam = FastSLAMConfig(n_particles=cfg.particles, max_observations=cfg.max_observations)
        onboard_config = OnboardConfig(fastslam=fastslam, frontend=frontend,
                                       seed=cfg.seed * 1000 + index, snapshot_interval=cfg.snapshot_interval,
                                       steer_on_estimate=cfg.odometry == "realistic" or not cfg.on_mocks,
                                       keep_readings=cfg.smooth)
        sensor_log = None
        if cfg.log_sensors:
            if not self.lockstep and self._epoch_offset is None:
                self._epoch_offset = epoch_offset_ns(self.clock)
            sensor_log = SensorLogWriter(cfg.out / f"{name}-log", {
                "robot": name, "camera": cfg.camera, "rectified": True, "geometry": geometry.to_dict(),
                "true_start_pose": None if pose is None else [float(v) for v in pose], "seed": onboard_config.seed,
                "fastslam": onboard_config.fastslam.to_dict(), "harris": dataclasses.asdict(frontend.harris),
                "t0": t0}, epoch_offset=self._epoch_offset)
        onboard = Onboard(name, link, camera, onboard_config, exchange=self.exchange,
                          controller=self._controller(world, name, pose), logger=self.logger,
                          sensor_log=sensor_log, clock=self.clock, t0=t0,
                          truth=(lambda: world.pose(name)) if pose is not None else None, true_start=pose,
                          head_mount=left_camera_mount(geometry), on_event=self.events,
                          on_failure=self._on_failure, time_base=self.time_base)
        stack.callback(onboard.stop)  # runs before the link, camera and server close (LIFO)
        if self.logger is not None:
            self.logger.log_robot_frame(name, pose if pose is not None else np.zeros(3))
            g = geometry
            self.logger.log_camera_model(name, g.fx, g.fy, g.cx, g.cy, 640, 480, g.baseline)
        return RobotSetup(name, onboard, pose)

    def _odometry_errors(self):
        from mocks.p3at import OdometryErrors

        return OdometryErrors.realistic() if self.config.odometry == "realistic" else OdometryErrors()

    def _serve_robots_apart(self, stack: ExitStack, world, names: list[str]) -> None:
        """On the wall clock, the virtual robots run in a process of their own, as real robots are other machines:
        beside rendering and FastSLAM, the GIL and the CPU would decide when a SIP leaves (issue 15). Their true
        poses stay visible in ``world`` for the heads and the scores. Closed after every driver (LIFO)."""
        from mocks.p3at import RobotSpec, serve_tcp_process

        specs = [RobotSpec(name, tuple(world.start_poses[name]), odometry=self._odometry_errors(),
                           seed=self.config.seed + 100 * _world_index(world, name)) for name in names]
        self._robot_process = serve_tcp_process(world, specs, time_scale=self.config.time_scale)
        stack.callback(self._robot_process.close)
        self.events(f"virtual robots served by process {self._robot_process.pid} "
                    f"(scheduling priority: {self._robot_process.priority})")

    def _camera(self, stack: ExitStack, world, index: int, name: str):
        cfg = self.config
        rng = np.random.default_rng(cfg.seed * 7919 + index)
        if cfg.camera == "synthetic":
            from mocks.synthetic_stereo import SyntheticStereo
            from runtime.adapters import SyntheticCamera

            camera = SyntheticCamera(SyntheticStereo.from_world(world, rng), lambda: world.pose(name),
                                     rate=cfg.camera_rate, clock=self.clock)
            return camera, camera.geometry
        from drivers.videre.head import StereoHead
        from runtime.adapters import VidereCamera

        if cfg.camera == "usb":
            head = StereoHead.open(clock=self.clock, latency=cfg.camera_latency or 0.0)
            camera = VidereCamera(head, rate=cfg.camera_rate)
            stack.callback(camera.close)
            return camera, camera.geometry
        from mocks.stereo_head import VirtualStereoHead
        from mocks.stereo_head.backend import DEFAULT_LATENCY

        # one renderer (its texture atlas) shared by every head in the building
        latency = DEFAULT_LATENCY if cfg.camera_latency is None else cfg.camera_latency
        # on the wall clock a frame that cannot arrive at exposure + latency is dropped at the head, never
        # delivered with a stamp that is not its exposure time; in simulated time none is ever late
        virtual = VirtualStereoHead(world, name, rng=rng, realtime=True, clock=self.clock,
                                    renderer=getattr(self, "_renderer", None), latency=latency,
                                    drop_late=not self.lockstep)
        self._renderer = virtual.renderer
        self._virtual_heads[name] = virtual
        # the driver stamps frames with their exposure time: the head's stated exposure-to-delivery delay
        head = StereoHead.open(backend=virtual, clock=self.clock, latency=virtual.latency)
        camera = VidereCamera(head, rate=cfg.camera_rate)
        stack.callback(camera.close)
        return camera, camera.geometry

    def _controller(self, world, name: str, start: np.ndarray | None):
        from runtime.motion import load_route

        cfg = self.config
        if cfg.motion == "route" and cfg.route_file is not None:
            return PurePursuit(load_route(cfg.route_file), speed=cfg.speed)
        if cfg.motion == "route" and world is not None and start is not None and name in world.routes:
            waypoints = keep_right(np.asarray(world.routes[name], float))
            # the route is given in the world; the robot follows it in its own odometry frame
            local = between(start, np.column_stack([waypoints, np.zeros(len(waypoints))]))[:, :2]
            return PurePursuit(local, speed=cfg.speed)
        if cfg.motion in ("route", "explore"):
            return WallFollower(side="right" if len(self.robots) % 2 == 0 else "left")
        return NoMotion()

    # -- running ------------------------------------------------------------------------------------------
    def run(self) -> MissionResult:
        from mocks.world import World

        cfg = self.config
        cfg.out.mkdir(parents=True, exist_ok=True)
        alone = None
        if cfg.on_mocks:
            world = World.load(cfg.world)
            names = sorted(world.start_poses)[: cfg.robots]
            if cfg.robot_name is not None:
                if cfg.robot_name not in world.start_poses:
                    raise MissionError(f"the world '{world.name}' has no robot {cfg.robot_name!r} "
                                       f"(it has {', '.join(sorted(world.start_poses))})")
                names = [cfg.robot_name]
                # a fleet's robot processes (p3at demo --processes) each build their own world: say what that means
                alone = (f"{cfg.robot_name} is alone in its copy of the world: the fleet's other robots are not in "
                         "it, so it can neither touch them nor hear them on its sonar")
            if len(names) < cfg.robots:
                raise MissionError(f"the world '{world.name}' has {len(names)} start poses, "
                                   f"{cfg.robots} robots asked")
        else:
            world, names = None, [cfg.robot_name or "robot1"]
        if cfg.rerun != "none":
            self._open_logger(names, world)
        if alone is not None:
            self.events(alone)
            if self.logger is not None:
                self.logger.log_event(0.0, alone, "WARN")
        try:
            try:
                t0 = self._run_robots(world, names)
            finally:
                if self._own_clock:
                    self.clock.close()
            end = self._end_time if self._end_time is not None else self.clock() - t0
            if self.config.smooth:
                self._smooth_maps()
            final = self._fuse_guarded(end, final=True)
            return self._finish(final, end)
        except BaseException:
            if self.logger is not None:  # keep what was recorded readable
                with contextlib.suppress(RuntimeError):  # a dead writer: the error being raised says more
                    self.logger.close()
            self._discard_pending_recording()
            raise

    def _run_robots(self, world, names: list[str]) -> float:
        """Set up, start, run and stop every robot (motors stopped and files flushed on any exit).

        In simulated time the setup runs with the clock held (it advances only while a driver waits for its
        first SIP), the mission loop is a participant, and every robot is told to stop at one simulated
        instant; the joins, the wait for the robots to stand still and the sensor logs' last records follow in
        simulated time, the loop still a participant (so the same seed gives the same logs, however busy the
        machine); the drivers' goodbyes then run on the released clock. A stall (the watchdog) releases the clock
        and every wait of the stop then runs out on the wall clock."""
        with ExitStack() as stack:
            if self.lockstep:
                stack.callback(self.clock.release)  # runs last (LIFO): the closes below never wait on lockstep
            watchdog = self._start_watchdog() if self.lockstep else None
            if watchdog is not None:
                stack.callback(watchdog.set)
            if world is not None and self.clock is time.monotonic and self.config.robot_process:
                self._serve_robots_apart(stack, world, names)
            with self.clock.hold() if self.lockstep else contextlib.nullcontext():
                t0 = self.clock()
                for index, name in enumerate(names):
                    if world is not None:
                        index = _world_index(world, name)
                    self.robots.append(self._robot(stack, world, index, name, t0))
                self._commit_recording()
                if self.logger is not None and self.robots[0].true_start is not None:
                    self.logger.log_robot_frame("fused", self.robots[0].true_start)  # fused maps: robot 1's frame
                t0 = self.clock()
                self._wall_start = time.monotonic()
                token = self.clock.add_participant("mission") if self.lockstep else None
            try:
                with self.clock.participant(token) if token is not None else contextlib.nullcontext():
                    # the robots start as the participant: its grant comes once every SIP sent has reached the
                    # runtime (the clock's quiescence), so each robot's odometry and sensor log begin with the same
                    # SIP however busy the machine is (started from the setup thread, a SIP still in the driver's
                    # reader was delivered before or after the subscription by chance: one SIP more in a log)
                    for robot in self.robots:
                        robot.onboard.t0 = t0
                        robot.onboard.start()
                    self._loop(t0)
                    self._end_time = self.clock() - t0
                    for robot in self.robots:  # motors first, every robot at this instant
                        robot.onboard.request_stop()
                    # joins, a last snapshot, logs flushed (before the final fusion), still as a participant: its
                    # waits (each stage's end, the robot standing still) are on simulated time, so the stop and the
                    # sensor logs' last records do not depend on the machine's load; every wait is bounded
                    for robot in self.robots:
                        robot.onboard.stop()
            finally:
                self._wall_end = time.monotonic()
        return t0

    def _smooth_maps(self) -> None:
        """--smooth: every robot's final map smoothed over its readings (Onboard.smooth_final_map publishes it for the
        final fusion, or says in one line why not and leaves the filter's), one robot after the other, after the clock
        is released; the wall time of the mission includes it."""
        for r in self.robots:
            self.smoothing[r.name] = r.onboard.smooth_final_map()
        self._wall_end = time.monotonic()

    def _start_watchdog(self) -> threading.Event:
        """A wall-clock thread outside the lockstep: a simulation that stops making progress (a participant that
        never waits, a driver that stopped delivering SIPs) ends the mission with the reason, not a hang."""
        done = threading.Event()

        def watch() -> None:
            while not done.wait(0.5):
                dead = {name: s.error for name, s in self._servers.items() if s.error is not None}
                if self.clock.hook_errors:  # the virtual robots' physics raised in the clock's advance hook
                    dead["virtual world"] = self.clock.hook_errors[0]
                stall = self.clock.stall
                if dead or stall is not None:
                    for name, error in dead.items():
                        self._record_failure(StageFailure(name, "virtual robot", f"{type(error).__name__}: {error}",
                                                          self.clock()))
                    if stall is not None:
                        self._record_failure(StageFailure("mission", "simulation",
                                                          f"simulated time stalled: {stall}", self.clock()))
                    self.clock.release()  # let every timeout run out on the wall clock: the mission ends
                    return
        threading.Thread(target=watch, name="mission-watchdog", daemon=True).start()
        return done

    def _on_failure(self, failure: StageFailure) -> None:
        if failure.stage == "sensor log" and self._log_failed(failure.robot):
            return  # the writer's fault, reported when the mission saw it (_check_links); its close says it again
        self._record_failure(failure)

    def _log_failed(self, robot: str) -> bool:
        """Has ``robot``'s sensor log already been reported failed? (Its writer's fault is said once.)"""
        return any(f.robot == robot and f.stage == "sensor log" for f in self.failures)

    def _record_failure(self, failure: StageFailure) -> None:
        self.failures.append(failure)
        message = str(failure)
        self.events(f"FAILED: {message}")
        if self.logger is not None:
            try:
                self.logger.log_event(failure.t, message, "ERROR")
            except Exception:  # noqa: BLE001 - the report on stderr and in the summary still stands
                pass
        self._stop.set()

    def _wait_tick(self, t0: float, k: int) -> bool:
        """Wait for the loop's k-th tick (every 0.2 s); True if the mission was asked to stop."""
        if self.lockstep:
            return self.clock.wait_for(self._stop.is_set, until=t0 + 0.2 * k)
        return self._stop.wait(0.2)

    def _loop(self, t0: float) -> None:
        cfg = self.config
        next_fusion = cfg.fusion_interval if cfg.fusion_interval > 0 else np.inf
        next_save = cfg.map_save_interval if cfg.map_save_interval > 0 else np.inf
        next_progress = 0.0
        k = 1
        while not self._wait_tick(t0, k):
            k += 1
            t = self.clock() - t0
            self._check_links(t)
            self._check_contacts(t)
            if self._stop.is_set():
                break
            if t >= cfg.seconds:
                self.events(f"mission time of {cfg.seconds:g} s reached")
                break
            if cfg.motion == "route" and all(r.onboard.route_done.is_set() for r in self.robots):
                self.events("every robot has finished its route")
                break
            if t >= next_progress:
                self.progress(self._progress_line(t))
                self._publish_status()   # a fleet exchange (Zenoh) gets each robot's health once a second
                next_progress = t + 1.0
            if t >= next_fusion:
                self._fuse_guarded(t)
                next_fusion = t + cfg.fusion_interval
            if t >= next_save:
                self._save_maps()
                next_save = t + cfg.map_save_interval
        # the last status says the loop is over: a fleet that hears no more from this robot while it saves its
        # files knows it is not stuck (p3at demo --processes stops a robot whose statuses stop mid-mission)
        self._publish_status(mission_over=True)

    def _publish_status(self, mission_over: bool = False) -> None:
        """Each robot's health on a fleet exchange (runtime/fleet/status.py; nothing on one without statuses)."""
        publish_robot_status(self.exchange, [(r.onboard, self._drivers.get(r.name)) for r in self.robots],
                             clock="simulated" if self.lockstep else "wall",
                             wall_time=time.monotonic() - self._wall_start, failures=self.failures,
                             mission_over=mission_over)

    def _check_links(self, t: float) -> None:
        """Threads that report their faults as state: a sensor log whose writer failed and a virtual robot whose
        server thread died end the mission; a driver whose link is down is reported, and a link that stays down
        for 10 s ends the mission (the driver keeps trying to reconnect until then)."""
        for r in self.robots:  # the sensor log's writer thread keeps running after a fault; the mission does not
            log = r.onboard.sensor_log
            if log is not None and getattr(log, "error", None) is not None and not self._log_failed(r.name):
                self._record_failure(StageFailure(r.name, "sensor log", _write_error(log.error, log.folder), t))
        for name, driver in self._drivers.items():
            server = self._servers.get(name)
            if server is not None and server.error is not None:
                self._record_failure(StageFailure(name, "virtual robot", f"{type(server.error).__name__}: "
                                                  f"{server.error}", t))
                continue
            if driver.connected:
                if self._link_lost_since.pop(name, None) is not None:
                    self.events(f"{name}: link restored")
                continue
            since = self._link_lost_since.setdefault(name, t)
            if since == t:
                self.events(f"{name}: link lost; the driver is reconnecting")
            elif t - since >= 10.0:
                self._record_failure(StageFailure(name, "driver", f"link lost for {t - since:.0f} s", t))

    def _check_contacts(self, t: float) -> None:
        """A virtual robot that ran into another robot: an event naming both, with the bumpers its driver reports,
        also in Rerun's mission/events (WARN), so that a reviewer sees it. Looked at every tick (0.2 s), so a touch
        shorter than that can pass unseen; walls are not reported."""
        for name, server in self._servers.items():
            touching = getattr(server, "touching", None)
            if touching == self._touching.get(name):
                continue
            self._touching[name] = touching
            if touching is None or touching == "wall":
                continue
            driver = self._drivers.get(name)
            state = driver.last_state if driver is not None else None
            bumpers = "" if state is None else (f": front bumpers {state.front_bumpers:#04x}, "
                                                 f"rear {state.rear_bumpers:#04x}")
            message = f"{name} ran into {touching} and stopped{bumpers}"
            self.events(message)
            if self.logger is not None:
                self.logger.log_event(t, message, "WARN")

    def _save_maps(self) -> None:
        """Every robot's current map to OUT/<robot>.npz, atomically: what a hard kill leaves behind."""
        for r in self.robots:
            snapshot = r.onboard.current_map()
            if snapshot is None:
                continue
            path = self.config.out / f"{r.name}.npz"
            try:
                snapshot.save(path)
            except (OSError, MapFileError) as exc:
                # a full or vanished disk, or a map its reader would refuse (a NaN from a diverged filter: not
                # written, its last good file stays): say so and stop rather than map on unsaved
                self._record_failure(StageFailure(r.name, "map save", _write_error(exc, path),
                                                  self.clock() - r.onboard.t0))
                if isinstance(exc, OSError):  # the disk: the other robots' maps cannot be saved either
                    return

    def _save_final(self, owner: str, m: LandmarkMap, stem: str, t: float) -> list[Path]:
        """``m`` to OUT/<stem>.npz and .ply; a map its reader would refuse is a failure of ``owner``'s map save (one
        line), written nowhere (the .npz keeps its last periodic save, if any): the files written."""
        npz, ply = self.config.out / f"{stem}.npz", self.config.out / f"{stem}.ply"
        written = []
        for path, write in ((npz, m.save), (ply, m.export_ply)):
            try:
                write(path)
            except (OSError, MapFileError) as exc:
                # a map its reader would refuse, or a full, read-only or vanished disk: one line naming the file;
                # the mission's other files are still written, and its summary printed
                self._record_failure(StageFailure(owner, "map save", _write_error(exc, path), t))
                return written
            written.append(path)
        return written

    def _save_trajectories(self, r: RobotSetup, t: float) -> dict[str, Path]:
        """The robot's TUM files (:meth:`TrajectoryRecorder.write_tum`); a file that cannot be written is a failure of
        its robot's ``trajectory save``, said in one line naming it, and the others are still written."""
        try:
            return r.onboard.trajectories.write_tum(self.config.out, r.name)
        except OSError as exc:
            where = f"{r.name}'s .tum files in {self.config.out}"
            self._record_failure(StageFailure(r.name, "trajectory save", _write_error(exc, where), t))
            return {}

    def _close_recording(self, summary: dict) -> None:
        """The summary into the recording, and the recording closed; a recording that cannot be finished (its writer
        died on a full disk) is a failure of the mission's ``recording``, added to ``summary``'s failures."""
        try:
            self.logger.log_summary(summary)
            self.logger.close()
        except RuntimeError as exc:  # Rerun's 'File-writer thread shut down prematurely' and its like
            where = f"{self.recording_path}: " if self.recording_path is not None else ""
            failure = StageFailure("mission", "recording", f"{where}{exc}", summary["duration"])
            self._record_failure(failure)
            summary["failures"].append(dataclasses.asdict(failure))

    def _fuse_guarded(self, t: float, final: bool = False) -> FusionReport | None:
        try:
            return self._fuse(t, final)
        except Exception as exc:  # noqa: BLE001 - the supervisor reports the stage and ends the mission
            self._record_failure(StageFailure("mission", "fusion", f"{type(exc).__name__}: {exc}", t))
            return None

    def _progress_line(self, t: float) -> str:
        parts = [f"t={t:5.1f}s"]
        for r in self.robots:
            s = r.onboard.stats
            parts.append(f"{r.name}: {s.frames_processed} frames ({s.dropped_frames} dropped), "
                         f"map {s.map_landmarks} landmarks")
        if self.fusion_history and self.fusion_history[-1].pairs:
            p = self.fusion_history[-1].pairs[0]
            parts.append(fusion_progress_part(p))
        return " | ".join(parts)

    def _fuse(self, t: float, final: bool = False) -> FusionReport | None:
        messages = self.exchange.receive()
        maps = {name: message.landmark_map for name, message in messages.items()}
        if len(maps) < 2:
            return None
        priors = self._start_priors()
        cache = self.fusion_cache
        if hasattr(cache, "start_round"):          # confirming live fusions (fusion/confirmation.py)
            cache.start_round(t)
            if final and self._routes_finished():  # complete maps: decided on them alone, as p3at fuse decides
                cache = cache.inner
        report = fuse_maps(maps, self.config.preset, self.config.method, t,
                           np.random.default_rng(self.config.seed + len(self.fusion_history)),
                           cache=cache, priors=priors)
        if priors and not self.fusion_history:      # said once: the fusion is not blind to where the robots started
            for (a, b), prior in priors.items():
                line = start_prior_line(a, b, prior)
                self.events(line)
                if self.logger is not None:
                    self.logger.log_event(t, line, "INFO")
        keep_latest_map(self.fusion_history, report)
        if self.logger is not None:
            for pair in report.pairs:
                self.logger.log_alignment(t, pair.reference, pair.other, {
                    **pair.as_dict(), "merged": 0 if report.merged is None else len(report.merged)})
            if report.merged is not None:
                self.logger.log_map("fused", t, report.merged)
        for pair in report.pairs:
            self.events(fusion_event_line(t, pair))
        return report

    def _routes_finished(self) -> bool:
        """Every robot drove its whole route: the maps are complete.  A mission cut short (``--seconds``, Ctrl-C) or
        without routes ends with maps that would have grown, so its final fusion is confirmed like a live one."""
        return self.config.motion == "route" and all(r.onboard.route_done.is_set() for r in self.robots)

    def _start_priors(self) -> dict | None:
        """With ``start_prior``: every pair's relative start from the configured start poses (where the robots were
        put), each at the given σ (fusion.prior.named_pair_priors); None without."""
        if self.config.start_prior is None:
            return None
        from fusion.prior import named_pair_priors

        starts = {r.name: (r.true_start, self.config.start_prior) for r in self.robots if r.true_start is not None}
        return named_pair_priors(starts, source="configured start poses")

    def _finish(self, final: FusionReport | None, duration: float) -> MissionResult:
        cfg = self.config
        maps = {r.name: r.onboard.final_map() for r in self.robots}
        files: list[Path] = []   # every file this mission leaves, for the summary
        for name, outcome in self.smoothing.items():   # --smooth: the filter's map beside the smoothed one
            if outcome.smoothed is not None:
                files += self._save_final(name, maps[name], f"{name}-filter", duration)
                maps[name] = outcome.smoothed
        for name, m in maps.items():
            files += self._save_final(name, m, name, duration)
        # TUM files beside each map: <robot>.tum (estimated), <robot>-odometry.tum, <robot>-truth.tum (mocks)
        trajectory_files = {r.name: self._save_trajectories(r, duration) for r in self.robots}
        files += [p for written in trajectory_files.values() for p in written.values()]
        fused = final.merged if final is not None else None
        if fused is not None:
            files += self._save_final("mission", fused, "fused", duration)
        if cfg.log_sensors:
            files += [cfg.out / f"{r.name}-log" for r in self.robots]
        if self.recording_path is not None:
            files.append(self.recording_path)
        robots = {}
        for r in self.robots:
            s, core = r.onboard.stats, r.onboard.core
            frames = max(1, s.frames_processed)
            final_pose, dead_reckoning = core.slam.best_pose(), core.dead_reckoning_pose()
            true_final = odometry_error = None
            truth_rows = r.onboard.trajectories.get("truth")
            if len(truth_rows):
                # the estimate, odometry and truth at the last frame with a truth row, as the TUM files (and evo)
                # have them: the truth at the stop is later when the robot still moves (0.152 vs 0.086 m, 60 s demo)
                t_last, true_final = truth_rows[-1, 0], truth_rows[-1, 1:]
                final_pose = _row_at(r.onboard.trajectories.get("estimated"), t_last)
                dead_reckoning = _row_at(r.onboard.trajectories.get("odometry"), t_last)
            elif r.onboard.final_true_pose is not None and r.true_start is not None:
                true_final = between(r.true_start, r.onboard.final_true_pose)
            if true_final is not None and dead_reckoning is not None:
                odometry_error = float(np.hypot(*(dead_reckoning[:2] - true_final[:2])))
            robots[r.name] = {
                "landmarks": len(maps[r.name]),
                "frames_received": s.frames_received, "frames_processed": s.frames_processed,
                "frames_dropped": s.dropped_frames, "frames_without_odometry": s.frames_without_odometry,
                # processed frames that faced a surface nearer than the stereo head measures: no reading from them
                "frames_too_near": core.frames_too_near,
                "final_position_error": None if true_final is None
                else float(np.hypot(*(final_pose[:2] - true_final[:2]))),
                "odometry_position_error": odometry_error,
                # mock heads on the wall clock: frames that could not arrive at exposure + latency, dropped at the
                # head (by reason); in simulated time there are none
                "frames_late": getattr(self._virtual_heads.get(r.name), "late_frames", None),
                "frames_dropped_at_head": dict(getattr(self._virtual_heads.get(r.name), "dropped_at_head", {})),
                "ms_per_frame": {k: round(1000.0 * v / frames, 2) for k, v in s.stage_seconds.items()},
                "map_file": str(cfg.out / f"{r.name}.npz"), "ply_file": str(cfg.out / f"{r.name}.ply"),
                "trajectory_files": [str(p) for p in trajectory_files[r.name].values()],
                # records the sensor log's writer had no room for (a disk slower than the sensors): the log lacks
                # them, so a replay does not rebuild this map; None without a log
                "sensor_log_dropped": None if r.onboard.sensor_log is None else r.onboard.sensor_log.dropped,
            }
            if r.name in self.smoothing:   # --smooth: what the smoothing did (or why not), its files
                robots[r.name]["smoothing"] = smoothing_figures(self.smoothing[r.name].figures)
                if self.smoothing[r.name].smoothed is not None:
                    robots[r.name]["filter_map_file"] = str(cfg.out / f"{r.name}-filter.npz")
        for name, figures in robots.items():
            if figures["sensor_log_dropped"] and self.logger is not None:  # the command says it on stderr
                self.logger.log_event(duration, sensor_log_dropped_line(name, figures["sensor_log_dropped"]), "WARN")
            dropped, received = sum(figures["frames_dropped_at_head"].values()), figures["frames_received"]
            if dropped:
                reasons = "; ".join(f"{n} {why}" for why, n in figures["frames_dropped_at_head"].items())
                self.events(f"{name}: the virtual head dropped {dropped} frames ({received} delivered): {reasons} "
                            f"(the machine does not keep up in real time: simulated time, fewer robots, a lower "
                            f"--camera-rate or --camera synthetic)")
        wall = getattr(self, "_wall_end", time.monotonic()) - self._wall_start
        summary = {
            "robots": robots, "duration": round(duration, 2), "seed": cfg.seed, "camera": cfg.camera,
            "clock": "simulated" if self.lockstep else "wall",
            "sim_seconds": round(duration, 3), "wall_seconds": round(wall, 3),
            "realtime_factor": round(duration / wall, 3) if wall > 0 else None,
            "failures": [dataclasses.asdict(f) for f in self.failures],
            "particles": cfg.particles, "fusion": None if final is None else final.as_dict(),
            "fusion_ms": None if final is None else round(1000.0 * final.seconds, 2),
            "fusions_during_mission": len(self.fusion_history) - (1 if final is not None else 0),
            "merged_map_file": str(cfg.out / "fused.npz") if cfg.out / "fused.npz" in files else None,
            "recording": None if self.recording_path is None else str(self.recording_path),
            "files": [str(f) for f in files],
        }
        if cfg.smooth:
            # the maps fused and saved as <robot>.npz are the smoothed ones where robots[...]["smoothing"] says so (the
            # filter's beside, <robot>-filter.npz); "smoothed": every robot's was
            summary["smoothed"] = bool(self.smoothing) and all(o.smoothed is not None for o in self.smoothing.values())
        if self.logger is not None:
            self._close_recording(summary)
        return MissionResult(summary, maps, fused, self.recording_path, self.fusion_history, list(self.failures))


def smoothing_figures(figures: dict) -> dict:
    """A robot's smoothing figures for the summary (JSON): counts as given, χ²/dof to 4 digits, seconds to 0.01 s."""
    out = {}
    for key, value in figures.items():
        if key.endswith("_s") or key == "seconds":
            value = round(float(value), 2)
        elif key == "chi2_per_dof":
            value = round(float(value), 4)
        out[key] = value
    return out


def sensor_log_dropped_line(robot: str, dropped: int) -> str:
    """What to say of a sensor log that lost records to a disk that did not keep up."""
    return (f"{robot}'s sensor log dropped {dropped} record{'s' if dropped != 1 else ''} (the disk did not keep up): "
            "the log is incomplete, and a replay of it will not rebuild the live map")


def _write_error(exc: BaseException, path: Path | str | None = None) -> str:
    """One line for a file that could not be written, naming it: an OSError's own text names no file when the write
    failed (``[Errno 28] No space left on device``)."""
    text = f"{type(exc).__name__}: {exc}"
    name = getattr(exc, "filename", None) or path
    if isinstance(exc, OSError) and name is not None and str(name) not in text:
        text += f" ({name})"
    return text


def _row_at(rows: np.ndarray, t: float) -> np.ndarray | None:
    """The pose (x, y, θ) of the last trajectory row stamped ``t`` (None when there is none)."""
    at = np.flatnonzero(rows[:, 0] == t) if len(rows) else ()
    return rows[at[-1], 1:] if len(at) else None


def _world_index(world, name: str) -> int:
    """A world's robot's index among the world's start poses, which sets its seeds: the same whether it runs
    alone or with others, and whether it is served in this process or another."""
    return sorted(world.start_poses).index(name)


def install_stop_signals(stop: Callable[[], None]) -> Callable[[], None]:
    """SIGTERM (and SIGINT) ask the mission to stop cleanly; returns a function restoring the old handlers."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    previous = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}
    for s in previous:
        signal.signal(s, lambda signum, frame: stop())

    def restore() -> None:
        for s, handler in previous.items():
            signal.signal(s, handler)
    return restore
