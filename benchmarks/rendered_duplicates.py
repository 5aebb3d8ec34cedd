"""What the rendered maps' duplicates are: every duplicate pair of the exported map, sorted into its cause.

Run from the repository root (replays the rendered frames' cache of ``eval_slam_rendered --frames-cache``):

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.rendered_duplicates --robot robot1 --seed 0
        --frames-cache DIR [--frame-rate 3.75] [--set KEY=VALUE ...] [--json]

A duplicate pair is two landmarks of the exported map (the most probable particle's) whose first sightings
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
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

import runtime.slam_sim as slam_sim
from benchmarks.eval_slam_rendered import _parse_set, _PointWorld, replay_default_run
from estimation.fastslam import FastSLAM, FastSLAMConfig
from estimation.fastslam.coincident import coincident_pairs
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
    observer, route, start = replay_default_run(world, robot, seed, frame_rate, frames_cache)
    arrays, starts = observer._arrays, observer._starts
    original = slam_sim.FastSLAM
    slam_sim.FastSLAM = _RecordingFastSLAM
    try:
        slam_sim.simulate(_PointWorld(world, observer), start_pose=start, route=route, seconds=300.0,
                          seed=seed, config=config, robot=robot, frame_rate=frame_rate, observer=observer)
    finally:
        slam_sim.FastSLAM = original
    slam = _RecordingFastSLAM.last
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", action="append", default=None, help="robot1 and/or robot2 (default both)")
    parser.add_argument("--seed", type=non_negative_int, action="append", default=None)
    parser.add_argument("--frame-rate", type=positive_float, default=3.75)
    parser.add_argument("--frames-cache", type=Path, required=True, metavar="DIR")
    parser.add_argument("--particles", type=positive_int, default=100)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a FastSLAMConfig field")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    config = replace(FastSLAMConfig(n_particles=args.particles), max_observations=0)
    config = replace(config, **_parse_set(args.set))
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
