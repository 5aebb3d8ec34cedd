"""The rendered stereo camera's detection rates as the filter's existence model sees them, measured with the truth.

Run from the repository root:

    .venv/bin/python -m benchmarks.stereo_detection_rates DEMO_DIR [DEMO_DIR ...] [--robots robot1,robot2]
        [--cache-dir DIR] [--filter-seed K] [--render-seed S]

``estimation/fastslam/existence.py`` can weigh a landmark's detections and misses by the sensor's own rates (P_D per
range band, P_FA, the lag-1 correlation ρ of a landmark's detected / missed frames); `p3at slam noise` fits them for
MRCLAM, and the stereo camera has kept the constants +1 / −0.5 ("no measured rates"). This script measures them on
replays of demo robots (``benchmarks.slam_demo_replay``'s replay: the route driven, the demo's odometry, frames
rendered again at the true pose; ``--cache-dir`` keeps the rendered frames, ``<demo name>-<robot>.npz``):

- P_D(r): of the update's best particle's confirmed landmarks (seen ≥ ``confirm_count`` times) standing for a true
  point, predicted well in view at sensor range r (the filter's own test: ``miss_fov_margin`` of the view and
  range), the share the frame matched — what the filter counts as a detection; bands 0–3, 3–5, > 5 m
  (``noise_model.DETECTION_BANDS``). Beside it, the share whose true point was among the frame's readings at all
  (reported, matched or not).
- ρ: the lag-1 correlation of each such landmark's matched / not-matched indicator over consecutive frames in
  which it is well in view (as ``noise_estimation._detection_correlation``).
- P_FA: the share of the frame's readings that are no point of the world: the ray meets nothing, or the reading
  lies outside the filter's gate (χ²₃ ``mahalanobis_gate``) about its true point under its own covariance.

Prints the figures per robot and pooled, and the ``--set`` items that give them to the filter.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

from benchmarks.slam_demo_replay import open_replay, predicted_frames, save_frames
from estimation.noise_model import DETECTION_BANDS
from runtime.commands.options import non_negative_int

SAME = 0.10  # m: a landmark made from a sighting of a true point this close stands for that point


def band_of(ranges: np.ndarray) -> np.ndarray:
    """Index (N,) of each sensor range's band in ``noise_model.DETECTION_BANDS``."""
    return np.searchsorted(np.array([edge for _, edge in DETECTION_BANDS[:-1]]), np.asarray(ranges, float),
                           side="right")


def lag1_correlation(sequences: list[np.ndarray]) -> float:
    """Lag-1 correlation of 0/1 indicators over consecutive entries of each sequence, pooled; 0 if undefined."""
    x = np.concatenate([s[:-1] for s in sequences if len(s) > 1] or [np.zeros(0)]).astype(float)
    y = np.concatenate([s[1:] for s in sequences if len(s) > 1] or [np.zeros(0)]).astype(float)
    if len(x) < 20 or x.std() == 0 or y.std() == 0:
        return 0.0
    return float(np.corrcoef(x, y)[0, 1])


