"""Why MRCLAM known-ID maps fail the landmark NEES bound: the map frame's error against the drift the export claims.

Run from the repository root:

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.mrclam_nees_diagnosis [--robots 1,2,3,4,5] [--seeds 0,1]
        [--set FIELD=VALUE ...] [--export-lever] [--one-landmark-heading] [--no-windows] [--landmarks] [--pinning T0,T1]
        [--nis [--dump DIR]] [--calibrated] [--json]

Each robot runs through `p3at slam dataset`'s code path (``run_landmark_log``, known-ID association, own noise
model) with the filter recorded at every update. For every landmark of the exported map:

- its error e in the start frame, split into the *frame part* f (where the landmark would be if it were placed
  exactly, relative to the pose that made it, from that pose as the final best particle's ancestry has it:
  f = x̂_c ⊕ (x_c ⊖ p) − p, x_c the true creation pose, x̂_c the estimated one, p the true landmark) and the
  *shape part* e − f (how far the landmark sits from the truth relative to the pose that made it);
- the NEES of e under the exported covariance Σ + C_l, of f under C_l = H D_l Hᵀ (the drift's share), of e − f
  under Σ (the mixture's share), and the pose NEES (χ²₃) of the creation pose's error under D_l;
- the same split for the landmarks outside the χ²₂ 95 % bound.

And per run: the live best particle's pose error against the drift tracker's D_r at every frame (χ²₃, the
position's χ²₂ and the heading's e_θ²/D_θθ; by the number of landmarks the frame matched, with the sum of the
log-changes of D_r's heading variance in the update), and whether the motion model covers dead reckoning over
windows of 5-120 s (the noise model's random walk is fitted on 5 s windows; MRCLAM's odometry errors are correlated
over longer spans). The ``eval_*`` figures are `eval_mrclam`'s (the same ``map_scores``).

``--export-lever``: ``FastSLAMConfig.drift_export="lever"``, the tracker ``export_drift.ExportLeverDriftTracker`` (the
gate reads the plain tracker, so every estimate is the same; the export carries the heading's lever);
``--one-landmark-heading``: ``drift_export="lever+heading"`` (docs/fastslam-history.md, "Session 13 ... (N)"). The
``export_drift`` figures are the live pose against that tracker's D_r. Without either flag the run uses
``range_bearing_config``'s export ("lever+heading+relative" since session 14); ``--set 'drift_export="plain"'`` gives
the plain tracker's.

``--nis`` (docs/fastslam-history.md, "Session 14 ... (I)"): every landmark update in every particle is recorded (the
innovation ν at the sampled pose and the S = Σ + R Q Rᵀ ``_ekf_update`` uses, the gate's d² of the same pair), the
final best particle's ancestry is traced through the resamplings' parents, and per landmark of the map its updates
there are tested (``innovation_consistency.py``: the NIS against χ²₂, the a-posteriori variance factor, the
whiteness); with the shape part's size and the particle's σ when it was placed, after 10 updates, half-way and at
the end; and the within-bound fraction if the export's mixture part were scaled by factors the innovations give, or
held at the particle's Σ after its first n updates. ``--calibrated``: the noise model fitted with eval_mrclam's
three calibrations (range, heading bias, odometry lag).
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

from benchmarks.config_overrides import config_overrides  # noqa: E402
from benchmarks.eval_mrclam import DATA  # noqa: E402
from benchmarks.output_paths import output_refusal  # noqa: E402
from estimation import dataset_slam  # noqa: E402
from estimation.datasets import read_mrclam  # noqa: E402
from estimation.fastslam import FastSLAM, range_bearing_config  # noqa: E402
from estimation.fastslam.innovation_consistency import (  # noqa: E402
    block_variance_ratio,
    lag1_correlation,
    normalised_innovations,
    variance_factor,
)
from estimation.fastslam.lever_drift import correlated_mean_factor  # noqa: E402
from estimation.fastslam.linalg import sym_matrices, sym_rotate_z  # noqa: E402
from estimation.fastslam.motion import increment_variance, propagate_covariance  # noqa: E402
from estimation.geometry import between, compose, wrap_angle  # noqa: E402
from estimation.landmark_scores import CHI2_95, points_nees  # noqa: E402
from estimation.noise_estimation import estimate_noise  # noqa: E402
from estimation.noise_model import with_fastslam  # noqa: E402

WINDOWS_S = (5.0, 20.0, 60.0, 120.0)


class RecordingFastSLAM(FastSLAM):
    """FastSLAM that keeps, after every update, the drift tracker's D_r, the best particle's pose and the ids made."""

    last: RecordingFastSLAM | None = None
    keep_estimates = False               # --pinning: keep the matched landmarks' estimates per frame

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.frames: list[dict] = []
        self.nis_rows: list[np.ndarray] = []   # --nis: one row per landmark update (all particles), see nis_rows
        self._gate_d2: tuple[np.ndarray, np.ndarray] | None = None
        self._parents: np.ndarray | None = None
        resample = self.store.resample

        def recording_resample(parents):   # the raw parents (the history's are re-indexed when it is pruned)
            self._parents = np.asarray(parents).copy()
            return resample(parents)
        self.store.resample = recording_resample
        RecordingFastSLAM.last = self

    def _gate(self, frame, poses, m, mj, mean, cov):
        out = super()._gate(frame, poses, m, mj, mean, cov)
        self._gate_d2 = (np.asarray(mj).copy(), out[3].copy())   # the gate's d² (predicted pose, with P's term)
        return out

    def _ekf_update(self, matched, predicted, poses, z, q6, mean, sigma, s_inv):
        if len(matched.m):
            self.nis_rows.append(update_nis(self, matched, poses, z, q6, mean, sigma))
        return super()._ekf_update(matched, predicted, poses, z, q6, mean, sigma, s_inv)

    def update(self, observations, *args, **kwargs):
        predicted = self.drift.robot.copy()
        self._parents = None
        n_rows = len(self.nis_rows)
        report = super().update(observations, *args, **kwargs)
        k = len(self.frames)
        for rows in self.nis_rows[n_rows:]:
            rows[:, 0] = k
        parents = self._parents if report.resampled else np.arange(len(self.poses))
        lever = getattr(self.drift, "lever_robot", None)   # the export's D_r (ExportLeverDriftTracker)
        self.frames.append({"robot_drift": self.drift.robot.copy(), "best_pose": self.poses[self._best].copy(),
                            "export_drift": None if lever is None else lever.copy(), "predicted_drift": predicted,
                            "matched": len(np.unique(report.best_matches[report.best_matches >= 0])),
                            "matched_ids": np.unique(report.best_matches[report.best_matches >= 0]),
                            "new": np.unique(report.new_landmark_ids[report.new_landmark_ids >= 0]),
                            "parents": parents, "resampled": bool(report.resampled)})
        if self.keep_estimates:   # the best particle's estimate of each landmark it matched (--pinning)
            self.frames[-1]["estimates"] = {int(lid): self.store.flat_state[self.store.flat_lid == lid][:1, :2].copy()
                                            for lid in self.frames[-1]["matched_ids"]}
        return report


CAPS = (5, 10, 20, 50)
NIS_COLUMNS = ("frame", "particle", "lid", "nis", "gate_d2", "count", "sd_m", "nu_x", "nu_y", "s_xx", "s_xy", "s_yy",
               "mean_x", "mean_y", "cov_xx", "cov_xy", "cov_yy")


def update_nis(slam: RecordingFastSLAM, matched, poses, z, q6, mean, sigma) -> np.ndarray:
    """One row per landmark update (NIS_COLUMNS): the planar NIS νᵀ S⁻¹ ν of the innovation the EKF uses (at the
    sampled pose, S = Σ + R Q Rᵀ as ``_ekf_update`` forms it in FastSLAM 2.0), the gate's d² of the same pair (at
    the predicted pose, S with the pose's term H P Hᵀ), the landmark's sightings and σ before the update. The
    range-bearing reading's height is a fixed 0 (``_Z_VARIANCE``), so both have two degrees of freedom (χ²₂)."""
    m, j = matched.m, matched.j
    pose = poses[m]
    c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    nu = np.stack([c * z[j, 0] - s * z[j, 1] + pose[:, 0] - mean[0], s * z[j, 0] + c * z[j, 1] + pose[:, 1] - mean[1]],
                  axis=1)
    big_s = sym_matrices(sigma + sym_rotate_z(c, s, q6[:, j]))[:, :2, :2]
    _, nis = normalised_innovations(nu, big_s)
    gate = np.full(len(m), np.nan)
    if slam._gate_d2 is not None:
        keys, d2 = slam._gate_d2
        order = np.argsort(keys, kind="stable")
        want = m * len(z) + j
        at = np.clip(np.searchsorted(keys[order], want), 0, max(len(keys) - 1, 0))
        if len(keys):
            hit = keys[order][at] == want
            gate[hit] = d2[order][at][hit]
    return np.stack([np.full(len(m), -1.0), m, slam.store.flat_lid[matched.g], nis, gate,
                     slam.store.flat_count[matched.g], np.sqrt(0.5 * (sigma[0] + sigma[3])), nu[:, 0], nu[:, 1],
                     big_s[:, 0, 0], big_s[:, 0, 1], big_s[:, 1, 1], mean[0], mean[1], sigma[0], sigma[1], sigma[3]],
                    axis=1)


