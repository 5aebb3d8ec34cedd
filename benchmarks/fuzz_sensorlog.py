"""Malformed sensor logs, camera_info and TUM files against their readers: clean errors, accepted, tracebacks, memory.

    python benchmarks/fuzz_sensorlog.py [--inputs 300] [--seed 0]

For each reader, ``--inputs`` damaged copies of a valid file (truncated, bytes overwritten, bytes inserted,
lengths set huge), read completely. Prints one row per reader: inputs, clean errors (the reader's own error
type), accepted (read without error: the damage hit nothing checked, e.g. padding), other exceptions
(tracebacks: the goal is 0), and the peak traced memory of one read.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import tracemalloc
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers.errors import BadFileError  # noqa: E402
from drivers.videre import camera_info  # noqa: E402
from mocks.stereo_head import default_calibration  # noqa: E402
from runtime.commands.options import non_negative_int, positive_int  # noqa: E402
from runtime.sensorlog import SensorLog, SensorLogError, SensorLogWriter  # noqa: E402
from runtime.trajectories import TrajectoryFileError, read_tum, write_tum  # noqa: E402


def _valid_log(folder: Path) -> Path:
    rng = np.random.default_rng(0)
    geometry = {"fx": 520.0, "fy": 520.0, "cx": 31.5, "cy": 23.5, "baseline": 0.09}
    with SensorLogWriter(folder / "log", {"robot": "robot1", "geometry": geometry}) as writer:
        for k in range(20):
            t = 0.1 * k
            writer.write("odometry", {"t": t, "x": 0.01 * k, "y": 0.0, "theta": 0.0, "sonar": rng.random(8),
                                      "sonar_poses": np.zeros((8, 3)), "raw": rng.integers(0, 256, 40, np.uint8)})
            image = rng.integers(0, 256, (48, 64), np.uint8)
            writer.write("frames", {"t": t + 0.01, "seq": k, "left": image, "right": image})
            writer.write("processed", {"t": t + 0.01, "seq": k})
    return next((folder / "log").iterdir())


def _damage(data: bytes, rng: np.random.Generator) -> bytes:
    out = bytearray(data)
    for _ in range(int(rng.integers(1, 4))):
        at = int(rng.integers(0, max(1, len(out))))
        kind = rng.integers(0, 4)
        if kind == 0:
            del out[at:]
        elif kind == 1:
            out[at:at + 4] = rng.integers(0, 256, 4, np.uint8).tobytes()
        elif kind == 2:
            out[at:at] = rng.integers(0, 256, int(rng.integers(1, 64)), np.uint8).tobytes()
        else:
            out[at:at + 8] = b"\xff\xff\xff\x7f\x00\x00\x00\x00"
    return bytes(out)


def _run(name: str, valid: bytes, place, read, clean: type[Exception], inputs: int, rng) -> tuple:
    errors = accepted = other = 0
    peak = 0
    for i in range(inputs):
        path = place(_damage(valid, rng), i)
        tracemalloc.start()
        try:
            read(path)
            accepted += 1
        except clean:
            errors += 1
        except Exception as e:  # noqa: BLE001 - what this script counts
            other += 1
            print(f"  {name} input {i}: {type(e).__name__}: {e}", file=sys.stderr)
        finally:
            peak = max(peak, tracemalloc.get_traced_memory()[1])
            tracemalloc.stop()
    return name, inputs, errors, accepted, other, peak


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--inputs", type=positive_int, default=300)
    parser.add_argument("--seed", type=non_negative_int, default=0)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        segment = _valid_log(tmp)

        def read_log(folder: Path) -> None:
            log = SensorLog(folder)
            for stream in ("odometry", "frames", "processed"):
                for _ in log.records(stream):
                    pass

        for suffix in (".mcap", ".mcap.part"):
            def place_log(data: bytes, i: int, suffix=suffix) -> Path:
                folder = tmp / f"log{suffix}{i}"
                folder.mkdir()
                (folder / f"robot1_0{suffix}").write_bytes(data)
                return folder
            rows.append(_run(f"sensor log ({suffix})", segment.read_bytes(), place_log, read_log, SensorLogError,
                             args.inputs, rng))

        camera_info.write_pair(default_calibration(), tmp / "ci")
        right = (tmp / "ci" / "right.yaml").read_bytes()

        def place_ci(data: bytes, i: int) -> Path:
            folder = tmp / f"ci{i}"
            folder.mkdir()
            (folder / "left.yaml").write_bytes((tmp / "ci" / "left.yaml").read_bytes())
            (folder / "right.yaml").write_bytes(data)
            return folder
        rows.append(_run("camera_info pair", right, place_ci, camera_info.read_pair, BadFileError, args.inputs, rng))

        write_tum(tmp / "t.tum", np.column_stack([np.arange(50.0), rng.normal(size=(50, 2)), rng.uniform(-3, 3, 50)]))

        def place_tum(data: bytes, i: int) -> Path:
            path = tmp / f"t{i}.tum"
            path.write_bytes(data)
            return path
        rows.append(_run("TUM trajectory", (tmp / "t.tum").read_bytes(), place_tum, read_tum, TrajectoryFileError,
                         args.inputs, rng))
    print(f"{'reader':26s} {'inputs':>7s} {'clean errors':>13s} {'accepted':>9s} {'tracebacks':>11s} {'peak MB':>8s}")
    for name, inputs, errors, accepted, other, peak in rows:
        print(f"{name:26s} {inputs:7d} {errors:13d} {accepted:9d} {other:11d} {peak / 1e6:8.1f}")
    return 0 if all(r[4] == 0 for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
