"""Memory over a long synthetic mission: samples the resident set size (RSS) of ``p3at demo`` and its children,
with the default Rerun recording and without one (``--rerun none``), side by side, and prints how each grows.

    .venv/bin/python benchmarks/bench_memory.py                          # 10-minute explore mission, both variants
    .venv/bin/python benchmarks/bench_memory.py --seconds 120 --variants recording   # one variant
    .venv/bin/python benchmarks/bench_memory.py --seconds 120 -- --robots 3   # extra demo arguments after --

The variants run at the same time (the machine's load is shared alike; memory does not depend on speed, except
that Rerun batches by wall time). The mission runs in simulated time (``p3at demo`` default), so it may finish
faster than 10 wall-clock minutes; samples are taken every ``--interval`` wall-clock seconds and placed on the
mission clock by the progress the demo reports (the ``t=`` of its progress line) when it prints one, else by the
share of wall time. Growth is reported two ways: from 10 % of the mission (imports and the first map are in) to
95 % (before the end-of-mission fusion and file writing, which is a peak, not growth), and the least-squares slope
from 50 % to 95 %, in MB per 100 s of mission. A bounded process shows a slope near zero; one that keeps
something per frame or per SIP shows a straight line.
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
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import psutil

from runtime.commands.options import positive_float, positive_int

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


VARIANTS = {"recording": [], "none": ["--rerun", "none"]}  # the demo's default sink (a saved .rrd), and none


@dataclass
class Run:
    """One demo process being sampled."""

    name: str
    proc: subprocess.Popen
    out: Path
    start: float
    samples: list[tuple[float, float]] = field(default_factory=list)   # (wall s, RSS MB)
    progress: list[tuple[float, float]] = field(default_factory=lambda: [(0.0, 0.0)])  # (wall s, mission s)
    tail: list[str] = field(default_factory=list)
    wall: float = 0.0

    def read_output(self) -> None:
        for line in self.proc.stdout:
            self.tail.append(line)
            del self.tail[:-50]
            found = PROGRESS.search(line.replace("\r", "\n").replace("\x1b[2K", ""))
            if found:
                self.progress.append((time.monotonic() - self.start, float(found.group(1))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=positive_float, default=600.0, help="mission length (default 600 s)")
    parser.add_argument("--robots", type=positive_int, default=2)
    parser.add_argument("--interval", type=positive_float, default=1.0, help="wall-clock seconds between samples")
    parser.add_argument("--variants", default="recording,none",
                        help=f"comma-separated, of {', '.join(VARIANTS)} (default: both, side by side)")
    parser.add_argument("--out", type=Path, help="demo output folders go under it (default: a temporary one)")
    parser.add_argument("demo_args", nargs="*", help="extra arguments for p3at demo (after --)")
    args = parser.parse_args()
    names = [v.strip() for v in args.variants.split(",") if v.strip()]
    unknown = [v for v in names if v not in VARIANTS]
    if unknown or not names:
        parser.error(f"--variants: unknown {', '.join(unknown) or '(none given)'}; choose from {', '.join(VARIANTS)}")
    root = args.out or Path(tempfile.mkdtemp(prefix="bench-memory-"))
    runs = []
    for name in names:
        out = root / name
        argv = [sys.executable, "-m", "runtime.cli", "demo", "--camera", "synthetic", "--motion", "explore",
                "--seconds", f"{args.seconds:g}", "--robots", str(args.robots), "--out", str(out),
                *VARIANTS[name], *args.demo_args]
        print(f"{name}: {' '.join(argv[1:])}", flush=True)
        proc = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                env={**os.environ, "PYTHONUNBUFFERED": "1", "COLUMNS": "200"})
        runs.append(Run(name, proc, out, time.monotonic()))
    readers = [threading.Thread(target=run.read_output, daemon=True) for run in runs]
    for reader in readers:
        reader.start()
    handles = {run.name: psutil.Process(run.proc.pid) for run in runs}
    while any(run.proc.poll() is None for run in runs):
        for run in runs:
            if run.proc.poll() is None:
                try:
                    run.samples.append((time.monotonic() - run.start, tree_rss(handles[run.name])))
                except psutil.NoSuchProcess:
                    pass
                run.wall = time.monotonic() - run.start
        time.sleep(args.interval)
    finished = []
    for run, reader in zip(runs, readers, strict=True):
        run.proc.wait()
        reader.join(5)
        if run.proc.returncode != 0 or len(run.samples) < 10:
            print("".join(run.tail)[-3000:])
            print(f"{run.name}: the demo ended with status {run.proc.returncode} after {run.wall:.0f} s "
                  f"({len(run.samples)} samples); left out of the report")
            continue
        run.progress.append((run.wall, args.seconds))
        finished.append(run)
    if finished:
        report(finished, args.seconds)
    print(f"(demo output under {root}; machine load average {os.getloadavg()[0]:.1f})")
    if len(finished) < len(runs):
        sys.exit(1)


def mission_times(run: Run) -> tuple[np.ndarray, np.ndarray]:
    """(mission s, RSS MB) of each sample."""
    w = np.array([s[0] for s in run.samples])
    rss = np.array([s[1] for s in run.samples])
    pw, pm = np.array(run.progress).T
    return np.interp(w, pw, np.maximum.accumulate(pm)), rss


def at(m: np.ndarray, rss: np.ndarray, t: float) -> float:
    """RSS of the first sample at or after mission time ``t`` (nan if none)."""
    index = np.flatnonzero(m >= t)
    return float(rss[index[0]]) if index.size else float("nan")


def report(runs: list[Run], seconds: float) -> None:
    series = {run.name: mission_times(run) for run in runs}
    print(f"\n{seconds:g} s of mission; wall time " + ", ".join(f"{r.name} {r.wall:.0f} s ({len(r.samples)} samples)"
                                                           for r in runs))
    print("| mission s | " + " | ".join(f"RSS MB, {r.name}" for r in runs) + " |")
    print("|---" * (len(runs) + 1) + "|")
    for fraction in np.linspace(0.0, 1.0, 11):
        values = [at(*series[run.name], fraction * seconds) for run in runs]
        cells = ["-" if np.isnan(v) else f"{v:.0f}" for v in values]  # "-": the process had ended
        print(f"| {fraction * seconds:.0f} | " + " | ".join(cells) + " |")
    print()
    for run in runs:
        m, rss = series[run.name]
        # The last 5 % hold the end of the mission (final fusion, maps and files written): a peak, not growth.
        window = (m >= 0.5 * seconds) & (m <= 0.95 * seconds)
        slope = np.polyfit(m[window], rss[window], 1)[0] * 100 if window.sum() > 3 else float("nan")
        start, middle, late = (at(m, rss, f * seconds) for f in (0.1, 0.5, 0.95))
        print(f"{run.name:>9}: RSS at 10 % {start:.0f} MB, 50 % {middle:.0f} MB, 95 % {late:.0f} MB, peak "
              f"{rss.max():.0f} MB (at {m[int(np.argmax(rss))]:.0f} s); growth 10-95 % {late - start:+.0f} MB; "
              f"slope 50-95 % {slope:+.1f} MB per 100 s of mission")


if __name__ == "__main__":
    main()