def lineage_nis(slam: RecordingFastSLAM) -> dict[int, np.ndarray]:
    """The landmark updates of the final best particle's ancestry, by landmark id: rows (NIS_COLUMNS) in time order.
    At frame k the update was made in particle parents_k[i_k] (before the resampling), i_k its index after it."""
    rows = np.concatenate(slam.nis_rows) if slam.nis_rows else np.zeros((0, len(NIS_COLUMNS)))
    ancestor = np.empty(len(slam.frames), np.int64)
    i = slam._best
    for k in range(len(slam.frames) - 1, -1, -1):
        ancestor[k] = slam.frames[k]["parents"][i]
        i = ancestor[k]
    on = rows[:, 1].astype(np.int64) == ancestor[rows[:, 0].astype(np.int64)]
    rows = rows[on]
    return {int(lid): rows[rows[:, 2] == lid] for lid in np.unique(rows[:, 2])}


def innovation_whiteness(u: np.ndarray) -> tuple[float, float]:
    """One landmark's updates (rows NIS_COLUMNS, time order): the lag-1 correlation ρ of its whitened innovations
    S^(-1/2) ν and the variance ratio of sums of 50 successive ones (innovation_consistency.py: 0 and 1 if white)."""
    c = {n: i for i, n in enumerate(NIS_COLUMNS)}
    nu = u[:, [c["nu_x"], c["nu_y"]]]
    s = np.stack([u[:, [c["s_xx"], c["s_xy"]]], u[:, [c["s_xy"], c["s_yy"]]]], axis=1)
    w, _ = normalised_innovations(nu, s)
    return lag1_correlation(w), block_variance_ratio(w, 50)


