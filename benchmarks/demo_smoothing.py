"""Does a full-SLAM smoothing of each rendered demo robot's run bring the final fusion closer to the truth? (issue 13)

Run from the repository root, on ``p3at demo --seed S --out DIR --log-sensors`` folders (robot1/2.npz, the TUM
files and robot1/2-log/):

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.demo_smoothing DIR [DIR ...] [--out ROOT] [--json]

or, the product itself (``p3at demo --smooth``, session 50) against the demo without it, seed after seed:

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.demo_smoothing --live [--seeds 0 1 ...] [--root ROOT]

which runs ``p3at demo --seed S --json --out ROOT/filter/demoS`` and then the same with ``--smooth`` into
ROOT/smoothed/demoS (nice -n 5, one at a time; a run whose ROOT/<kind>/demoS.json is there is not run again) and prints
each seed's final fusion (found, within 0.05 m / 0.01 rad, its error against the truth, merged landmarks), each robot's
smoothing (readings matched, cut, χ²/dof, seconds) and each run's wall time, with the counts, the median wall time and
the ratio of the two.

The association and the smoothed map are :mod:`estimation.stereo_readings`' (what ``--smooth`` runs); this benchmark
replays the logs to get the readings, which the mission keeps as it runs.

Per robot: the sensor log is replayed through the onboard pipeline (``runtime.replay``'s loop: the live map is rebuilt
bit for bit, which is checked against the folder's map), keeping each processed frame's observations and odometry.
Associations: ``estimation.stereo_readings.associate`` (its docstring says by which rules and why).
Then ``estimation.stereo_smoothing.smooth`` (Cauchy, then cut at χ²₃ 99 %) from the filter's trajectory and map,
pose 0 fixed; the smoothed map keeps the filter's ids, descriptors, counts and metadata, with the smoothed positions,
their marginal covariances, the smoothed trajectory, each landmark's drift (the smoothed pose's marginal where it was
first seen) and its sighting spread; a landmark no inlier reading holds keeps the filter's values. The smoothed
covariances carry the filter's observation floor (``observation_var_floor``, its "model error") once more, as an error
shared by all of a landmark's readings (``smooth(landmark_floor=...)``; ``--landmark-floor 0``: without it): without
it the smoothed landmarks' NEES falls to 68–94 % within χ²₃ 95 % on seeds 0, 5 and 6, because their readings'
errors do not average away (session 49).

Session 49, seeds 0–9: the demo's final fusion on the smoothed maps is found on the same 8 seeds, none wrong, within
0.05 m / 0.01 rad on 8 of 8 (the filter's maps: 5 of 8); robot 2's heading error at its supports rms 9.0 → 3.5 mrad;
smoothed landmark NEES ≥ 90 % on 18 of 20 maps (seed 4's robot 1, which lost its frame, 78 %; seed 9's robot 1 76 %).

Written: ROOT/<folder name>/robot1.npz, robot2.npz and links to the folder's TUM files (default ROOT
/tmp/demo-smoothed), so that ``benchmarks.demo_frame_errors`` and ``benchmarks.fusion_prior --demo`` read them as a
demo folder; the replay's records are cached in ROOT/<folder name>/robotN-replay.npz (a second run skips the replay).

Printed, filter vs smoothed, per seed: the final fusion as the demo decides it (``runtime.fusion_report.fuse_maps``,
no cache, the generator that reproduces the demo's own final alignment on the filter's maps), found, its error
against the truth, its own error (against the best rigid fit of the two maps to the simulator's features, as
``fusion_prior``); robot 2's heading error at its supports (its trajectory against the truth at the supports' median
creation time, as ``demo_frame_errors``, on the whole-map alignment of the last column); each map's landmark NEES
(share within χ²₃ 95 %) against its true point (the world point behind its readings' pixels at the true poses,
:func:`landmark_truth`; the same rows for both maps); each robot's trajectory heading error (rms) and ATE; the whole
maps aligned (``fusion.align``, robust, default_rng(0), as ``fusion_prior`` and ``demo_frame_errors``: without the
split check the demo runs on a map that flagged itself). Per robot the smoother's figures (frames, readings
associated, inliers, χ²/dof, seconds). The demo's summary (its ``--json`` output) is read from DIR/summary.json or
DIR.json beside the folder, for the generator that reproduces its final alignment.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from runtime.commands.options import non_negative_float, non_negative_int  # noqa: E402

GOAL_M, GOAL_RAD = 0.05, 0.01
TRUTH_SPREAD = 0.05      # m: a landmark's readings' true points further than this (median) from their median: no truth
CHI2_3_95 = 7.815
ROBOTS = ("robot1", "robot2")


# -- 1. the replay, keeping what the smoother needs --------------------------------------------------------------
def replayed(folder: Path, out: Path, name: str) -> dict:
    """Robot ``name``'s replay of demo ``folder`` (:func:`record`, cached in ``out``), its TUM files (estimated,
    odometry, truth) linked into ``out`` beside the maps a benchmark writes there."""
    for suffix in ("-truth.tum", "-odometry.tum", ".tum"):
        link = out / f"{name}{suffix}"
        if not link.exists():
            link.symlink_to((folder / f"{name}{suffix}").resolve())
    return record(folder / f"{name}-log", out / f"{name}-replay.npz")


def record(log_dir: Path, cache: Path):
    """Replay a robot's sensor log as ``runtime.replay.replay_log`` does, keeping per frame its time, odometry pose
    and observations; the final best particle's trajectory and map (exported, and with the particle's own
    covariances). Cached in ``cache`` (npz)."""
    from estimation.landmark_map import LandmarkMap

    if cache.is_file():
        z = np.load(cache, allow_pickle=False)
        meta = json.loads(bytes(z["meta"]).decode())
        return {k: z[k] for k in z.files if k != "meta"} | {"meta": meta,
                                                           "exported": LandmarkMap.load(cache.with_suffix(".map.npz"))}
    from runtime.replay import _frames, core_and_odometry, onboard_config_from_log
    from runtime.sensorlog import SensorLog

    log = SensorLog(log_dir)
    config = onboard_config_from_log(log)
    core, odometry = core_and_odometry(log, config)
    robot = core.robot
    processed = {int(r["seq"]) for r in log.records("processed")}
    times, odo, counts, points, covs, descs, pixels = [], [], [], [], [], [], []
    start = time.perf_counter()
    for frame in _frames(log, config.fastslam.descriptor_size):
        if frame.seq not in processed:
            continue
        pose = odometry.interpolate(frame.t)
        if pose is None:
            continue
        result = core.step(frame, pose)
        obs = frame.observations if frame.observations is not None else result.matches.to_observations(frame.t)
        times.append(frame.t)
        odo.append(np.asarray(pose, float))
        counts.append(len(obs))
        points.append(np.asarray(obs.points, float).reshape(-1, 3))
        covs.append(np.asarray(obs.covariances, float).reshape(-1, 3, 3))
        descs.append(np.asarray(obs.descriptors, np.float32).reshape(len(obs), config.fastslam.descriptor_size))
        pixels.append(np.asarray(obs.pixels, float).reshape(len(obs), 2))
    seconds = time.perf_counter() - start
    slam = core.slam
    exported = core.best_map()
    particle = slam.best_map(robot=robot, metadata=core.metadata, covariance="particle")
    out = {"times": np.array(times), "odometry": np.array(odo), "counts": np.array(counts, np.int64),
           "points": np.concatenate(points), "covariances": np.concatenate(covs),
           "descriptors": np.concatenate(descs), "pixels": np.concatenate(pixels), "trajectory": slam.trajectory(),
           "particle_positions": particle.positions, "particle_covariances": particle.covariances}
    meta = {"fastslam": config.fastslam.to_dict(), "replay_seconds": seconds, "robot": robot}
    cache.parent.mkdir(parents=True, exist_ok=True)
    np.savez(cache, meta=np.frombuffer(json.dumps(meta).encode(), np.uint8), **out)
    exported.save(cache.with_suffix(".map.npz"))
    return out | {"meta": meta, "exported": exported}


# -- 2. the association and the smoothing (estimation.stereo_readings, which the mission's --smooth uses) ----------
def readings_of(rec: dict):
    """The replay's records as ``estimation.stereo_readings.StereoReadings``."""
    from estimation.stereo_readings import StereoReadings

    return StereoReadings(rec["times"], rec["odometry"], rec["counts"], rec["points"], rec["covariances"],
                          rec["descriptors"], rec["pixels"])


