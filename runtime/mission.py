"""The multi-robot mission: N virtual P3-ATs explore the simulated building, each maps it on board, maps fused.

Each robot is a wire-level virtual P3-AT (``mocks.p3at``) driven by the real ARCOS driver, with a stereo
head (the rendering virtual head through the real Videre driver, or the fast synthetic observer), running
its own :class:`~runtime.onboard.Onboard`. The robots start at the world's start poses, which none of them
knows; they share maps only through the :class:`~runtime.exchange.MapExchange`. A fusion stage (what a base
station or any robot would run) reads the exchange every ``fusion_interval`` seconds and at the end, aligns
every map to the first robot's, merges them, and scores each alignment against the true start poses that
simulated maps carry in their metadata.
"""
from __future__ import annotations

import dataclasses
import signal
import threading
import time
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from estimation.fastslam import FastSLAMConfig
from estimation.frontend import FrontEndConfig, HarrisConfig
from estimation.geometry import between
from estimation.landmark_map import LandmarkMap
from runtime.exchange import InProcessExchange, MapExchange
from runtime.fusion_report import FusionReport, fuse_maps
from runtime.motion import NoMotion, PurePursuit, WallFollower, keep_right
from runtime.onboard import Clock, Onboard, OnboardConfig

CAMERAS = ("mock", "synthetic", "usb")
MOTIONS = ("route", "explore", "none")


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
    time_scale: float = 1.0           # virtual robots only: simulated seconds per wall-clock second
    odometry: str = "exact"           # virtual robots' wheel odometry: "exact" or "realistic" (1 % scale, 3 % track)
    robot_name: str | None = None     # this robot's name in a fleet; virtual: the world robot run alone

    @property
    def on_mocks(self) -> bool:
        return self.robot_url == "mock"

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
            raise ValueError("a real robot needs a real stereo head (--camera usb)")
        if self.camera_latency is not None and not 0.0 <= self.camera_latency < 1.0:
            raise ValueError(f"--camera-latency must be in [0, 1) s, not {self.camera_latency!r}")
        if self.odometry not in ("exact", "realistic"):
            raise ValueError(f"--odometry must be exact or realistic, not {self.odometry!r}")
        if self.on_mocks and self.camera == "usb":
            raise ValueError("--camera usb needs a real robot (--robot URL); the virtual robots use mock or synthetic")


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