def nis_summary(split_rows: list[dict], by_lid: dict[int, np.ndarray], slam: RecordingFastSLAM) -> dict:
    """Does the update's NIS see the shape part? Per landmark of the map, over its updates in the final best
    particle's ancestry: the mean NIS (χ²₂: 2), the fraction above χ²₂'s 95 % bound, the gate's d², the innovations'
    whiteness (:func:`innovation_whiteness`); for the landmarks whose shape part is outside the bound under the
    mixture Σ ("shape_out") and for the others. When the shape part arises: its size and the particle's σ at the
    landmark's first update (the placement), after 10 updates, half-way and at the end (the shape part at update
    i is μ_i − μ_end + (e − f)). And the export-only variants' figures, the mixture's part of the exported
    covariance scaled by a factor ≥ 1 (the drift's C_l kept): the a-posteriori variance factor F = Σ NIS / (2 n),
    the AR(1) (Bartlett) factor of ρ (lever_drift.correlated_mean_factor), the 50-update ratio, and a cap on the
    readings' count: the mixture no smaller (in trace) than the particle's Σ after the landmark's first n updates
    (``cap{n}``, n in CAPS)."""
    bound = CHI2_95[2]
    c = {n: i for i, n in enumerate(NIS_COLUMNS)}
    resampled = np.array([f["resampled"] for f in slam.frames])
    out: dict = {"resampled_frames": float(np.mean(resampled))}
    per = []
    for r in split_rows:
        u = by_lid.get(r["lid"])
        if u is None or not len(u):
            continue
        u = u[np.argsort(u[:, 0], kind="stable")]
        nis = u[:, c["nis"]]
        rho, ratio50 = innovation_whiteness(u)
        e, f = np.array(r["e"]), np.array(r["f"])
        mixture, drift = np.array(r["mixture"]), np.array(r["drift"])
        means = u[:, [c["mean_x"], c["mean_y"]]]
        shape_then = np.hypot(*(means - means[-1] + (e - f)).T)          # before each update
        sd_then = np.sqrt(0.5 * (u[:, c["cov_xx"]] + u[:, c["cov_yy"]]))

        def scaled(factor: float, e=e, mixture=mixture, drift=drift) -> float:
            return float(points_nees(e[None], (max(factor, 1.0) * mixture + drift)[None])[0])
        after_resampling = resampled[np.maximum(u[:, 0].astype(np.int64) - 1, 0)]
        half = len(u) // 2
        factors = {"nis": variance_factor(nis, 2),
                   "bartlett": float(correlated_mean_factor(np.array([len(u)]), min(max(rho, 0.0), 0.99))[0]),
                   "ratio50": ratio50 if np.isfinite(ratio50) else 1.0}
        for cap in CAPS:   # the landmark's σ no smaller than after its first `cap` updates (an effective count)
            at = min(cap, len(u) - 1)
            factors[f"cap{cap}"] = float((u[at, c["cov_xx"]] + u[at, c["cov_yy"]]) / max(np.trace(mixture), 1e-300))
        per.append({"shape_out": r["shape_nees"] >= bound, "updates": len(u), "nis_mean": float(np.mean(nis)),
                    "nis_over": float(np.mean(nis > bound)), "gate_mean": float(np.nanmean(u[:, c["gate_d2"]])),
                    "nis_first10": float(np.mean(nis[:10])), "nis_after_resampling":
                    float(np.mean(nis[after_resampling])) if after_resampling.any() else np.nan,
                    "nis_not_after_resampling": float(np.mean(nis[~after_resampling]))
                    if (~after_resampling).any() else np.nan,
                    "rho": rho, "ratio50": ratio50,
                    "shape_m_first": float(shape_then[0]), "shape_m_10": float(shape_then[min(10, len(u) - 1)]),
                    "shape_m_half": float(shape_then[half]), "shape_m_end": float(np.hypot(*(e - f))),
                    "sd_m_first": float(sd_then[0]), "sd_m_10": float(sd_then[min(10, len(u) - 1)]),
                    "sd_m_half": float(sd_then[half]),
                    "needed_factor": float(r["shape_nees"] / bound),
                    **{f"factor_{k}": v for k, v in factors.items()},
                    **{f"nees_{k}": scaled(v) for k, v in factors.items()}, "nees": r["nees"]})
        r["nis_mean"], r["nis_updates"], r["rho"], r["ratio50"] = per[-1]["nis_mean"], len(u), rho, ratio50
    if not per:
        return out
    a = {k: np.array([p[k] for p in per], float) for k in per[0]}
    for label, sel in (("shape_out", a["shape_out"] > 0), ("shape_in", a["shape_out"] == 0)):
        if sel.any():
            out[f"{label}_landmarks"] = int(sel.sum())
            for k in per[0]:
                if k not in ("shape_out", "nees") and not k.startswith("nees_"):
                    out[f"{label}_{k}_median"] = float(np.nanmedian(a[k][sel]))
    all_nis = np.concatenate([u[:, c["nis"]] for u in by_lid.values()])
    out.update({"updates": len(all_nis), "nis_mean_all": float(np.mean(all_nis)),
                "nis_over_all": float(np.mean(all_nis > bound)), "within": float(np.mean(a["nees"] < bound)),
                "nees_median": float(np.median(a["nees"]))})
    for k in ("nis", "bartlett", "ratio50", *(f"cap{cap}" for cap in CAPS)):
        out[f"within_scaled_{k}"] = float(np.mean(a[f"nees_{k}"] < bound))
        out[f"nees_median_scaled_{k}"] = float(np.median(a[f"nees_{k}"]))
    return out


