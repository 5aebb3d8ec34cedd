"""What holds the smoothed map's start frame where it is (`--smooth`'s start-frame landmark NEES, robot 1 foremost).

Run from the repository root:

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.smoother_frame_diagnosis [--robots 1] [--noise calibrated]
        [--early 5] [--cache DIR] [--json]

Per robot, the known-ID run with ``--smooth`` exactly as ``benchmarks.eval_mrclam --association id --seed 0
--smooth`` builds it (``--noise calibrated``: ``--range-calibration --heading-bias --odometry-lag``; ``turn``: those
and the forward deficit per radian turned, ``estimate_noise(turn_translation=True)``; ``default``: none; ``both``:
calibrated and default), its smoothing problem captured, then:

- **frame**: the smoothed map's error in the start frame as one rigid motion (dx, dy, dθ: the least-squares fit of
  the landmark errors, rotation about the origin), its covariance from the smoother's own information (the same
  linear functional of the landmarks), its NEES (χ²₃), and the start-frame landmark NEES within the χ²₂ 95 % bound
  with the fitted rotation, translation or both taken out: which part of the frame the covariances fail on.
- **attribution**: the same functional, linearised at the truth: the frame's error is ≈ −Σᵢ gᵢ rᵢ over the factors,
  rᵢ each factor's normalised residual at the true poses and landmarks (its actual error) and g = J H⁻¹ w; Σᵢ gᵢ² is
  the model's variance of it. Summed by kind (odometry θ, odometry x/y, bearings, ranges) and time window: which
  factors carry the frame (variance share) and whose errors moved it (contribution).
- **oracles**: the problem solved again with the first ``--early`` s of odometry replaced by the truth (θ only, x/y
  only, all; all with σ 10⁻⁵: the early poses fixed at the truth), or down-weighted (variances ×100: what the
  sightings alone say), and with the forward travel scaled per band of curvature (|dθ|/dx) by the log's true ratio
  (true/odometry) or, with no truth, by the smoother's own (three passes, each re-solved from the last), and with
  the turning increments' x/y variance multiplied by the turns' measured overdispersion (Σz/√n's rms², below; fitted
  on the log's truth as the noise model's calibrations are); figures as eval_mrclam prints them (start-frame and
  rigid NEES within the bound, ATE, pose NEES median) and the frame's (dx, dy, dθ).
- **curvature**: Σ true forward travel / Σ odometry forward travel per band of |dθ|/dx (rad/m) over the whole log;
  and through whole turns, the forward error's mean, lag-1 correlation and Σz/√n per turn (a unit normal if the
  random walk were right).
- **early poses**: the smoothed heading's error and σ (its Laplace covariance) at 0.5, 1, 2, 5, 10, 30 s.
- **landmarks**, by first sighting: each one's rotation about the origin and its tangential / radial error against
  its σ in each direction (are the first turn's landmarks the rotated ones?).

``--heading-loss student-t|mixture`` (``--heading-dof``, ``--stall-probability``, ``--stall-sigma``) solves every
variant with that heavy-tailed odometry heading loss (``estimation.landmark_smoother.HeadingLoss``;
docs/fastslam-history.md "Session 16 (P)") and prints the Gaussian default's figures beside it.
``--cache DIR`` keeps each robot's captured problem (an .npz of its arrays, the pipeline's figures as JSON; read
without pickle) so later runs skip the filter.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import io  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

import estimation.dataset_smoothing as dataset_smoothing  # noqa: E402
from benchmarks.output_paths import output_refusal  # noqa: E402
from estimation.dataset_slam import run_landmark_log, sighted_true_ids  # noqa: E402
from estimation.datasets import read_mrclam  # noqa: E402
from estimation.fastslam import range_bearing_config  # noqa: E402
from estimation.fastslam.motion import turn_spans, turning  # noqa: E402
from estimation.fileio import atomic_write_bytes  # noqa: E402
from estimation.geometry import between, compose, wrap_angle  # noqa: E402
from estimation.landmark_scores import CHI2_95, ate, map_scores, points_nees, pose_nees, rigid_functional  # noqa: E402
from estimation.landmark_smoother import (  # noqa: E402
    HeadingLoss,
    LandmarkLogProblem,
    NormalFactor,
    _jacobian,
    _residuals,
    smooth,
)
from estimation.noise_estimation import estimate_noise  # noqa: E402
from runtime.commands.options import float_where, non_negative_float, positive_float  # noqa: E402

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "mrclam" / "MRCLAM_Dataset2"
CALIBRATED = {"heading_bias": True, "range_calibration": True, "odometry_lag": True}
NOISE_FITS = {"calibrated": CALIBRATED, "default": {}, "turn": dict(CALIBRATED, turn_translation=True)}
WINDOWS = (0.0, 1.0, 5.0, 30.0, np.inf)           # s after the first sighting: attribution windows
EARLY_TIMES = (0.5, 1.0, 2.0, 5.0, 10.0, 30.0)
CURVATURE_BANDS = (0.0, 0.5, 2.0, 4.0, 8.0, np.inf)  # rad/m


@dataclasses.dataclass
class Captured:
    """One robot's smoothing problem as `--smooth` builds it, and the truth to score it."""

    problem: LandmarkLogProblem
    initial_poses: np.ndarray          # (T + 1, 3) the filter's best particle, pose 0 the origin
    initial_landmarks: np.ndarray      # (L, 2)
    landmark_ids: np.ndarray           # (L,) true id of each landmark index
    times: np.ndarray                  # (T + 1,) s after the first sighting
    true_poses: np.ndarray             # (T + 1, 3) Vicon in the start frame
    true_landmarks: np.ndarray         # (L, 2) in the start frame
    true_start: np.ndarray
    truth_ids: np.ndarray
    truth_positions: np.ndarray
    sighted: np.ndarray
    pipeline_metrics: dict