def smoothed_map(rec: dict, landmark_floor: float | None = None):
    """(the smoothed LandmarkMap, figures dict, (frame, reading, landmark row, inlier) of each association)."""
    from estimation.fastslam import FastSLAMConfig
    from estimation.stereo_readings import smoothed_map as smooth_readings

    config = FastSLAMConfig.from_dict(rec["meta"]["fastslam"])
    out = smooth_readings(readings_of(rec), rec["trajectory"], rec["exported"], rec["particle_positions"],
                          rec["particle_covariances"], config, landmark_floor)
    figures = out.figures | {"replay_s": rec["meta"]["replay_seconds"]}
    return out.landmark_map, figures, (out.frames, out.readings, out.rows, out.inliers)


# -- 4. scores -----------------------------------------------------------------------------------------------------
def landmark_truth(folder: Path, rec: dict, frames: np.ndarray, readings: np.ndarray, rows: np.ndarray,
                   renderer) -> np.ndarray:
    """(L, 3) each landmark's true point in the map's true start frame: the median over its readings of the world
    point behind the reading's left pixel at the robot's true pose then (``StereoRenderer.true_points``, as
    ``eval_slam_rendered``); NaN where no reading's ray meets a surface or they disagree by more than TRUTH_SPREAD."""
    from estimation.geometry import compose, inverse, transform_points
    from runtime.trajectories import planar, read_tum

    exported = rec["exported"]
    start = np.asarray(exported.metadata["true_start_pose"], float)
    truth = planar(read_tum(folder / f"{exported.robot}-truth.tum"))
    times = rec["times"]
    k = np.clip(np.searchsorted(truth[:, 0], times), 0, len(truth) - 1)
    if not np.allclose(truth[k, 0], times, atol=1e-6):
        raise SystemExit(f"{folder}: the truth has no row at some frame's time")
    points = np.full((len(readings), 3), np.nan)
    for frame in np.unique(frames):
        sel = frames == frame
        pose = compose(start, truth[k[frame], 1:])
        points[sel] = renderer.true_points(pose, rec["pixels"][readings[sel]], "left", rectified=True)
    out = np.full((len(exported), 3), np.nan)
    order = np.argsort(rows, kind="stable")
    bounds = np.searchsorted(rows[order], np.arange(len(exported) + 1))
    for lm in range(len(exported)):
        p = points[order[bounds[lm]:bounds[lm + 1]]]
        p = p[np.all(np.isfinite(p), axis=1)]
        if len(p):
            med = np.median(p, axis=0)
            if np.median(np.linalg.norm(p - med, axis=1)) <= TRUTH_SPREAD:
                out[lm] = med
    return transform_points(inverse(start), out)


