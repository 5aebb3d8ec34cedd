"""Replay one robot of a `p3at demo` output folder through FastSLAM offline and print its timeline.

Run from the repository root:

    .venv/bin/python -m benchmarks.slam_demo_replay DEMO_DIR [--robot robot2] [--filter-seed K]
        [--render-seed S] [--frames-cache FILE] [--from T0] [--to T1] [--every N] [--born-before T] [--demo-only]
        [--set KEY=VALUE ...]

The demo folder gives the route actually driven (``<robot>-truth.tum``), the odometry the filter was given
(``<robot>-odometry.tum``, per frame) and the filter's settings and true start pose (``<robot>.npz``'s
metadata). Each frame is rendered again at the true pose (``eval_slam_rendered.RenderedObserver``: the same
renderer, 1 DN noise of its own draw, the real front end), so the replay differs from the demo only in the
image noise and the filter's random draws (``--filter-seed``; the demo's own is ``seed * 1000 + robot index``).
``--frames-cache FILE`` keeps the rendered observations and replays them afterwards (the filter alone: minutes).

Prints, per window of ``--every`` frames: the best particle's position / heading error and the odometry's heading
error against the truth (start frame); the filter's own heading σ — the drift tracker's D_r (the pose's
uncertainty relative to the start), the weighted cloud's, FastSLAM 2.0's proposal; the effective sample size and
the share of frames resampled; observations per frame, matched / new / rejected (means over particles; rejected =
a landmark was a candidate but the gate refused it); the best particle's matches, its new landmarks and how many of
its matches joined two true points > 10 cm apart; the truth's largest turn per frame. Then a summary line.
``--born-before T`` adds a column: the best particle's matches to landmarks made before T s (is the map after T
tied back to the map made before it?), and in the summary their share after T, and the share of the observations
of true points already seen before T that it matched to a landmark made before T (the re-tie rate, with the truth
as the denominator a self-check would take from the filter's own in-view prediction).
``--set KEY=VALUE`` replays with a FastSLAM setting other than the demo's (``benchmarks/config_overrides.py``).
``--demo-only`` prints the demo's own estimate against its truth instead (no replay): the position / heading
error of the trajectory the demo wrote, the odometry's heading error, the truth's turn per frame.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

from benchmarks.config_overrides import config_overrides
from benchmarks.eval_slam_rendered import RecordingRenderedObserver, RenderedObserver, ReplayObserver
from estimation.fastslam import FastSLAM, FastSLAMConfig
from estimation.geometry import between, compose, wrap_angle
from estimation.observations import OdometryIncrement
from runtime import trajectories
from runtime.commands.options import non_negative_float, non_negative_int, positive_int

WRONG_MATCH = 0.10  # m: a match whose true point is this far from its landmark's first sighting joins two points


def read_tum(path: Path) -> np.ndarray:
    """(T, 4) rows (t, x, y, θ) of a planar TUM file (runtime.trajectories' reader: validated)."""
    return trajectories.planar(trajectories.read_tum(path))


def open_replay(demo: Path, robot: str, filter_seed: int, render_seed: int, cache: Path | None,
                overrides: dict | None = None) -> tuple[np.ndarray, FastSLAMConfig, np.ndarray, np.ndarray, object,
                                                        FastSLAM]:
    """One robot of a `p3at demo --out` folder set up for replay: its true start pose, the demo's FastSLAM settings
    (with ``overrides``), its truth and odometry (T, 4) on the same frames, the observer (the frames cache when it
    exists, else the rendered camera, recording) and a fresh filter."""
    from mocks.world import World

    with np.load(demo / f"{robot}.npz", allow_pickle=False) as data:
        meta = json.loads(bytes(data["meta"]).decode())["metadata"]
    start = np.array(meta["true_start_pose"], float)
    config = FastSLAMConfig.from_dict({**meta["fastslam"], **(overrides or {})})
    truth, odometry = read_tum(demo / f"{robot}-truth.tum"), read_tum(demo / f"{robot}-odometry.tum")
    if len(truth) != len(odometry) or not np.allclose(truth[:, 0], odometry[:, 0]):
        raise SystemExit(f"{demo}: {robot}'s truth and odometry files do not have the same frames")
    if cache is not None and cache.exists():
        observer = ReplayObserver(cache)
    else:
        observer = RecordingRenderedObserver(RenderedObserver(World.load(), np.random.default_rng([render_seed, 1])))
    return start, config, truth, odometry, observer, FastSLAM(config, np.random.default_rng(filter_seed))


def save_frames(observer, cache: Path | None) -> None:
    """Keep a rendered replay's frames in ``cache`` for later runs (nothing when they came from it, or no cache)."""
    if isinstance(observer, RecordingRenderedObserver) and cache is not None:
        cache.parent.mkdir(parents=True, exist_ok=True)
        observer.save(cache)


def add_replay_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of a replay of one demo robot, shared by the replay scripts."""
    parser.add_argument("demo", type=Path, help="a `p3at demo --out` folder")
    parser.add_argument("--robot", default="robot2")
    parser.add_argument("--filter-seed", type=non_negative_int, default=0)
    parser.add_argument("--render-seed", type=non_negative_int, default=0, help="the image noise's draw")
    parser.add_argument("--frames-cache", type=Path, default=None, metavar="FILE",
                        help="keep the rendered observations in FILE and replay them on later runs")


def predicted_frames(start: np.ndarray, truth: np.ndarray, odometry: np.ndarray, observer, slam: FastSLAM):
    """Each frame of a replay after the filter's prediction from the demo's odometry: (frame, t, the true pose in the
    start frame, the true pose in the world, the observations, each observation's true point or -1)."""
    for i, (t, *pose) in enumerate(truth):
        delta = between(odometry[i - 1, 1:], odometry[i, 1:]) if i else np.zeros(3)
        slam.predict(OdometryIncrement(*map(float, delta), float(truth[i - 1, 0]) if i else float(t), float(t)))
        world_pose = compose(start, np.array(pose))
        observations, index = observer.observe(world_pose, float(t))
        yield i, t, pose, world_pose, observations, index


def replay(demo: Path, robot: str, filter_seed: int, render_seed: int, cache: Path | None,
           born_before: float = 0.0, overrides: dict | None = None) -> dict[str, np.ndarray]:
    """Per-frame arrays of the replay (see the module docstring)."""
    start, config, truth, odometry, observer, slam = open_replay(demo, robot, filter_seed, render_seed, cache,
                                                                 overrides)
    rows: dict[str, list] = {k: [] for k in ("t", "truth", "odometry", "best", "drift", "cloud", "proposal", "ess",
                                             "resampled", "n_obs", "matched", "new", "best_matched", "best_new",
                                             "best_wrong", "best_old", "old_seen", "old_seen_retied")}
    origin: dict[int, int] = {}   # landmark id -> the true point of its first sighting
    born: dict[int, float] = {}   # landmark id -> the time it was made
    first_seen: dict[int, float] = {}   # true point -> the time it was first observed
    for i, t, pose, _, observations, index in predicted_frames(start, truth, odometry, observer, slam):
        report = slam.update(observations)
        points = observer.points
        for j in np.flatnonzero(report.new_landmark_ids >= 0):
            origin[int(report.new_landmark_ids[j])] = int(index[j])
            born.setdefault(int(report.new_landmark_ids[j]), float(t))
        old = sum(born.get(int(k), np.inf) < born_before for k in report.best_matches[report.best_matches >= 0])
        for point in index[index >= 0]:
            first_seen.setdefault(int(point), float(t))
        seen_before = [j for j in np.flatnonzero(index >= 0) if first_seen[int(index[j])] < born_before]
        retied = sum(born.get(int(report.best_matches[j]), np.inf) < born_before for j in seen_before)
        wrong = 0
        for j in np.flatnonzero(report.best_matches >= 0):
            first = origin.get(int(report.best_matches[j]), -1)
            if first >= 0 and index[j] >= 0:
                wrong += int(np.linalg.norm(points[first] - points[index[j]]) > WRONG_MATCH)
        proposal = slam._proposal_cov if slam._proposal_cov is not None else np.full((3, 3), np.nan)
        for key, value in (("t", t), ("truth", pose), ("odometry", odometry[i, 1:]), ("best", slam.best_pose()),
                           ("drift", slam.drift.robot[2, 2]), ("cloud", report.pose_covariance[2, 2]),
                           ("proposal", proposal[2, 2]), ("ess", report.ess), ("resampled", report.resampled),
                           ("n_obs", report.n_observations), ("matched", report.matched),
                           ("new", report.new_landmarks), ("best_matched", int(np.sum(report.best_matches >= 0))),
                           ("best_new", int(np.sum(report.new_landmark_ids >= 0))), ("best_wrong", wrong),
                           ("best_old", old), ("old_seen", len(seen_before)), ("old_seen_retied", retied)):
            rows[key].append(value)
    save_frames(observer, cache)
    out = {k: np.array(v, float) for k, v in rows.items()}
    out["landmarks"] = np.array(len(slam.best_map(robot=robot)))
    return out


def print_timeline(d: dict[str, np.ndarray], t0: float, t1: float, every: int, born_before: float = 0.0) -> None:
    error_xy = np.hypot(*(d["best"][:, :2] - d["truth"][:, :2]).T)
    error_theta = wrap_angle(d["best"][:, 2] - d["truth"][:, 2])
    odometry_theta = wrap_angle(d["odometry"][:, 2] - d["truth"][:, 2])
    rejected = d["n_obs"] - d["matched"] - d["new"]
    turn = np.abs(wrap_angle(np.diff(d["truth"][:, 2], prepend=d["truth"][0, 2])))
    sd = {k: np.sqrt(np.maximum(d[k], 0.0)) for k in ("drift", "cloud", "proposal")}
    extra = " best: matched, made before T |" if born_before else ""
    print("| t (s) | error m / rad | odometry rad | σθ drift / cloud / proposal | ESS / resampled | obs / matched / "
          "new / rejected | best: matched / new / wrong | turn per frame |" + extra)
    print("|---|---|---|---|---|---|---|---|" + ("---|" if born_before else ""))
    for k in range(0, len(d["t"]), every):
        if not t0 <= d["t"][k] <= t1:
            continue
        s = slice(k, k + every)
        print(f"| {d['t'][k]:.1f} | {error_xy[k]:.2f} / {error_theta[k]:+.3f} | {odometry_theta[k]:+.3f} | "
              f"{sd['drift'][k]:.3f} / {np.mean(sd['cloud'][s]):.3f} / {np.nanmean(sd['proposal'][s]):.3f} | "
              f"{np.mean(d['ess'][s]):.0f} / {np.mean(d['resampled'][s]):.1f} | {np.mean(d['n_obs'][s]):.1f} / "
              f"{np.mean(d['matched'][s]):.1f} / {np.mean(d['new'][s]):.1f} / {np.mean(rejected[s]):.1f} | "
              f"{np.mean(d['best_matched'][s]):.1f} / {np.mean(d['best_new'][s]):.1f} / "
              f"{np.sum(d['best_wrong'][s]):.0f} | {np.max(turn[s]):.3f} |"
              + (f" {np.mean(d['best_old'][s]):.1f} |" if born_before else ""))
    late = d["t"] > d["t"][0] + 50.0
    print(f"ATE {np.sqrt(np.mean(error_xy ** 2)):.3f} m, largest position error {error_xy.max():.2f} m, final "
          f"{error_xy[-1]:.2f} m / {error_theta[-1]:+.3f} rad, largest |heading error| after the first 50 s "
          f"{np.max(np.abs(error_theta[late]), initial=0.0):.3f} rad, largest σθ drift {sd['drift'].max():.3f} rad, "
          f"landmarks {int(d['landmarks'])}")
    if born_before:
        after = d["t"] > born_before
        old, matched = np.sum(d["best_old"][after]), np.sum(d["best_matched"][after])
        print(f"after {born_before:g} s: {old:.0f} of the best particle's {matched:.0f} matches "
              f"({100 * old / max(1.0, matched):.1f} %) are of landmarks made before it; of its "
              f"{np.sum(d['old_seen'][after]):.0f} observations of true points seen before it, "
              f"{np.sum(d['old_seen_retied'][after]):.0f} matched a landmark made before it "
              f"({100 * np.sum(d['old_seen_retied'][after]) / max(1.0, np.sum(d['old_seen'][after])):.1f} %)")


def print_demo(demo: Path, robot: str, t0: float, t1: float, every: int) -> None:
    """The demo's own estimate (``<robot>.tum``) and odometry against its truth, per window of frames."""
    estimate, truth = read_tum(demo / f"{robot}.tum"), read_tum(demo / f"{robot}-truth.tum")
    odometry = read_tum(demo / f"{robot}-odometry.tum")
    n = min(len(estimate), len(truth), len(odometry))
    error_xy = np.hypot(*(estimate[:n, 1:3] - truth[:n, 1:3]).T)
    error_theta = wrap_angle(estimate[:n, 3] - truth[:n, 3])
    odometry_theta = wrap_angle(odometry[:n, 3] - truth[:n, 3])
    turn = np.abs(wrap_angle(np.diff(truth[:n, 3], prepend=truth[0, 3])))
    print("| t (s) | error m / rad | odometry rad | true heading | turn per frame |")
    print("|---|---|---|---|---|")
    for k in range(0, n, every):
        if t0 <= truth[k, 0] <= t1:
            print(f"| {truth[k, 0]:.1f} | {error_xy[k]:.2f} / {error_theta[k]:+.3f} | {odometry_theta[k]:+.3f} | "
                  f"{truth[k, 3]:+.2f} | {np.max(turn[k:k + every]):.3f} |")
    print(f"{n} frames over {truth[n - 1, 0] - truth[0, 0]:.0f} s; final error {error_xy[-1]:.2f} m / "
          f"{error_theta[-1]:+.3f} rad; odometry {odometry_theta[-1]:+.3f} rad")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_replay_arguments(parser)
    parser.add_argument("--from", dest="t0", type=non_negative_float, default=0.0, help="first time printed (s)")
    parser.add_argument("--to", dest="t1", type=non_negative_float, default=1e9, help="last time printed (s)")
    parser.add_argument("--every", type=positive_int, default=10, help="frames per printed window")
    parser.add_argument("--born-before", type=non_negative_float, default=0.0, metavar="T",
                        help="count the best particle's matches to landmarks made before T s (0: off)")
    parser.add_argument("--demo-only", action="store_true", help="the demo's own estimate against its truth")
    parser.add_argument("--set", dest="settings", action="append", default=[], metavar="KEY=VALUE",
                        help="a FastSLAM setting over the demo's, e.g. existence_miss=0 (benchmarks/config_overrides)")
    args = parser.parse_args(argv)
    for name in (f"{args.robot}.npz", f"{args.robot}-truth.tum", f"{args.robot}-odometry.tum"):
        if not (args.demo / name).is_file():
            raise SystemExit(f"{args.demo}: no {name} (a `p3at demo --out` folder of a mock run is needed)")
    if args.demo_only:
        print_demo(args.demo, args.robot, args.t0, args.t1, args.every)
        return 0
    cv2.setNumThreads(1)
    print_timeline(replay(args.demo, args.robot, args.filter_seed, args.render_seed, args.frames_cache,
                          args.born_before, config_overrides(args.settings)), args.t0, args.t1, args.every,
                   args.born_before)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