def capture(log, noise, seed: int = 0) -> Captured:
    """Run the known-ID filter and smoother as eval_mrclam does; keep the smoothing problem it built."""
    kept = {}
    original_smooth, original_problem = dataset_smoothing.smooth, dataset_smoothing._problem

    def spy_problem(*args):
        kept["problem"], kept["ids"] = original_problem(*args)
        return kept["problem"], kept["ids"]

    def spy_smooth(problem, initial_poses, initial_landmarks, **kwargs):
        kept.update(poses=np.array(initial_poses), landmarks=np.array(initial_landmarks))
        return original_smooth(problem, initial_poses, initial_landmarks, **kwargs)

    dataset_smoothing.smooth, dataset_smoothing._problem = spy_smooth, spy_problem
    try:
        run = run_landmark_log(log, range_bearing_config(n_particles=100), np.random.default_rng(seed), noise=noise,
                               association="id", robot=log.name, smooth=True)
    finally:
        dataset_smoothing.smooth, dataset_smoothing._problem = original_smooth, original_problem
    true_start = np.asarray(run.map.metadata["true_start_pose"], float)
    t0 = float(run.map.trajectory[0, 0])
    problem, landmark_ids = kept["problem"], np.asarray(kept["ids"], np.int64)
    index = {int(i): k for k, i in enumerate(log.truth_ids)}
    world = np.array([log.truth_positions[index[int(i)]] if int(i) in index else (np.nan, np.nan)
                      for i in landmark_ids]).reshape(-1, 2)
    true_landmarks = between(true_start, np.column_stack([world, np.zeros(len(world))]))[:, :2]
    true_poses = np.vstack([np.zeros(3), between(true_start, run.true_trajectory[:, 1:])])
    times = np.append(0.0, run.true_trajectory[:, 0] - t0)
    return Captured(problem, kept["poses"], kept["landmarks"], landmark_ids, times, true_poses, true_landmarks,
                    true_start, np.asarray(log.truth_ids), np.asarray(log.truth_positions),
                    sighted_true_ids(log, t0, None), dict(run.metrics))


