"""When did a demo robot lose its frame, and when could its self-check have said so? (session 11, S)

Run from the repository root:

    .venv/bin/python -m benchmarks.self_check_timeline DEMO_DIR --frames-cache FILE [--robot robot2]
        [--filter-seed K ...] [--kick T,RAD] [--set KEY=JSON ...] [--every N] [--from T0] [--to T1] [--out FILE.npz]
    .venv/bin/python -m benchmarks.self_check_timeline --summary FILE.npz [FILE.npz ...]

Replays one robot of a `p3at demo --out` folder from a frame cache (``slam_demo_replay``'s inputs: the true route,
the odometry, the demo's filter settings; the cache as ``slam_demo_replay --frames-cache`` writes it) with each
``--filter-seed`` (the demo's own is seed * 1000 + 1 for robot 2) and prints per window of ``--every`` frames:
the best particle's position / heading error against the truth, the drift tracker's heading σ, the particle cloud's
heading σ, the best particle's matches, and the self-check's figures (old landmarks predicted in view, re-detected,
expected; its CUSUM statistic). Beside the filter's own self-check (read only) it runs, on the same frames, a second
one that counts *every* old landmark in view, whatever the direction it is seen from (``view="any"``): how much
evidence the descriptor's view rule withholds; and two rules tried in session 11 and not kept (``FirstLooks``:
an old landmark counts once per reference; ``UnansweredGap``: old = made before the earliest gap whose question is
still open, "S_first" in the arrays).

``--kick T,RAD`` turns the odometry the filter is given by RAD from time T on (one increment off, the rest as
driven): the heading error a blind turn on the spot leaves at the re-entry (demo seeds 2 and 4: -0.13 and +0.25 rad
at 45 s), made on purpose, so that a replay whose own draws recover can be put where the demo was.

The truth: *lost* from the first frame after which the position error stays above ``LOST_M`` = 0.3 m for
``HELD_FRAMES`` frames (session 10's reading of seeds 2 and 4); the run is *healthy* if that never happens.
``--out`` keeps each run's per-frame arrays; ``--summary`` reads such files and prints, per self-check, the largest
statistic any healthy run reached (before any alarm resets it) and, for each lost run, the first time its statistic
passed that level and the default threshold: how early the check could have said so without a false flag on these
healthy runs (an empirical floor from these runs, not a threshold to adopt).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

from benchmarks.config_overrides import config_overrides
from benchmarks.slam_demo_replay import read_tum
from estimation.fastslam.self_check import SelfCheck
from estimation.geometry import between, compose, wrap_angle
from estimation.landmark_map import LandmarkMap
from estimation.observations import OdometryIncrement
from runtime.commands.options import non_negative_float, non_negative_int, positive_int

LOST_M = 0.3        # m: session 10's "lost its frame" (seeds 2 and 4: > 0.3 m from 52 s and 55 s)
HELD_FRAMES = 30    # ~8 s at 3.75 Hz: held, not a turn's passing excursion


class _Tee:
    """The filter's self-check, plus shadow checks fed the same calls (read only: the filter uses the first)."""

    def __init__(self, primary: SelfCheck, shadows: list[SelfCheck]) -> None:
        self._checks = [primary, *shadows]

    def made(self, *args) -> None:
        for c in self._checks:
            c.made(*args)

    def observe(self, *args):
        out = [c.observe(*args) for c in self._checks]
        return out[0]

    def __getattr__(self, name):
        return getattr(self._checks[0], name)


class FirstLooks(SelfCheck):
    """Tried in session 11, not kept: an old landmark counts once per reference (its first look after the latest gap),
    not in every frame it stays in view and is missed (a landmark hidden for a reason of its own, missed again and
    again, as one piece of evidence)."""

    def __init__(self, config, keep_history: bool = False) -> None:
        super().__init__(config, keep_history)
        self._looked: dict[int, int] = {}   # landmark id -> the reference it was counted under

    def observe(self, t, detected, missed, n_matched, n_ids, miss_weight=1.0):
        def first(view):
            ids, counts, ranges, bearings = view
            old = self._old(ids, counts) & self._redetectable(ids, ranges, bearings)
            keep = np.array([not o or self._looked.get(int(i)) != self.reference_ids
                             for i, o in zip(ids, old, strict=True)], bool)
            for i in np.asarray(ids)[old & keep]:
                self._looked[int(i)] = self.reference_ids
            return tuple(np.asarray(a)[keep] for a in view)
        return super().observe(t, first(detected), first(missed), n_matched, n_ids, miss_weight)


