"""Map consistency scores of a simulated FastSLAM run: landmark NEES against the truth, duplicates, pose NEES.

Used by ``bench_fastslam.py --accuracy`` (synthetic sensor) and ``eval_slam_rendered.py`` (rendered frames):
``runtime.slam_sim.simulate`` is run with a filter that records its update reports and an observer that records
which true point each observation stands for, so every landmark of the exported map has its true position.

Landmark NEES = eᵀ Σ⁻¹ e, e = the landmark's position minus its true point, both in the robot's start frame
(known exactly in simulation), Σ the exported covariance. A consistent map has NEES ~ χ²₃: 95 % of the
landmarks below 7.815. Duplicate fraction = (landmarks − distinct true points they stand for) / landmarks.
"""
from __future__ import annotations

import numpy as np

import runtime.slam_sim as slam_sim
from estimation.fastslam import FastSLAM
from estimation.geometry import rot_z

CHI2_3_95 = 7.815
WRONG_MERGE_M = 0.10   # m: merged landmarks whose true points are farther apart joined two points


class RecordingFastSLAM(FastSLAM):
    """A FastSLAM that keeps every update's report (the last instance made is ``RecordingFastSLAM.last``)."""

    last: RecordingFastSLAM | None = None

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.reports = []
        RecordingFastSLAM.last = self

    def update(self, observations):
        report = super().update(observations)
        self.reports.append(report)
        return report


class RecordingObserver:
    """Wraps an observer; keeps the per-observation true point index of every frame."""

    def __init__(self, observer) -> None:
        self.observer = observer
        self.indices: list[np.ndarray] = []

    def observe(self, pose, timestamp: float = 0.0):
        observations, index = self.observer.observe(pose, timestamp)
        self.indices.append(np.asarray(index, np.int64))
        return observations, index


def landmark_scores(landmark_map, start_pose, truth_points: np.ndarray, reports, indices) -> dict:
    """NEES (L,) of the map's landmarks whose creating observation has a true point, and summary figures."""
    point_of = {}
    for report, index in zip(reports, indices, strict=False):
        for j in np.flatnonzero(report.new_landmark_ids >= 0):
            point_of.setdefault(int(report.new_landmark_ids[j]), int(index[j]))
    points = np.array([point_of.get(int(i), -1) for i in landmark_map.ids], np.int64)
    known = points >= 0
    start = np.asarray(start_pose, float)
    truth_world = truth_points[points[known]]
    truth_start = (truth_world - [start[0], start[1], 0.0]) @ rot_z(start[2])   # Rᵀ (p − t), row vectors
    err = landmark_map.positions[known] - truth_start
    nees = np.einsum("ni,ni->n", err, np.linalg.solve(landmark_map.covariances[known], err[..., None])[..., 0])
    n = len(landmark_map)
    distinct = len(np.unique(points[known]))
    return {
        "landmark_nees": nees,
        "landmark_nees_median": float(np.median(nees)) if len(nees) else float("nan"),
        "landmark_nees_within_bound": float(np.mean(nees < CHI2_3_95)) if len(nees) else float("nan"),
        "landmark_error_median_m": float(np.median(np.linalg.norm(err, axis=1))) if len(err) else float("nan"),
        "duplicate_fraction": float((known.sum() - distinct) / n) if n else 0.0,
    }


