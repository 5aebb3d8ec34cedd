"""What the rendered maps' duplicates are: every duplicate pair of the exported map, sorted into its cause.

Run from the repository root (replays the rendered frames' cache of ``eval_slam_rendered --frames-cache``):

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.rendered_duplicates --robot robot1 --seed 0
        --frames-cache DIR [--frame-rate 3.75] [--set KEY=VALUE ...] [--exported [--pairs]] [--json]

**With ``--exported``** (session 18): the map ``eval_slam_rendered`` scores, from the same run (its default config,
100 particles; a replay of the cache gives its scores): ``best_map``, after the export's merge of coincident
landmarks. Each exported landmark stands for the 5 cm cluster of its (kept id's) first sighting, as ``simulate``
counts ``duplicate_landmarks``, and each newer landmark of a cluster is paired with the oldest, so the number of
pairs is eval's count (printed beside it; it matches). Per pair: the estimates' distance (along the newer's line
of sight, across it, in height), d² under the export merge's own covariances (the conditional ones, merged alike:
every residual pair is beyond χ²₃ 95 % there by construction), under the exported ones and with the pose's drift
between the two creations added (``drift_merge.relative_drift``); whether the best particle detected the two in
one frame (``made_beside``: the newer made in a frame that saw the older, with the two readings' own d² and true
points; ``codetected``: later; else ``never_together``); when each was made and the best trajectory's error then;
the first sightings' raw true points (the rendered ray's hit, before the scorer's snapping) and the landmarks' own
points (the median true point of every reading each made or matched). Also: the scorer's clustering redone at
2, 3 and 5 cm (5 cm gives eval's count), a count free of its clusters (landmarks whose first sightings' true points
chain within 1-3 cm), and what a further merge would do (``merge_further``: the relative drift, or the exported
covariances, never co-detected pairs), scored as eval scores the export's merges.

**Without it** (sessions 5-9; the map before the export's merge, ``max_observations=0``): a duplicate pair is
two landmarks of the best particle's map whose first sightings
stand for the same true surface point (``eval_slam_rendered``'s 5 cm clusters); each newer one is paired with
the oldest of its cluster. Each pair goes to the first of these causes that fits (session 5's categories):

- ``made_beside``: the newer was made in a frame in which the best particle also detected (or made) the older:
  two observations of one point in one frame, which the front end reports as two corners;
- ``codetected``: not made beside it, but detected together with it in some later frame;
- ``descriptor``: one point by the particle's own geometry (d² < χ²₃ 95 % under Σ_a + Σ_b, its EKF covariances)
  but the descriptors are apart (≥ the merge's threshold): the look changed with the viewing range;
- ``beyond_gate``: d² ≥ χ²₃ 95 %: the estimates are apart by more than the EKF claims (drift, slid corners);
- ``mergeable``: the rest (one point by geometry and descriptor, not merged yet: the merge's radius or timing).

Also per frame (``frames``): pairs of observations of one frame whose triangulated points coincide within their
own covariances (d² < χ²₃ 95 % under Q_i + Q_j, the filter's floor added to each), split by whether they stand
for the same true cluster, points 5-10 cm apart, or more than 10 cm apart (what a "one observation per
physical point" rule would join).
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
from benchmarks.eval_slam_rendered import replay_through, runtime_config
from estimation.fastslam import FastSLAM, FastSLAMConfig
from estimation.fastslam.coincident import coincident_pairs
from estimation.fastslam.drift_merge import relative_drift
from estimation.fastslam.export_merge import merge_coincident
from estimation.fastslam.linalg import sym_matrices
from estimation.geometry import transform_points
from runtime.commands.options import non_negative_int, positive_float, positive_int

CHI2_3_95 = 7.815
CAUSES = ("made_beside", "codetected", "descriptor", "beyond_gate", "mergeable")


class _RecordingFastSLAM(FastSLAM):
    last: _RecordingFastSLAM | None = None

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.reports = []
        _RecordingFastSLAM.last = self

    def update(self, observations):
        report = super().update(observations)
        self.reports.append(report)
        return report


def frame_coincidences(arrays: dict, starts: np.ndarray, floor: float) -> dict:
    """Coincident observation pairs over all cached frames, scored by the true points behind them."""
    truth = arrays["true_points"].reshape(-1, 3)
    same = near = far = unknown = 0
    observations = int(starts[-1])
    in_pairs = 0
    for k in range(len(starts) - 1):
        lo, hi = starts[k], starts[k + 1]
        i, j = coincident_pairs(arrays["points"][lo:hi], arrays["covariances"][lo:hi] + floor * np.eye(3))
        if not len(i):
            continue
        pairs = np.stack([i, j], axis=1)
        in_pairs += len(np.unique(pairs))
        index = arrays["index"][lo:hi]
        a, b = index[pairs[:, 0]], index[pairs[:, 1]]
        ok = (a >= 0) & (b >= 0)
        unknown += int((~ok).sum())
        dist = np.linalg.norm(truth[a[ok]] - truth[b[ok]], axis=1)
        same += int((a[ok] == b[ok]).sum())
        near += int(((a[ok] != b[ok]) & (dist <= 0.10)).sum())
        far += int((dist > 0.10).sum())
    total = same + near + far
    return {"observations": observations, "observations_in_a_pair": in_pairs, "pairs": total + unknown,
            "same_cluster": same, "apart_5_10cm": near, "apart_over_10cm": far, "no_truth": unknown,
            "share_same_cluster": same / total if total else float("nan"),
            "share_over_10cm": far / total if total else float("nan")}


def run(robot: str, seed: int, frame_rate: float, frames_cache: Path, config: FastSLAMConfig) -> dict:
    """Replay one robot's cached frames through the filter and sort the exported map's duplicate pairs."""
    from mocks.world import World

    world = World.load()
    observer, start, result, slam = replay_through(_RecordingFastSLAM, world, robot, seed, frame_rate,
                                                   frames_cache, config)
    arrays, starts = observer._arrays, observer._starts
    lmap = slam.particle_map(slam.best_index, config.confirm_count, covariance="particle")
    row_of = {int(i): r for r, i in enumerate(lmap.ids)}

    made: dict[int, tuple[int, int]] = {}              # landmark id -> (frame, observation)
    detected: list[set[int]] = []                      # per frame: ids the best particle detected or made
    for k, report in enumerate(slam.reports):
        ids = set(int(i) for i in report.best_matches[report.best_matches >= 0])
        for j in np.flatnonzero(report.new_landmark_ids >= 0):
            lid = int(report.new_landmark_ids[j])
            made.setdefault(lid, (k, int(j)))
            ids.add(lid)
        detected.append(ids)
    frames_of: dict[int, set[int]] = {}
    for k, ids in enumerate(detected):
        for lid in ids:
            if lid in row_of:
                frames_of.setdefault(lid, set()).add(k)

    clusters: dict[int, list[int]] = {}
    for lid in row_of:
        if lid in made:
            k, j = made[lid]
            point = int(arrays["index"][starts[k] + j])
            if point >= 0:
                clusters.setdefault(point, []).append(lid)
    pairs = []
    for lids in clusters.values():
        lids = sorted(lids)
        for newer in lids[1:]:
            pairs.append((lids[0], newer))

    rows = []
    for older, newer in pairs:
        a, b = row_of[older], row_of[newer]
        d = lmap.positions[a] - lmap.positions[b]
        d2 = float(d @ np.linalg.solve(lmap.covariances[a] + lmap.covariances[b], d))
        desc = float(np.linalg.norm(lmap.descriptors[a] - lmap.descriptors[b]))
        (ka, ja), (kb, jb) = made[older], made[newer]
        depth_a = float(arrays["points"][starts[ka] + ja][0])
        depth_b = float(arrays["points"][starts[kb] + jb][0])
        together = frames_of.get(older, set()) & frames_of.get(newer, set())
        beside = older in detected[kb]
        if beside:
            cause = "made_beside"
        elif together:
            cause = "codetected"
        elif d2 >= CHI2_3_95:
            cause = "beyond_gate"
        elif desc >= config.merge_descriptor_threshold:
            cause = "descriptor"
        else:
            cause = "mergeable"
        rows.append({"cause": cause, "distance_m": float(np.linalg.norm(d)), "d2": d2, "descriptor": desc,
                     "depth_ratio": depth_b / depth_a, "codetected_frames": len(together)})
    counts = {c: sum(r["cause"] == c for r in rows) for c in CAUSES}
    n = len(rows)

    def median(key, cause=None):
        v = [r[key] for r in rows if cause is None or r["cause"] == cause]
        return float(np.median(v)) if v else float("nan")

    return {
        "robot": robot, "seed": seed, "landmarks": len(lmap), "duplicate_pairs": n,
        "causes": counts, "cause_shares": {c: counts[c] / n if n else float("nan") for c in CAUSES},
        "distance_median_m": median("distance_m"), "d2_median": median("d2"),
        "descriptor_median": median("descriptor"), "depth_ratio_median": median("depth_ratio"),
        "by_cause": {c: {"distance_median_m": median("distance_m", c), "d2_median": median("d2", c),
                         "descriptor_median": median("descriptor", c), "depth_ratio_median": median("depth_ratio", c)}
                     for c in CAUSES if counts[c]},
        "frames": frame_coincidences(arrays, starts, config.observation_var_floor),
    }


SNAPS_M = (0.02, 0.03, 0.05)              # the scorer's clustering redone at these radii (0.05: its own)
SAME_POINT_RADII_M = (0.01, 0.02, 0.03)   # the scorer-independent counts: first sightings' true points this close
CREATION_ERROR_M = 0.15                   # a landmark "made off the frame": the best trajectory's error then


def export_groups(ids, merged_at_export) -> dict[int, set[int]]:
    """Each exported landmark's id -> the filter's ids merged into it (``metadata["merged_at_export"]``, in rounds:
    a merged id may have absorbed others in an earlier round)."""
    groups = {int(i): {int(i)} for i in ids}
    absorbed: dict[int, set[int]] = {}
    for kept, merged in merged_at_export:
        members = absorbed.pop(int(merged), {int(merged)})
        absorbed.setdefault(int(kept), {int(kept)}).update(members)
    for kept, members in absorbed.items():
        if kept in groups:
            groups[kept] |= members
    return groups


def same_point_duplicates(points: np.ndarray, radius: float) -> int:
    """Landmarks minus groups of landmarks whose true points (N, 3) chain within ``radius`` (single linkage): a
    duplicate count that does not depend on the scorer's first-seen 5 cm clusters."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    points = np.asarray(points, float).reshape(-1, 3)
    if len(points) < 2:
        return 0
    pairs = cKDTree(points).query_pairs(radius, output_type="ndarray").reshape(-1, 2)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(points), len(points)))
    return len(points) - int(connected_components(graph, directed=False)[0])