def scores(cap: Captured, solution) -> dict:
    """eval_mrclam's smoothed figures of ``solution`` and the frame's rigid error."""
    seen = np.all(np.isfinite(solution.landmark_covariances.reshape(len(solution.landmarks), -1)), axis=1)
    m = map_scores(solution.landmarks[seen], solution.landmark_covariances[seen], cap.landmark_ids[seen],
                   cap.true_start, cap.truth_ids, cap.truth_positions, cap.sighted)
    truth_world = compose(cap.true_start, cap.true_poses[1:])
    nees = pose_nees(solution.poses[solution.covariance_poses] - cap.true_poses[solution.covariance_poses],
                     solution.pose_covariances)
    frame = frame_error(cap, solution)
    return {"start_frame_within": m["landmark_nees_within_bound"],
            "rigid_within": m["landmark_nees_rigid_within_bound"],
            "ate_m": ate(compose(cap.true_start, solution.poses[1:]), truth_world),
            "pose_nees_median": float(np.nanmedian(nees)),
            "landmark_error_median_m": m["landmark_error_median_m"],
            "frame": frame, "chi2_per_dof": solution.chi2_per_dof, "converged": bool(solution.converged)}


def frame_error(cap: Captured, solution) -> dict:
    """The map's start-frame error as one rigid motion, its covariance from the landmarks' joint covariance
    (the smoother's information), its NEES, and the landmark NEES within the bound with parts of it removed."""
    functional = rigid_functional(cap.true_landmarks)
    errors = solution.landmarks - cap.true_landmarks
    motion = functional @ errors.ravel()
    covariance = _functional_covariance(cap.problem, solution.poses, solution.landmarks, solution.inliers,
                                        functional)
    tl = cap.true_landmarks
    rotation = motion[2] * np.column_stack([-tl[:, 1], tl[:, 0]])
    cov = solution.landmark_covariances

    def within(e):
        return float(np.mean(points_nees(e, cov) < CHI2_95[2]))

    return {"dx_m": float(motion[0]), "dy_m": float(motion[1]), "dtheta_rad": float(motion[2]),
            "sd": [float(s) for s in np.sqrt(np.diag(covariance))],
            "nees": float(motion @ np.linalg.solve(covariance, motion)),
            "within_rotation_removed": within(errors - rotation),
            "within_translation_removed": within(errors - motion[:2]),
            "within_both_removed": within(errors - rotation - motion[:2])}


def _functional_covariance(problem, poses, landmarks, inliers, functional):
    t = problem.n_poses
    jac = _jacobian(problem, poses, landmarks, len(landmarks), inliers.astype(float))
    w = np.zeros((3, 3 * t + 2 * len(landmarks)))
    w[:, 3 * t:] = functional
    return w @ NormalFactor((jac.T @ jac).tocsc(), t).solve(w.T)


def attribution(cap: Captured, inliers: np.ndarray) -> dict:
    """The frame's error attributed to the factors' actual errors, linearised at the truth (module docstring)."""
    p, t = cap.problem, cap.problem.n_poses
    n_landmarks = len(cap.true_landmarks)
    jac = _jacobian(p, cap.true_poses, cap.true_landmarks, n_landmarks, inliers.astype(float))
    odometry, sightings = _residuals(p, cap.true_poses, cap.true_landmarks)
    residual = np.concatenate([odometry, (sightings.reshape(-1, 2) * inliers[:, None]).ravel()])
    w = np.zeros((3, 3 * t + 2 * n_landmarks))
    w[:, 3 * t:] = rigid_functional(cap.true_landmarks)
    u = NormalFactor((jac.T @ jac).tocsc(), t).solve(w.T)
    g = np.asarray(jac @ u)
    variance = np.sum(g ** 2, axis=0)
    contribution = -g * residual[:, None]
    kind = np.concatenate([np.tile(["odometry x", "odometry y", "odometry θ"], t),
                           np.tile(["range", "bearing"], len(p.ranges))])
    when = np.concatenate([np.repeat(cap.times[1:], 3), np.repeat(cap.times[p.pose_index], 2)])
    rows = []
    for name in ("odometry θ", "odometry x", "odometry y", "bearing", "range"):
        for a, b in zip(WINDOWS[:-1], WINDOWS[1:], strict=True):
            sel = (kind == name) & (when > a if a > 0 else when >= a) & (when <= b)
            if sel.any():
                rows.append({"factor": name, "from_s": a, "to_s": b, "n": int(sel.sum()),
                             "variance_share": [float(v) for v in np.sum(g[sel] ** 2, axis=0) / variance],
                             "contribution": [float(c) for c in contribution[sel].sum(axis=0)]})
    top = np.argsort(-np.abs(contribution[:, 2]))[:5]
    return {"predicted": [float(c) for c in contribution.sum(axis=0)], "sd": [float(s) for s in np.sqrt(variance)],
            "rows": rows, "largest_rotation": [{"factor": str(kind[i]), "t_s": float(when[i]),
                                                "residual_sigma": float(residual[i]),
                                                "contribution_rad": float(contribution[i, 2])} for i in top]}