def landmark_nees(m, truth: np.ndarray) -> tuple[float, int, float]:
    """Share of the map's landmarks with a truth within χ²₃ 95 %, how many were scored, their median error (m)."""
    ok = np.all(np.isfinite(truth), axis=1) & np.isfinite(m.covariances[:, 0, 0])
    e = m.positions[ok] - truth[ok]
    nees = np.einsum("ni,ni->n", e, np.linalg.solve(m.covariances[ok], e[:, :, None])[:, :, 0])
    return float(np.mean(nees <= CHI2_3_95)), int(ok.sum()), float(np.median(np.linalg.norm(e, axis=1)))


def trajectory_errors(folder: Path, m) -> tuple[float, float]:
    """(ATE rms m, heading rms rad) of the map's trajectory against the truth on the same frames."""
    from demo_frame_errors import _map_truth

    from estimation.geometry import wrap_angle

    traj, truth = _map_truth(folder, m)
    return (float(np.sqrt(np.mean(np.sum((traj[:, 1:3] - truth[:, 1:3]) ** 2, 1)))),
            float(np.sqrt(np.mean(wrap_angle(traj[:, 3] - truth[:, 3]) ** 2))))


def fusion_row(folder: Path, m1, m2, rng_seed: int, features) -> dict:
    """The final fusion as the demo decides it, the own error, robot 2's heading error at the supports."""
    from demo_frame_errors import _map_truth, creation_times
    from eval_fusion import _feature_fit

    from estimation.geometry import between, wrap_angle
    from fusion.alignment import align, alignment_error_xy_theta, true_relative_pose
    from runtime.fusion_report import fuse_maps

    report = fuse_maps({"robot1": m1, "robot2": m2}, "robust", 1, 0.0, np.random.default_rng(rng_seed))
    pair = report.pairs[0]
    truth = true_relative_pose(m1, m2)
    best = between(_feature_fit(m1, features)[0], _feature_fit(m2, features)[0])
    row = {"found": bool(pair.aligned), "supports": pair.supports, "note": pair.note[:60], "pose": None}
    if pair.aligned:
        pose = np.array([pair.tx, pair.ty, pair.theta])
        row["pose"] = pose.tolist()
        row["error"] = alignment_error_xy_theta(pose, truth)
        row["own"] = alignment_error_xy_theta(pose, best)
    a = align(m1, m2, "robust", np.random.default_rng(0))    # fusion_prior's and demo_frame_errors' alignment
    row["align_found"] = bool(a.found)
    if a.found:
        row["align_error"] = alignment_error_xy_theta(a.pose, truth)
        rows = a.supports[:, 1]
        made = creation_times(m2)[rows]
        traj, truth_rows = _map_truth(folder, m2)
        k = np.clip(np.searchsorted(truth_rows[:, 0], made), 0, len(truth_rows) - 1)
        row["r2_heading"] = float(np.median(wrap_angle(traj[k, 3] - truth_rows[k, 3])))
        row["r2_made"] = float(np.nanmedian(made))
    return row