def snap_clusters(points: np.ndarray, snap: float) -> np.ndarray:
    """(N,) cluster index of each true point (N, 3) taken in order, as ``eval_slam_rendered.RenderedObserver`` makes
    them with its ``SNAP``: the nearest earlier cluster's first point within ``snap``, else a new cluster (-1 for
    NaN). With snap = 0.05 m this reproduces the scorer's clusters; other values say how its count depends on it."""
    cells: dict[tuple[int, int, int], list[int]] = {}
    firsts: list[np.ndarray] = []
    out = np.full(len(points), -1, np.int64)
    for n, p in enumerate(np.asarray(points, float).reshape(-1, 3)):
        if not np.all(np.isfinite(p)):
            continue
        cell = np.floor(p / snap).astype(int)
        best, best_d = -1, snap
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for dz in (-1, 0, 1):
                    for i in cells.get((cell[0] + dx, cell[1] + dy, cell[2] + dz), ()):
                        d = float(np.linalg.norm(firsts[i] - p))
                        if d < best_d:
                            best, best_d = i, d
        if best < 0:
            best = len(firsts)
            firsts.append(p)
            cells.setdefault(tuple(int(c) for c in cell), []).append(best)
        out[n] = best
    return out


def _duplicates(clusters: np.ndarray, made: dict, starts: np.ndarray, row_of: dict) -> int:
    """Landmarks with a cluster (their first sighting's) minus the distinct clusters: eval's count."""
    known = [int(clusters[starts[made[i][0]] + made[i][1]]) for i in row_of if i in made]
    known = [c for c in known if c >= 0]
    return len(known) - len(set(known))