def _with(problem: LandmarkLogProblem, increments=None, variances=None) -> LandmarkLogProblem:
    return dataclasses.replace(problem, increments=problem.increments if increments is None else increments,
                               increment_variances=problem.increment_variances if variances is None else variances)


def oracle_problems(cap: Captured, early_s: float) -> dict[str, LandmarkLogProblem]:
    """The variants of the problem the oracles solve (module docstring)."""
    p = cap.problem
    true_increments = between(cap.true_poses[:-1], cap.true_poses[1:])
    early = cap.times[1:] <= early_s
    out = {"as built": p}
    for label, axes in ((f"true θ, first {early_s:g} s", [2]), (f"true x/y, first {early_s:g} s", [0, 1]),
                        (f"true x/y/θ, first {early_s:g} s", [0, 1, 2])):
        inc = p.increments.copy()
        inc[np.ix_(early, axes)] = true_increments[np.ix_(early, axes)]
        out[label] = _with(p, inc)
    inc = p.increments.copy()
    inc[early] = true_increments[early]
    var = p.increment_variances.copy()
    var[early] = 1e-10
    out[f"true poses fixed, first {early_s:g} s"] = _with(p, inc, var)
    for label, axes in ((f"odometry θ variance ×100, first {early_s:g} s", [2]),
                        (f"odometry x/y variance ×100, first {early_s:g} s", [0, 1]),
                        (f"odometry variance ×100, first {early_s:g} s", [0, 1, 2])):
        var = p.increment_variances.copy()
        var[np.ix_(early, axes)] *= 100.0
        out[label] = _with(p, variances=var)
    ratio = curvature_ratios(cap)
    inc = p.increments.copy()
    band = np.digitize(_curvature(p.increments), CURVATURE_BANDS[1:-1])
    inc[:, :2] *= np.array([r["ratio"] for r in ratio])[band][:, None]
    out["forward travel scaled by curvature (true ratios)"] = _with(p, inc)
    return out


def self_calibrated(cap: Captured, smooth_options: dict, passes: int = 3):
    """No truth: the forward travel per band of curvature rescaled by the smoother's own ratio (smoothed forward
    travel over the odometry's, bands with ≥ 20 moving increments), re-solved from the last solution, ``passes``
    times. Returns (solution, ratios per band)."""
    p = cap.problem
    band = np.digitize(_curvature(p.increments), CURVATURE_BANDS[1:-1])
    moving = np.abs(p.increments[:, 0]) > 0.005
    solution = smooth(p, cap.initial_poses, cap.initial_landmarks, **smooth_options)
    ratios = np.ones(len(CURVATURE_BANDS) - 1)
    for _ in range(passes):
        smoothed = between(solution.poses[:-1], solution.poses[1:])
        for b in range(len(ratios)):
            sel = moving & (band == b)
            if sel.sum() >= 20:
                ratios[b] = smoothed[sel, 0].sum() / p.increments[sel, 0].sum()
        increments = p.increments.copy()
        increments[:, :2] *= ratios[band][:, None]
        solution = smooth(_with(p, increments), solution.poses, solution.landmarks, **smooth_options)
    return solution, ratios