class Mission:
    """Set up with a config, ``run()`` until the time is up, the routes are done, or ``stop()`` is called."""

    def __init__(self, config: MissionConfig, *, clock: Clock = time.monotonic,
                 progress: Callable[[str], None] | None = None, events: Callable[[str], None] | None = None,
                 exchange: MapExchange | None = None) -> None:
        self.config = config
        self.clock = clock
        self.progress = progress or (lambda line: None)
        self.events = events or (lambda line: None)
        self.exchange = exchange if exchange is not None else InProcessExchange()
        self._stop = threading.Event()
        self.robots: list[RobotSetup] = []
        self._virtual_heads: dict = {}  # robot -> its VirtualStereoHead (mock cameras), for the late-frame count
        self.fusion_history: list[FusionReport] = []
        self.logger = None
        self.recording_path: Path | None = None

    def stop(self) -> None:
        """Ask the mission to end (thread- and signal-safe)."""
        self._stop.set()

    # -- setup --------------------------------------------------------------------------------------------
    def _open_logger(self, names: list[str], world) -> None:
        from runtime.rerun_log import MissionLog, mission_blueprint, open_recording

        cfg = self.config
        sink = cfg.rerun
        if sink == "file":
            self.recording_path = cfg.out / "mission.rrd"
            sink = str(self.recording_path)
        rec = open_recording(sink, blueprint=mission_blueprint(names))
        self.logger = MissionLog(rec, names, blueprint=False)  # open_recording sent it as the default
        if world is not None:
            self.logger.log_building(world.walls, world.wall_heights)

    def _robot(self, stack: ExitStack, world, index: int, name: str, t0: float) -> RobotSetup:
        from drivers.arcos.robot import P3AT
        from mocks.p3at import serve_tcp
        from runtime.adapters import P3ATLink, left_camera_mount
        from runtime.sensorlog import SensorLogWriter

        cfg = self.config
        if cfg.on_mocks:
            pose = np.asarray(world.start_poses[name], float)
            from mocks.p3at import OdometryErrors

            errors = OdometryErrors.realistic() if cfg.odometry == "realistic" else OdometryErrors()
            server = serve_tcp(world, name, pose, host="127.0.0.1", port=0, clock=self.clock,
                               time_scale=cfg.time_scale, seed=cfg.seed + 100 * index, odometry=errors)
            stack.callback(server.close)
            url = server.url
        else:
            pose, url = None, cfg.robot_url
        driver = P3AT(url, clock=self.clock)
        stack.callback(driver.close)
        driver.connect()
        link = P3ATLink(driver)
        camera, geometry = self._camera(stack, world, index, name)
        frontend = FrontEndConfig(geometry=geometry, harris=HarrisConfig(max_corners=cfg.max_corners))
        fastslam = FastSLAMConfig(n_particles=cfg.particles, max_observations=cfg.max_observations)
        onboard_config = OnboardConfig(fastslam=fastslam, frontend=frontend,
                                       seed=cfg.seed * 1000 + index, snapshot_interval=cfg.snapshot_interval,
                                       steer_on_estimate=cfg.odometry == "realistic" or not cfg.on_mocks)
        sensor_log = None
        if cfg.log_sensors:
            from runtime.adapters import geometry_to_dict
            sensor_log = SensorLogWriter(cfg.out / f"{name}-log", {
                "robot": name, "camera": cfg.camera, "rectified": True, "geometry": geometry_to_dict(geometry),
                "true_start_pose": None if pose is None else [float(v) for v in pose], "seed": onboard_config.seed,
                "fastslam": onboard_config.fastslam.to_dict(), "harris": dataclasses.asdict(frontend.harris),
                "t0": t0})
        onboard = Onboard(name, link, camera, onboard_config, exchange=self.exchange,
                          controller=self._controller(world, name, pose), logger=self.logger,
                          sensor_log=sensor_log, clock=self.clock, t0=t0,
                          truth=(lambda: world.pose(name)) if pose is not None else None, true_start=pose,
                          head_mount=left_camera_mount(geometry), on_event=self.events)
        stack.callback(onboard.stop)  # runs before the link, camera and server close (LIFO)
        if self.logger is not None:
            self.logger.log_robot_frame(name, pose if pose is not None else np.zeros(3))
            g = geometry
            self.logger.log_camera_model(name, g.fx, g.fy, g.cx, g.cy, 640, 480, g.baseline)
        return RobotSetup(name, onboard, pose)

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
        virtual = VirtualStereoHead(world, name, rng=rng, realtime=True, clock=self.clock,
                                    renderer=getattr(self, "_renderer", None), latency=latency)
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
        if cfg.on_mocks:
            world = World.load(cfg.world)
            names = sorted(world.start_poses)[: cfg.robots]
            if cfg.robot_name is not None:
                if cfg.robot_name not in world.start_poses:
                    raise MissionError(f"the world '{world.name}' has no robot {cfg.robot_name!r} "
                                       f"(it has {', '.join(sorted(world.start_poses))})")
                names = [cfg.robot_name]
            if len(names) < cfg.robots:
                raise MissionError(f"the world '{world.name}' has {len(names)} start poses, "
                                   f"{cfg.robots} robots asked")
        else:
            world, names = None, [cfg.robot_name or "robot1"]
        if cfg.rerun != "none":
            self._open_logger(names, world)
        try:
            t0 = self._run_robots(world, names)
            final = self._fuse(self.clock() - t0)
            return self._finish(final, self.clock() - t0)
        except BaseException:
            if self.logger is not None:  # keep what was recorded readable
                self.logger.close()
            raise

    def _run_robots(self, world, names: list[str]) -> float:
        """Set up, start, run and stop every robot (motors stopped and files flushed on any exit)."""
        with ExitStack() as stack:
            t0 = self.clock()
            for index, name in enumerate(names):
                if world is not None:  # a world's robot keeps its seeds whether it runs alone or with the others
                    index = sorted(world.start_poses).index(name)
                self.robots.append(self._robot(stack, world, index, name, t0))
            if self.logger is not None and self.robots[0].true_start is not None:
                self.logger.log_robot_frame("fused", self.robots[0].true_start)  # fused maps are in robot 1's frame
            t0 = self.clock()
            for robot in self.robots:
                robot.onboard.t0 = t0
                robot.onboard.start()
            self._loop(t0)
            # stop every robot (motors first) before the final fusion
            for robot in self.robots:
                robot.onboard.stop()
        return t0

    def _loop(self, t0: float) -> None:
        cfg = self.config
        next_fusion = cfg.fusion_interval if cfg.fusion_interval > 0 else np.inf
        next_progress = 0.0
        while not self._stop.wait(0.2):
            t = self.clock() - t0
            if t >= cfg.seconds:
                self.events(f"mission time of {cfg.seconds:g} s reached")
                break
            if cfg.motion == "route" and all(r.onboard.route_done.is_set() for r in self.robots):
                self.events("every robot has finished its route")
                break
            if t >= next_progress:
                self.progress(self._progress_line(t))
                next_progress = t + 1.0
            if t >= next_fusion:
                self._fuse(t)
                next_fusion = t + cfg.fusion_interval

    def _progress_line(self, t: float) -> str:
        parts = [f"t={t:5.1f}s"]
        for r in self.robots:
            s = r.onboard.stats
            parts.append(f"{r.name}: {s.frames_processed} frames ({s.dropped_frames} dropped), "
                         f"map {s.map_landmarks} landmarks")
        if self.fusion_history and self.fusion_history[-1].pairs:
            p = self.fusion_history[-1].pairs[0]
            parts.append(f"fusion: error {p.error_xy:.2f} m" if p.error_xy is not None else "fusion: no alignment")
        return " | ".join(parts)

    def _fuse(self, t: float) -> FusionReport | None:
        messages = self.exchange.receive()
        maps = {name: message.landmark_map for name, message in messages.items()}
        if len(maps) < 2:
            return None
        report = fuse_maps(maps, self.config.preset, self.config.method, t,
                           np.random.default_rng(self.config.seed + len(self.fusion_history)))
        self.fusion_history.append(report)
        if self.logger is not None:
            for pair in report.pairs:
                self.logger.log_alignment(t, pair.reference, pair.other, {
                    **pair.as_dict(), "merged": 0 if report.merged is None else len(report.merged)})
            if report.merged is not None:
                self.logger.log_map("fused", t, report.merged)
        for pair in report.pairs:
            if pair.aligned:
                self.events(f"fusion at t={t:.0f}s: {pair.other} -> {pair.reference} "
                            f"({pair.supports} supports, {pair.common} common)"
                            + (f", error {pair.error_xy:.3f} m / {pair.error_theta:.4f} rad"
                               if pair.error_xy is not None else ""))
            else:
                self.events(f"fusion at t={t:.0f}s: {pair.other} does not overlap {pair.reference} yet")
        return report

    def _finish(self, final: FusionReport | None, duration: float) -> MissionResult:
        cfg = self.config
        maps = {r.name: r.onboard.core.best_map() for r in self.robots}
        for name, m in maps.items():
            m.save(cfg.out / f"{name}.npz")
        # TUM files beside each map: <robot>.tum (estimated), <robot>-odometry.tum, <robot>-truth.tum (mocks)
        trajectory_files = {r.name: r.onboard.trajectories.write_tum(cfg.out, r.name) for r in self.robots}
        fused = final.merged if final is not None else None
        if fused is not None:
            fused.save(cfg.out / "fused.npz")
            fused.export_ply(cfg.out / "fused.ply")
        robots = {}
        for r in self.robots:
            s, core = r.onboard.stats, r.onboard.core
            frames = max(1, s.frames_processed)
            final_pose = core.slam.best_pose()
            true_final = odometry_error = None
            if r.onboard.final_true_pose is not None and r.true_start is not None:
                true_final = between(r.true_start, r.onboard.final_true_pose)
                dead_reckoning = core.dead_reckoning_pose()
                if dead_reckoning is not None:
                    odometry_error = float(np.hypot(*(dead_reckoning[:2] - true_final[:2])))
            robots[r.name] = {
                "landmarks": len(maps[r.name]),
                "frames_received": s.frames_received, "frames_processed": s.frames_processed,
                "frames_dropped": s.dropped_frames, "frames_without_odometry": s.frames_without_odometry,
                "final_position_error": None if true_final is None
                else float(np.hypot(*(final_pose[:2] - true_final[:2]))),
                "odometry_position_error": odometry_error,
                # mock heads: frames rendered slower than the head's stated latency, whose stamps are late
                "frames_late": getattr(self._virtual_heads.get(r.name), "late_frames", None),
                "ms_per_frame": {k: round(1000.0 * v / frames, 2) for k, v in s.stage_seconds.items()},
                "map_file": str(cfg.out / f"{r.name}.npz"),
                "trajectory_files": [str(p) for p in trajectory_files[r.name].values()],
            }
        for name, figures in robots.items():
            late, received = figures["frames_late"], max(1, figures["frames_received"])
            if late and late > 0.05 * received:
                self.events(f"{name}: {late} of {received} frames were rendered later than the virtual head's "
                            f"latency, so their timestamps are late too (the machine is overloaded: fewer robots, "
                            f"a lower --camera-rate or --camera synthetic)")
        summary = {
            "robots": robots, "duration": round(duration, 2), "seed": cfg.seed, "camera": cfg.camera,
            "particles": cfg.particles, "fusion": None if final is None else final.as_dict(),
            "fusion_ms": None if final is None else round(1000.0 * final.seconds, 2),
            "fusions_during_mission": len(self.fusion_history) - (1 if final is not None else 0),
            "merged_map_file": None if fused is None else str(cfg.out / "fused.npz"),
            "recording": None if self.recording_path is None else str(self.recording_path),
        }
        if self.logger is not None:
            self.logger.log_summary(summary)
            self.logger.close()
        return MissionResult(summary, maps, fused, self.recording_path, self.fusion_history)


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