def _d2(d: np.ndarray, covariance: np.ndarray) -> float:
    return float(d @ np.linalg.solve(covariance, d))


RULES = ("relative_drift", "exported")


def merge_further(rule: str, ids, positions, conditional, exported, counts, frames_of: dict[int, set[int]], tracker,
                  cluster_of: dict[int, int], cluster_points: np.ndarray, gate: float = CHI2_3_95,
                  radius: float = 1.0) -> dict:
    """What a further merge of the exported map would do, scored against the truth (an experiment, not the
    filter's): pairs never detected in one frame whose estimates coincide, d² < ``gate``, under Σ_a + Σ_b + R_ab
    (``rule`` "relative_drift": the conditional covariances and the pose's drift between the two creations,
    ``drift_merge.relative_drift``) or under the exported covariances ("exported": mixture + each one's absolute
    drift); closest first, each landmark once a round, rounds until none passes, merged as the export merges.
    Returns the duplicates left (eval's count) and the merges' true distances."""
    from scipy.spatial import cKDTree

    ids = [int(i) for i in ids]
    positions, conditional, exported = positions.copy(), conditional.copy(), exported.copy()
    frames = {i: set(frames_of.get(i, set())) for i in ids}
    counts = {i: float(c) for i, c in zip(ids, counts, strict=True)}
    alive = np.ones(len(ids), bool)
    apart = []
    while True:
        rows = np.flatnonzero(alive)
        tree = cKDTree(positions[rows])
        cand = np.array(sorted(tree.query_pairs(radius)), np.int64).reshape(-1, 2)
        if not len(cand):
            break
        a, b = rows[cand[:, 0]], rows[cand[:, 1]]
        a, b = np.where([ids[x] < ids[y] for x, y in zip(a, b, strict=True)], a, b), np.where(
            [ids[x] < ids[y] for x, y in zip(a, b, strict=True)], b, a)
        d = positions[a] - positions[b]
        if rule == "relative_drift":
            mid = 0.5 * (positions[a] + positions[b])
            extra = sym_matrices(relative_drift(tracker, np.array([ids[x] for x in a]),
                                                np.array([ids[y] for y in b]), mid))
            cov = conditional[a] + conditional[b] + extra
        else:
            cov = exported[a] + exported[b]
        d2 = np.einsum("ni,ni->n", d, np.linalg.solve(cov, d[..., None])[..., 0])
        ok = (d2 < gate) & np.array([not (frames[ids[x]] & frames[ids[y]]) for x, y in zip(a, b, strict=True)])
        used = set()
        merged_any = False
        for k in np.flatnonzero(ok)[np.argsort(np.einsum("ni,ni->n", d, d)[ok], kind="stable")]:
            x, y = int(a[k]), int(b[k])
            if x in used or y in used:
                continue
            used |= {x, y}
            merged_any = True
            ca, cb = cluster_of.get(ids[x], -1), cluster_of.get(ids[y], -1)
            if ca >= 0 and cb >= 0:
                apart.append(float(np.linalg.norm(cluster_points[ca] - cluster_points[cb])))
            wa = counts[ids[x]] / (counts[ids[x]] + counts[ids[y]])
            wb = 1.0 - wa
            spread = np.outer(positions[x] - positions[y], positions[x] - positions[y]) * wa * wb
            for m in (conditional, exported):
                m[x] = wa * m[x] + wb * m[y] + spread
            positions[x] = wa * positions[x] + wb * positions[y]
            counts[ids[x]] += counts[ids[y]]
            frames[ids[x]] |= frames[ids[y]]
            alive[y] = False
        if not merged_any:
            break
    kept = [ids[r] for r in np.flatnonzero(alive)]
    known = [cluster_of[i] for i in kept if cluster_of.get(i, -1) >= 0]
    apart = np.array(apart)
    return {"rule": rule, "merges": len(apart), "merges_wrong": int(np.sum(apart > 0.10)),
            "merges_5_to_10cm": int(np.sum((apart > 0.05) & (apart <= 0.10))),
            "landmarks": len(kept), "duplicates": len(known) - len(set(known)),
            "duplicate_fraction": (len(known) - len(set(known))) / max(len(kept), 1)}