def _curvature(increments):
    return np.abs(increments[:, 2]) / np.maximum(np.abs(increments[:, 0]), 1e-3)


def curvature_ratios(cap: Captured) -> list[dict]:
    """Σ true forward travel / Σ odometry forward travel per band of curvature |dθ|/dx over the log."""
    p = cap.problem
    true_increments = between(cap.true_poses[:-1], cap.true_poses[1:])
    curvature = _curvature(p.increments)
    moving = np.abs(p.increments[:, 0]) > 0.005
    out = []
    for a, b in zip(CURVATURE_BANDS[:-1], CURVATURE_BANDS[1:], strict=True):
        sel = moving & (curvature >= a) & (curvature < b)
        odometry = float(p.increments[sel, 0].sum())
        truth = float(true_increments[sel, 0].sum())
        z = (true_increments[sel, 0] - p.increments[sel, 0]) / np.sqrt(p.increment_variances[sel, 0])
        out.append({"from_rad_per_m": a, "to_rad_per_m": b, "n": int(sel.sum()), "odometry_m": odometry,
                    "true_m": truth, "ratio": truth / odometry if sel.sum() >= 3 and odometry > 0 else 1.0,
                    "mean_z": float(z.mean()) if sel.any() else float("nan")})
    return out


def turn_errors(cap: Captured, min_increments: int = 4) -> dict:
    """The odometry's forward error through whole turns (runs of ≥ ``min_increments`` consecutive increments of a
    turn, ``motion.turning``: ≥ 2 rad/m over > 5 mm, as the filter's inflation reads them; gaps < 1 s):
    z = (true − odometry) forward travel / σ per increment; the random walk says each turn's Σz/√n is a unit
    normal. Mean z, its lag-1 correlation about the mean, and Σz/√n's rms and mean over the turns."""
    p = cap.problem
    true_increments = between(cap.true_poses[:-1], cap.true_poses[1:])
    z = (true_increments[:, 0] - p.increments[:, 0]) / np.sqrt(p.increment_variances[:, 0])
    in_turn = turning(p.increments) & (np.diff(cap.times) < 1.0)
    pair = in_turn[:-1] & in_turn[1:]
    centred = z - z[in_turn].mean() if in_turn.any() else z
    a, b = centred[:-1][pair], centred[1:][pair]
    lag1 = float(np.sum(a * b) / np.sqrt(np.sum(a ** 2) * np.sum(b ** 2))) if pair.sum() > 2 else float("nan")
    runs = turn_spans(in_turn, min_increments)
    per_turn = np.array([z[start:stop].sum() / np.sqrt(stop - start) for start, stop in runs])
    return {"increments": int(in_turn.sum()), "mean_z": float(z[in_turn].mean()) if in_turn.any() else float("nan"),
            "lag1_correlation": lag1, "turns": len(runs),
            "turn_sum_rms": float(np.sqrt(np.mean(per_turn ** 2))) if len(runs) else float("nan"),
            "turn_sum_mean": float(np.mean(per_turn)) if len(runs) else float("nan")}


def early_poses(cap: Captured, solution) -> list[dict]:
    """The smoothed heading's error and its Laplace σ at a few times after the first sighting."""
    which = np.unique([min(int(np.searchsorted(cap.times, s)), len(cap.times) - 1) for s in EARLY_TIMES])
    which = which[which >= 1]
    p, t = cap.problem, cap.problem.n_poses
    jac = _jacobian(p, solution.poses, solution.landmarks, len(solution.landmarks), solution.inliers.astype(float))
    factor = NormalFactor((jac.T @ jac).tocsc(), t)
    unit = np.zeros((3 * t + 2 * len(solution.landmarks), len(which)))
    unit[3 * (which - 1) + 2, np.arange(len(which))] = 1.0
    variance = np.einsum("ij,ij->j", unit, factor.solve(unit))
    out = []
    for k, var in zip(which, variance, strict=True):
        err = float(wrap_angle(solution.poses[k, 2] - cap.true_poses[k, 2]))
        out.append({"t_s": float(cap.times[k]), "pose": int(k), "heading_error_rad": err,
                    "heading_sd_rad": float(np.sqrt(var)),
                    "position_error_m": float(np.hypot(*(solution.poses[k, :2] - cap.true_poses[k, :2])))})
    return out


