"""What ``LandmarkMap.save``'s check costs: the bytes it writes are read back with the reader's own checks before the
file is replaced (session 46), so that a map ``load`` would refuse is never written.

Per map size, the median over ``--repeats`` of: the archive's serialisation (``LandmarkMap.archive_bytes``, what
``save`` always did), the check (``check_map_bytes``: the reader's checks, what ``save`` now adds) and the whole
``save`` (serialisation, check, atomic write with its fsyncs). Maps are random and sound (every optional member
present).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_map_save.py
"""
from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from estimation.landmark_map import LandmarkMap, check_map_bytes  # noqa: E402
from runtime.commands.options import positive_int  # noqa: E402

SIZES = ((300, 32, 3_000), (3_000, 32, 30_000), (20_000, 32, 100_000))   # landmarks, descriptor floats, trajectory rows


def sound_map(n: int, d: int, t: int, rng: np.random.Generator) -> LandmarkMap:
    a = rng.normal(size=(n, 3, 3)) * 0.1
    spd = a @ np.swapaxes(a, 1, 2) + 0.01 * np.eye(3)
    return LandmarkMap(rng.uniform(-20, 20, (n, 3)), spd, rng.normal(size=(n, d)).astype(np.float32),
                       trajectory=np.column_stack([np.arange(t, dtype=float), rng.normal(size=(t, 3))]),
                       drift_covariances=spd, drift_origins=rng.normal(size=(n, 2)), sighting_covariances=spd)


def median_ms(f, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        f()
        times.append(time.perf_counter() - start)
    return 1000.0 * statistics.median(times)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=positive_int, default=5, help="runs of each step per size (default 5)")
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    print(f"median of {args.repeats} runs, ms (OPENBLAS_NUM_THREADS=1)")
    print(f"{'landmarks':>9} {'trajectory':>10} {'file kB':>8} {'serialise':>10} {'check':>8} {'save':>8}  check/save")
    with tempfile.TemporaryDirectory(prefix="bench_map_save-") as tmp:
        for n, d, t in SIZES:
            m = sound_map(n, d, t, rng)
            data = m.archive_bytes()
            serialise = median_ms(m.archive_bytes, args.repeats)
            checked = median_ms(lambda data=data: check_map_bytes(data, "x"), args.repeats)
            save = median_ms(lambda m=m: m.save(Path(tmp) / "map.npz"), args.repeats)
            print(f"{n:9d} {t:10d} {len(data) / 1000:8.0f} {serialise:10.1f} {checked:8.1f} {save:8.1f}  "
                  f"{checked / save:.2f}")


if __name__ == "__main__":
    main()