def run_exported(robot: str, seed: int, frame_rate: float, frames_cache: Path, config: FastSLAMConfig,
                 with_pairs: bool = False) -> dict:
    """Replay one robot's cached frames as ``eval_slam_rendered`` runs it and sort the duplicate pairs of the map it
    scores: the exported map (``best_map``, coincident landmarks merged), each landmark attributed to the cluster
    of its (kept id's) first sighting, as ``eval_slam_rendered``/``simulate`` count ``duplicate_landmarks``."""
    from benchmarks.eval_slam_rendered import CALIBRATION
    from drivers.videre import calibration
    from mocks.stereo_head.renderer import StereoRenderer
    from mocks.world import World

    world = World.load()
    observer, start, result, slam = replay_through(_RecordingFastSLAM, world, robot, seed, frame_rate,
                                                   frames_cache, config)
    arrays, starts = observer._arrays, observer._starts
    lmap = result.map
    # the export merge's own covariances for the merged map: the conditional ones, merged the same way
    particle = slam.particle_map(slam.best_index, config.confirm_count, covariance="particle")
    conditional_map = merge_coincident(particle, particle.covariances) if config.export_merge_coincident else particle
    if not np.array_equal(conditional_map.ids, lmap.ids) or not np.allclose(conditional_map.positions, lmap.positions):
        raise SystemExit("the conditional merge does not reproduce the exported map")
    conditional = conditional_map.covariances
    row_of = {int(i): r for r, i in enumerate(lmap.ids)}
    groups = export_groups(lmap.ids, lmap.metadata.get("merged_at_export", []))
    group_of = {m: kept for kept, members in groups.items() for m in members}

    made: dict[int, tuple[int, int]] = {}              # filter id -> (frame, observation) of its creation
    readings: dict[int, list[tuple[int, int]]] = {}    # exported id -> (frame, observation) it made or matched
    detected: list[set[int]] = []                      # per frame: exported ids the best particle detected or made
    for k, report in enumerate(slam.reports):
        ids = set()
        for j in np.flatnonzero(report.new_landmark_ids >= 0):
            made.setdefault(int(report.new_landmark_ids[j]), (k, int(j)))
        for j in range(report.n_observations):
            # the reading the best particle matched, and the one that made a landmark (in the particle whose
            # lineage kept it, which need not be this frame's best)
            for lid in {int(report.best_matches[j]), int(report.new_landmark_ids[j])}:
                if lid >= 0 and lid in group_of:
                    ids.add(group_of[lid])
                    readings.setdefault(group_of[lid], []).append((k, j))
        detected.append(ids)
    frames_of: dict[int, set[int]] = {}
    for k, ids in enumerate(detected):
        for lid in ids:
            frames_of.setdefault(lid, set()).add(k)

    # the raw true point behind every reading (the rendered ray's hit; the scorer snaps these to 5 cm clusters)
    renderer = StereoRenderer(world, calibration.load(CALIBRATION))
    raw = np.full((len(arrays["index"]), 3), np.nan)
    for k in range(len(starts) - 1):
        lo, hi = starts[k], starts[k + 1]
        if hi > lo:
            raw[lo:hi] = renderer.true_points(arrays["pose"][k], arrays["pixels"][lo:hi], "left", rectified=True)
    cluster_points = arrays["true_points"].reshape(-1, 3)

    # the best trajectory's error at each frame (row k + 1 is after frame k)
    est, true = result.estimated_trajectory, result.true_trajectory
    n = min(len(est), len(true))
    pos_err = np.full(len(starts), np.nan)
    head_err = np.full(len(starts), np.nan)
    pos_err[: n - 1] = np.linalg.norm(est[1:n, 1:3] - true[1:n, 1:3], axis=1)
    head_err[: n - 1] = (est[1:n, 3] - true[1:n, 3] + np.pi) % (2 * np.pi) - np.pi
    in_world = transform_points(start, lmap.positions)

    clusters: dict[int, list[int]] = {}
    first_raw = {}
    for lid in row_of:
        if lid in made:
            k, j = made[lid]
            point = int(arrays["index"][starts[k] + j])
            first_raw[lid] = raw[starts[k] + j]
            if point >= 0:
                clusters.setdefault(point, []).append(lid)
    pairs = [(sorted(lids)[0], newer, point) for point, lids in clusters.items() for newer in sorted(lids)[1:]]
    known = sum(len(v) for v in clusters.values())

    def own_point(lid):   # the median raw true point of every reading the landmark made or matched
        r = np.array([raw[starts[k] + j] for k, j in readings.get(lid, [])]).reshape(-1, 3)
        r = r[np.all(np.isfinite(r), axis=1)]
        return np.median(r, axis=0) if len(r) else np.full(3, np.nan)

    tracker = slam.drift
    rows = []
    for older, newer, point in pairs:
        a, b = row_of[older], row_of[newer]
        d = lmap.positions[a] - lmap.positions[b]
        (ka, ja), (kb, jb) = made[older], made[newer]
        mid = 0.5 * (lmap.positions[a] + lmap.positions[b])
        rel = sym_matrices(relative_drift(tracker, np.array([older]), np.array([newer]), mid[None]))[0]
        together = frames_of.get(older, set()) & frames_of.get(newer, set())
        beside = older in detected[kb]
        ray = mid[:2] - tracker.landmark_origins(np.array([newer]))[0]      # the newer's line of sight (x, y)
        ray /= max(float(np.linalg.norm(ray)), 1e-9)
        row = {"older": older, "newer": newer, "cluster": point,
               "cause": "made_beside" if beside else "codetected" if together else "never_together",
               "distance_m": float(np.linalg.norm(d)),
               "d2_conditional": _d2(d, conditional[a] + conditional[b]),
               "d2_exported": _d2(d, lmap.covariances[a] + lmap.covariances[b]),
               "d2_relative_drift": _d2(d, conditional[a] + conditional[b] + rel),
               "along_sight_m": float(abs(d[:2] @ ray)), "across_sight_m": float(abs(d[0] * ray[1] - d[1] * ray[0])),
               "height_m": float(abs(d[2])),
               "descriptor": float(np.linalg.norm(lmap.descriptors[a] - lmap.descriptors[b])),
               "made_s": (float(arrays["t"][ka]), float(arrays["t"][kb])),
               "depth_m": (float(arrays["points"][starts[ka] + ja][0]), float(arrays["points"][starts[kb] + jb][0])),
               "codetected_frames": len(together),
               "pose_error_at_made_m": (float(pos_err[ka]), float(pos_err[kb])),
               "heading_error_at_made_rad": (float(head_err[ka]), float(head_err[kb])),
               "true_apart_m": float(np.linalg.norm(first_raw[older] - first_raw[newer])),
               "own_points_apart_m": float(np.linalg.norm(own_point(older) - own_point(newer))),
               "errors_m": (float(np.linalg.norm(in_world[a] - cluster_points[point])),
                            float(np.linalg.norm(in_world[b] - cluster_points[point]))),
               "merged_into": (len(groups[older]) - 1, len(groups[newer]) - 1)}
        if beside:   # the two readings of frame kb: the newer's and the one the older's landmark took
            lo, hi = starts[kb], starts[kb + 1]
            js = [j for k, j in readings.get(older, []) if k == kb]
            z = arrays["points"][lo:hi]
            q = arrays["covariances"][lo:hi] + config.observation_var_floor * np.eye(3)
            best = min(js, key=lambda j: float(np.linalg.norm(z[j] - z[jb])))
            row["beside_readings_d2"] = _d2(z[best] - z[jb], q[best] + q[jb])
            row["beside_readings_apart_m"] = float(np.linalg.norm(z[best] - z[jb]))
            row["beside_true_apart_m"] = float(np.linalg.norm(raw[lo + best] - raw[lo + jb]))
            row["beside_same_cluster"] = bool(arrays["index"][lo + best] == arrays["index"][lo + jb])
        rows.append(row)

    def share(sel):
        return float(np.mean(sel)) if len(sel) else float("nan")

    def values(key, cause=None):
        return np.array([r[key] for r in rows if cause is None or r["cause"] == cause], float)

    bins = (0.0, 0.01, 0.03, 0.05, 0.10, np.inf)
    true_apart, own_apart = values("true_apart_m"), values("own_points_apart_m")
    made_err = np.array([pos_err[made[i][0]] for i in row_of if i in made])
    newer_err = np.array([r["pose_error_at_made_m"][1] for r in rows])
    gate = CHI2_3_95
    raws = np.array([first_raw[i] for i in row_of if i in made and np.all(np.isfinite(first_raw[i]))])
    beside_d2 = np.array([r["beside_readings_d2"] for r in rows if "beside_readings_d2" in r])
    beside_true = np.array([r["beside_true_apart_m"] for r in rows if "beside_true_apart_m" in r])
    out = {
        "robot": robot, "seed": seed, "map": "exported", "landmarks": len(lmap), "known": known,
        "duplicate_pairs": len(rows), "eval_duplicate_landmarks": int(result.metrics["duplicate_landmarks"]),
        "duplicate_fraction": len(rows) / len(lmap) if len(lmap) else 0.0, "ate_m": result.metrics["ate_m"],
        "export_merges": len(lmap.metadata.get("merged_at_export", [])),
        "causes": {c: int(sum(r["cause"] == c for r in rows)) for c in ("made_beside", "codetected", "never_together")},
        "distance_m_quartiles": np.percentile(values("distance_m"), [25, 50, 75]).tolist() if rows else [],
        "d2_conditional_quartiles": np.percentile(values("d2_conditional"), [25, 50, 75]).tolist() if rows else [],
        "d2_exported_below_gate": share(values("d2_exported") < gate),
        "d2_relative_drift_below_gate": share(values("d2_relative_drift") < gate),
        "true_apart_m_bins": {f"{lo:g}-{hi:g}": int(np.sum((true_apart >= lo) & (true_apart < hi)))
                              for lo, hi in zip(bins[:-1], bins[1:], strict=True)},
        "own_points_apart_m_bins": {f"{lo:g}-{hi:g}": int(np.sum((own_apart >= lo) & (own_apart < hi)))
                                    for lo, hi in zip(bins[:-1], bins[1:], strict=True)},
        "beside_readings_coincide": int(np.sum(beside_d2 < gate)), "beside_readings": len(beside_d2),
        "beside_true_apart_median_m": float(np.median(beside_true)) if len(beside_true) else float("nan"),
        "newer_made_off_frame": share(newer_err > CREATION_ERROR_M),
        "all_made_off_frame": share(made_err > CREATION_ERROR_M),
        "same_point_duplicates": {f"{r:g}": same_point_duplicates(raws, r) for r in SAME_POINT_RADII_M},
        "scorer_duplicates_by_snap": {f"{snap:g}": _duplicates(snap_clusters(raw, snap), made, starts, row_of)
                                      for snap in SNAPS_M},
    }
    cluster_of = {lid: int(arrays["index"][starts[made[lid][0]] + made[lid][1]]) for lid in row_of if lid in made}
    out["further_merges"] = {rule: merge_further(rule, lmap.ids, lmap.positions, conditional, lmap.covariances,
                                                 lmap.counts, frames_of, tracker, cluster_of, cluster_points)
                             for rule in RULES}
    if with_pairs:
        out["pairs"] = rows
    return out