def measure(demo: Path, robot: str, filter_seed: int, render_seed: int, cache: Path | None) -> dict:
    """Counts of one robot's replay: per band in view / matched / reported, the runs for ρ, readings / outliers."""
    start, config, truth, odometry, observer, slam = open_replay(demo, robot, filter_seed, render_seed, cache)
    origin: dict[int, int] = {}
    n_bands = len(DETECTION_BANDS)
    in_view, matched, reported = np.zeros(n_bands, int), np.zeros(n_bands, int), np.zeros(n_bands, int)
    runs: dict[int, list[tuple[int, int]]] = {}     # landmark id -> (frame, matched) while well in view
    readings = outliers = 0
    for i, _, _, world_pose, observations, index in predicted_frames(start, truth, odometry, observer, slam):
        store = slam.store
        kept_table, kept_blocks = store.table.copy(), store.n_blocks.copy()
        kept_lid, kept_state, kept_count = store.lid.copy(), store.state.copy(), store.count.copy()
        report = slam.update(observations)
        points = observer.points
        for j in np.flatnonzero(report.new_landmark_ids >= 0):
            origin.setdefault(int(report.new_landmark_ids[j]), int(index[j]))
        # P_FA: readings that are no world point (the true point is in the world frame; the reading in base_link)
        z = np.asarray(observations.points, float)
        cov = np.asarray(observations.covariances, float) + config.observation_var_floor * np.eye(3)
        c, s = np.cos(world_pose[2]), np.sin(world_pose[2])
        readings += len(z)
        for j in range(len(z)):
            if index[j] < 0:
                outliers += 1
                continue
            d = points[index[j]] - np.array([world_pose[0], world_pose[1], 0.0])
            local = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], d[2]])
            nu = z[j] - local
            outliers += int(nu @ np.linalg.solve(cov[j], nu) >= config.mahalanobis_gate)
        # P_D: the best particle's confirmed real landmarks well in view (its pose after the update, map before)
        best = int(slam._history[-1][2][slam._best])
        b = store.block_size
        phys = kept_table[best, : kept_blocks[best]]
        slots = (phys[:, None] * b + np.arange(b)).ravel()
        lids = kept_lid.ravel()[slots]
        keep = (lids >= 0) & (kept_count.ravel()[slots] >= config.confirm_count)
        slots, lids = slots[keep], lids[keep]
        real = np.array([lid in origin and origin[lid] >= 0 for lid in lids.tolist()], bool)
        slots, lids = slots[real], lids[real]
        if len(lids) == 0:
            continue
        mean = kept_state.reshape(-1, 9)[slots, :3]
        p = slam.poses[best]
        dx, dy = mean[:, 0] - p[0], mean[:, 1] - p[1]
        x, y = np.cos(p[2]) * dx + np.sin(p[2]) * dy, np.cos(p[2]) * dy - np.sin(p[2]) * dx
        view = slam._well_in_view(x, y, mean[:, 2])
        ox, oy, _ = config.sensor_offset
        ranges = np.hypot(x - ox, y - oy)
        seen_points = points[index[index >= 0]]
        hit = np.isin(lids, report.best_matches[report.best_matches >= 0])
        for k in np.flatnonzero(view):
            band = int(band_of(ranges[k : k + 1])[0])
            in_view[band] += 1
            matched[band] += int(hit[k])
            if len(seen_points):
                reported[band] += int(np.min(np.linalg.norm(seen_points - points[origin[int(lids[k])]], axis=1)) < SAME)
            runs.setdefault(int(lids[k]), []).append((i, int(hit[k])))
    save_frames(observer, cache)
    sequences = []
    for entries in runs.values():   # split each landmark's frames into runs of consecutive frames
        frames = np.array([f for f, _ in entries])
        hits = np.array([h for _, h in entries])
        for part in np.split(np.arange(len(frames)), np.flatnonzero(np.diff(frames) > 1) + 1):
            sequences.append(hits[part])
    return {"in_view": in_view, "matched": matched, "reported": reported, "sequences": sequences,
            "readings": readings, "outliers": outliers}


def summary(counts: list[dict]) -> dict:
    in_view = sum(c["in_view"] for c in counts)
    matched = sum(c["matched"] for c in counts)
    reported = sum(c["reported"] for c in counts)
    readings, outliers = sum(c["readings"] for c in counts), sum(c["outliers"] for c in counts)
    return {"p_d": matched / np.maximum(in_view, 1), "reported": reported / np.maximum(in_view, 1),
            "in_view": in_view, "rho": lag1_correlation([s for c in counts for s in c["sequences"]]),
            "p_fa": outliers / max(readings, 1), "readings": readings}


def print_summary(label: str, s: dict) -> None:
    bands = ", ".join(f"{name} {s['p_d'][k]:.3f} (reported {s['reported'][k]:.3f}; {s['in_view'][k]} in view)"
                      for k, (name, _) in enumerate(DETECTION_BANDS))
    print(f"{label}: P_D matched {bands}; ρ {s['rho']:.3f}; P_FA {s['p_fa']:.4f} of {s['readings']} readings")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("demos", type=Path, nargs="+", help="`p3at demo --out` folders")
    parser.add_argument("--robots", default="robot1,robot2", help="comma-separated robot names (default both)")
    parser.add_argument("--cache-dir", type=Path, default=None, metavar="DIR",
                        help="keep each robot's rendered frames in DIR/<demo name>-<robot>.npz and replay them later")
    parser.add_argument("--filter-seed", type=non_negative_int, default=0)
    parser.add_argument("--render-seed", type=non_negative_int, default=0, help="the image noise's draw")
    args = parser.parse_args(argv)
    robots = [r for r in args.robots.split(",") if r]
    for demo in args.demos:
        for robot in robots:
            for name in (f"{robot}.npz", f"{robot}-truth.tum", f"{robot}-odometry.tum"):
                if not (demo / name).is_file():
                    raise SystemExit(f"{demo}: no {name} (a `p3at demo --out` folder of a mock run is needed)")
    cv2.setNumThreads(1)
    counts = []
    for demo in args.demos:
        for robot in robots:
            cache = args.cache_dir / f"{demo.name}-{robot}.npz" if args.cache_dir is not None else None
            counts.append(measure(demo, robot, args.filter_seed, args.render_seed, cache))
            print_summary(f"{demo} {robot}", summary(counts[-1:]))
    pooled = summary(counts)
    print_summary("pooled", pooled)
    edges = ",".join(f"{edge:g}" for _, edge in DETECTION_BANDS[:-1])
    p_d = ",".join(f"{float(np.clip(p, 0.01, 0.99)):.3f}" for p in pooled["p_d"])
    print(f"--set detection_probabilities=[{p_d}] --set detection_range_edges=[{edges}] "
          f"--set false_alarm_probability={float(np.clip(pooled['p_fa'], 1e-3, 0.5)):.4f} "
          f"--set detection_correlation={float(np.clip(pooled['rho'], 0.0, 0.95)):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
