"""The smoothing after the mission with and without the odometry's scales as unknowns on the rendered demo (session 52).

Run from the repository root, on ``p3at demo --seed S --out DIR --log-sensors`` folders (as
``benchmarks.demo_smoothing`` and ``benchmarks.demo_keyframes``, whose replay, keyframes, scores and fusion it reuses):

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.demo_odometry_calibration DIR [DIR ...] [--out ROOT]
        [--window T0 T1] [--diagnose] [--json]

Per robot: the replay's frames (cached in ROOT/<folder>/robotN-replay.npz) given one by one to a
``ReadingsRecorder`` with the default ``KeyframeRule`` (what ``p3at demo`` keeps), smoothed by
``estimation.stereo_readings.smoothed_map`` from the same filter trajectory and map twice: as the demo does (the
odometry unbiased) and with ``calibrate_odometry=True`` (``stereo_smoothing.smooth``'s distance and turn scales s_d,
s_θ, prior N(1, 0.05²)). The estimate reads no truth; the truth only scores:

- the scales against the mock's (``--odometry realistic``: distance 0.99, turn 0.99 / 1.03 ≈ 0.961) and against the
  least-squares ratio of the odometry's per-frame increments to the true ones (robotN-odometry.tum and
  robotN-truth.tum, both in the start frame: forward travel and turn, each through the origin);
- landmark NEES (share within χ²₃ 95 %; median error) against each landmark's true point
  (``demo_smoothing.landmark_truth`` from the uncalibrated smoothing's inlier readings, the same rows for both);
- pose NEES (share within χ²₃ 95 %; median) of the keyframes' smoothed poses (pose 0, the gauge, left out) against the
  truth at their times, with the smoothed marginals; the largest |x| and |y| error and the x σ in ``--window`` (s)
  (each keyframe's time, errors, σ and NEES are in the JSON, "profile");
- ATE and heading rms at every frame (``demo_smoothing.trajectory_errors``);
- per seed the final fusion as the demo decides it (``demo_smoothing.fusion_row`` with the generator that reproduces
  the demo's own final alignment on its maps), against the truth.

With ``--diagnose``, per robot also what makes its smoothed poses wrong, the smoothing run again (plain, as the demo)
with one input replaced by the truth: the odometry (the keyframes' exact true increments; the measured ones divided by
the mock's scales) and the readings (each replaced by its landmark's true point, the median over its readings' pixels'
true points, plus white noise of its own covariance; or the readings whose own pixel's true point lies more than
OFF_POINT from their landmark's cut, an oracle), with the keyframe increments' errors in units of the motion model's σ
and the off-point readings' share and χ² at the solution. The readings' variants build the problem as
``smoothed_map`` does (its association, covariances and odometry; checked: unchanged, they give its poses to the bit).

Also printed: whether the uncalibrated smoothing reproduces the demo's own smoothed map (robotN.npz) to the bit, and
the smoothing seconds. Each seed's figures are written to ROOT/<folder name>.json; given those files instead of
folders (``ROOT/seed*.json``), it prints their tables again without computing.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import demo_keyframes as dk  # noqa: E402
import demo_smoothing as ds  # noqa: E402

from runtime.commands.options import non_negative_float  # noqa: E402

KINDS = ("plain", "calibrated")
MOCK_SCALES = (0.99, 0.99 / 1.03)   # mocks.p3at.options.OdometryErrors.realistic(): measured / true distance, turn
OFF_POINT = 0.05                    # m: --diagnose's off-point reading: its pixel's true point this far from its
#                                     landmark's


def truth_scales(folder: Path, name: str) -> tuple[float, float]:
    """(distance, turn) least-squares ratio of the odometry's per-frame increments to the true ones (scoring only)."""
    from estimation.geometry import between
    from runtime.trajectories import planar, read_tum

    truth = planar(read_tum(folder / f"{name}-truth.tum"))
    odo = planar(read_tum(folder / f"{name}-odometry.tum"))
    if len(truth) != len(odo) or not np.allclose(truth[:, 0], odo[:, 0]):
        raise SystemExit(f"{folder}: {name}'s odometry and truth files have different rows")
    bt, bo = between(truth[:-1, 1:], truth[1:, 1:]), between(odo[:-1, 1:], odo[1:, 1:])
    return (float(bo[:, 0] @ bt[:, 0] / (bt[:, 0] @ bt[:, 0])), float(bo[:, 2] @ bt[:, 2] / (bt[:, 2] @ bt[:, 2])))