def readings_shared_error(log, noise) -> float:
    """Median over the landmarks of the distance from the truth of the mean of a landmark's readings projected from
    the TRUE poses (the noise model's corrections, no filter): the error a landmark's readings share, which no
    number of them averages out (landmarks with ≥ 5 readings)."""
    ranges, bearings = noise.range_bearing.corrected(log.ranges, log.bearings)
    pose = log.true_pose(log.sighting_times)
    errors = []
    for lid in log.truth_ids:
        sel = log.landmark_ids == lid
        if sel.sum() < 5:
            continue
        angle = pose[sel, 2] + bearings[sel]
        seen = pose[sel, :2] + ranges[sel, None] * np.stack([np.cos(angle), np.sin(angle)], axis=1)
        errors.append(np.hypot(*(seen.mean(axis=0) - log.truth_positions[np.searchsorted(log.truth_ids, lid)])))
    return float(np.median(errors)) if errors else float("nan")


def pinning(result, slam: RecordingFastSLAM, log, t_from: float, t_to: float) -> list[str]:
    """The frames between t_from and t_to (s) that matched two or more landmarks and cut D_r's heading variance by
    more than 30 %: the heading error then, and each matched landmark's creation time, D_l's σθ and its estimate's
    distance from the truth in the start frame at that frame."""
    true_start = np.asarray(result.map.metadata["true_start_pose"], float)
    truth = between(true_start, result.true_trajectory[:, 1:])
    t = result.true_trajectory[:, 0] - result.true_trajectory[0, 0]
    created: dict[int, int] = {}
    for k, frame in enumerate(slam.frames):
        for lid in frame["new"]:
            created.setdefault(int(lid), k)
    index = {int(i): k for k, i in enumerate(log.truth_ids)}
    lines = []
    for k, frame in enumerate(slam.frames):
        before, after = frame["predicted_drift"][2, 2], frame["robot_drift"][2, 2]
        if not t_from <= t[k] <= t_to or len(frame["matched_ids"]) < 2 or after > 0.7 * before:
            continue
        e = wrap_angle(frame["best_pose"][2] - truth[k][2])
        parts = []
        for lid in frame["matched_ids"]:
            ext = int(slam.external_ids(np.array([lid]))[0])
            sd = float(np.sqrt(max(slam.drift.landmark_pose_covariances(np.array([lid]))[5, 0], 0.0)))
            est = frame["estimates"].get(int(lid), np.zeros((0, 2)))
            err = np.nan
            if ext in index and len(est):
                p = between(true_start, np.append(log.truth_positions[index[ext]], 0.0)[None])[0, :2]
                err = float(np.hypot(*(est[0] - p)))
            made = t[created[int(lid)]] if int(lid) in created else float("nan")
            parts.append(f"id {ext} made {made:.0f} s, D_l σθ {sd:.3f}, off {err:.2f} m")
        lines.append(f"{t[k]:6.1f} s: heading error {e:+.3f} rad, σθ {np.sqrt(before):.3f} -> {np.sqrt(after):.3f} | "
                     + "; ".join(parts))
    return lines


