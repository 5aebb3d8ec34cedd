"""The smoothing after the mission with keyframes against every frame, on the rendered demo's logs (session 51).

Run from the repository root, on ``p3at demo --seed S --out DIR --log-sensors`` folders (as
``benchmarks.demo_smoothing``, whose replay, scores and fusion it reuses):

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.demo_keyframes DIR [DIR ...] [--out ROOT]
        [--distance M] [--angle RAD] [--overlap SHARE] [--json]

Per robot: the replay's frames (cached in ROOT/<folder>/robotN-replay.npz as ``demo_smoothing`` does) are given one by
one to an ``estimation.stereo_readings.ReadingsRecorder``, once as the mission keeps them (every frame; checked equal,
array by array, to the replay's records) and once with a ``KeyframeRule`` (the odometry between keyframes composed by
the recorder), and each is smoothed by ``stereo_readings.smoothed_map`` from the same filter trajectory and map.
Printed per map, every frame vs keyframes: frames and readings kept, associate and smoothing seconds, landmark NEES
(share within χ²₃ 95 %; median error) against the landmark's true point (``demo_smoothing.landmark_truth`` from the
every-frame association's inlier readings, the same rows for both: the landmarks are the filter's), the trajectory's
ATE and heading rms at every frame (the keyframe smoothing's trajectory fills the frames between keyframes with the
filter's poses moved by the interpolated correction), the smoothed map's self-check (lost or not); per seed the final
fusion as the demo decides it (``runtime.fusion_report.fuse_maps`` with the generator that reproduces the demo's own
final alignment), against the truth.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import demo_smoothing as ds  # noqa: E402

from runtime.commands.options import non_negative_float, positive_float  # noqa: E402

KINDS = ("every", "keyframes")


class _Frame(SimpleNamespace):
    def __len__(self) -> int:
        return len(self.points)


def recorded(rec: dict, rule) -> tuple:
    """(StereoReadings, seconds) the replay's frames given one by one to a ReadingsRecorder (``rule``: a KeyframeRule,
    None: every frame)."""
    from estimation.fastslam import FastSLAMConfig
    from estimation.stereo_readings import ReadingsRecorder

    config = FastSLAMConfig.from_dict(rec["meta"]["fastslam"])
    recorder = ReadingsRecorder(config.descriptor_size, keyframes=rule, config=config if rule else None)
    offsets = np.r_[0, np.cumsum(rec["counts"])]
    start = time.perf_counter()
    for k, t in enumerate(rec["times"]):
        a, b = offsets[k], offsets[k + 1]
        recorder.add(t, rec["odometry"][k], _Frame(points=rec["points"][a:b], covariances=rec["covariances"][a:b],
                                                   descriptors=rec["descriptors"][a:b], pixels=rec["pixels"][a:b]))
    return recorder.readings_kept(), time.perf_counter() - start


def run(folders: list[Path], root: Path, rule, as_json: bool) -> list[dict]:
    from fusion_sim import load_world

    from estimation.fastslam import FastSLAMConfig
    from estimation.landmark_map import LandmarkMap
    from estimation.stereo_readings import smoothed_map
    from mocks.stereo_head import default_calibration
    from mocks.stereo_head.renderer import StereoRenderer

    world = load_world()
    renderer = StereoRenderer(world, default_calibration())
    results = []
    for folder in folders:
        out = root / folder.name
        out.mkdir(parents=True, exist_ok=True)
        maps = {kind: {} for kind in KINDS}
        row: dict = {"folder": str(folder), "robots": {}}
        for name in ds.ROBOTS:
            rec = ds.replayed(folder, out, name)
            config = FastSLAMConfig.from_dict(rec["meta"]["fastslam"])
            every = ds.readings_of(rec)
            figures, truth = {}, None
            for kind in KINDS:
                readings, record_s = recorded(rec, rule if kind == "keyframes" else None)
                if kind == "every":
                    figures["every_equals_replay"] = all(
                        np.array_equal(getattr(readings, a), getattr(every, a))
                        for a in ("times", "odometry", "counts", "points", "covariances", "descriptors", "pixels"))
                s = smoothed_map(readings, rec["trajectory"], rec["exported"], rec["particle_positions"],
                                 rec["particle_covariances"], config)
                inl = s.inliers
                if truth is None:
                    truth = ds.landmark_truth(folder, rec, s.frames[inl], s.readings[inl], s.rows[inl], renderer)
                m = s.landmark_map
                maps[kind][name] = m
                verdict = m.metadata.get("self_check") or {}
                figures[kind] = s.figures | {"record_s": record_s, "nees": ds.landmark_nees(m, truth),
                                             "traj": ds.trajectory_errors(folder, m),
                                             "lost": bool(verdict.get("lost")), "seen": int(rec["counts"].size),
                                             "readings_seen": int(rec["counts"].sum())}
                m.save(out / f"{name}-{kind}.npz")
            row["robots"][name] = figures
        filt = {name: LandmarkMap.load(folder / f"{name}.npz") for name in ds.ROBOTS}
        seed = ds.demo_rng_seed(folder, filt["robot1"], filt["robot2"])
        row["rng_seed"] = seed
        for kind in KINDS:
            row[kind] = ds.fusion_row(folder, maps[kind]["robot1"], maps[kind]["robot2"], seed, world.features)
        results.append(row)
        print(f"{folder.name}: done", file=sys.stderr)
    return results


def print_table(results: list[dict], rule) -> None:
    print(f"\n### Smoothing every frame vs keyframes ({rule}) (benchmarks.demo_keyframes)\n")
    print("| run | robot | kind | frames kept of | readings kept of | associate s | smooth s | inliers | χ²/dof | "
          "landmark NEES within χ²₃ 95 % (scored; median error m) | ATE m / heading rms mrad | self-check |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for row in results:
        for name, figs in row["robots"].items():
            for kind in KINDS:
                f = figs[kind]
                n = f["nees"]
                print(f"| {Path(row['folder']).name} | {name} | {kind} | {f['frames']} of {f['seen']} | "
                      f"{f['readings']} of {f['readings_seen']} | {f['associate_s']:.1f} | {f['smooth_s']:.1f} | "
                      f"{f['inliers']} | {f['chi2_per_dof']:.2f} | {100 * n[0]:.0f} % ({n[1]}; {n[2]:.3f}) | "
                      f"{f['traj'][0]:.3f} / {1000 * f['traj'][1]:.1f} | {'lost' if f['lost'] else 'ok'} |")
    print("\n| run | every frame: final fusion vs truth xy / θ (own; supports) | keyframes |")
    print("|---|---|---|")
    for row in results:
        print(f"| {Path(row['folder']).name} | {ds._cell(row['every'])} | {ds._cell(row['keyframes'])} |")
    print()
    for kind in KINDS:
        rows = [row[kind] for row in results]
        found = [r for r in rows if r["found"]]
        wrong = sum(1 for r in found if r["error"][0] > 0.3 or r["error"][1] > 0.1)
        goal = sum(1 for r in found if r["error"][0] <= ds.GOAL_M and r["error"][1] <= ds.GOAL_RAD)
        figs = [row["robots"][n][kind] for row in results for n in row["robots"]]
        honest = sum(1 for f in figs if f["nees"][0] >= 0.9)
        print(f"- {kind}: found {len(found)} of {len(rows)}, wrong {wrong}, within the goal {goal}; maps with landmark "
              f"NEES ≥ 90 % within: {honest} of {len(figs)}; frames kept {sum(f['frames'] for f in figs)} of "
              f"{sum(f['seen'] for f in figs)}, readings {sum(f['readings'] for f in figs)} of "
              f"{sum(f['readings_seen'] for f in figs)}; smoothing s median "
              f"{np.median([f['smooth_s'] for f in figs]):.1f} "
              f"(total {sum(f['smooth_s'] for f in figs):.0f}); ATE median "
              f"{np.median([f['traj'][0] for f in figs]):.3f} m; self-check lost {sum(f['lost'] for f in figs)}")


def main(argv: list[str] | None = None) -> int:
    from estimation.stereo_readings import KeyframeRule

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folders", nargs="+", type=Path, help="p3at demo --log-sensors output folders")
    parser.add_argument("--out", type=Path, default=Path("/tmp/demo-keyframes"),
                        help="where the smoothed maps and the replay caches go (default /tmp/demo-keyframes)")
    parser.add_argument("--distance", type=positive_float, default=KeyframeRule.distance, metavar="M",
                        help=f"a keyframe after this many metres (default {KeyframeRule.distance})")
    parser.add_argument("--angle", type=positive_float, default=KeyframeRule.angle, metavar="RAD",
                        help=f"... or this turn (default {KeyframeRule.angle})")
    parser.add_argument("--overlap", type=non_negative_float, default=KeyframeRule.overlap, metavar="SHARE",
                        help=f"... or when fewer than this share of the frame's readings match the last keyframe's "
                             f"(default {KeyframeRule.overlap}; 0: never)")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = parser.parse_args(argv)
    ds.refuse_non_demo_folders(parser, args.folders)
    try:
        rule = KeyframeRule(args.distance, args.angle, args.overlap)
    except ValueError as exc:
        parser.error(str(exc))
    results = run(args.folders, args.out, rule, args.json)
    if args.json:
        print(json.dumps({"rule": vars(rule), "results": results}, indent=1, default=float))
    else:
        print_table(results, rule)
    return 0


if __name__ == "__main__":
    sys.exit(main())