def pose_scores(folder: Path, name: str, poses: np.ndarray, times: np.ndarray, covariances: np.ndarray,
                window: tuple[float, float]) -> dict:
    """Pose NEES of the keyframes' smoothed ``poses`` (K, 3) at ``times`` with their marginals against the truth (the
    start frame), and the errors in ``window``."""
    from estimation.geometry import wrap_angle
    from runtime.trajectories import planar, read_tum

    truth = planar(read_tum(folder / f"{name}-truth.tum"))
    k = np.clip(np.searchsorted(truth[:, 0], times - 1e-6), 0, len(truth) - 1)
    if not np.allclose(truth[k, 0], times, atol=1e-6):
        raise SystemExit(f"{folder}: the truth has no row at some keyframe's time")
    e = np.column_stack([poses[:, :2] - truth[k, 1:3], wrap_angle(poses[:, 2] - truth[k, 3])])[1:]
    nees = np.einsum("ta,ta->t", e, np.linalg.solve(covariances[1:], e[:, :, None])[:, :, 0])
    w = (times[1:] >= window[0]) & (times[1:] <= window[1])
    sd = np.sqrt(np.diagonal(covariances[1:], axis1=1, axis2=2))
    out = {"pose_nees": [float(np.mean(nees <= ds.CHI2_3_95)), float(np.median(nees))],
           "profile": np.column_stack([times[1:], e, sd, nees]).round(6).tolist()}   # t, errors, σ, NEES (JSON)
    if w.any():
        out["window"] = {"x_err_max": float(np.abs(e[w, 0]).max()), "y_err_max": float(np.abs(e[w, 1]).max()),
                         "x_sd": [float(v) for v in np.sqrt(covariances[1:][w, 0, 0])[[0, -1]]],
                         "x_sd_max": float(np.sqrt(covariances[1:][w, 0, 0]).max()),
                         "nees_within": float(np.mean(nees[w] <= ds.CHI2_3_95))}
    return out


def _pose_fit(poses: np.ndarray, covariances: np.ndarray, truth: np.ndarray) -> dict:
    """Share of poses (the gauge left out) within χ²₃ 95 %, the largest |x| error, the heading rms."""
    from estimation.geometry import wrap_angle

    e = np.column_stack([poses[:, :2] - truth[:, :2], wrap_angle(poses[:, 2] - truth[:, 2])])[1:]
    nees = np.einsum("ta,ta->t", e, np.linalg.solve(covariances[1:], e[:, :, None])[:, :, 0])
    return {"within": float(np.mean(nees <= ds.CHI2_3_95)), "x_err_max": float(np.abs(e[:, 0]).max()),
            "theta_rms": float(np.sqrt(np.mean(e[:, 2] ** 2)))}