def run(log, noise, config, seed: int) -> tuple:
    """The run through ``run_landmark_log`` with a recording filter: (DatasetRun, the filter)."""
    original = dataset_slam.FastSLAM
    dataset_slam.FastSLAM = RecordingFastSLAM
    try:
        result = dataset_slam.run_landmark_log(log, config, np.random.default_rng(seed), noise=noise,
                                               association="id", robot=log.name)
    finally:
        dataset_slam.FastSLAM = original
    return result, RecordingFastSLAM.last


def landmark_split(result, slam: RecordingFastSLAM, log) -> dict:
    """Per landmark of the exported map: the start-frame error, its frame and shape parts and their NEES."""
    lmap = result.map
    meta = lmap.metadata
    true_start = np.asarray(meta["true_start_pose"], float)
    times = result.true_trajectory[:, 0]
    truth_start = between(true_start, result.true_trajectory[:, 1:])            # (T, 3) true poses, start frame
    trajectory = slam.trajectory()[1:, 1:]                                      # the final best particle's ancestry
    created = {}
    for k, frame in enumerate(slam.frames):
        for lid in frame["new"]:
            created[int(lid)] = k                                              # the latest creation of that id
    external = slam.external_ids(lmap.ids)
    index = {int(i): k for k, i in enumerate(log.truth_ids)}
    rows = []
    drift_c = slam.drift.landmark_covariances(lmap.ids)                         # C_l (N, 3, 3)
    pose_d = lmap.drift_covariances                                             # D_l (N, 3, 3)
    for n, (lid, ext) in enumerate(zip(lmap.ids, external, strict=True)):
        if int(ext) not in index or int(lid) not in created:
            continue
        k = created[int(lid)]
        world = np.append(log.truth_positions[index[int(ext)]], 0.0)
        p = between(true_start, world[None])[0, :2]                            # the true landmark, start frame
        relative = between(truth_start[k][None], np.append(p, 0.0)[None])       # p seen from the true creation pose
        f = compose(trajectory[k][None], relative)[0, :2] - p                   # the frame part
        e = lmap.positions[n, :2] - p
        pose_error = trajectory[k] - truth_start[k]
        pose_error[2] = wrap_angle(pose_error[2])
        total = lmap.covariances[n, :2, :2]
        c = drift_c[n, :2, :2]
        d = pose_d[n]
        pose_nees = float(pose_error @ np.linalg.solve(d, pose_error)) if np.linalg.cond(d) < 1e12 else np.nan
        rows.append({"id": int(ext), "lid": int(lid), "e": e.tolist(), "f": f.tolist(),   # --nis reads these
                     "mixture": (total - c).tolist(), "drift": c.tolist(),
                     "created_s": float(times[k] - times[0]), "error_m": float(np.hypot(*e)),
                     "frame_m": float(np.hypot(*f)), "shape_m": float(np.hypot(*(e - f))),
                     "nees": float(points_nees(e[None], total[None])[0]),
                     "frame_nees": float(points_nees(f[None], c[None])[0]),
                     "shape_nees": float(points_nees((e - f)[None], (total - c)[None])[0]),
                     "nees_without_frame": float(points_nees((e - f)[None], total[None])[0]),
                     "creation_pose_nees": pose_nees,
                     "creation_heading_error_rad": float(pose_error[2]),
                     "creation_heading_sd_rad": float(np.sqrt(max(d[2, 2], 0.0))),
                     "creation_position_error_m": float(np.hypot(*pose_error[:2])),
                     "creation_position_sd_m": float(np.sqrt(max(0.5 * (d[0, 0] + d[1, 1]), 0.0))),
                     "sd_m": float(np.sqrt(0.5 * np.trace(total))), "drift_sd_m": float(np.sqrt(0.5 * np.trace(c)))})
    return {"landmarks": rows}


