"""The onboard pipeline's speed as a ratio to real time, per stage (run by hand; prints a table).

    .venv/bin/python benchmarks/bench_pipeline.py [--frames 150] [--particles 100] [--rate 15] [--cpu] [--rerun-rows]

A virtual P3-AT's stereo head (the rendering mock, through the real Videre driver) looks at the building
from poses along robot1's route at 0.35 m/s and ``--rate`` Hz, 640×480. Every stage of the onboard pipeline
is timed on one thread (one core): the driver's grab (de-interleave) + rectification, the front end, FastSLAM
predict and update with ``--particles`` particles, logging to Rerun (a saved ``.rrd`` in a temporary folder, as
``p3at run --out`` writes; ``--rerun-rows``: each row sent as it is logged, as a live viewer's stream gets them,
instead of held and sent as columns about once a second) and to a sensor log. Rendering belongs to the mock,
not the robot, and is reported apart. The ratio is the frame period over the mean time per frame: ≥ 1 keeps up
with the camera; the goal is ≥ 3 for the whole onboard pipeline. A second table runs the same filter on the
synthetic observer (no images).

Stages are timed in wall time (``time.perf_counter``) unless ``--cpu``: then every stage reads the main
thread's CPU time (``time.thread_time``), which the other processes on a shared machine disturb much less
(the pipeline runs on one thread; the driver's reader thread, if any, is not counted).
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")  # as the runtime does (runtime/__init__.py); before numpy loads

import numpy as np

from drivers.videre.frames import deinterleave, interleave
from drivers.videre.head import StereoHead
from estimation.fastslam import FastSLAMConfig
from estimation.frontend import FrontEndConfig, HarrisConfig
from estimation.geometry import between, compose
from mocks.stereo_head import VirtualStereoHead
from mocks.synthetic_stereo import SyntheticStereo
from mocks.world import World
from runtime.adapters import VidereCamera, left_camera_mount
from runtime.commands.options import positive_float, positive_int
from runtime.motion import PurePursuit
from runtime.onboard import CameraFrame, OnboardConfig, SlamCore, frame_record, log_step
from runtime.rerun_log import MissionLog
from runtime.rerun_sink import open_recording
from runtime.sensorlog import SensorLogWriter


def route_poses(world: World, n: int, rate: float, speed: float = 0.35) -> np.ndarray:
    """n true poses (n, 3) along robot1's route, one per camera frame."""
    pose = np.asarray(world.start_poses["robot1"], float)
    controller = PurePursuit(world.routes["robot1"], speed=speed)
    poses = []
    for _ in range(n):
        command = controller.command(pose)
        pose = compose(pose, np.array([command.v / rate, 0.0, command.w / rate]))
        poses.append(pose)
    return np.array(poses)