def diagnose(folder: Path, name: str, rec: dict, readings, renderer) -> dict:
    """--diagnose (module docstring): the plain smoothing with the odometry or the readings replaced by the truth."""
    from dataclasses import replace

    from estimation.fastslam import FastSLAMConfig
    from estimation.geometry import between, compose, inverse, transform_points, wrap_angle
    from estimation.stereo_readings import associate, smoothed_map
    from estimation.stereo_smoothing import StereoLogProblem, observation_chi2, smooth
    from runtime.trajectories import planar, read_tum

    config = FastSLAMConfig.from_dict(rec["meta"]["fastslam"])
    truth = planar(read_tum(folder / f"{name}-truth.tum"))
    k = np.clip(np.searchsorted(truth[:, 0], readings.times - 1e-6), 0, len(truth) - 1)
    true_poses = truth[k, 1:]
    args = (rec["trajectory"], rec["exported"], rec["particle_positions"], rec["particle_covariances"], config)
    bt, bo = between(true_poses[:-1], true_poses[1:]), between(readings.odometry[:-1], readings.odometry[1:])
    sd = np.sqrt(np.diagonal(readings.increment_covariances, axis1=1, axis2=2))
    scales = np.array([MOCK_SCALES[0], MOCK_SCALES[0], MOCK_SCALES[1]])
    out: dict = {}
    for label, inc in (("increment_error_sd", bt), ("increment_error_sd_unscaled", bt * scales)):
        e = bo - inc
        e[:, 2] = wrap_angle(e[:, 2])
        out[label] = np.sqrt(np.mean((e / sd) ** 2, axis=0)).tolist()

    def chain(increments):
        poses = [readings.odometry[0]]
        for d in increments:
            poses.append(compose(poses[-1], d))
        return np.array(poses)

    plain = None
    for label, odometry in (("odometry measured", readings.odometry), ("odometry true", chain(bt)),
                            ("odometry measured ÷ mock's scales", chain(bo / scales))):
        s = smoothed_map(replace(readings, odometry=odometry), *args)
        poses = s.landmark_map.trajectory[1:][readings.frame_index, 1:]
        out[label] = _pose_fit(poses, s.pose_covariances, true_poses)
        plain = s if plain is None else plain
    # the readings: the problem smoothed_map solves, built again (its association, covariances and odometry)
    exported, full = rec["exported"], rec["trajectory"]
    traj = np.vstack([full[:1], full[1:][readings.frame_index]])
    f, j, lm = associate(readings, traj, exported, rec["particle_covariances"], config)
    q = config.observation_cov_scale * readings.covariances[j] + config.observation_var_floor * np.eye(3)
    var = np.diagonal(readings.increment_covariances, axis1=1, axis2=2).copy()
    start = np.asarray(exported.metadata["true_start_pose"], float)
    own = np.full((len(j), 3), np.nan)                      # each reading's pixel's true point, the start frame
    for frame in np.unique(f):
        sel = f == frame
        own[sel] = renderer.true_points(compose(start, true_poses[frame]), readings.pixels[j[sel]], "left",
                                        rectified=True)
    own = transform_points(inverse(start), own)
    landmark = np.full((len(exported), 3), np.nan)
    for row in np.unique(lm):
        p = own[lm == row]
        p = p[np.all(np.isfinite(p), axis=1)]
        if len(p):
            landmark[row] = np.median(p, axis=0)
    off = np.linalg.norm(own - landmark[lm], axis=1) > OFF_POINT     # NaN compares False: no truth, not off

    def smooth_readings(points, keep):
        problem = StereoLogProblem(bo, var, f[keep], lm[keep], points[keep], q[keep], len(exported))
        sol = smooth(problem, traj[1:, 1:], exported.positions, landmark_floor=config.observation_var_floor,
                     view_floor=config.observation_var_floor, view_model="sandwich")
        held = sol.held & np.all(np.isfinite(landmark), axis=1)
        e = sol.landmarks[held] - landmark[held]
        nees = np.einsum("la,la->l", e, np.linalg.solve(sol.landmark_covariances[held], e[:, :, None])[:, :, 0])
        return sol, _pose_fit(sol.poses, sol.pose_covariances, true_poses) | {
            "landmarks_within": float(np.mean(nees <= ds.CHI2_3_95))}

    every = np.ones(len(j), bool)
    sol, out["readings measured"] = smooth_readings(readings.points[j], every)
    out["readings_problem_is_smoothed_maps"] = bool(np.array_equal(sol.poses, plain.landmark_map.trajectory[1:][
        readings.frame_index, 1:]))
    chi2 = observation_chi2(StereoLogProblem(bo, var, f, lm, readings.points[j], q, len(exported)), sol.poses,
                            sol.landmarks)
    out["off_point"] = {"share": float(np.mean(off)), "chi2_below_3": float(np.mean(chi2[off] < 3.0)),
                        "landmarks": int(len(np.unique(lm[off])))}
    p = true_poses[f]
    c, s_ = np.cos(p[:, 2]), np.sin(p[:, 2])
    d = landmark[lm, :2] - p[:, :2]
    at_truth = np.column_stack([c * d[:, 0] + s_ * d[:, 1], -s_ * d[:, 0] + c * d[:, 1], landmark[lm, 2]])
    white = (np.linalg.cholesky(q) @ np.random.default_rng(0).standard_normal((len(j), 3, 1)))[:, :, 0]
    replaced = np.where(np.all(np.isfinite(at_truth), axis=1)[:, None], at_truth + white, readings.points[j])
    out["readings: the landmark's true point + white"] = smooth_readings(replaced, every)[1]
    out[f"readings measured, off-point (> {OFF_POINT:g} m) cut"] = smooth_readings(readings.points[j], ~off)[1]
    return out