def live_drift(result, slam: RecordingFastSLAM) -> dict:
    """The live best particle's pose error against the tracker's D_r at every frame."""
    true_start = np.asarray(result.map.metadata["true_start_pose"], float)
    truth = between(true_start, result.true_trajectory[:, 1:])
    out = {}
    for key, name in (("robot_drift", "drift"), ("export_drift", "export_drift")):
        nees, heading, position = [], [], []
        for k, frame in enumerate(slam.frames):
            d = frame[key]
            if d is None:
                break
            e = frame["best_pose"] - truth[k]
            e[2] = wrap_angle(e[2])
            if np.linalg.cond(d) < 1e12:
                nees.append(float(e @ np.linalg.solve(d, e)))
                position.append(float(e[:2] @ np.linalg.solve(d[:2, :2], e[:2])))
            heading.append(float(e[2] ** 2 / max(d[2, 2], 1e-300)))
        if not heading:
            continue
        nees, heading, position = np.array(nees), np.array(heading), np.array(position)
        counts = np.array([frame["matched"] for frame in slam.frames[:len(heading)]])
        change = np.array([np.log(max(frame[key][2, 2], 1e-300) / max(frame["predicted_drift"][2, 2], 1e-300))
                           for frame in slam.frames[:len(heading)]]) if key == "robot_drift" else None
        for label, sel in (("1", counts == 1), ("2", counts == 2), ("3+", counts >= 3)):
            if sel.any():   # frames by the number of landmarks the best particle matched
                out[f"heading_vs_{name}_within_chi2_95_matched_{label}"] = float(np.mean(heading[sel] < CHI2_95[1]))
                if change is not None:
                    out[f"frames_matched_{label}"] = float(np.mean(sel))
                    out[f"heading_variance_log_change_sum_matched_{label}"] = float(np.sum(change[sel]))
        out.update({f"pose_vs_{name}_nees_median": float(np.median(nees)),
                    f"pose_vs_{name}_within_chi2_95": float(np.mean(nees < CHI2_95[3])),
                    f"position_vs_{name}_within_chi2_95": float(np.mean(position < CHI2_95[2])),
                    f"heading_vs_{name}_within_chi2_95": float(np.mean(heading < CHI2_95[1]))})
    return out