def landmark_errors(cap: Captured, solution) -> list[dict]:
    """Each landmark's start-frame error split across (tangential, about the origin) and along (radial) its
    direction from the origin, with its σ in each, and when it was first sighted: are the landmarks seen in the
    first turn the rotated ones?"""
    p = cap.problem
    out = []
    for j in np.argsort([cap.times[p.pose_index[p.landmark_index == j]].min() for j in range(len(cap.landmark_ids))]):
        sel = p.landmark_index == j
        true = cap.true_landmarks[j]
        distance = float(np.hypot(*true))
        radial = true / distance
        tangential = np.array([-radial[1], radial[0]])
        error = solution.landmarks[j] - true
        cov = solution.landmark_covariances[j]
        out.append({"id": int(cap.landmark_ids[j]), "first_seen_s": float(cap.times[p.pose_index[sel]].min()),
                    "sightings": int(sel.sum()), "distance_m": distance,
                    "rotation_rad": float(tangential @ error / distance),
                    "tangential_m": float(tangential @ error), "tangential_sd_m": float(np.sqrt(tangential @ cov
                                                                                                 @ tangential)),
                    "radial_m": float(radial @ error), "radial_sd_m": float(np.sqrt(radial @ cov @ radial)),
                    "nees": float(points_nees(error[None], cov[None])[0])})
    return out


def diagnose(cap: Captured, early_s: float, smooth_options: dict) -> dict:
    base = smooth(cap.problem, cap.initial_poses, cap.initial_landmarks, **smooth_options)
    out = {"scores": scores(cap, base), "attribution": attribution(cap, base.inliers),
           "gaussian_scores": scores(cap, smooth(cap.problem, cap.initial_poses, cap.initial_landmarks))
           if smooth_options else None,
           "heading_weights_below_half": int(np.sum(base.heading_weights < 0.5))
           if base.heading_weights is not None else None,
           "early_poses": early_poses(cap, base), "landmarks": landmark_errors(cap, base),
           "curvature": curvature_ratios(cap), "turns": turn_errors(cap), "oracles": {}}
    for label, problem in oracle_problems(cap, early_s).items():
        if label == "as built":
            continue
        solution = smooth(problem, cap.initial_poses, cap.initial_landmarks, **smooth_options)
        out["oracles"][label] = scores(cap, solution)
    turns = out["turns"]
    factor = turns["turn_sum_rms"] ** 2 if np.isfinite(turns["turn_sum_rms"]) else 1.0
    variances = cap.problem.increment_variances.copy()
    variances[turning(cap.problem.increments), :2] *= factor
    solution = smooth(_with(cap.problem, variances=variances), cap.initial_poses, cap.initial_landmarks,
                      **smooth_options)
    out["oracles"][f"turning x/y variance ×{factor:.1f} (the turns' Σz/√n rms²)"] = dict(
        scores(cap, solution), factor=float(factor))
    solution, ratios = self_calibrated(cap, smooth_options)
    out["oracles"]["forward travel scaled by the smoother's ratios"] = dict(
        scores(cap, solution), ratios=[float(r) for r in ratios])
    return out


def save_captured(cap: Captured, path: Path) -> None:
    """Write ``cap`` as an .npz (the problem's arrays under ``problem.``, the pipeline's figures as JSON text)."""
    arrays = {f"problem.{f.name}": getattr(cap.problem, f.name) for f in dataclasses.fields(cap.problem)}
    arrays.update({f.name: getattr(cap, f.name) for f in dataclasses.fields(cap)
                   if f.name not in ("problem", "pipeline_metrics")})
    arrays["pipeline_metrics"] = np.array(json.dumps(cap.pipeline_metrics))
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, buffer.getvalue())