def merge_scores(merged_pairs, truth_points: np.ndarray, reports, indices) -> dict:
    """The filter's merges (``FastSLAM.merged_pairs``: older id, newer id, by co-visibility) against the truth:
    the distance between the true points behind each pair's first observations. A merge of points more than
    ``WRONG_MERGE_M`` apart joined distinct landmarks; the front end's own corners slide by up to 8-9 cm (90th
    percentile, docs/fastslam-history.md), so merges of points 5-10 cm apart are counted separately, not as wrong."""
    point_of = {}
    for report, index in zip(reports, indices, strict=False):
        for j in np.flatnonzero(report.new_landmark_ids >= 0):
            point_of.setdefault(int(report.new_landmark_ids[j]), int(index[j]))
    pairs = {(int(a), int(b)): bool(e) for a, b, e in merged_pairs}
    apart = []
    for (a, b), by_evidence in pairs.items():
        pa, pb = point_of.get(a, -1), point_of.get(b, -1)
        if pa >= 0 and pb >= 0:
            apart.append((float(np.linalg.norm(truth_points[pa] - truth_points[pb])), by_evidence))
    d = np.array([x for x, _ in apart])
    ev = np.array([e for _, e in apart], bool)
    return {"merges": len(pairs), "merges_by_covisibility": int(sum(pairs.values())), "merges_scored": len(d),
            "merges_5_to_10cm": int(np.sum((d > 0.05) & (d <= WRONG_MERGE_M))),
            "merges_wrong": int(np.sum(d > WRONG_MERGE_M)),
            "merges_wrong_by_covisibility": int(np.sum((d > WRONG_MERGE_M) & ev)),
            "merge_true_distance_p90_m": float(np.percentile(d, 90)) if len(d) else float("nan")}


ASSOCIATION_RATIO_BINS = (0.0, 0.2, 0.4, np.inf)   # |ln r / r_made|: the range of a match against its landmark's first


def association_scores(reports, indices, truth_points: np.ndarray, ranges) -> dict:
    """The most probable particle's matches against the truth: a match whose observation stands for a true point
    more than ``WRONG_MERGE_M`` from the one behind the landmark's first sighting joined two points. Per frame:
    ``reports`` (UpdateReport), ``indices`` (N,) true point per observation, ``ranges`` (N,) m from the sensor;
    shares overall and by |ln(range / range at the landmark's creation)| (``ASSOCIATION_RATIO_BINS``)."""
    origin: dict[int, tuple[int, float]] = {}
    apart, log_ratio = [], []
    for report, index, rng in zip(reports, indices, ranges, strict=False):
        for j in np.flatnonzero(report.best_matches >= 0):
            point, made_at = origin.get(int(report.best_matches[j]), (-1, np.nan))
            if point >= 0 and index[j] >= 0:
                apart.append(float(np.linalg.norm(truth_points[index[j]] - truth_points[point])))
                log_ratio.append(abs(float(np.log(rng[j] / made_at))))
        for j in np.flatnonzero(report.new_landmark_ids >= 0):
            origin.setdefault(int(report.new_landmark_ids[j]), (int(index[j]), float(rng[j])))
    apart, log_ratio = np.array(apart), np.array(log_ratio)
    out = {"matches_scored": len(apart),
           "matches_wrong_share": float(np.mean(apart > WRONG_MERGE_M)) if len(apart) else float("nan")}
    edges = ASSOCIATION_RATIO_BINS
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        sel = (log_ratio >= lo) & (log_ratio < hi)
        out[f"matches_ln_ratio_{lo:g}_{hi:g}"] = int(sel.sum())
        out[f"matches_wrong_share_ln_ratio_{lo:g}_{hi:g}"] = float(np.mean(apart[sel] > WRONG_MERGE_M)) \
            if sel.any() else float("nan")
    return out


def run_scored(world, *, robot: str, seed: int, config, observer, scoring_world=None, **simulate_kwargs) -> dict:
    """``slam_sim.simulate`` with ``observer`` (wrapped to record), plus :func:`landmark_scores`; returns the
    simulate metrics, the landmark scores and the filter's stats."""
    recording = RecordingObserver(observer)
    original = slam_sim.FastSLAM
    slam_sim.FastSLAM = RecordingFastSLAM
    try:
        result = slam_sim.simulate(scoring_world or world, start_pose=world.start_poses[robot], robot=robot,
                                   seed=seed, config=config, observer=recording, **simulate_kwargs)
    finally:
        slam_sim.FastSLAM = original
    slam = RecordingFastSLAM.last
    truth = (scoring_world or world).features
    scores = landmark_scores(result.map, world.start_poses[robot], truth, slam.reports, recording.indices)
    stats = getattr(slam, "stats", None)
    return {**result.metrics, **{k: v for k, v in scores.items() if k != "landmark_nees"},
            "stats": vars(stats).copy() if stats is not None else {}, "_result": result, "_slam": slam}