def print_exported(r: dict) -> None:
    c = r["causes"]
    print(f"{r['robot']} seed {r['seed']} (exported map): {r['landmarks']} landmarks, {r['duplicate_pairs']} duplicate "
          f"pairs ({100 * r['duplicate_fraction']:.1f} %; eval's duplicate_landmarks {r['eval_duplicate_landmarks']}), "
          f"ATE {r['ate_m']:.3f} m, {r['export_merges']} export merges")
    print(f"  made beside the older {c['made_beside']}, co-detected later {c['codetected']}, never together "
          f"{c['never_together']}; the two readings of the frame coincide (d² < χ²₃ 95 %) in "
          f"{r['beside_readings_coincide']} of {r['beside_readings']}, their true points "
          f"{100 * r['beside_true_apart_median_m']:.1f} cm apart (median)")
    q, d = r["distance_m_quartiles"], r["d2_conditional_quartiles"]
    if q:
        print(f"  estimates apart {q[0]:.3f} / {q[1]:.3f} / {q[2]:.3f} m (quartiles), d² under the conditional "
              f"covariances {d[0]:.1f} / {d[1]:.1f} / {d[2]:.1f}; below the gate under the exported covariances "
              f"{100 * r['d2_exported_below_gate']:.0f} %, with the relative drift "
              f"{100 * r['d2_relative_drift_below_gate']:.0f} %")
    print(f"  first sightings' true points apart (m): {r['true_apart_m_bins']}; the landmarks' own points "
          f"(median of their readings): {r['own_points_apart_m_bins']}")
    print(f"  newer made while the best trajectory was > {CREATION_ERROR_M:g} m off: "
          f"{100 * r['newer_made_off_frame']:.0f} % (all landmarks: {100 * r['all_made_off_frame']:.0f} %)")
    print("  scorer-independent duplicates (first sightings' true points chained within r): "
          + ", ".join(f"{100 * float(k):g} cm {v}" for k, v in r["same_point_duplicates"].items()))
    print("  the scorer's clusters redone at other radii (its own 5 cm first): "
          + ", ".join(f"{100 * float(k):g} cm {v}" for k, v in reversed(r["scorer_duplicates_by_snap"].items())))
    for rule, f in r["further_merges"].items():
        print(f"  a further merge ({rule}, never co-detected): {f['merges']} merges ({f['merges_wrong']} > 10 cm, "
              f"{f['merges_5_to_10cm']} 5-10 cm apart), {f['landmarks']} landmarks, {f['duplicates']} duplicates "
              f"({100 * f['duplicate_fraction']:.1f} %)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", action="append", default=None, help="robot1 and/or robot2 (default both)")
    parser.add_argument("--seed", type=non_negative_int, action="append", default=None)
    parser.add_argument("--frame-rate", type=positive_float, default=3.75)
    parser.add_argument("--frames-cache", type=Path, required=True, metavar="DIR")
    parser.add_argument("--particles", type=positive_int, default=100)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a FastSLAMConfig field")
    parser.add_argument("--exported", action="store_true",
                        help="the map eval_slam_rendered scores: its default config (the runtime's), the "
                             "exported map after the export's merge; sorted by co-detection, with distances, d², "
                             "creation times and true points (the module docstring's second part)")
    parser.add_argument("--pairs", action="store_true", help="with --exported --json: every pair's row")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    config = replace(runtime_config(args.particles), **config_overrides(args.set))
    if args.exported:
        out = [run_exported(robot, seed, args.frame_rate, args.frames_cache, config, args.pairs)
               for seed in (args.seed or [0]) for robot in (args.robot or ["robot1", "robot2"])]
        if args.json:
            print(json.dumps(out, indent=2))
            return 0
        for r in out:
            print_exported(r)
        return 0
    out = [run(robot, seed, args.frame_rate, args.frames_cache, config)
           for seed in (args.seed or [0]) for robot in (args.robot or ["robot1", "robot2"])]
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    for r in out:
        shares = ", ".join(f"{c} {r['causes'][c]} ({100 * r['cause_shares'][c]:.0f} %)" for c in CAUSES)
        f = r["frames"]
        print(f"{r['robot']} seed {r['seed']}: {r['landmarks']} landmarks, {r['duplicate_pairs']} duplicate pairs: "
              f"{shares}")
        print(f"  pairs: distance median {r['distance_median_m']:.3f} m, d² {r['d2_median']:.1f}, descriptor "
              f"{r['descriptor_median']:.2f}, newer/older depth {r['depth_ratio_median']:.2f}")
        print(f"  frames: {f['pairs']} coincident observation pairs in one frame ({f['observations_in_a_pair']} of "
              f"{f['observations']} observations): same cluster {f['same_cluster']}, 5-10 cm apart "
              f"{f['apart_5_10cm']}, > 10 cm apart {f['apart_over_10cm']}, no truth {f['no_truth']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