class UnansweredGap(SelfCheck):
    """Tried in session 11, not kept: the reference (old = made before it) moves at a gap only once the previous
    gap's question was answered (a frame tested old landmarks and left the statistic at 0, or an alarm), so a loss
    followed by more gaps is tested against the map made before the loss, not a mix with the lost frame's part."""

    def __init__(self, config, keep_history: bool = False) -> None:
        super().__init__(config, keep_history)
        self._answered = True

    def observe(self, t, detected, missed, n_matched, n_ids, miss_weight=1.0):
        before, alarms = self.reference_ids, self.n_alarms
        e = super().observe(t, detected, missed, n_matched, n_ids, miss_weight)
        if (e.predicted and self.statistic == 0.0) or self.n_alarms > alarms:
            self._answered = True
        if self.reference_ids != before:   # a gap moved it
            if self._answered:
                self._answered = False
            else:
                self.reference_ids = before
        return e


def lost_onset(t: np.ndarray, error_xy: np.ndarray) -> float | None:
    """The first time after which the position error stays above LOST_M for HELD_FRAMES frames, or None."""
    above = error_xy > LOST_M
    run = 0
    for i, a in enumerate(above):
        run = run + 1 if a else 0
        if run >= HELD_FRAMES:
            return float(t[i - HELD_FRAMES + 1])
    return None


def replay(demo: Path, robot: str, cache: Path, filter_seed: int,
           kick: tuple[float, float] = (np.inf, 0.0), overrides: dict | None = None) -> dict[str, np.ndarray]:
    from benchmarks.eval_slam_rendered import ReplayObserver
    from estimation.fastslam import FastSLAM, FastSLAMConfig

    meta = LandmarkMap.load(demo / f"{robot}.npz").metadata
    start, config = np.array(meta["true_start_pose"], float), FastSLAMConfig.from_dict(meta["fastslam"])
    if overrides:
        config = FastSLAMConfig.from_dict({**config.to_dict(), **overrides})
    truth, odometry = read_tum(demo / f"{robot}-truth.tum"), read_tum(demo / f"{robot}-odometry.tum")
    observer = ReplayObserver(cache)
    slam = FastSLAM(config, np.random.default_rng(filter_seed))
    primary, any_view = SelfCheck(config, keep_history=True), SelfCheck(config, keep_history=True)
    any_view._by_view = False   # every old landmark in view counts, from any direction
    looks, first = FirstLooks(config, keep_history=True), UnansweredGap(config, keep_history=True)
    slam.self_check = _Tee(primary, [any_view, looks, first])
    rows: dict[str, list] = {k: [] for k in ("t", "error_xy", "error_theta", "drift", "cloud", "best_matched",
                                             "S", "S_any", "S_looks", "S_first", "predicted", "redetected", "expected",
                                             "predicted_any", "redetected_any", "reference_ids")}
    for i, (t, *pose) in enumerate(truth):
        delta = between(odometry[i - 1, 1:], odometry[i, 1:]) if i else np.zeros(3)
        if i and truth[i - 1, 0] < kick[0] <= t:
            delta[2] += kick[1]
        slam.predict(OdometryIncrement(*map(float, delta), float(truth[i - 1, 0]) if i else float(t), float(t)))
        report = slam.update(observer.observe(compose(start, np.array(pose)), float(t))[0])
        best = slam.best_pose()
        e, ea = primary.history[-1], any_view.history[-1]
        for key, value in (("t", t), ("error_xy", np.hypot(*(best[:2] - np.array(pose[:2])))),
                           ("error_theta", wrap_angle(best[2] - pose[2])), ("drift", slam.drift.robot[2, 2]),
                           ("cloud", report.pose_covariance[2, 2]),
                           ("best_matched", int(np.sum(report.best_matches >= 0))),
                           ("S", primary.statistic if primary.n_alarms == 0 else np.nan),
                           ("S_any", any_view.statistic if any_view.n_alarms == 0 else np.nan),
                           ("S_looks", looks.statistic if looks.n_alarms == 0 else np.nan),
                           ("S_first", first.statistic if first.n_alarms == 0 else np.nan),
                           ("predicted", e.predicted), ("redetected", e.redetected), ("expected", e.expected),
                           ("predicted_any", ea.predicted), ("redetected_any", ea.redetected),
                           ("reference_ids", primary.reference_ids)):
            rows[key].append(value)
    out = {k: np.array(v, float) for k, v in rows.items()}
    out["threshold"] = np.array(primary.threshold)
    out["alarm_t"] = np.array(primary.alarms[0]["t"] if primary.alarms else np.nan)
    out["alarm_any_t"] = np.array(any_view.alarms[0]["t"] if any_view.alarms else np.nan)
    out["alarm_first_t"] = np.array(first.alarms[0]["t"] if first.alarms else np.nan)
    out["alarm_looks_t"] = np.array(looks.alarms[0]["t"] if looks.alarms else np.nan)
    return out