def demo_rng_seed(folder: Path, m1, m2) -> int:
    """The generator seed whose fuse_maps reproduces the demo's own final alignment on its maps (the mission draws
    default_rng(seed + number of fusions so far)); the demo's seed if none does."""
    from runtime.fusion_report import fuse_maps

    files = [p for p in (folder / "summary.json", folder.with_suffix(".json")) if p.is_file()]
    if not files:
        return 0
    summary = json.loads(files[0].read_text())
    seed = int(summary.get("seed", 0))
    final = (summary.get("fusion") or {}).get("pairs") or []
    if not final or not final[0].get("aligned"):
        return seed
    want = np.array([final[0]["tx"], final[0]["ty"], final[0]["theta"]])
    for n in range(0, 40):
        p = fuse_maps({"robot1": m1, "robot2": m2}, "robust", 1, 0.0, np.random.default_rng(seed + n)).pairs[0]
        if p.aligned and np.allclose([p.tx, p.ty, p.theta], want, atol=1e-9):
            return seed + n
    return seed


def _cell(row: dict) -> str:
    if not row["found"]:
        return f"not found ({row['supports']} supports)"
    e, o = row["error"], row["own"]
    goal = "✓" if e[0] <= GOAL_M and e[1] <= GOAL_RAD else "✗"
    return f"{goal} {e[0]:.3f} / {e[1]:.4f} (own {o[0]:.3f} / {o[1]:.4f}; {row['supports']})"


