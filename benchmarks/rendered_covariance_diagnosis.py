"""Why the rendered building's exported landmark covariances are overconfident: each landmark's error, split.

Run from the repository root (replays the rendered frames' cache of ``eval_slam_rendered --frames-cache``):

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.rendered_covariance_diagnosis --robot robot1 --seed 0
        [--frame-rate 3.75] [--frames-cache /tmp/d6/frames] [--set KEY=VALUE ...] [--json]

Every landmark l of the exported map (the most probable particle's, as ``eval_slam_rendered`` scores it) was
made at frame k from observation j. Its error against the scored truth p (the surface-point cluster behind the
first sighting, in the start frame) is split exactly into four parts, e = μ − p = e_snap + e_pose + e_obs + e_later:

- ``snap``:  p_exact − p, the scoring's own resolution (the exact point behind the pixel against the first point
  of its 5 cm cluster; not an error of the filter);
- ``pose``:  T̂_k(z_true) − p_exact, the best particle's pose error at the creation frame carried to the
  landmark (shared by every landmark made in that stretch: the drift);
- ``obs``:   R̂_k (z_obs − z_true), the front end's triangulation error of the creating observation (along the
  pixel's ray: the truth is the point behind the same pixel);
- ``later``: μ − T̂_k(z_obs), what later updates and merges did (observations of slid corners and from drifted
  poses averaged in, the EKF shrinking meanwhile).

Each part against what the filter claims for it: ``pose`` against C_l (the drift term at creation, 2-D NEES,
χ²₂ 95 % = 5.991), ``obs`` against the claimed observation covariance R̂ Q R̂ᵀ (with the floor; χ²₃), ``obs +
later`` against the particle's own EKF covariance Σ_m (the error given its trajectory), the whole against the
export (χ²₃ 95 % = 7.815). "Coverage without X": the share within the bound if part X were zero (which part
the misses come from). ``slide``: the true points of the best particle's later matches of l, their centroid
against p (a corner that slides along the texture with the viewing distance, averaged in by the EKF).

Pose: the cloud's mean against the truth per frame; NEES against the cloud's covariance (what ``simulate``
reports, whose error is in the estimate's own frame: also given in the start frame, the covariance's frame) and
against the drift tracker's D_r (the pose's uncertainty relative to the start frame that the export uses); the
heading error's mean and spread beside the cloud's heading σ (particle depletion: spread ≪ error; a bias: mean ≫
spread of the error).
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

from benchmarks.config_overrides import config_overrides
from benchmarks.eval_slam_rendered import CALIBRATION, replay_through
from estimation.fastslam import FastSLAM, FastSLAMConfig
from estimation.geometry import between, compose, rot_z, wrap_angle
from runtime.commands.options import non_negative_int, positive_float

CHI2_2_95, CHI2_3_95 = 5.991, 7.815
DEPTH_BANDS = (0.0, 2.0, 4.0, 6.0, 13.0)   # m, the creating observation's depth (base_link x)


class _RecordingFastSLAM(FastSLAM):
    """Keeps every update's report and the drift tracker's pose covariance D_r after it."""

    last: _RecordingFastSLAM | None = None

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.reports, self.robot_drift = [], []
        _RecordingFastSLAM.last = self

    def update(self, observations):
        report = super().update(observations)
        self.reports.append(report)
        self.robot_drift.append(self.drift.robot.copy())
        return report


def _nees(e: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """eᵀ C⁻¹ e per row, (N, d) with (N, d, d); inf where C is singular."""
    out = np.full(len(e), np.inf)
    ok = np.linalg.det(cov) > 1e-30
    if ok.any():
        out[ok] = np.einsum("ni,ni->n", e[ok], np.linalg.solve(cov[ok], e[ok][..., None])[..., 0])
    return out


def run(robot: str, seed: int, frame_rate: float, frames_cache: Path, config: FastSLAMConfig) -> dict:
    """Replay one robot's cached frames through the filter and split every exported landmark's error."""
    from drivers.videre import calibration
    from mocks.stereo_head.renderer import StereoRenderer
    from mocks.world import World

    world = World.load()
    observer, start, result, slam = replay_through(_RecordingFastSLAM, world, robot, seed, frame_rate,
                                                   frames_cache, config)
    frames, starts = observer._arrays, observer._starts
    renderer = StereoRenderer(world, calibration.load(CALIBRATION))
    lmap = result.map
    lids = np.asarray(lmap.ids, np.int64)

    made: dict[int, tuple[int, int]] = {}          # landmark id -> (frame, observation)
    for k, report in enumerate(slam.reports):
        for j in np.flatnonzero(report.new_landmark_ids >= 0):
            made.setdefault(int(report.new_landmark_ids[j]), (k, int(j)))
    # later matches of each landmark by the frame's most probable particle: their true points' centroid
    matched_points: dict[int, list[int]] = {}
    for k, report in enumerate(slam.reports):
        index = frames["index"][starts[k]:starts[k + 1]]
        for j in np.flatnonzero(report.best_matches >= 0):
            if index[j] >= 0:
                matched_points.setdefault(int(report.best_matches[j]), []).append(int(index[j]))

    trajectory = slam.trajectory()                  # (T, 4) start frame, row 0 the initial pose
    true_start = np.array([between(start, p) for p in frames["pose"]])   # true poses in the start frame
    to_start = rot_z(start[2]).T
    points = observer.points
    keep, rows = [], []
    for i, lid in enumerate(lids):
        if int(lid) not in made:
            continue
        k, j = made[int(lid)]
        g = starts[k] + j
        if frames["index"][g] < 0:
            continue
        exact_world = renderer.true_points(frames["pose"][k], frames["pixels"][g][None], "left", rectified=True)[0]
        if not np.all(np.isfinite(exact_world)):
            continue
        cluster = (points[frames["index"][g]] - [start[0], start[1], 0.0]) @ to_start.T
        exact = (exact_world - [start[0], start[1], 0.0]) @ to_start.T
        tp, ep = true_start[k], trajectory[k + 1, 1:]
        z_true = (exact - [tp[0], tp[1], 0.0]) @ rot_z(tp[2])               # Rᵀ (p − t)
        r_est = rot_z(ep[2])
        z_obs = frames["points"][g]
        q = config.observation_cov_scale * frames["covariances"][g] + config.observation_var_floor * np.eye(3)
        mapped = lambda z, r=r_est, p=ep: r @ z + [p[0], p[1], 0.0]   # noqa: E731
        slid = matched_points.get(int(lid), [])
        slide = (np.mean((points[slid] - [start[0], start[1], 0.0]) @ to_start.T, axis=0) - cluster) if slid \
            else np.zeros(3)
        keep.append(i)
        rows.append(dict(snap=exact - cluster, pose=mapped(z_true) - exact, obs=r_est @ (z_obs - z_true),
                         later=lmap.positions[i] - mapped(z_obs), q=r_est @ q @ r_est.T, depth=float(z_obs[0]),
                         slide=slide, matches=len(slid), frame=k))
    keep = np.array(keep, np.int64)
    stack = {key: np.array([r[key] for r in rows]) for key in rows[0]} if rows else {}
    export = lmap.covariances[keep]
    particle = np.array([c for c in slam.particle_map(slam._best, config.confirm_count,
                                                       covariance="particle").covariances])
    particle_of = {int(l_): c for l_, c in zip(slam.particle_map(slam._best, config.confirm_count).ids, particle,
                                               strict=True)}
    sigma_m = np.array([particle_of[int(lids[i])] for i in keep])
    drift_c = slam.drift.landmark_covariances(lids[keep])
    total = stack["snap"] + stack["pose"] + stack["obs"] + stack["later"]
    nees_total = _nees(total, export)
    parts = {"snap": stack["snap"], "pose": stack["pose"], "obs": stack["obs"], "later": stack["later"]}
    without = {name: float(np.mean(_nees(total - part, export) < CHI2_3_95)) for name, part in parts.items()}
    without["pose+snap"] = float(np.mean(_nees(total - parts["pose"] - parts["snap"], export) < CHI2_3_95))
    norms = {name: np.linalg.norm(part, axis=1) for name, part in parts.items()}
    nees_pose = _nees(parts["pose"][:, :2], drift_c[:, :2, :2])
    nees_obs = _nees(parts["obs"], stack["q"])
    nees_local = _nees(parts["obs"] + parts["later"], sigma_m)
    shrink = np.sqrt(np.trace(sigma_m, axis1=1, axis2=2) / np.trace(stack["q"], axis1=1, axis2=2))
    depth = stack["depth"]
    by_depth = []
    for lo, hi in zip(DEPTH_BANDS[:-1], DEPTH_BANDS[1:], strict=True):
        sel = (depth >= lo) & (depth < hi)
        if not sel.any():
            continue
        by_depth.append({"depth_m": f"{lo:g}-{hi:g}", "n": int(sel.sum()),
                         "within_bound": float(np.mean(nees_total[sel] < CHI2_3_95)),
                         **{f"{name}_median_m": float(np.median(norms[name][sel])) for name in parts},
                         "slide_median_m": float(np.median(np.linalg.norm(stack["slide"][sel], axis=1))),
                         "obs_nees_within": float(np.mean(nees_obs[sel] < CHI2_3_95)),
                         "local_nees_within": float(np.mean(nees_local[sel] < CHI2_3_95)),
                         "claimed_obs_sigma_median_m": float(np.median(np.sqrt(np.trace(stack["q"][sel], axis1=1,
                                                                                        axis2=2)))),
                         "ekf_sigma_median_m": float(np.median(np.sqrt(np.trace(sigma_m[sel], axis1=1,
                                                                                axis2=2))))})
    return {"robot": robot, "seed": seed, "ate_m": result.metrics["ate_m"], "landmarks": len(lmap),
            "scored": len(keep), "within_bound": float(np.mean(nees_total < CHI2_3_95)),
            "nees_median": float(np.median(nees_total)),
            "median_m": {name: float(np.median(v)) for name, v in norms.items()},
            "p90_m": {name: float(np.percentile(v, 90)) for name, v in norms.items()},
            "total_median_m": float(np.median(np.linalg.norm(total, axis=1))),
            "slide_median_m": float(np.median(np.linalg.norm(stack["slide"], axis=1))),
            "within_if_zero": without,
            "pose_nees2_within": float(np.mean(nees_pose < CHI2_2_95)),
            "pose_nees2_median": float(np.median(nees_pose)),
            "obs_nees_within": float(np.mean(nees_obs < CHI2_3_95)),
            "obs_nees_median": float(np.median(nees_obs)),
            "local_nees_within": float(np.mean(nees_local < CHI2_3_95)),
            "local_nees_median": float(np.median(nees_local)),
            "ekf_over_obs_sigma_median": float(np.median(shrink)),
            "matches_median": float(np.median(stack["matches"])),
            "by_depth": by_depth, **_pose_figures(slam, result, start),
            "observations": observation_errors(frames, starts, renderer, config),
            "translation": translation_drift(slam, result, start)}


def observation_errors(frames: dict, starts: np.ndarray, renderer, config: FastSLAMConfig) -> dict:
    """Every cached observation against the exact point behind its pixel: the along-ray error normalised by the
    claimed σ (floor included) and its lag-1 correlation over pairs of one surface point seen in successive frames
    (what ``observation_correlation`` takes), overall and by depth; share of gross errors (|r| > 4)."""
    n = len(frames["points"])
    z_true = np.full((n, 3), np.nan)
    for k in range(len(frames["t"])):
        lo, hi = starts[k], starts[k + 1]
        if hi > lo:
            p, pose = renderer.true_points(frames["pose"][k], frames["pixels"][lo:hi], "left", rectified=True), \
                frames["pose"][k]
            z_true[lo:hi] = (p - [pose[0], pose[1], 0.0]) @ rot_z(pose[2])
    q = config.observation_cov_scale * frames["covariances"] + config.observation_var_floor * np.eye(3)
    ray = frames["points"] - np.asarray(config.sensor_offset)
    u = ray / np.linalg.norm(ray, axis=1)[:, None]
    r = np.einsum("ni,ni->n", frames["points"] - z_true, u) / np.sqrt(np.einsum("ni,nij,nj->n", u, q, u))
    frame_of = np.repeat(np.arange(len(frames["t"])), frames["count"])
    last: dict[int, int] = {}
    pairs = []
    for g in np.flatnonzero(np.isfinite(r) & (frames["index"] >= 0)):
        c = int(frames["index"][g])
        if c in last and frame_of[last[c]] == frame_of[g] - 1:
            pairs.append((last[c], g))
        last[c] = g
    pairs = np.array(pairs, np.int64).reshape(-1, 2)
    bulk = (np.abs(r[pairs[:, 0]]) < 4) & (np.abs(r[pairs[:, 1]]) < 4)   # gross mismatches would dominate ρ
    depth = frames["points"][:, 0]
    out = {"pairs": len(pairs), "correlation": float(np.corrcoef(r[pairs[bulk, 0]], r[pairs[bulk, 1]])[0, 1]),
           "normalised_sd": float(np.std(r[np.abs(r) < 4])),
           "gross_share": float(np.mean(np.abs(r[np.isfinite(r)]) > 4)),
           "by_depth": []}
    for lo, hi in zip(DEPTH_BANDS[:-1], DEPTH_BANDS[1:], strict=True):
        sel = bulk & (depth[pairs[:, 0]] >= lo) & (depth[pairs[:, 0]] < hi)
        one = np.isfinite(r) & (depth >= lo) & (depth < hi)
        if sel.sum() > 2:
            out["by_depth"].append({"depth_m": f"{lo:g}-{hi:g}", "pairs": int(sel.sum()),
                                    "correlation": float(np.corrcoef(r[pairs[sel, 0]], r[pairs[sel, 1]])[0, 1]),
                                    "normalised_sd": float(np.std(r[one & (np.abs(r) < 4)])),
                                    "gross_share": float(np.mean(np.abs(r[one]) > 4))})
    return out


def _pose_figures(slam: _RecordingFastSLAM, result, start: np.ndarray) -> dict:
    """The cloud's pose NEES (as simulate reports it, and in the start frame) and against D_r; heading error."""
    truth = result.true_trajectory[1:, 1:]
    n = min(len(truth), len(slam.reports))
    body, frame, drift, heading, cloud_heading_sd, drift_heading_sd, trace = [], [], [], [], [], [], []
    for k in range(n):
        report = slam.reports[k]
        mean, cov = report.pose_mean, report.pose_covariance
        true_local = between(start, truth[k])
        e_start = true_local - mean
        e_start[2] = wrap_angle(e_start[2])
        e_body = between(compose(start, mean), truth[k])
        e_body[2] = wrap_angle(e_body[2])
        if np.linalg.cond(cov) < 1e12:
            body.append(float(e_body @ np.linalg.solve(cov, e_body)))
            frame.append(float(e_start @ np.linalg.solve(cov, e_start)))
        drift.append(float(_nees(e_start[None], slam.robot_drift[k][None])[0]))
        heading.append(e_start[2])
        trace.append([result.true_trajectory[k + 1, 0], float(np.hypot(*e_start[:2])),
                      float(np.sqrt(slam.robot_drift[k][0, 0] + slam.robot_drift[k][1, 1])), float(e_start[2]),
                      float(np.sqrt(slam.robot_drift[k][2, 2]))])
        cloud_heading_sd.append(np.sqrt(cov[2, 2]))
        drift_heading_sd.append(np.sqrt(slam.robot_drift[k][2, 2]))
    heading = np.array(heading)
    return {"pose_nees_cloud_median": float(np.median(body)), "pose_nees_cloud_start_frame_median":
            float(np.median(frame)), "pose_nees_cloud_within": float(np.mean(np.array(frame) < CHI2_3_95)),
            "pose_nees_drift_median": float(np.median(drift)),
            "pose_nees_drift_within": float(np.mean(np.array(drift) < CHI2_3_95)),
            "heading_error_mean_rad": float(np.mean(heading)), "heading_error_sd_rad": float(np.std(heading)),
            "heading_error_abs_median_rad": float(np.median(np.abs(heading))),
            "cloud_heading_sd_median_rad": float(np.median(cloud_heading_sd)),
            "drift_heading_sd_median_rad": float(np.median(drift_heading_sd)),
            "pose_trace": trace}   # per frame: t (s), |position error| (m), D_r's position σ (m), heading error, σ


