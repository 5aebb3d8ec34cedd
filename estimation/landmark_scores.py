"""Scores of a planar landmark SLAM run against ground truth: trajectory, map and consistency figures.

Pure functions over arrays (no filter, no files), shared by the dataset runner and the evaluation scripts.
Poses are (x, y, θ); trajectories (T, 4) rows (t, x, y, θ).
"""
from __future__ import annotations

import numpy as np

from .geometry import between, compose, wrap_angle

CHI2_95 = {1: 3.841, 2: 5.991, 3: 7.815}   # χ² 95 % quantiles by degrees of freedom
NEES_WITHIN_GOAL = 0.9     # issue 13: at least 90 % of a map's landmarks within the χ² 95 % NEES bound
DUPLICATE_GOAL = 0.05      # issue 13: duplicates under 5 % of a map


def ate(estimate: np.ndarray, truth: np.ndarray) -> float:
    """RMS planar position error (m) of (T, ≥3) poses against (T, ≥3) true poses at the same instants."""
    if len(estimate) == 0:
        return float("nan")
    return float(np.sqrt(np.mean(np.sum((estimate[:, :2] - truth[:, :2]) ** 2, axis=1))))


def rigid_fit_2d(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The planar pose (x, y, θ) minimising Σ |pose ⊕ source_i − target_i|² (Kabsch; source, target (N, ≥2))."""
    a, b = np.asarray(source, float)[:, :2], np.asarray(target, float)[:, :2]
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    h = (a - ca).T @ (b - cb)
    theta = np.arctan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    c, s = np.cos(theta), np.sin(theta)
    t = cb - np.array([[c, -s], [s, c]]) @ ca
    return np.array([t[0], t[1], theta])


def points_nees(errors: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """eᵀ Σ⁻¹ e per point: errors (N, 2), covariances (N, 2, 2) -> (N,) (inf where Σ is singular)."""
    out = np.full(len(errors), np.inf)
    det = covariances[:, 0, 0] * covariances[:, 1, 1] - covariances[:, 0, 1] * covariances[:, 1, 0]
    ok = det > 0
    e, c = errors[ok], covariances[ok]
    # closed-form 2×2 inverse: [[d, -b], [-c, a]] / det
    out[ok] = (e[:, 0] ** 2 * c[:, 1, 1] - e[:, 0] * e[:, 1] * (c[:, 0, 1] + c[:, 1, 0])
               + e[:, 1] ** 2 * c[:, 0, 0]) / det[ok]
    return out


def count_sightings(votes: dict[int, dict[int, int]], true_ids: np.ndarray, report) -> None:
    """Add one frame's sightings to ``votes`` (map id -> {true id: count}): each sighting j of true landmark
    ``true_ids[j]`` votes for the landmark it made and the one it matched (``report``: the filter's
    ``UpdateReport``, ``new_landmark_ids`` / ``best_matches``, -1 none)."""
    for j, true_id in enumerate(true_ids):
        for lid in (report.new_landmark_ids[j], report.best_matches[j]):
            if lid >= 0:
                tally = votes.setdefault(int(lid), {})
                tally[int(true_id)] = tally.get(int(true_id), 0) + 1


def attribute_landmarks(votes: dict[int, dict[int, int]], map_ids: np.ndarray) -> np.ndarray:
    """The true landmark (N,) each map landmark stands for: the one most of its creating and matched sightings
    were of (-1 for a landmark no sighting voted for). ``votes``: map id -> {true id: count}."""
    out = np.full(len(map_ids), -1, np.int64)
    for i, lid in enumerate(map_ids):
        tally = votes.get(int(lid))
        if tally:
            out[i] = max(tally.items(), key=lambda kv: (kv[1], -kv[0]))[0]
    return out


def map_scores(positions: np.ndarray, covariances: np.ndarray, attributed: np.ndarray, true_start: np.ndarray,
               truth_ids: np.ndarray, truth_positions: np.ndarray, sighted_ids: np.ndarray) -> dict:
    """Landmark figures of a map in the robot's start frame.

    positions (N, ≥2), covariances (N, ≥2, ≥2) in the start frame; attributed (N,) true id per landmark (-1:
    none); true_start (3,) the start pose in the world; truth_ids (L,), truth_positions (L, 2) in the world;
    sighted_ids: the true ids the robot saw (its map should hold each once).
    """
    n = len(positions)
    index = {int(i): k for k, i in enumerate(truth_ids)}
    known = np.array([int(a) in index for a in attributed], bool) if n else np.zeros(0, bool)
    true_world = np.array([truth_positions[index[int(a)]] for a in attributed[known]]).reshape(-1, 2)
    # the truth seen from the true start pose: where a perfect map in the start frame puts each landmark
    true_start_frame = compose(np.zeros(3), between(true_start, np.column_stack(
        [true_world, np.zeros(len(true_world))])))[:, :2] if len(true_world) else np.zeros((0, 2))
    estimate = positions[known, :2]
    errors = estimate - true_start_frame
    distances = np.linalg.norm(errors, axis=1)
    nees = points_nees(errors, covariances[known][:, :2, :2])
    distinct = len(np.unique(attributed[known]))
    scores = {
        "landmarks": int(n),
        "true_landmarks": int(len(np.unique(sighted_ids))),
        "mapped_true_landmarks": int(distinct),
        "unattributed_landmarks": int(n - known.sum()),
        "duplicate_landmarks": int(known.sum() - distinct),
        "duplicate_fraction": float((known.sum() - distinct) / n) if n else 0.0,
        "landmark_error_median_m": _median(distances),
        "landmark_error_rms_m": float(np.sqrt(np.mean(distances ** 2))) if len(distances) else float("nan"),
        "landmark_nees_within_bound": float(np.mean(nees < CHI2_95[2])) if len(nees) else float("nan"),
        "landmark_nees_median": _median(nees),
        "landmark_sd_median_m": _median(np.sqrt(0.5 * (covariances[:, 0, 0] + covariances[:, 1, 1])))
        if n else float("nan"),
    }
    if known.sum() >= 2:
        fit = rigid_fit_2d(estimate, true_world)
        fitted = compose(fit, np.column_stack([estimate, np.zeros(len(estimate))]))[:, :2]
        rigid = np.linalg.norm(fitted - true_world, axis=1)
        scores["landmark_error_rigid_median_m"] = _median(rigid)
        # the same residuals, in the map's frame, against the map's own covariances
        c, s = np.cos(fit[2]), np.sin(fit[2])
        residual_map = (true_world - fitted) @ np.array([[c, -s], [s, c]])
        scores["landmark_nees_rigid_within_bound"] = float(
            np.mean(points_nees(residual_map, covariances[known][:, :2, :2]) < CHI2_95[2]))
    else:
        scores["landmark_error_rigid_median_m"] = float("nan")
        scores["landmark_nees_rigid_within_bound"] = float("nan")
    return scores


def rigid_functional(truth: np.ndarray) -> np.ndarray:
    """(3, 2N): the linear map from landmark errors eᵢ (rows (x₀, y₀, x₁, …)) to their least-squares rigid motion
    (dx, dy, dθ), eᵢ ≈ d + dθ (−yᵢ, xᵢ) at the true positions ``truth`` (N, ≥2) (N ≥ 2, not all in one place)."""
    truth = np.asarray(truth, float)[:, :2]
    design = np.zeros((2 * len(truth), 3))
    design[0::2, 0] = design[1::2, 1] = 1.0
    design[0::2, 2], design[1::2, 2] = -truth[:, 1], truth[:, 0]
    return np.linalg.solve(design.T @ design, design.T)


def frame_error(estimate: np.ndarray, truth: np.ndarray, joint_covariance: np.ndarray) -> dict:
    """A map's error as one rigid motion of its frame, against the map's own joint covariance.

    estimate, truth (N, 2): the landmarks in the map's frame and where a perfect map puts them (the truth seen from
    the true pose of the frame's origin); joint_covariance (2N, 2N): the estimate's joint covariance, rows (x₀, y₀,
    x₁, …). The motion (dx, dy, dθ) is the least-squares fit of the errors eᵢ = estimateᵢ − truthᵢ ≈ d + dθ (−yᵢ, xᵢ)
    at the true positions: a rotation about the frame's origin (the robot's pose at its first sighting) and a
    translation, dθ > 0 counter-clockwise. It is a linear function F e of the errors, so its covariance is F Σ Fᵀ:
    ``landmark_frame_error`` [dx, dy, dθ] (m, m, rad), ``landmark_frame_sd`` their σ, ``landmark_frame_nees`` the χ²₃
    NEES of the motion (95 % bound 7.815). A start-frame miss with a large frame NEES and a small rigid-fit one is the
    frame's (its few first factors), not the map's shape. NaN with fewer than 2 landmarks.
    """
    truth = np.asarray(truth, float)[:, :2]
    if len(truth) < 2:
        return {"landmark_frame_error": [float("nan")] * 3, "landmark_frame_sd": [float("nan")] * 3,
                "landmark_frame_nees": float("nan")}
    functional = rigid_functional(truth)
    motion = functional @ (np.asarray(estimate, float)[:, :2] - truth).ravel()
    covariance = functional @ np.asarray(joint_covariance, float) @ functional.T
    covariance = 0.5 * (covariance + covariance.T)
    return {"landmark_frame_error": [float(v) for v in motion],
            "landmark_frame_sd": [float(v) for v in np.sqrt(np.diag(covariance))],
            "landmark_frame_nees": float(motion @ np.linalg.solve(covariance, motion))}


def pose_nees_figures(nees: np.ndarray) -> dict:
    """The figures of a pose NEES series (T,) over the frames that have one (NaN entries left out): mean, median, the
    share within χ²₃ 95 % and how many frames; the three figures NaN when no frame has one."""
    finite = nees[np.isfinite(nees)]
    if not len(finite):
        return {"pose_nees_mean": float("nan"), "pose_nees_median": float("nan"),
                "pose_nees_within_chi2_95": float("nan"), "pose_nees_frames": 0}
    return {"pose_nees_mean": float(np.mean(finite)), "pose_nees_median": float(np.median(finite)),
            "pose_nees_within_chi2_95": float(np.mean(finite < CHI2_95[3])), "pose_nees_frames": int(len(finite))}


def pose_nees(errors: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """eᵀ P⁻¹ e per pose: errors (T, 3) (θ wrapped here), covariances (T, 3, 3) -> (T,); NaN where P is singular."""
    e = np.array(errors, float)
    e[:, 2] = wrap_angle(e[:, 2])
    out = np.full(len(e), np.nan)
    for i in range(len(e)):   # T is the number of sightings (thousands): a plain loop is fast enough
        p = covariances[i]
        if np.all(np.isfinite(p)) and np.linalg.cond(p) < 1e12:
            out[i] = float(e[i] @ np.linalg.solve(p, e[i]))
    return out


def _median(values: np.ndarray) -> float:
    values = np.asarray(values, float)
    return float(np.median(values)) if len(values) else float("nan")