def run(folders: list[Path], root: Path, as_json: bool, landmark_floor: float | None = None) -> int:
    from fusion_sim import load_world

    from estimation.landmark_map import LandmarkMap
    from mocks.stereo_head import default_calibration
    from mocks.stereo_head.renderer import StereoRenderer

    world = load_world()
    features = world.features
    renderer = StereoRenderer(world, default_calibration())
    results = []
    for folder in folders:
        out = root / folder.name
        out.mkdir(parents=True, exist_ok=True)
        filt, smooth_, figs, truths = {}, {}, {}, {}
        for name in ROBOTS:
            filt[name] = LandmarkMap.load(folder / f"{name}.npz")
            rec = replayed(folder, out, name)
            same = (len(rec["exported"]) == len(filt[name])
                    and np.array_equal(rec["exported"].positions, filt[name].positions))
            smooth_[name], figs[name], (f, j, lm, inl) = smoothed_map(rec, landmark_floor)
            truths[name] = landmark_truth(folder, rec, f[inl], j[inl], lm[inl], renderer)
            figs[name]["replay_equals_live"] = bool(same)
            smooth_[name].save(out / f"{name}.npz")
        seed = demo_rng_seed(folder, filt["robot1"], filt["robot2"])
        row = {"folder": str(folder), "rng_seed": seed, "robots": figs}
        for kind, maps in (("filter", filt), ("smoothed", smooth_)):
            r = fusion_row(folder, maps["robot1"], maps["robot2"], seed, features)
            for name in ROBOTS:
                r[f"{name}_nees"] = landmark_nees(maps[name], truths[name])
                r[f"{name}_traj"] = trajectory_errors(folder, maps[name])
            row[kind] = r
        results.append(row)
        if not as_json:
            print(f"{folder.name}: done", file=sys.stderr)
    if as_json:
        print(json.dumps(results, indent=1, default=float))
        return 0
    print_table(results)
    return 0