def table(title: str, rows: list[tuple[str, float]], period: float, onboard: list[str]) -> None:
    print(f"\n{title}")
    print(f"{'stage':<28}{'ms/frame':>10}{'x real time':>13}")
    for name, ms in rows:
        print(f"{name:<28}{ms:>10.2f}{(1000 * period / ms if ms > 0 else float('inf')):>13.1f}")
    total = sum(ms for name, ms in rows if name in onboard)
    print(f"{'onboard total':<28}{total:>10.2f}{1000 * period / total:>13.1f}   (goal >= 3)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=positive_int, default=150)
    parser.add_argument("--particles", type=positive_int, default=100)
    parser.add_argument("--rate", type=positive_float, default=15.0)
    parser.add_argument("--max-corners", type=positive_int, default=150,
                        help="Harris corners per image (runtime default)")
    parser.add_argument("--rerun-rows", action="store_true",
                        help="send each Rerun row as it is logged (a live stream's way) instead of holding a saved "
                             "file's per-frame rows and sending them as columns")
    parser.add_argument("--cpu", action="store_true",
                        help="time every stage with the main thread's CPU time (time.thread_time) "
                             "instead of wall time")
    args = parser.parse_args()
    clock = time.thread_time if args.cpu else time.perf_counter
    try:
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core
    except (AttributeError, OSError):
        pass
    period = 1.0 / args.rate
    world = World.load()
    world.add_robot("robot1", world.start_poses["robot1"])
    poses = route_poses(world, args.frames, args.rate)
    rng = np.random.default_rng(0)

    virtual = VirtualStereoHead(world, "robot1", rng=rng)
    camera = VidereCamera(StereoHead.open(backend=virtual), rate=args.rate)
    config = OnboardConfig(fastslam=FastSLAMConfig(n_particles=args.particles, max_observations=0),
                           frontend=FrontEndConfig(geometry=camera.geometry,
                                                   harris=HarrisConfig(max_corners=args.max_corners)))
    core = SlamCore("robot1", config, timer=clock)
    scratch = tempfile.TemporaryDirectory()
    logger = MissionLog(open_recording(str(Path(scratch.name) / "bench.rrd")), ["robot1"],
                        hold_rows=False if args.rerun_rows else None)
    times = {k: 0.0 for k in ("render (mock, not onboard)", "grab + rectify", "frontend", "predict", "update",
                              "rerun logging", "sensor log")}
    n_obs = 0
    rerun_per_frame = []
    with tempfile.TemporaryDirectory() as tmp:
        writer = SensorLogWriter(Path(tmp) / "log", {"robot": "robot1", "camera": "mock", "rectified": True,
                                                     "geometry": camera.geometry.to_dict()})   # as the mission's
        start = world.start_poses["robot1"]
        for i, pose in enumerate(poses):
            world.set_pose("robot1", pose)
            t0 = clock()
            left_raw, right_raw = virtual.renderer.render(pose)  # the mock's own cost, measured apart
            t1 = clock()
            frame = camera.read(timeout=2.0)  # renders again inside the virtual head: not timed
            wire = interleave(left_raw, right_raw)
            t1b = clock()
            left, right = deinterleave(wire, 640, 480)  # what the driver does with the bulk transfer ...
            camera.calibration.rectify(left, right)     # ... and the adapter with the pair
            t2 = clock()
            frame = CameraFrame(i * period, i, frame.left, frame.right)
            result = core.step(frame, between(start, pose))
            t3 = clock()
            landmarks = None
            if i % config.landmarks_every == 0:
                landmarks = core.slam.particle_map(core.slam.best_index, 1, "robot1")
            log_step(logger, "robot1", frame.t, frame, result, core.slam.poses, true_pose=between(start, pose),
                     head_mount=left_camera_mount(camera.geometry), landmarks=landmarks)
            t4 = clock()
            writer.write(*frame_record(frame))
            t5 = clock()
            times["render (mock, not onboard)"] += t1 - t0
            times["grab + rectify"] += t2 - t1b
            times["rerun logging"] += t4 - t3
            rerun_per_frame.append(1000 * (t4 - t3))
            times["sensor log"] += t5 - t4
            n_obs += result.n_observations
            del left_raw, right_raw
        writer.close()
    camera.close()
    logger.close()
    scratch.cleanup()
    for k in ("frontend", "predict", "update"):
        times[k] = core.totals[k]
    n = len(poses)
    print(f"{n} frames 640x480 at {args.rate:g} Hz ({n * period:.1f} s of robot time), {args.particles} particles, "
          f"{args.max_corners} corners/image, "
          f"{n_obs / n:.0f} observations/frame, {len(core.best_map())} landmarks in the final map, one core, "
          f"{'CPU time (main thread)' if args.cpu else 'wall time'}")
    rows = [(k, 1000 * v / n) for k, v in times.items()]
    table("Rendered frames (mock head through the Videre driver)", rows, period,
          ["grab + rectify", "frontend", "predict", "update", "rerun logging", "sensor log"])
    median, p90, worst = np.percentile(rerun_per_frame, [50, 90, 100])
    print(f"rerun logging per frame: median {median:.2f}, p90 {p90:.2f}, max {worst:.2f} ms "
          f"({'each row sent as logged' if args.rerun_rows else 'per-frame rows held, sent as columns'}; "
          f"the stereo pair every 0.5 s, landmarks every {config.landmarks_every} frames)")

    observer = SyntheticStereo.from_world(world, np.random.default_rng(1))
    core = SlamCore("robot1", config, timer=clock)
    t_observe = 0.0
    for i, pose in enumerate(poses):
        t0 = clock()
        observations, _ = observer.observe(pose, i * period)
        t_observe += clock() - t0
        core.step(CameraFrame(i * period, i, observations=observations), between(start, pose))
    rows = [("synthetic observer (mock)", 1000 * t_observe / n)] + [(k, 1000 * core.totals[k] / n)
                                                                     for k in ("predict", "update")]
    table("Synthetic observations (no images)", rows, period, ["predict", "update"])


if __name__ == "__main__":
    main()