def first_at_or_above(t: np.ndarray, s: np.ndarray, level: float) -> float | None:
    """The first time the statistic (nan after the first alarm: it then restarts) reaches level."""
    i = np.flatnonzero(np.nan_to_num(s, nan=np.inf) >= level)
    return float(t[i[0]]) if len(i) else None


def print_timeline(d: dict[str, np.ndarray], t0: float, t1: float, every: int) -> None:
    print("| t (s) | error m / rad | σθ drift / cloud | best matched | old in view: predicted / re-detected / "
          "expected | CUSUM | any view: predicted / re-detected | CUSUM any view |")
    print("|---|---|---|---|---|---|---|---|")
    for k in range(0, len(d["t"]), every):
        if not t0 <= d["t"][k] <= t1:
            continue
        s = slice(k, k + every)
        print(f"| {d['t'][k]:.1f} | {d['error_xy'][k]:.2f} / {d['error_theta'][k]:+.3f} | "
              f"{np.sqrt(d['drift'][k]):.3f} / {np.sqrt(np.mean(d['cloud'][s])):.3f} | "
              f"{np.mean(d['best_matched'][s]):.1f} | {np.sum(d['predicted'][s]):.0f} / "
              f"{np.sum(d['redetected'][s]):.0f} / {np.sum(d['expected'][s]):.1f} | "
              f"{np.nanmax(d['S'][s], initial=-1):.1f} | "
              f"{np.sum(d['predicted_any'][s]):.0f} / {np.sum(d['redetected_any'][s]):.0f} | "
              f"{np.nanmax(d['S_any'][s], initial=-1):.1f} |")


def run_line(name: str, d: dict[str, np.ndarray]) -> str:
    onset = lost_onset(d["t"], d["error_xy"])
    ate = float(np.sqrt(np.mean(d["error_xy"] ** 2)))
    def when(key: str) -> str:
        return "none" if key not in d or np.isnan(float(d[key])) else f"{float(d[key]):.1f} s"

    def peak(key: str) -> str:
        return f"{np.nanmax(d[key], initial=0.0):.1f}" if key in d else "-"

    return (f"{name}: ATE {ate:.3f} m, " + (f"lost from {onset:.1f} s" if onset is not None else "healthy")
            + f"; first alarm {when('alarm_t')} (any view: {when('alarm_any_t')}; first looks: "
            f"{when('alarm_looks_t')}; unanswered gap: {when('alarm_first_t')}); max CUSUM {peak('S')} / any view "
            f"{peak('S_any')} / first looks {peak('S_looks')} / unanswered gap "
            f"{peak('S_first')} of {float(d['threshold']):.1f}")


