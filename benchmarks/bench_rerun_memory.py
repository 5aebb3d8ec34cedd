"""Does logging to Rerun grow the process's memory over a long mission? Prints RSS per simulated minute.

A synthetic mission (no SLAM: the logging alone) at the demo's rates: per robot a frame at 4 Hz (pose, truth,
odometry, 100 particles, scalars), the best particle's landmarks every 5 frames (growing to ``--landmarks``),
a 640x480 stereo pair every 0.5 s, a map snapshot every 5 s, a fusion every 10 s; written to a file as fast as
the machine goes. What the logger itself keeps is bounded (tests/runtime/test_rerun_blueprint.py); this measures
the whole process, Rerun's Rust-side buffers included.

    .venv/bin/python benchmarks/bench_rerun_memory.py --minutes 10
"""
from __future__ import annotations

import argparse
import ctypes
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from estimation.landmark_map import LandmarkMap  # noqa: E402
from runtime.commands.options import non_negative_float, positive_float, positive_int  # noqa: E402
from runtime.rerun_log import MissionLog  # noqa: E402
from runtime.rerun_sink import open_recording  # noqa: E402
from runtime.rerun_style import mission_blueprint  # noqa: E402
from runtime.rrd_salvage import scan_rrd  # noqa: E402

ROBOTS = ["robot1", "robot2"]


def rss_mb() -> float:
    """Resident set size now (Linux /proc), MB."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize() / 1e6


def landmark_map(robot: str, n: int, rng: np.random.Generator, t: float) -> LandmarkMap:
    trajectory = np.column_stack([np.linspace(0, t, max(2, int(4 * t))), np.zeros((max(2, int(4 * t)), 3))])
    return LandmarkMap(rng.uniform(-20, 20, (n, 3)), np.tile(0.01 * np.eye(3), (n, 1, 1)),
                       rng.normal(size=(n, 64)).astype(np.float32), np.arange(n), rng.integers(1, 9, n), robot,
                       "start", trajectory=trajectory)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=positive_float, default=10.0, help="simulated mission length (default 10)")
    parser.add_argument("--landmarks", type=positive_int, default=2000,
                        help="landmarks per robot at the end (default 2000)")
    parser.add_argument("--no-images", action="store_true", help="log no stereo pairs")
    parser.add_argument("--no-maps", action="store_true", help="log no landmarks and no map snapshots")
    parser.add_argument("--constant-map", action="store_true",
                        help="maps of --landmarks landmarks from the start (else they grow linearly to it)")
    parser.add_argument("--flush", action="store_true",
                        help="wait for Rerun to write everything before each sample (no queue behind the writer)")
    parser.add_argument("--footer", action="store_true",
                        help="save with Rerun's footer (an index of every chunk, kept in memory until the end)")
    parser.add_argument("--trim", action="store_true",
                        help="return freed heap to the system (glibc malloc_trim) before each sample")
    parser.add_argument("--pace", type=non_negative_float, default=0.0,
                        help="wall seconds per simulated second at least (the demo runs at 0.5-0.7; Rerun batches "
                             "by wall time, so the pace sets the number of chunks per simulated minute)")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    # a textured image (JPEG-compressible like a camera's, unlike pure noise): gradients, blocks and some noise
    v, u = np.mgrid[0:480, 0:640]
    image = ((u // 40 + v // 40) % 2 * 80 + u / 8 + rng.normal(0, 6, (480, 640))).clip(0, 255).astype(np.uint8)
    with tempfile.TemporaryDirectory() as scratch:
        rrd = Path(scratch) / "bench.rrd"
        rec = open_recording(str(rrd), blueprint=mission_blueprint(ROBOTS), footer=args.footer)
        log = MissionLog(rec, ROBOTS, blueprint=False)
        trim = ctypes.CDLL("libc.so.6").malloc_trim if args.trim else None
        log.log_building(np.array([[-5.0, -2.0, 40.0, -2.0], [-5.0, 2.0, 40.0, 2.0]]), np.array([2.5, 2.5]))
        for name in ROBOTS:
            log.log_robot_frame(name, np.zeros(3))
            log.log_camera_model(name, 520, 520, 319.5, 239.5, 640, 480, 0.09)
        frames = int(args.minutes * 60 * 4)
        start, samples = time.perf_counter(), [(0.0, rss_mb())]
        print(f"{'sim min':>7} {'RSS MB':>8} {'file MB':>8} {'wall s':>7}")
        for frame in range(frames):
            t = frame / 4.0
            if args.pace > 0:
                time.sleep(max(0.0, start + args.pace * t - time.perf_counter()))
            n = args.landmarks if args.constant_map else int(50 + (args.landmarks - 50) * frame / frames)
            for name in ROBOTS:
                pose = np.array([0.1 * t % 30, np.sin(t / 10), t / 20])
                log.log_pose(name, t, frame, pose, pose + 0.02, (0.12, 0.045, 0.5), odometry=pose * 1.02)
                log.log_particles(name, t, frame, pose + rng.normal(0, 0.05, (100, 3)))
                log.log_scalars(name, t, {"ess": 60.0, "landmarks/all": n, "observations": 40, "dropped": 0,
                                          "time/frontend": 5.0, "time/predict": 0.5, "time/update": 9.0}, frame)
                if not args.no_images:
                    pixels = rng.uniform(0, 600, (40, 2))
                    log.log_stereo(name, t, frame, image, image, pixels, pixels - [20, 0])
                if frame % 5 == 0 and not args.no_maps:
                    log.log_robot_landmarks(name, t, frame, landmark_map(name, n, rng, t), confirm_count=3)
                if frame % 20 == 0 and not args.no_maps:
                    log.log_map(name, t, landmark_map(name, int(0.8 * n), rng, t))
            if frame % 40 == 0:
                log.log_alignment(t, "robot1", "robot2", {"aligned": True, "tx": 5.0, "ty": 0.0, "theta": 3.1,
                                                          "error_xy": 0.05, "error_theta": 0.01, "common": 50,
                                                          "merged": n})
            if (frame + 1) % 240 == 0:
                if args.flush:
                    log.flush()
                if trim is not None:
                    trim(0)
                samples.append(((frame + 1) / 240, rss_mb()))
                print(f"{samples[-1][0]:7.0f} {samples[-1][1]:8.1f} {rrd.stat().st_size / 1e6:8.1f} "
                      f"{time.perf_counter() - start:7.1f}")
        log.close()
        scan = scan_rrd(rrd)
        print(f"{scan.messages} messages (chunks) in {scan.file_size / 1e6:.0f} MB, footer {args.footer}, "
              f"{time.perf_counter() - start:.0f} s of wall time")
    minutes = np.array([m for m, _ in samples[1:]])
    rss = np.array([r for _, r in samples[1:]])
    if len(minutes) >= 3:
        tail = minutes >= minutes[len(minutes) // 2]  # the second half: after the first-use allocations
        slope = np.polyfit(minutes[tail], rss[tail], 1)[0]
        print(f"RSS {samples[0][1]:.1f} MB at start, {rss[0]:.1f} MB after 1 min, {rss[-1]:.1f} MB at the end; "
              f"growth over the second half: {slope:.2f} MB per simulated minute")


if __name__ == "__main__":
    main()