def print_diagnosis(results: list[dict]) -> None:
    if not any(f.get("diagnosis") for row in results for f in row["robots"].values()):
        return
    print("\n### --diagnose: the plain smoothing with one input replaced by the truth\n")
    print("| run | robot | keyframe increments' error / model σ, rms x y θ (mock's scales removed) | off-point "
          "readings: share, χ² < 3, landmarks | smoothed with | poses within χ²₃ 95 % | x err max mm | θ rms mrad | "
          "landmarks within |")
    print("|---|---|---|---|---|---|---|---|---|")
    for row in results:
        for name, figs in row["robots"].items():
            d = figs.get("diagnosis")
            if not d:
                continue
            inc = (" ".join(f"{v:.2f}" for v in d["increment_error_sd"]) + " ("
                   + " ".join(f"{v:.2f}" for v in d["increment_error_sd_unscaled"]) + ")")
            o = d["off_point"]
            head = f"{inc} | {100 * o['share']:.1f} %, {100 * o['chi2_below_3']:.0f} %, {o['landmarks']}"
            for label, v in d.items():
                if not (isinstance(v, dict) and "within" in v):
                    continue
                lw = f"{100 * v['landmarks_within']:.1f} %" if "landmarks_within" in v else "–"
                print(f"| {Path(row['folder']).name} | {name} | {head} | {label} | {100 * v['within']:.0f} % | "
                      f"{1000 * v['x_err_max']:.0f} | {1000 * v['theta_rms']:.1f} | {lw} |")
                head = " | "
            if not d["readings_problem_is_smoothed_maps"]:
                print(f"| {Path(row['folder']).name} | {name} | (the readings' problem does not reproduce "
                      "smoothed_map's poses) |")


