"""Sensor-log size and cost: the MCAP log of a rendered-camera run, and the same frames in other encodings.

    python benchmarks/bench_sensorlog.py                 # runs a 25 s one-robot mission with rendered stereo
    python benchmarks/bench_sensorlog.py --log OUT/robot1-log   # an existing log

Prints the log's size (MB and MB per minute), bytes per topic, and for the logged frames: PNG at levels 1, 3 and
9 (lossless: what replay needs), raw ``sensor_msgs/Image`` in zstd chunks, the former npz-chunk format
(``np.savez_compressed``), and JPEG quality 90 (lossy: for comparison only, it cannot feed a bit-exact replay),
each as MB per minute of log and ms of CPU per frame (median).
"""
from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import io
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import zstandard

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from runtime.commands.options import positive_float  # noqa: E402
from runtime.sensorlog import SensorLog  # noqa: E402


def _run_mission(out: Path, seconds: float) -> Path:
    from runtime.mission import Mission, MissionConfig

    config = MissionConfig(robots=1, seconds=seconds, camera="mock", camera_rate=15.0, particles=20,
                           fusion_interval=0.0, out=out, rerun="none", log_sensors=True)
    Mission(config).run()
    return out / "robot1-log"


def _timed(fn, frames) -> tuple[int, float]:
    sizes, times = 0, []
    for left, right in frames:
        start = time.process_time()
        sizes += fn(left, right)
        times.append(time.process_time() - start)
    return sizes, 1000 * statistics.median(times)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--log", type=Path, default=None, help="an existing sensor-log folder")
    parser.add_argument("--seconds", type=positive_float, default=25.0, help="mission length when no --log is given")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.log or _run_mission(Path(tmp), args.seconds)
        log = SensorLog(folder)
        total = sum(f.stat().st_size for f in log.files)
        t0, t1 = log.time_span()
        minutes = max(t1 - t0, 1e-9) / 60
        print(f"{folder}: {len(log.files)} segment(s), {total / 1e6:.1f} MB for {60 * minutes:.1f} s of log "
              f"({total / 1e6 / minutes:.1f} MB/min); messages per topic:")
        per_topic: dict[str, int] = {}
        for m in log.messages():
            per_topic[m.topic] = per_topic.get(m.topic, 0) + len(m.data)
        for topic, size in sorted(per_topic.items(), key=lambda kv: -kv[1])[:8]:
            print(f"  {topic:48s} {size / 1e6:8.2f} MB (CDR, before chunk compression) {log.counts[topic]:6d} msgs")
        frames = [(r["left"], r["right"]) for r in log.records("frames")]
        if not frames:
            print("no image frames in this log")
            return 0
        zstd = zstandard.ZstdCompressor(level=3)

        def png(level):
            return lambda a, b: sum(len(cv2.imencode(".png", x, [cv2.IMWRITE_PNG_COMPRESSION, level])[1])
                                    for x in (a, b))

        def npz(a, b):
            buf = io.BytesIO()
            np.savez_compressed(buf, left=a[None], right=b[None])
            return len(buf.getvalue())

        encodings = {"PNG level 1 (the log's)": png(1), "PNG level 3": png(3), "PNG level 9": png(9),
                     "raw Image, zstd level 3": lambda a, b: len(zstd.compress(a.tobytes() + b.tobytes())),
                     "npz (format 1), per frame": npz,
                     "JPEG q90 (lossy, not replayable)": lambda a, b: sum(
                         len(cv2.imencode(".jpg", x, [cv2.IMWRITE_JPEG_QUALITY, 90])[1]) for x in (a, b))}
        print(f"{len(frames)} frames {frames[0][0].shape}: image bytes per minute of log, CPU per frame (median)")
        for name, fn in encodings.items():
            size, ms = _timed(fn, frames)
            print(f"  {name:34s} {size / 1e6 / minutes:8.1f} MB/min  {ms:6.2f} ms/frame")
    return 0


if __name__ == "__main__":
    sys.exit(main())
