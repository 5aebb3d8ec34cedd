"""MRCLAM's Vicon glitches: the ground-truth rows whose heading jumps away for a row or a few and comes back.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.mrclam_truth_glitches [--robots 1 2 ...] [--clean DIR]
                                                                                 [--json]

A step between consecutive truth rows faster than TRUTH_MAX_TURN_RATE (4 rad/s) or TRUTH_MAX_SPEED (2 m/s), over
max(dt, TRUTH_MIN_STEP_S) (estimation.odometry_response, session 44 (D)), is a glitch's edge. The rows to drop are
found in two passes: (1) a row whose heading lies more than GLITCH_RAD from the median of its 2·NEIGHBOURS neighbours'
(the median of the wrapped differences) or whose position lies more than GLITCH_M from theirs; (2) while a fast step
is left, the later of its two rows if the step from the earlier to the next row is slow, else the earlier if the
step from the previous row is slow, else the later (a lone row at ~0 rad between +π and −π neighbours escapes (1):
half its neighbours are +π away, half −π). Printed per robot: rows, fast steps, rows dropped, the episodes (dropped
rows within 5 rows of each other), how many lie where the heading crosses ±π, and how many share a stamp with a
neighbour.

On data set 2 (session 44 (E)): 17–27 rows per robot in 12–16 episodes, every one where the heading crosses ±π:
Vicon's heading interpolated linearly across the wrap (a row between 3.133 and −3.138 reads −0.003), not a timestamp
problem and no position jump.

``--clean DIR`` writes a copy of the data set folder with those rows deleted from each RobotN_Groundtruth.dat (the
other lines byte-identical, gzip-compressed if the original is) and the other files linked, for `p3at slam noise
mrclam DIR` against a truth without them.
"""
from __future__ import annotations

import argparse
import gzip
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from estimation.geometry import wrap_angle  # noqa: E402
from estimation.odometry_response import fast_truth_steps  # noqa: E402
from runtime.commands.options import positive_int  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "mrclam" / "MRCLAM_Dataset2"
GLITCH_RAD = 0.1      # rad off the neighbours' median heading: a glitch row (a real turn moves < 0.02 rad a row)
GLITCH_M = 0.05       # m off the neighbours' median position
NEIGHBOURS = 5        # rows on each side
EPISODE_GAP = 5       # dropped rows further apart than this are two episodes