def load_captured(path: Path) -> Captured:
    """Read what :func:`save_captured` wrote (no pickle: object arrays are refused)."""
    with np.load(path, allow_pickle=False) as z:
        arrays = {name: z[name] for name in z.files}
    problem = LandmarkLogProblem(**{k.removeprefix("problem."): v for k, v in arrays.items()
                                    if k.startswith("problem.")})
    rest = {k: v for k, v in arrays.items() if not k.startswith("problem.") and k != "pipeline_metrics"}
    return Captured(problem=problem, pipeline_metrics=json.loads(str(arrays["pipeline_metrics"])), **rest)


def load(robot: int, noise_kind: str, data: Path, cache: Path | None) -> Captured:
    path = cache / f"robot{robot}-{noise_kind}.npz" if cache else None
    if path and path.exists():
        return load_captured(path)
    log = read_mrclam(data, robot)
    noise = estimate_noise([log], **NOISE_FITS[noise_kind]).model
    cap = capture(log, noise)
    if path:
        save_captured(cap, path)
    return cap


def _print(robot, kind, result):
    s = result["scores"]
    f = s["frame"]
    g = result["gaussian_scores"]
    if g is not None:
        print(f"\nrobot {robot}, {kind} noise, Gaussian heading (the default): start-frame NEES within "
              f"{100 * g['start_frame_within']:.0f} %, rigid {100 * g['rigid_within']:.0f} %, ATE {g['ate_m']:.3f} m, "
              f"pose NEES median {g['pose_nees_median']:.1f}; with the heading loss below "
              f"({result['heading_weights_below_half']} heading increments weighted under 0.5):", end="")
    print(f"\nrobot {robot}, {kind} noise: start-frame NEES within {100 * s['start_frame_within']:.0f} %, rigid "
          f"{100 * s['rigid_within']:.0f} %, ATE {s['ate_m']:.3f} m, pose NEES median {s['pose_nees_median']:.1f}")
    print(f"  frame error dx {f['dx_m']:+.3f} m dy {f['dy_m']:+.3f} m dθ {f['dtheta_rad']:+.4f} rad; σ "
          f"{f['sd'][0]:.3f} m {f['sd'][1]:.3f} m {f['sd'][2]:.4f} rad; NEES₃ {f['nees']:.1f} (χ²₃ 95 % 7.8)")
    print(f"  landmarks within the bound with the frame's rotation removed {100 * f['within_rotation_removed']:.0f} %"
          f", translation removed {100 * f['within_translation_removed']:.0f} %, both "
          f"{100 * f['within_both_removed']:.0f} %")
    a = result["attribution"]
    print(f"  attribution at the truth: predicted (dx, dy, dθ) ({a['predicted'][0]:+.3f}, {a['predicted'][1]:+.3f}, "
          f"{a['predicted'][2]:+.4f}), model σ ({a['sd'][0]:.3f}, {a['sd'][1]:.3f}, {a['sd'][2]:.4f})")
    print("    factor      window (s)   n      variance share dx/dy/dθ     contribution dx/dy/dθ")
    for row in a["rows"]:
        share, c = row["variance_share"], row["contribution"]
        if max(share) < 0.02 and max(abs(c[0]), abs(c[1]), abs(c[2]) * 2) < 0.005:
            continue
        print(f"    {row['factor']:11s} {row['from_s']:4g}-{row['to_s']:<5g} {row['n']:6d}   "
              f"{share[0]:5.2f} {share[1]:5.2f} {share[2]:5.2f}      {c[0]:+.3f} {c[1]:+.3f} {c[2]:+.4f}")
    print("  early poses: " + "; ".join(f"{e['t_s']:.1f} s θ err {e['heading_error_rad']:+.3f} σ "
                                         f"{e['heading_sd_rad']:.3f}" for e in result["early_poses"]))
    print("  landmarks by first sighting (s): rotation about the origin (rad), tangential / radial error (σ) (m):")
    for lm in result["landmarks"]:
        print(f"    {lm['id']:3d} at {lm['first_seen_s']:6.1f} s, {lm['distance_m']:4.1f} m: "
              f"{lm['rotation_rad']:+.3f}; {lm['tangential_m']:+.3f} ({lm['tangential_sd_m']:.3f}) / "
              f"{lm['radial_m']:+.3f} ({lm['radial_sd_m']:.3f}); NEES {lm['nees']:.1f}")
    print("  forward travel true/odometry by curvature: " + ", ".join(
        f"{c['from_rad_per_m']:g}-{c['to_rad_per_m']:g} rad/m {c['ratio']:.2f} (n {c['n']})"
        for c in result["curvature"]))
    t = result["turns"]
    print(f"  forward error through turns (≥ 2 rad/m): {t['increments']} increments, mean z {t['mean_z']:+.2f}, lag-1 "
          f"correlation {t['lag1_correlation']:+.2f}; over {t['turns']} turns of ≥ 4 increments Σz/√n has rms "
          f"{t['turn_sum_rms']:.2f} and mean {t['turn_sum_mean']:+.2f} (the random walk: 1 and 0)")
    print("  oracles:                                            within  rigid   ATE    poseNEES  frame dx, dy, dθ")
    for label, o in result["oracles"].items():
        f = o["frame"]
        print(f"    {label:50s} {100 * o['start_frame_within']:4.0f} % {100 * o['rigid_within']:4.0f} % "
              f"{o['ate_m']:.3f} {o['pose_nees_median']:7.1f}   {f['dx_m']:+.3f} {f['dy_m']:+.3f} "
              f"{f['dtheta_rad']:+.4f}")