def _print(r: dict) -> None:
    print(f"\n{r['robot']} seed {r['seed']}: ATE {r['ate_m']:.3f} m, {r['landmarks']} landmarks "
          f"({r['scored']} scored), within the χ²₃ 95 % bound {100 * r['within_bound']:.0f} %, "
          f"NEES median {r['nees_median']:.1f}; |e| median {r['total_median_m']:.3f} m")
    print("| part | median \\|e\\| (m) | p90 (m) | within bound if this part were zero | its own NEES (against) |")
    print("|---|---|---|---|---|")
    own = {"snap": "—", "pose": f"{100 * r['pose_nees2_within']:.0f} % (median {r['pose_nees2_median']:.1f}; "
           "C_l, χ²₂)", "obs": f"{100 * r['obs_nees_within']:.0f} % (median {r['obs_nees_median']:.2f}; claimed Q)",
           "later": f"obs + later: {100 * r['local_nees_within']:.0f} % (median {r['local_nees_median']:.1f}; Σ_m)"}
    for name in ("snap", "pose", "obs", "later"):
        print(f"| {name} | {r['median_m'][name]:.3f} | {r['p90_m'][name]:.3f} | "
              f"{100 * r['within_if_zero'][name]:.0f} % | {own[name]} |")
    print(f"| pose + snap | | | {100 * r['within_if_zero']['pose+snap']:.0f} % | |")
    print(f"slide of later matches' true points (centroid vs first): median {r['slide_median_m']:.3f} m over "
          f"{r['matches_median']:.0f} matches; EKF σ / claimed observation σ median "
          f"{r['ekf_over_obs_sigma_median']:.2f}")
    print("| depth (m) | n | within | snap | pose | obs | later | slide | obs NEES within | (obs+later) vs Σ_m within |"
          " claimed obs σ | EKF σ |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for b in r["by_depth"]:
        print(f"| {b['depth_m']} | {b['n']} | {100 * b['within_bound']:.0f} % | {b['snap_median_m']:.3f} | "
              f"{b['pose_median_m']:.3f} | {b['obs_median_m']:.3f} | {b['later_median_m']:.3f} | "
              f"{b['slide_median_m']:.3f} | {100 * b['obs_nees_within']:.0f} % | {100 * b['local_nees_within']:.0f} % |"
              f" {b['claimed_obs_sigma_median_m']:.3f} | {b['ekf_sigma_median_m']:.3f} |")
    print(f"pose NEES median: cloud {r['pose_nees_cloud_median']:.0f} (as simulate: error in the estimate's frame), "
          f"{r['pose_nees_cloud_start_frame_median']:.0f} in the start frame ({100 * r['pose_nees_cloud_within']:.0f} %"
          f" within); against D_r {r['pose_nees_drift_median']:.1f} "
          f"({100 * r['pose_nees_drift_within']:.0f} % within)")
    print(f"heading error: mean {r['heading_error_mean_rad']:+.4f} rad, sd {r['heading_error_sd_rad']:.4f}, "
          f"|median| {r['heading_error_abs_median_rad']:.4f}; cloud heading σ median "
          f"{r['cloud_heading_sd_median_rad']:.4f}, D_r heading σ median {r['drift_heading_sd_median_rad']:.4f}")


def translation_drift(slam: _RecordingFastSLAM, result, start: np.ndarray,
                      windows: tuple[int, ...] = (3, 7, 14, 28)) -> dict:
    """The best particle's position error increments over windows of W frames, less what the heading error at the
    window's start explains (its lever over the true displacement), against the distance driven: rms² = a + b·d
    fitted over the windows; b / 2 is the random walk per axis and metre (``drift_translation_per_m``), a the
    per-frame jitter."""
    est = slam.trajectory()[1:, 1:]
    truth = np.array([between(start, p) for p in result.true_trajectory[1:, 1:]])[:len(est)]
    e = truth - est
    e[:, 2] = wrap_angle(e[:, 2])
    step = np.linalg.norm(np.diff(truth[:, :2], axis=0), axis=1)
    d, ms = [], []
    for w in windows:
        k = np.arange(0, len(e) - w, w)
        dp = truth[k + w, :2] - truth[k, :2]
        inc = e[k + w, :2] - e[k, :2] - e[k, 2:3] * np.column_stack([-dp[:, 1], dp[:, 0]])
        dist = np.array([step[i:i + w].sum() for i in k])
        moving = dist > 0.05 * w
        d.append(float(dist[moving].mean()))
        ms.append(float(np.mean(np.sum(inc[moving] ** 2, axis=1))))
    b, a = np.polyfit(d, ms, 1)
    return {"windows_m": d, "rms_m": [float(np.sqrt(v)) for v in ms], "per_axis_m2_per_m": float(b / 2),
            "jitter_m2": float(a)}


def _print_trace(r: dict, every: int) -> None:
    print("| t (s) | position error (m) | D_r position σ (m) | heading error (rad) | D_r heading σ (rad) |")
    print("|---|---|---|---|---|")
    for t, e, s, h, sh in r["pose_trace"][::every]:
        print(f"| {t:.1f} | {e:.3f} | {s:.3f} | {h:+.4f} | {sh:.4f} |")


def _print_observations(o: dict) -> None:
    print(f"observations against the point behind the pixel: along-ray error / claimed σ sd {o['normalised_sd']:.2f} "
          f"(|r| < 4), gross (|r| > 4) {100 * o['gross_share']:.1f} %; lag-1 correlation over {o['pairs']} "
          f"successive-frame pairs of one point {o['correlation']:.2f}")
    print("| depth (m) | pairs | lag-1 correlation | sd of r | gross |")
    print("|---|---|---|---|---|")
    for b in o["by_depth"]:
        print(f"| {b['depth_m']} | {b['pairs']} | {b['correlation']:.2f} | {b['normalised_sd']:.2f} | "
              f"{100 * b['gross_share']:.1f} % |")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", action="append", default=[], help="route name (repeatable; default both)")
    parser.add_argument("--seed", type=non_negative_int, action="append", default=[], help="repeatable; default 0")
    parser.add_argument("--frame-rate", type=positive_float, default=3.75)
    parser.add_argument("--frames-cache", type=Path, default=Path("/tmp/d6/frames"))
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--trace", type=non_negative_int, default=0, metavar="N",
                        help="also print the pose error beside D_r every N frames")
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    config = replace(FastSLAMConfig(max_observations=0), **config_overrides(args.set))
    out = [run(robot, seed, args.frame_rate, args.frames_cache, config)
           for seed in (args.seed or [0]) for robot in (args.robot or ["robot1", "robot2"])]
    if args.json:
        print(json.dumps(out, indent=1))
    else:
        for r in out:
            _print(r)
            _print_observations(r["observations"])
            t = r["translation"]
            print("position error increments the heading's lever does not explain: rms "
                  + ", ".join(f"{m:.3f} m over {w:.2f} m" for m, w in zip(t["rms_m"], t["windows_m"], strict=True))
                  + f"; fit: {t['per_axis_m2_per_m']:.2e} m² per axis per m driven (drift_translation_per_m), "
                  f"jitter {t['jitter_m2']:.1e} m²")
            if args.trace > 0:
                _print_trace(r, args.trace)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