def _fast(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(fast_truth_steps(np.stack([a, b]))[0])


def glitch_rows(truth: np.ndarray) -> np.ndarray:
    """The sorted indices of the rows of ``truth`` (N, 4: time, x, y, θ) to drop (module docstring); after dropping
    them no step is fast."""
    n = len(truth)
    if n < 3:
        return np.zeros(0, np.int64)
    shifts = np.array([s for s in range(-NEIGHBOURS, NEIGHBOURS + 1) if s])
    near = np.clip(np.arange(n)[:, None] + shifts[None, :], 0, n - 1)
    heading_off = np.abs(np.median(wrap_angle(truth[near, 3] - truth[:, None, 3]), axis=1))
    position_off = np.hypot(np.median(truth[near, 1], axis=1) - truth[:, 1],
                            np.median(truth[near, 2], axis=1) - truth[:, 2])
    dropped = set(np.flatnonzero((heading_off > GLITCH_RAD) | (position_off > GLITCH_M)).tolist())
    keep = [i for i in range(n) if i not in dropped]
    k = 0
    while k < len(keep) - 1:
        a, b = keep[k], keep[k + 1]
        if not _fast(truth[a], truth[b]):
            k += 1
        elif k + 2 < len(keep) and not _fast(truth[a], truth[keep[k + 2]]):
            dropped.add(b)
            del keep[k + 1]
        elif k > 0 and not _fast(truth[keep[k - 1]], truth[b]):
            dropped.add(a)
            del keep[k]
            k -= 1
        else:
            dropped.add(b)
            del keep[k + 1]
    return np.array(sorted(dropped), np.int64)


def census(truth: np.ndarray) -> dict:
    """The figures the script prints for one robot's truth."""
    rows = glitch_rows(truth)
    keep = np.setdiff1d(np.arange(len(truth)), rows)
    episodes = int(len(rows) > 0) + int(np.sum(np.diff(rows) > EPISODE_GAP))
    # the nearest kept rows on either side of each dropped row
    before = keep[np.clip(np.searchsorted(keep, rows) - 1, 0, len(keep) - 1)]
    after = keep[np.clip(np.searchsorted(keep, rows), 0, len(keep) - 1)]
    at_wrap = (np.abs(truth[before, 3]) > 3.0) & (np.abs(truth[after, 3]) > 3.0)
    shared = (truth[rows, 0] == truth[before, 0]) | (truth[rows, 0] == truth[after, 0])
    return {"rows": len(truth), "fast_steps": int(fast_truth_steps(truth).sum()), "dropped": len(rows),
            "episodes": episodes, "at_the_wrap": int(at_wrap.sum()), "sharing_a_stamp": int(shared.sum()),
            "fast_steps_left": int(fast_truth_steps(truth[keep]).sum()),
            "dropped_times_s": [float(t) for t in truth[rows, 0]]}


def _truth_file(folder: Path, robot: int) -> Path:
    for name in (f"Robot{robot}_Groundtruth.dat", f"Robot{robot}_Groundtruth.dat.gz"):
        if (folder / name).is_file():
            return folder / name
    raise FileNotFoundError(f"{folder}: no Robot{robot}_Groundtruth.dat(.gz)")


def read_truth_lines(path: Path) -> tuple[list[bytes], list[int], np.ndarray]:
    """The file's lines, the indices of its data lines (not blank, not #) and their rows (time, x, y, θ)."""
    raw = gzip.open(path, "rb").read() if path.suffix == ".gz" else path.read_bytes()
    lines = raw.split(b"\n")
    data = [i for i, line in enumerate(lines) if line.strip() and not line.lstrip().startswith(b"#")]
    return lines, data, np.array([[float(x) for x in lines[i].split()[:4]] for i in data]).reshape(-1, 4)


def write_clean(folder: Path, out: Path, robots: list[int]) -> dict[int, int]:
    """The data set folder ``folder`` copied to ``out`` with each robot's glitch rows deleted (the other lines
    byte-identical; every other file linked); the number of rows deleted per robot."""
    out.mkdir(parents=True, exist_ok=True)
    truth_names = set()
    deleted = {}
    for robot in robots:
        path = _truth_file(folder, robot)
        truth_names.add(path.name)
        lines, data, truth = read_truth_lines(path)
        drop = {data[i] for i in glitch_rows(truth)}
        text = b"\n".join(line for i, line in enumerate(lines) if i not in drop)
        target = out / path.name
        target.unlink(missing_ok=True)
        if path.suffix == ".gz":
            with gzip.open(target, "wb") as f:
                f.write(text)
        else:
            target.write_bytes(text)
        deleted[robot] = len(drop)
    for item in folder.iterdir():
        link = out / item.name
        if item.name not in truth_names and not link.exists():
            link.symlink_to(item.resolve())
    return deleted


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--robots", type=positive_int, nargs="+", default=[1, 2, 3, 4, 5])
    parser.add_argument("--clean", type=Path, default=None, metavar="DIR",
                        help="write the data set with the glitch rows deleted from the truth files to DIR")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    if not args.data.is_dir():
        print(f"mrclam_truth_glitches: no data set at {args.data}", file=sys.stderr)
        return 2
    if args.clean is not None and args.clean.resolve() == args.data.resolve():
        print("mrclam_truth_glitches: --clean must not be the data set's own folder", file=sys.stderr)
        return 2
    result = {r: census(read_truth_lines(_truth_file(args.data, r))[2]) for r in args.robots}
    if args.clean is not None:
        write_clean(args.data, args.clean, args.robots)
    if args.json:
        print(json.dumps(result, indent=1))
        return 0
    print("robot  rows   fast steps  dropped  episodes  at ±π  sharing a stamp  fast steps left")
    for r, c in result.items():
        print(f"{r:5d}  {c['rows']:6d}  {c['fast_steps']:9d}  {c['dropped']:7d}  {c['episodes']:8d}  "
              f"{c['at_the_wrap']:5d}  {c['sharing_a_stamp']:15d}  {c['fast_steps_left']:15d}")
    if args.clean is not None:
        print(f"cleaned copy: {args.clean}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