def summary(files: list[Path]) -> None:
    runs = {}
    for f in files:
        with np.load(f, allow_pickle=False) as data:
            for key in {k.split("/")[0] for k in data.files}:
                runs[f"{f.stem}/{key}"] = {k.split("/", 1)[1]: data[k] for k in data.files if k.startswith(key + "/")}
    for name, d in sorted(runs.items()):
        print(run_line(name, d))
    for stat, label in (("S", "the filter's self-check"), ("S_any", "old landmarks from any direction"),
                        ("S_looks", "first looks (FirstLooks)"),
                        ("S_first", "the earliest unanswered gap (UnansweredGap)")):
        if not all(stat in d for d in runs.values()):
            continue
        alarm_key = {"S": "alarm_t", "S_any": "alarm_any_t", "S_looks": "alarm_looks_t",
                     "S_first": "alarm_first_t"}[stat]
        healthy = [float(d["threshold"]) if not np.isnan(float(d[alarm_key])) else np.nanmax(d[stat], initial=0.0)
                   for d in runs.values() if lost_onset(d["t"], d["error_xy"]) is None]   # a false flag: >= h
        lost = {n: d for n, d in runs.items() if lost_onset(d["t"], d["error_xy"]) is not None}
        level = max(healthy, default=0.0)
        print(f"{label}: healthy runs {len(healthy)}, their largest statistic {level:.1f} (false flags "
              f"{sum(h >= float(next(iter(runs.values()))['threshold']) for h in healthy)}) "
              f"(threshold {float(next(iter(runs.values()))['threshold']):.1f})")
        for n, d in sorted(lost.items()):
            onset = lost_onset(d["t"], d["error_xy"])
            above = first_at_or_above(d["t"], d[stat], level + 1e-9)
            at_h = first_at_or_above(d["t"], d[stat], float(d["threshold"]))
            print(f"  {n}: lost from {onset:.1f} s; above the healthy runs' largest at "
                  f"{'never' if above is None else f'{above:.1f} s ({above - onset:+.1f} s)'}; at the threshold "
                  f"{'never' if at_h is None else f'{at_h:.1f} s ({at_h - onset:+.1f} s)'}")


def _kick(text: str) -> tuple[float, float]:
    try:
        t, rad = (float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--kick takes T,RAD (seconds, radians), not {text!r}") from None
    if not (np.isfinite(t) and np.isfinite(rad) and t >= 0.0):
        raise argparse.ArgumentTypeError(f"--kick takes a time >= 0 and a finite angle, not {text!r}")
    return t, rad


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("demo", type=Path, nargs="?", help="a `p3at demo --out` folder")
    parser.add_argument("--frames-cache", type=Path, default=None)
    parser.add_argument("--robot", default="robot2")
    parser.add_argument("--filter-seed", type=non_negative_int, action="append", default=[])
    parser.add_argument("--kick", type=_kick, default=(np.inf, 0.0), metavar="T,RAD",
                        help="turn the odometry by RAD from time T on")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a FastSLAMConfig field of the demo's settings (VALUE as JSON)")
    parser.add_argument("--every", type=positive_int, default=15)
    parser.add_argument("--from", dest="t0", type=non_negative_float, default=0.0)
    parser.add_argument("--to", dest="t1", type=non_negative_float, default=1e9)
    parser.add_argument("--out", type=Path, default=None, help="keep each run's per-frame arrays (.npz)")
    parser.add_argument("--summary", type=Path, nargs="+", default=None, help="read --out files, print the floor")
    args = parser.parse_args(argv)
    if args.summary:
        summary(args.summary)
        return 0
    if args.demo is None or args.frames_cache is None or not args.frames_cache.is_file():
        raise SystemExit("a demo folder and an existing --frames-cache FILE are needed (slam_demo_replay writes one)")
    arrays = {}
    for seed in args.filter_seed or [0]:
        d = replay(args.demo, args.robot, args.frames_cache, seed, args.kick, config_overrides(args.set))
        print(f"## {args.demo.name} {args.robot}, filter seed {seed}"
              + (f", odometry kicked {args.kick[1]:+g} rad at {args.kick[0]:g} s" if args.kick[1] else ""))
        print_timeline(d, args.t0, args.t1, args.every)
        print(run_line(f"{args.demo.name} {args.robot} seed {seed}", d), flush=True)
        arrays.update({f"{args.robot}-{seed}" + (f"-kick{args.kick[1]:+g}" if args.kick[1] else "") + f"/{k}": v
                       for k, v in d.items()})
    if args.out is not None:
        np.savez_compressed(args.out, **arrays)
        print(json.dumps({"saved": str(args.out)}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