def odometry_windows(log, noise, config) -> dict:
    """Dead reckoning over windows of WINDOWS_S against the motion model propagated over the same steps (χ²₃)."""
    times = np.unique(log.sighting_times)
    odometry = log.odometry_pose(noise.odometry_times(times))
    increments = noise.calibrate_increments(between(odometry[:-1], odometry[1:]))
    truth = log.true_pose(times)
    cfg = with_fastslam(noise, config)
    out = {}
    for window in WINDOWS_S:
        nees, heading = [], []
        start = 0
        while True:
            stop = int(np.searchsorted(times, times[start] + window))
            if stop >= len(times):
                break
            pose, cov = np.zeros(3), np.zeros((3, 3))
            for k in range(start, stop):
                delta = increments[k]
                variance = increment_variance(delta, cfg, times[k + 1] - times[k])
                cov = propagate_covariance(pose[None], cov[None], delta, variance)[0]
                pose = compose(pose[None], delta[None])[0]
            true = between(truth[start][None], truth[stop][None])[0]
            e = pose - true
            e[2] = wrap_angle(e[2])
            nees.append(float(e @ np.linalg.solve(cov + 1e-12 * np.eye(3), e)))
            heading.append(float(e[2] ** 2 / max(cov[2, 2], 1e-300)))
            start = stop
        if nees:
            out[f"{window:g}s"] = {"windows": len(nees), "nees_median": float(np.median(nees)),
                                   "within_chi2_95": float(np.mean(np.array(nees) < CHI2_95[3])),
                                   "heading_ratio_median": float(np.median(heading))}
    return out