def print_table(results: list[dict]) -> None:
    """The tables of :func:`run`'s results (also of its ``--json`` output, read back)."""
    print("\n### Rendered demo: the filter's maps against their full-SLAM smoothing (benchmarks.demo_smoothing)\n")
    print("| run | maps | final fusion: ✓ within 0.05 m / 0.01 rad; vs truth xy / θ (own; supports) | robot 2's "
          "heading error at its supports, mrad (made at) | landmark NEES within χ²₃ 95 %: robot 1 / robot 2 "
          "(scored; median error) | heading rms mrad / ATE m: robot 1; robot 2 | the whole maps aligned (no split "
          "check): vs truth |")
    print("|---|---|---|---|---|---|---|")
    for row in results:
        for kind in ("filter", "smoothed"):
            r = row[kind]
            head = (f"{1000 * r['r2_heading']:+.1f} ({r['r2_made']:.0f} s)" if "r2_heading" in r else "–")
            nees = " / ".join(f"{100 * r[f'{n}_nees'][0]:.0f} % ({r[f'{n}_nees'][1]}; {r[f'{n}_nees'][2]:.3f} m)"
                              for n in ROBOTS)
            tr = "; ".join(f"{1000 * r[f'{n}_traj'][1]:.1f} / {r[f'{n}_traj'][0]:.3f}" for n in ROBOTS)
            whole = (f"{r['align_error'][0]:.3f} / {r['align_error'][1]:.4f}" if r.get("align_found")
                     else "not found")
            print(f"| {Path(row['folder']).name} | {kind} | {_cell(r)} | {head} | {nees} | {tr} | {whole} |")
    print()
    for kind in ("filter", "smoothed"):
        rows = [row[kind] for row in results]
        found = [r for r in rows if r["found"]]
        wrong = [r for r in found if r["error"][0] > 0.3 or r["error"][1] > 0.1]
        goal = sum(1 for r in found if r["error"][0] <= GOAL_M and r["error"][1] <= GOAL_RAD)
        heads = np.array([r["r2_heading"] for r in rows if "r2_heading" in r])
        rms = f"{1000 * np.sqrt(np.mean(heads ** 2)):.1f}" if len(heads) else "–"
        whole = [r for r in rows if r.get("align_found")]
        whole_wrong = sum(1 for r in whole if r["align_error"][0] > 0.3 or r["align_error"][1] > 0.1)
        whole_goal = sum(1 for r in whole if r["align_error"][0] <= GOAL_M and r["align_error"][1] <= GOAL_RAD)
        print(f"- {kind}: found {len(found)} of {len(rows)}, wrong {len(wrong)}, within the goal {goal}; robot 2's "
              f"heading error at its supports rms {rms} mrad; the whole maps aligned: found {len(whole)}, wrong "
              f"{whole_wrong}, within the goal {whole_goal}")
    print("\n| run | robot | frames | readings: associated, inliers | χ²/dof | landmarks held | replay s | "
          "associate s | smooth s | replay = live map |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for row in results:
        for name, f in row["robots"].items():
            print(f"| {Path(row['folder']).name} | {name} | {f['frames']} | {f['readings']}: {f['associated']}, "
                  f"{f['inliers']} | {f['chi2_per_dof']:.2f} | {f['held']} of {f['landmarks']} | "
                  f"{f['replay_s']:.0f} | {f['associate_s']:.1f} | {f['smooth_s']:.1f} | {f['replay_equals_live']} |")


# -- the real demo with and without --smooth (--live) ---------------------------------------------------------------
KINDS = ("filter", "smoothed")


def live_run(seeds: list[int], root: Path) -> list[dict]:
    """``p3at demo --seed S --json --out ROOT/<kind>/demoS`` without and with ``--smooth``, seed after seed (each run
    alone, nice -n 5; its JSON in ROOT/<kind>/demoS.json, its wall time in demoS.wall): a run whose JSON is there is
    not run again."""
    import os
    import subprocess

    p3at = Path(sys.executable).parent / "p3at"
    env = os.environ | {"OPENBLAS_NUM_THREADS": "1"}
    rows = []
    for seed in seeds:
        row = {"seed": seed}
        for kind in KINDS:
            out = root / kind / f"demo{seed}"
            json_file, wall_file = out.with_suffix(".json"), out.with_suffix(".wall")
            if not json_file.is_file():
                out.parent.mkdir(parents=True, exist_ok=True)
                command = ["nice", "-n", "5", str(p3at), "demo", "--seed", str(seed), "--json", "--out", str(out)]
                start = time.monotonic()
                with open(out.with_suffix(".err"), "w") as err:
                    done = subprocess.run(command + (["--smooth"] if kind == "smoothed" else []), env=env,
                                          stdout=subprocess.PIPE, stderr=err, text=True, check=False)
                wall_file.write_text(f"{time.monotonic() - start} {done.returncode}\n")
                json_file.write_text(done.stdout)
                print(f"demo {seed} {kind}: exit {done.returncode}, {time.monotonic() - start:.0f} s", file=sys.stderr)
            row[kind] = json.loads(json_file.read_text())
            row[f"{kind}_wall"] = float(wall_file.read_text().split()[0])
        rows.append(row)
    return rows


def _live_cell(summary: dict) -> tuple[str, str]:
    """(the final fusion: ✓/✗ within the goal, its error; merged landmarks) of a demo's summary."""
    pairs = (summary.get("fusion") or {}).get("pairs") or []
    if not pairs or not pairs[0]["aligned"]:
        return f"not found ({pairs[0]['supports'] if pairs else 0} supports)", "–"
    p = pairs[0]
    goal = "✓" if p["error_xy"] <= GOAL_M and p["error_theta"] <= GOAL_RAD else "✗"
    return (f"{goal} {p['error_xy']:.3f} / {p['error_theta']:.4f} ({p['supports']})",
            str(summary["fusion"]["merged_landmarks"]))


def print_live(rows: list[dict]) -> None:
    """The table of :func:`live_run`'s runs."""
    print("\n### The rendered demo without and with --smooth (benchmarks.demo_smoothing --live)\n")
    print("| seed | maps | final fusion: ✓ within 0.05 m / 0.01 rad; vs truth xy m / θ rad (supports) | merged "
          "landmarks | smoothing per robot: matched of readings, cut, χ²/dof, s | wall s |")
    print("|---|---|---|---|---|---|")
    for row in rows:
        for kind in KINDS:
            summary = row[kind]
            cell, merged = _live_cell(summary)
            smoothing = "; ".join(
                (f"{name} {f['associated']} of {f['readings']}, {f['cut']}, {f['chi2_per_dof']:.2f}, {f['seconds']:.1f}"
                 if f.get("smoothed") else f"{name} not smoothed: {f.get('reason')}")
                for name, r in summary["robots"].items() if (f := r.get("smoothing")) is not None) or "–"
            print(f"| {row['seed']} | {kind} | {cell} | {merged} | {smoothing} | {row[f'{kind}_wall']:.0f} |")
    print()
    for kind in KINDS:
        pairs = [((row[kind].get("fusion") or {}).get("pairs") or [{}])[0] for row in rows]
        found = [p for p in pairs if p.get("aligned")]
        wrong = sum(1 for p in found if p["error_xy"] > 0.3 or p["error_theta"] > 0.1)
        goal = sum(1 for p in found if p["error_xy"] <= GOAL_M and p["error_theta"] <= GOAL_RAD)
        xy = np.array([p["error_xy"] for p in found])
        th = np.array([p["error_theta"] for p in found])
        errors = (f"error median {np.median(xy):.3f} m / {np.median(th):.4f} rad, worst {xy.max():.3f} m / "
                  f"{th.max():.4f} rad" if len(found) else "no error")
        walls = [row[f"{kind}_wall"] for row in rows]
        print(f"- {kind}: found {len(found)} of {len(rows)}, wrong {wrong}, within the goal {goal}; {errors}; wall "
              f"median {np.median(walls):.0f} s (total {sum(walls):.0f} s)")
    ratios = [row["smoothed_wall"] / row["filter_wall"] for row in rows]
    smooth_s = [f["seconds"] for row in rows for r in row["smoothed"]["robots"].values()
                if (f := r.get("smoothing")) is not None]
    print(f"- wall time with --smooth / without, per seed: median {np.median(ratios):.2f} (range {min(ratios):.2f}–"
          f"{max(ratios):.2f}); the smoothing itself {np.median(smooth_s):.1f} s a robot (median; "
          f"{min(smooth_s):.1f}–{max(smooth_s):.1f})")


def main(argv: list[str] | None = None) -> int:
    if argv is None:
        argv = sys.argv[1:]
    if argv[:1] == ["--live"]:
        parser = argparse.ArgumentParser(description="the rendered demo without and with --smooth, seed after seed")
        parser.add_argument("--live", action="store_true", required=True)
        parser.add_argument("--seeds", type=non_negative_int, nargs="+", default=list(range(10)),
                            help="demo seeds (default 0-9)")
        parser.add_argument("--root", type=Path, default=Path("/tmp/demo-smooth-live"),
                            help="where the demos' folders, JSON and wall times go (default /tmp/demo-smooth-live)")
        args = parser.parse_args(argv)
        print_live(live_run(args.seeds, args.root))
        return 0
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folders", nargs="+", type=Path, help="p3at demo --log-sensors output folders")
    parser.add_argument("--out", type=Path, default=Path("/tmp/demo-smoothed"),
                        help="where the smoothed maps and the replay caches go (default /tmp/demo-smoothed)")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    parser.add_argument("--landmark-floor", type=non_negative_float, default=None, metavar="M2",
                        help="m², the error shared by a landmark's readings, added to its smoothed covariance "
                             "(default: the filter's observation_var_floor, 0.0004; 0: none)")
    args = parser.parse_args(argv)
    refuse_non_demo_folders(parser, args.folders)
    return run(args.folders, args.out, args.json, args.landmark_floor)


def refuse_non_demo_folders(parser: argparse.ArgumentParser, folders: list[Path]) -> None:
    """parser.error (one line) for a folder that is not a ``p3at demo --log-sensors --out`` folder."""
    for f in folders:
        missing = [p for p in ("robot1.npz", "robot2.npz", "robot1-log", "robot2-log", "robot1-truth.tum")
                   if not (f / p).exists()]
        if missing:
            parser.error(f"{f}: no {', '.join(missing)} (a p3at demo --log-sensors --out folder)")


if __name__ == "__main__":
    sys.exit(main())