def run(folders: list[Path], root: Path, window: tuple[float, float], diagnosis: bool = False) -> list[dict]:
    from fusion_sim import load_world

    from estimation.fastslam import FastSLAMConfig
    from estimation.landmark_map import LandmarkMap
    from estimation.stereo_readings import KeyframeRule, smoothed_map
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
            readings, _ = dk.recorded(rec, KeyframeRule())
            times = readings.times
            figures: dict = {"truth_scales": truth_scales(folder, name)}
            truth = None
            for kind in KINDS:
                s = smoothed_map(readings, rec["trajectory"], rec["exported"], rec["particle_positions"],
                                 rec["particle_covariances"], config, calibrate_odometry=kind == "calibrated")
                inl = s.inliers
                if truth is None:   # the keyframes' frames and readings as rows of the replay's records
                    frames = readings.frame_index[s.frames[inl]]
                    rows = (np.r_[0, np.cumsum(rec["counts"])][frames] + s.readings[inl]
                            - readings.offsets[s.frames[inl]])
                    truth = ds.landmark_truth(folder, rec, frames, rows, s.rows[inl], renderer)
                m = s.landmark_map
                maps[kind][name] = m
                poses = m.trajectory[1:][readings.frame_index, 1:]
                figures[kind] = (s.figures | {"nees": ds.landmark_nees(m, truth),
                                              "traj": ds.trajectory_errors(folder, m)}
                                 | pose_scores(folder, name, poses, times, s.pose_covariances, window))
                m.save(out / f"{name}-{kind}.npz")
            demo_map = LandmarkMap.load(folder / f"{name}.npz")
            figures["plain_equals_demo"] = bool(
                np.array_equal(demo_map.positions, maps["plain"][name].positions)
                and np.array_equal(demo_map.covariances, maps["plain"][name].covariances))
            if diagnosis:
                figures["diagnosis"] = diagnose(folder, name, rec, readings, renderer)
            row["robots"][name] = figures
        demo = {name: LandmarkMap.load(folder / f"{name}.npz") for name in ds.ROBOTS}
        seed = ds.demo_rng_seed(folder, demo["robot1"], demo["robot2"])
        row["rng_seed"] = seed
        for kind in KINDS:
            row[kind] = ds.fusion_row(folder, maps[kind]["robot1"], maps[kind]["robot2"], seed, world.features)
        (root / f"{folder.name}.json").write_text(json.dumps(row, indent=1, default=float))
        results.append(row)
        print(f"{folder.name}: done", file=sys.stderr)
    return results