def summarise(rows: list[dict]) -> dict:
    """The split's figures over a map's landmarks (and over those outside the bound)."""
    if not rows:
        return {}
    a = {k: np.array([r[k] for r in rows], float) for k in rows[0] if not isinstance(rows[0][k], list)}
    out_bound = a["nees"] >= CHI2_95[2]
    s = {"landmarks": len(rows), "within": float(np.mean(~out_bound)), "nees_median": float(np.median(a["nees"])),
         "sd_median_m": float(np.median(a["sd_m"])), "drift_sd_median_m": float(np.median(a["drift_sd_m"])),
         "error_median_m": float(np.median(a["error_m"])), "frame_median_m": float(np.median(a["frame_m"])),
         "shape_median_m": float(np.median(a["shape_m"])),
         "frame_within_under_drift": float(np.mean(a["frame_nees"] < CHI2_95[2])),
         "shape_within_under_mixture": float(np.mean(a["shape_nees"] < CHI2_95[2])),
         "within_if_frame_zero": float(np.mean(a["nees_without_frame"] < CHI2_95[2])),
         "creation_pose_nees_median": float(np.nanmedian(a["creation_pose_nees"])),
         "creation_heading_abs_error_median_rad": float(np.median(np.abs(a["creation_heading_error_rad"]))),
         "creation_heading_sd_median_rad": float(np.median(a["creation_heading_sd_rad"])),
         "creation_position_error_median_m": float(np.median(a["creation_position_error_m"])),
         "creation_position_sd_median_m": float(np.median(a["creation_position_sd_m"])),
         "outside": int(out_bound.sum())}
    if out_bound.any():
        s["outside_frame_median_m"] = float(np.median(a["frame_m"][out_bound]))
        s["outside_shape_median_m"] = float(np.median(a["shape_m"][out_bound]))
        s["outside_frame_larger"] = int(np.sum(a["frame_m"][out_bound] > a["shape_m"][out_bound]))
    return s


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--robots", default="1,2,3,4,5")
    parser.add_argument("--seeds", default="0")
    parser.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE")
    parser.add_argument("--no-windows", action="store_true", help="skip the dead-reckoning windows")
    parser.add_argument("--landmarks", action="store_true", help="print every landmark's row")
    parser.add_argument("--export-lever", action="store_true", help="export the drift with the heading's lever, "
                        "the gate's tracker unchanged (estimation/fastslam/export_drift.py)")
    parser.add_argument("--one-landmark-heading", action="store_true", help="with the export's lever: a frame that "
                        "matched one landmark keeps the predicted heading uncertainty as a turn about it")
    parser.add_argument("--pinning", metavar="T0,T1", help="print the frames between T0 and T1 s (first robot and "
                        "seed) whose two or more matched landmarks cut D_r's heading σ, and how far those are off")
    parser.add_argument("--nis", action="store_true", help="the landmark updates' NIS in the final best particle's "
                        "ancestry, for the landmarks whose shape part is outside the bound and the others")
    parser.add_argument("--calibrated", action="store_true", help="fit the noise model with the range's calibration, "
                        "the heading bias and the odometry lag (eval_mrclam's three options)")
    parser.add_argument("--dump", type=Path, help="with --nis: save each run's ancestry updates and landmark rows "
                        "(DIR/robotR_seedS.npz)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    RecordingFastSLAM.keep_estimates = bool(args.pinning)
    if not args.data.is_dir():
        print(f"mrclam_nees_diagnosis: no data set at {args.data}", file=sys.stderr)
        return 2
    refusal = output_refusal("mrclam_nees_diagnosis", "--dump", args.dump, args.data)
    if refusal:
        print(refusal, file=sys.stderr)
        return 2
    overrides = config_overrides(args.set)
    if args.export_lever or args.one_landmark_heading:   # FastSLAMConfig.drift_export (export_drift.py)
        overrides["drift_export"] = "lever+heading" if args.one_landmark_heading else "lever"
    out = {}
    for r in (int(x) for x in args.robots.split(",")):
        log = read_mrclam(args.data, r)
        noise = estimate_noise([log], **({"range_calibration": True, "heading_bias": True, "odometry_lag": True}
                                         if args.calibrated else {})).model
        config = range_bearing_config(**overrides)
        windows = {} if args.no_windows else odometry_windows(log, noise, config)
        for seed in (int(x) for x in args.seeds.split(",")):
            result, slam = run(log, noise, config, seed)
            split = landmark_split(result, slam, log)
            entry = {"ate_m": result.metrics["ate_m"],
                     "eval_within": result.metrics["landmark_nees_within_bound"],
                     "eval_rigid_within": result.metrics["landmark_nees_rigid_within_bound"],
                     "eval_nees_median": result.metrics["landmark_nees_median"],
                     **summarise(split["landmarks"]), **live_drift(result, slam), "windows": windows}
            if args.nis:
                by_lid = lineage_nis(slam)
                entry["nis"] = nis_summary(split["landmarks"], by_lid, slam)
                entry["nis"]["readings_shared_error_median_m"] = readings_shared_error(log, noise)
                if args.dump:
                    args.dump.mkdir(parents=True, exist_ok=True)
                    np.savez(args.dump / f"robot{r}_seed{seed}.npz", columns=np.array(NIS_COLUMNS),
                             updates=np.concatenate(list(by_lid.values())),
                             landmarks=json.dumps(split["landmarks"]))
            if args.landmarks:
                entry["rows"] = [{k: v for k, v in row.items() if not isinstance(v, list)}
                                 for row in split["landmarks"]]
            if args.pinning:
                t_from, t_to = (float(x) for x in args.pinning.split(","))
                entry["pinning"] = pinning(result, slam, log, t_from, t_to)
                if not args.json:
                    print("\n".join(entry["pinning"]))
            out[f"robot{r}/seed{seed}"] = entry
            if not args.json:
                print(f"robot{r} seed {seed}: " + json.dumps({k: (round(v, 4) if isinstance(v, float) else v)
                                                              for k, v in entry.items() if k != "rows"}), flush=True)
    if args.json:
        print(json.dumps({"runs": out, "overrides": overrides}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