def _probability(text: str) -> float:
    return float_where(text, "in (0, 1)", lambda v: 0 < v < 1)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--robots", default="1")
    parser.add_argument("--noise", choices=("calibrated", "default", "turn", "both"), default="calibrated",
                        help="calibrated: the three calibrations; turn: those and the forward deficit per radian "
                        "turned (estimate_noise(turn_translation=True)); both: calibrated and default")
    parser.add_argument("--early", type=non_negative_float, default=5.0, help="seconds after the first sighting "
                        "the oracles change (robot 1's first turn ends at 4.6 s)")
    parser.add_argument("--cache", type=Path, help="keep/reuse each robot's captured problem here")
    parser.add_argument("--heading-loss", choices=("gaussian", "student-t", "mixture"), default="gaussian",
                        help="the smoother's odometry heading loss for every variant (HeadingLoss)")
    parser.add_argument("--heading-dof", type=positive_float, default=3.0, help="Student-t degrees of freedom")
    parser.add_argument("--stall-probability", type=_probability, default=0.01, help="mixture: stall probability per "
                        "increment")
    parser.add_argument("--stall-sigma", type=positive_float, default=0.12, help="mixture: a stall's σ (rad)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    if not args.data.is_dir():
        print(f"smoother_frame_diagnosis: no data set at {args.data}", file=sys.stderr)
        return 2
    refusal = output_refusal("smoother_frame_diagnosis", "--cache", args.cache, args.data)
    if refusal:
        print(refusal, file=sys.stderr)
        return 2
    kinds = ("calibrated", "default") if args.noise == "both" else (args.noise,)
    options = {} if args.heading_loss == "gaussian" else {"heading_loss": HeadingLoss(
        args.heading_loss, dof=args.heading_dof, stall_probability=args.stall_probability,
        stall_sigma_rad=args.stall_sigma)}
    results = {}
    for kind in kinds:
        for robot in (int(r) for r in args.robots.split(",")):
            result = diagnose(load(robot, kind, args.data, args.cache), args.early, options)
            results[f"{kind}/robot{robot}"] = result
            if not args.json:
                _print(robot, kind, result)
    if args.json:
        print(json.dumps(results, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