def print_table(results: list[dict], window: tuple[float, float]) -> None:
    print("\n### The smoothing with the odometry's scales as unknowns (benchmarks.demo_odometry_calibration)\n")
    print(f"Scales: estimate ± σ (mock's truth distance {MOCK_SCALES[0]:.3f}, turn {MOCK_SCALES[1]:.3f}; least-squares "
          "ratio of the odometry's to the true increments in brackets).\n")
    print("| run | robot | kind | s_d | s_θ | landmark NEES within χ²₃ 95 % (scored; median m) | pose NEES within "
          f"(median) | window {window[0]:g}–{window[1]:g} s: max |x|, |y| err mm; x σ mm; poses within | "
          "ATE m / heading mrad | χ²/dof | smooth s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for row in results:
        for name, figs in row["robots"].items():
            ts = figs["truth_scales"]
            for kind in KINDS:
                f = figs[kind]
                n = f["nees"]
                if kind == "calibrated":
                    sc, sd = f["odometry_scales"], f["odometry_scale_sd"]
                    cells = (f"{sc[0]:.4f} ± {sd[0]:.4f} ({ts[0]:.4f})", f"{sc[1]:.4f} ± {sd[1]:.4f} ({ts[1]:.4f})")
                else:
                    cells = ("–", "–")
                w = f.get("window")
                wc = (f"{1000 * w['x_err_max']:.0f}, {1000 * w['y_err_max']:.0f}; {1000 * w['x_sd'][0]:.0f}–"
                      f"{1000 * w['x_sd'][1]:.0f} (max {1000 * w['x_sd_max']:.0f}); {100 * w['nees_within']:.0f} %"
                      if w else "–")
                print(f"| {Path(row['folder']).name} | {name} | {kind} | {cells[0]} | {cells[1]} | "
                      f"{100 * n[0]:.1f} % ({n[1]}; {n[2]:.3f}) | {100 * f['pose_nees'][0]:.0f} % "
                      f"({f['pose_nees'][1]:.2f}) | {wc} | {f['traj'][0]:.3f} / {1000 * f['traj'][1]:.1f} | "
                      f"{f['chi2_per_dof']:.3f} | {f['smooth_s']:.1f} |")
    print("\n| run | plain: final fusion vs truth xy / θ (own; supports) | calibrated | plain = the demo's map |")
    print("|---|---|---|---|")
    for row in results:
        same = " / ".join(str(row["robots"][n]["plain_equals_demo"]) for n in ds.ROBOTS)
        print(f"| {Path(row['folder']).name} | {ds._cell(row['plain'])} | {ds._cell(row['calibrated'])} | {same} |")
    print()
    for kind in KINDS:
        rows = [row[kind] for row in results]
        found = [r for r in rows if r["found"]]
        wrong = sum(1 for r in found if r["error"][0] > 0.3 or r["error"][1] > 0.1)
        goal = sum(1 for r in found if r["error"][0] <= ds.GOAL_M and r["error"][1] <= ds.GOAL_RAD)
        figs = [row["robots"][n][kind] for row in results for n in row["robots"]]
        errs = [r["error"][0] for r in found]
        print(f"- {kind}: found {len(found)} of {len(rows)}, wrong {wrong}, within the goal {goal} (median error "
              f"{np.median(errs) if errs else float('nan'):.3f} m); maps with landmark NEES ≥ 90 % within: "
              f"{sum(f['nees'][0] >= 0.9 for f in figs)} of {len(figs)} (min "
              f"{100 * min(f['nees'][0] for f in figs):.1f} %); pose NEES ≥ 90 %: "
              f"{sum(f['pose_nees'][0] >= 0.9 for f in figs)} (median share "
              f"{100 * np.median([f['pose_nees'][0] for f in figs]):.0f} %); ATE median "
              f"{np.median([f['traj'][0] for f in figs]):.3f} m, heading rms median "
              f"{1000 * np.median([f['traj'][1] for f in figs]):.1f} mrad (max "
              f"{1000 * max(f['traj'][1] for f in figs):.1f}); smoothing s median "
              f"{np.median([f['smooth_s'] for f in figs]):.1f}")
    cal = [row["robots"][n] for row in results for n in row["robots"]]
    if cal:
        sd = np.array([c["calibrated"]["odometry_scales"] for c in cal])
        sig = np.array([c["calibrated"]["odometry_scale_sd"] for c in cal])
        z = (sd - np.array(MOCK_SCALES)) / sig
        print(f"- scales over {len(cal)} maps: s_d {sd[:, 0].mean():.4f} (range {sd[:, 0].min():.4f}–"
              f"{sd[:, 0].max():.4f}; σ median {np.median(sig[:, 0]):.4f}), s_θ {sd[:, 1].mean():.4f} (range "
              f"{sd[:, 1].min():.4f}–{sd[:, 1].max():.4f}; σ median {np.median(sig[:, 1]):.4f}); (estimate − mock) / σ "
              f"rms {np.sqrt(np.mean(z[:, 0] ** 2)):.2f} and {np.sqrt(np.mean(z[:, 1] ** 2)):.2f}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folders", nargs="+", type=Path,
                        help="p3at demo --log-sensors output folders (or an earlier run's ROOT/<folder>.json files)")
    parser.add_argument("--out", type=Path, default=Path("/tmp/demo-odometry-calibration"),
                        help="where the smoothed maps, the replay caches and each seed's JSON go "
                             "(default /tmp/demo-odometry-calibration)")
    parser.add_argument("--window", type=non_negative_float, nargs=2, default=(20.0, 37.0), metavar=("T0", "T1"),
                        help="seconds whose pose errors and σ are printed (default 20 37: seed 9's robot 1)")
    parser.add_argument("--diagnose", action="store_true",
                        help="also smooth with the odometry or the readings replaced by the truth (module docstring)")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = parser.parse_args(argv)
    if not args.window[0] < args.window[1]:
        parser.error(f"--window must be T0 < T1, not {args.window[0]:g} {args.window[1]:g}")
    if all(f.suffix == ".json" for f in args.folders):     # an earlier run's figures
        try:
            results = [json.loads(f.read_text()) for f in args.folders]
        except (OSError, ValueError) as exc:
            parser.error(f"cannot read the figures: {exc}")
    else:
        ds.refuse_non_demo_folders(parser, args.folders)
        results = run(args.folders, args.out, tuple(args.window), args.diagnose)
    if args.json:
        print(json.dumps(results, indent=1, default=float))
    else:
        print_table(results, tuple(args.window))
        print_diagnosis(results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
