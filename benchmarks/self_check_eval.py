"""Does a map's self-check (estimation/fastslam/self_check.py) flag the maps that lost their place, and only those?

Run from the repository root:

    .venv/bin/python -m benchmarks.self_check_eval maps DEMO_DIR [DEMO_DIR ...]
    .venv/bin/python -m benchmarks.self_check_eval replay DEMO_DIR --frames-cache FILE [--filter-seed K ...]
    .venv/bin/python -m benchmarks.self_check_eval mrclam MAPS_DIR [--eval-json FILE]

``maps``: `p3at demo --out` folders (made with the self-check: their robot maps carry metadata["self_check"]).
Per robot: the verdict (first alarm, its figures, alarms in all) beside the truth: the demo's own trajectory
(``<robot>.tum``) against ``<robot>-truth.tum``, ATE and the median |heading error| over the second half of the
run. A map is *diverged* when that median exceeds ``DIVERGED_HEADING`` = 0.1 rad: a map built in a turned frame
(docs/fastslam-history.md: the diverged runs stay 0.13-0.25 rad off, the healthy ones return within 0.04 rad). The table
counts detected / missed / false flags.

``replay``: one robot of a demo folder replayed offline from a frame cache (``slam_demo_replay``'s inputs: the
true route, the odometry, the demo's filter settings; ``--frames-cache`` as written by it or
``eval_slam_rendered``) with each ``--filter-seed`` (the demo's own is seed * 1000 + 1 for robot 2): the same
frames, different filter draws, some diverge and some recover.

``mrclam``: maps written by ``benchmarks.eval_mrclam --maps MAPS_DIR`` (MAPS_DIR/{id,unknown}/robotN.npz); with
``--eval-json`` (its ``--json`` output) each robot's ATE beside the verdict.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

from benchmarks.slam_demo_replay import read_tum
from estimation.geometry import between, compose, wrap_angle
from estimation.landmark_map import LandmarkMap
from runtime.commands.options import non_negative_int
from runtime.map_self_check import read_self_check

DIVERGED_HEADING = 0.1   # rad, median |heading error| over the run's second half (see the module docstring)
ONSET_FRAMES = 11        # ~3 s at 3.75 Hz: a heading error held, not one frame's jump


def truth_figures(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float, float | None]:
    """(ATE m, median |heading error| over the second half rad, first time the median |heading error| over
    ONSET_FRAMES frames exceeds DIVERGED_HEADING or None) of (T, 4) trajectories (t, x, y, θ) on the same frames."""
    n = min(len(estimate), len(truth))
    error_xy = np.hypot(*(estimate[:n, 1:3] - truth[:n, 1:3]).T)
    error_theta = np.abs(wrap_angle(estimate[:n, 3] - truth[:n, 3]))
    windows = np.lib.stride_tricks.sliding_window_view(error_theta, min(ONSET_FRAMES, n))
    above = np.flatnonzero(np.median(windows, axis=1) > DIVERGED_HEADING)
    onset = float(truth[above[0], 0]) if len(above) else None
    return float(np.sqrt(np.mean(error_xy ** 2))), float(np.median(error_theta[n // 2:])), onset


def verdict_cells(verdict: dict | None) -> str:
    if verdict is None:
        return "no self-check | | |"
    if not verdict["lost"]:
        return f"not flagged (max CUSUM {verdict['max_statistic']:.1f} of {verdict['threshold']:.1f}) | | |"
    a = verdict["alarms"][0]
    return (f"flagged at {a['t']:.1f} s (since {a['since']:.1f}) | {a['redetected']:.0f} of {a['predicted']:.0f} "
            f"re-detected, {a['expected']:.1f} expected | {verdict['n_alarms']:.0f} | {verdict['dispersion']:.1f} |")


def tally(rows: list[tuple[bool, bool]]) -> str:
    detected = sum(d and f for d, f in rows)
    missed = sum(d and not f for d, f in rows)
    false = sum(f and not d for d, f in rows)
    healthy = sum(not d for d, _ in rows)
    return (f"diverged maps flagged {detected} of {detected + missed} (missed {missed}); healthy maps flagged "
            f"{false} of {healthy} (false flags)")


def run_maps(dirs: list[Path]) -> None:
    print("| demo | robot | ATE m | heading error, 2nd half median rad | truth | self-check | first alarm's "
          "figures | alarms | dispersion |")
    print("|---|---|---|---|---|---|---|---|---|")
    rows = []
    for demo in dirs:
        for robot_file in sorted(demo.glob("robot*.npz")):
            robot = robot_file.stem
            if not (demo / f"{robot}.tum").is_file() or not (demo / f"{robot}-truth.tum").is_file():
                continue
            verdict = read_self_check(LandmarkMap.load(robot_file).metadata)
            ate, heading, onset = truth_figures(read_tum(demo / f"{robot}.tum"), read_tum(demo / f"{robot}-truth.tum"))
            diverged = heading > DIVERGED_HEADING
            truth = "diverged" + (f" (> {DIVERGED_HEADING} rad first at {onset:.1f} s)" if onset is not None else "") \
                if diverged else "holds"
            print(f"| {demo.name} | {robot} | {ate:.3f} | {heading:.3f} | {truth} | {verdict_cells(verdict)}")
            if verdict is not None:
                rows.append((diverged, verdict["lost"]))
    print(tally(rows))


def run_replays(demo: Path, cache: Path, seeds: list[int], robot: str) -> None:
    from benchmarks.eval_slam_rendered import ReplayObserver
    from estimation.fastslam import FastSLAM, FastSLAMConfig
    from estimation.observations import OdometryIncrement

    meta = LandmarkMap.load(demo / f"{robot}.npz").metadata
    start, config = np.array(meta["true_start_pose"], float), FastSLAMConfig.from_dict(meta["fastslam"])
    truth, odometry = read_tum(demo / f"{robot}-truth.tum"), read_tum(demo / f"{robot}-odometry.tum")
    print("| demo | filter seed | ATE m | heading error, 2nd half median rad | truth | self-check | first alarm's "
          "figures | alarms | dispersion |")
    print("|---|---|---|---|---|---|---|---|---|")
    rows = []
    for seed in seeds:
        observer = ReplayObserver(cache)
        slam = FastSLAM(config, np.random.default_rng(seed))
        estimate = []
        for i, (t, *pose) in enumerate(truth):
            delta = between(odometry[i - 1, 1:], odometry[i, 1:]) if i else np.zeros(3)
            slam.predict(OdometryIncrement(*map(float, delta), float(truth[i - 1, 0]) if i else float(t), float(t)))
            slam.update(observer.observe(compose(start, np.array(pose)), float(t))[0])
            estimate.append((t, *slam.best_pose()))
        verdict = read_self_check(slam.best_map(robot=robot).metadata)
        ate, heading, onset = truth_figures(np.array(estimate), truth)
        diverged = heading > DIVERGED_HEADING
        truth_text = "diverged" + (f" (> {DIVERGED_HEADING} rad first at {onset:.1f} s)" if onset is not None else "") \
            if diverged else "holds"
        print(f"| {demo.name} {robot} | {seed} | {ate:.3f} | {heading:.3f} | {truth_text} | {verdict_cells(verdict)}",
              flush=True)
        rows.append((diverged, verdict["lost"]))
    print(tally(rows))


def run_mrclam(maps: Path, eval_json: Path | None) -> None:
    figures = {}
    if eval_json is not None:
        figures = json.loads(eval_json.read_text()).get("runs", {})
    print("| mode | robot | ATE m | self-check | first alarm's figures | alarms | dispersion |")
    print("|---|---|---|---|---|---|---|")
    flagged = total = 0
    for mode in ("id", "unknown"):
        for path in sorted((maps / mode).glob("robot*.npz")):
            verdict = read_self_check(LandmarkMap.load(path).metadata)
            ate = figures.get(f"{mode}/{path.stem}", {}).get("ate_m")
            print(f"| {mode} | {path.stem} | {'' if ate is None else f'{ate:.3f}'} | {verdict_cells(verdict)}")
            total += verdict is not None
            flagged += bool(verdict and verdict["lost"])
    print(f"{flagged} of {total} MRCLAM maps flagged")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="what", required=True)
    p = sub.add_parser("maps", help="demo folders' maps against their truth")
    p.add_argument("dirs", nargs="+", type=Path)
    p = sub.add_parser("replay", help="one demo robot replayed from a frame cache, several filter seeds")
    p.add_argument("demo", type=Path)
    p.add_argument("--frames-cache", type=Path, required=True)
    p.add_argument("--filter-seed", type=non_negative_int, action="append", default=[])
    p.add_argument("--robot", default="robot2")
    p = sub.add_parser("mrclam", help="eval_mrclam's maps")
    p.add_argument("maps", type=Path)
    p.add_argument("--eval-json", type=Path, default=None)
    args = parser.parse_args(argv)
    if args.what == "maps":
        run_maps(args.dirs)
    elif args.what == "replay":
        if not args.frames_cache.is_file():
            raise SystemExit(f"{args.frames_cache}: no frame cache (slam_demo_replay --frames-cache writes one)")
        run_replays(args.demo, args.frames_cache, args.filter_seed or [0], args.robot)
    else:
        run_mrclam(args.maps, args.eval_json)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
