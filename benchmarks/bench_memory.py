"""Memory over a long synthetic mission: samples the resident set size (RSS) of ``p3at demo`` and its children
and prints how it grows.

    .venv/bin/python benchmarks/bench_memory.py                          # 10-minute explore mission
    .venv/bin/python benchmarks/bench_memory.py --seconds 120 -- --rerun none   # extra demo arguments after --

The mission runs in simulated time (``p3at demo`` default), so it may finish faster than 10 wall-clock minutes;
samples are taken every ``--interval`` wall-clock seconds and placed on the mission clock by the progress the
demo reports (the ``t=`` of its progress line) when it prints one, else by the share of wall time.
Growth is reported two ways: from 10 % of the mission (imports and the first map are in) to 95 % (before the
end-of-mission fusion and file writing, which is a peak, not growth), and the least-squares slope from 50 % to
95 %, in MB per 100 s of mission. A bounded process shows a slope near zero; one that keeps something per frame
or per SIP shows a straight line.
"""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import psutil

ROOT = Path(__file__).resolve().parents[1]
PROGRESS = re.compile(r"^t=\s*(\d+(?:\.\d+)?)s \|", re.MULTILINE)  # the demo's progress line, every 5 s


def tree_rss(process: psutil.Process) -> float:
    """RSS of the process and all its children, MB."""
    total = 0
    for p in [process, *process.children(recursive=True)]:
        try:
            total += p.memory_info().rss
        except (psutil.NoSuchProcess, psutil.AccessDenied):
            pass
    return total / 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=600.0, help="mission length (default 600 s)")
    parser.add_argument("--robots", type=int, default=2)
    parser.add_argument("--interval", type=float, default=1.0, help="wall-clock seconds between samples")
    parser.add_argument("--out", type=Path, help="demo output folder (default: a temporary one)")
    parser.add_argument("demo_args", nargs="*", help="extra arguments for p3at demo (after --)")
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="bench-memory-"))
    argv = [sys.executable, "-m", "runtime.cli", "demo", "--camera", "synthetic", "--motion", "explore",
            "--seconds", f"{args.seconds:g}", "--robots", str(args.robots), "--out", str(out), *args.demo_args]
    print("command:", " ".join(argv[1:]), flush=True)
    start = time.monotonic()
    proc = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1", "COLUMNS": "200"})
    handle = psutil.Process(proc.pid)
    progress: list[tuple[float, float]] = [(0.0, 0.0)]  # (wall s, mission s) from the progress lines
    tail: list[str] = []

    def read_output() -> None:
        for line in proc.stdout:
            tail.append(line)
            del tail[:-50]
            found = PROGRESS.search(line.replace("\r", "\n").replace("\x1b[2K", ""))
            if found:
                progress.append((time.monotonic() - start, float(found.group(1))))
    reader = threading.Thread(target=read_output, daemon=True)
    reader.start()
    samples: list[tuple[float, float]] = []  # (wall s, RSS MB)
    while proc.poll() is None:
        try:
            samples.append((time.monotonic() - start, tree_rss(handle)))
        except psutil.NoSuchProcess:
            break
        time.sleep(args.interval)
    proc.wait()
    reader.join(5)
    wall = time.monotonic() - start
    if proc.returncode != 0 or len(samples) < 10:
        print("".join(tail)[-3000:])
        print(f"the demo ended with status {proc.returncode} after {wall:.0f} s ({len(samples)} samples)")
        sys.exit(1)
    progress.append((wall, args.seconds))
    report(samples, progress, wall, args.seconds)
    print(f"(demo output in {out}; machine load average {os.getloadavg()[0]:.1f})")


def report(samples: list[tuple[float, float]], progress: list[tuple[float, float]], wall: float,
           seconds: float) -> None:
    w = np.array([s[0] for s in samples])
    rss = np.array([s[1] for s in samples])
    pw, pm = np.array(progress).T
    m = np.interp(w, pw, np.maximum.accumulate(pm))  # mission time of each sample
    print(f"\n{len(samples)} samples over {wall:.0f} s of wall time ({seconds:g} s of mission)")
    print("| mission s | wall s | RSS MB |")
    print("|---|---|---|")
    for k in np.linspace(0, len(samples) - 1, 11).astype(int):
        print(f"| {m[k]:.0f} | {w[k]:.0f} | {rss[k]:.0f} |")
    def at(fraction: float) -> float:
        """RSS of the first sample at or after ``fraction`` of the mission."""
        index = np.flatnonzero(m >= fraction * seconds)
        return float(rss[index[0]]) if index.size else float("nan")
    # The last 5 % hold the end of the mission (final fusion, maps and files written): a peak, not growth.
    window = (m >= 0.5 * seconds) & (m <= 0.95 * seconds)
    slope = np.polyfit(m[window], rss[window], 1)[0] * 100 if window.sum() > 3 else float("nan")
    start, middle, late = at(0.1), at(0.5), at(0.95)
    print(f"\nRSS at 10 % of the mission {start:.0f} MB, at 50 % {middle:.0f} MB, at 95 % {late:.0f} MB; "
          f"peak {rss.max():.0f} MB (at {m[int(np.argmax(rss))]:.0f} s of mission)")
    print(f"growth from 10 % to 95 %: {late - start:+.0f} MB ({(late - start) / start * 100:+.0f} %); slope from 50 % "
          f"to 95 %: {slope:+.1f} MB per 100 s of mission")

if __name__ == "__main__":
    main()
