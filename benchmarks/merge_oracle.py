"""Why merging more costs the rendered maps: the duplicate merge with the truth vetoing its wrong pairs.

Run from the repository root (replays the rendered frames' cache of ``eval_slam_rendered --frames-cache``):

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.merge_oracle --robot robot1 --seed 0
        --frames-cache DIR [--frame-rate 3.75] [--set KEY=VALUE ...] [--oracle right|none] [--within 0.1]

The filter runs as configured (e.g. ``--set merge_descriptor_threshold=0.8``: merges more), except that with
``--oracle right`` every pair its "alike" test proposes (``FastSLAM._alike_pairs``: one point by the EKFs and
by the descriptors) is kept only if the true points behind the two landmarks' first sightings are within
``--within`` m (0.1: what ``slam_consistency.merge_scores`` does not count as wrong). So the run merges only
right pairs, and its ATE says whether a *right* merge helps or costs the estimate:

- a threshold that merges more, oracle on, ATE as good as the default or better: the cost of merging more is the
  wrong pairs, and what is needed is a test that tells them apart;
- ATE worse with right merges only: the merge's update of the particle is what costs.

A diagnostic only: the truth never reaches the filter otherwise. Prints the ``eval_slam_rendered`` scores (one
JSON row) plus ``oracle_vetoed`` (alike pairs the truth refused, counted per pass) and ``oracle_kept``.
"""
from __future__ import annotations

import argparse
import io
import json
import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

from benchmarks import eval_slam_rendered as rendered
from benchmarks.config_overrides import config_overrides
from drivers.fileio import atomic_write_bytes
from estimation.fastslam import FastSLAMConfig
from runtime.commands.options import non_negative_int, positive_float, positive_int


class _OracleFastSLAM(rendered._TimedFastSLAM):
    """The timed filter whose alike pairs pass only if their true points are within ``within`` m."""

    within: float | None = None
    start_theta = 0.0                # the robot's true start heading (world -> map frame)
    filter_seed: int | None = None   # another draw of the filter's own randomness (the run-to-run spread)

    def __init__(self, config, rng, *args, **kwargs) -> None:
        if self.filter_seed is not None:
            rng = np.random.default_rng([self.filter_seed, 10])
        super().__init__(config, rng, *args, **kwargs)
        self.point_of: dict[int, int] = {}      # landmark id -> true point behind its first sighting (-1: none)
        self.made_at: dict[int, tuple[int, float]] = {}   # landmark id -> (update, range of its first sighting)
        self.vetoed = self.kept = 0
        self.proposed: list[tuple] = []          # (older, newer, update, descriptor distance, true distance)
        self.seen_in: dict[int, set[int]] = {}   # landmark id -> updates the most probable particle detected it in
        self.truths: dict[int, dict[int, int]] = {}   # landmark id -> {true point: sightings} (best particle)
        self.geometry: list[tuple] = []          # per proposed pair: see save_proposed
        self.readings: dict[tuple[int, int], tuple] = {}   # (landmark id, update) -> (reading, its covariance)

    def _add_landmarks(self, had_candidate, poses, z, q6, desc, lids=None):
        new_ids, n = super()._add_landmarks(had_candidate, poses, z, q6, desc, lids)
        # max_observations=0 and every reading used: z is the frame as observed, in the observer's order
        index = self.observer.indices[-1]
        if len(index) != len(z):
            raise SystemExit("merge_oracle: the filter used a subset of the frame; run with --set max_observations=0")
        ranges = self._sensor_range(z)
        for j in np.flatnonzero(new_ids >= 0):
            self.point_of.setdefault(int(new_ids[j]), int(index[j]))
            self.made_at.setdefault(int(new_ids[j]), (len(self.reports), float(ranges[j])))
        return new_ids, n

    def update(self, observations):
        report = super().update(observations)
        # what the most probable particle detected this frame: its matches, and the landmarks made where it
        # matched nothing (approximately its own: new_landmark_ids says some particle made one)
        index, u = self.observer.indices[-1], len(self.reports) - 1
        lids = np.where(report.best_matches >= 0, report.best_matches, report.new_landmark_ids)
        z = np.asarray(observations.points, float)
        q = np.asarray(observations.covariances, float) + self.config.observation_var_floor * np.eye(3)
        for j in np.flatnonzero(lids >= 0).tolist():
            lid, point = int(lids[j]), int(index[j])
            self.seen_in.setdefault(lid, set()).add(u)
            self.readings[lid, u] = (z[j], q[j])
            tally = self.truths.setdefault(lid, {})
            tally[point] = tally.get(point, 0) + 1
        return report

    def _majority(self, lid: int) -> int:
        tally = self.truths.get(lid)
        return max(tally, key=tally.get) if tally else -1

    def _pair_geometry(self, cand, a, b, pa, pb) -> None:
        """Per proposed pair, in the most probable particle (nan where it does not hold both): d² of the estimates
        under Σ_a + Σ_b, d² of the first sightings' *true* separation under the same Σ_a + Σ_b (rotated into the
        map frame), detected in one frame by that particle, both landmarks' sightings counts and σ along the
        largest axis, and the distance between the true points most of their sightings were of."""
        truth = self.observer.points
        state = self.store.flat_state
        best = cand.m == self._best
        row_of = dict(zip(self.store.flat_lid[cand.g[best]].tolist(), cand.g[best].tolist(), strict=True))
        c, s = np.cos(self.start_theta), np.sin(self.start_theta)
        to_map = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])   # world difference -> start frame
        for i, k, p, q in zip(a.tolist(), b.tolist(), pa.tolist(), pb.tolist(), strict=True):
            ra, rb = row_of.get(i), row_of.get(k)
            both = self.seen_in.get(i, set()) & self.seen_in.get(k, set())
            codetected = bool(both)
            # the co-detected frames' own measure of the pair: d² of the two readings under Q_a + Q_b (max)
            frame_d2 = np.nan
            for u in both:
                (za, qa), (zb, qb) = self.readings[i, u], self.readings[k, u]
                dz = za - zb
                frame_d2 = np.nanmax([frame_d2, float(dz @ np.linalg.solve(qa + qb, dz))])
            # the share of the older's sightings so far that were of a point within 10 cm of the newer's first
            tally = self.truths.get(i, {})
            near = (sum(n for t, n in tally.items() if np.linalg.norm(truth[t] - truth[q]) <= 0.1)
                    / max(sum(tally.values()), 1)) if q >= 0 else np.nan
            ma, mb = self._majority(i), self._majority(k)
            major = float(np.linalg.norm(truth[ma] - truth[mb])) if ma >= 0 and mb >= 0 else np.nan
            if ra is None or rb is None:
                self.geometry.append((np.nan, np.nan, codetected, np.nan, np.nan, np.nan, np.nan, major, frame_d2,
                                      near))
                continue
            xa, xb = state[ra], state[rb]
            cov = _sym(xa[3:]) + _sym(xb[3:])
            inv = np.linalg.inv(cov)
            diff = xa[:3] - xb[:3]
            d2_true = np.nan
            if p >= 0 and q >= 0:
                t = to_map @ (truth[p] - truth[q])
                d2_true = float(t @ inv @ t)
            sig = [float(np.sqrt(np.linalg.eigvalsh(_sym(x[3:]))[-1])) for x in (xa, xb)]
            self.geometry.append((float(diff @ inv @ diff), d2_true, codetected,
                                  float(self.store.flat_count[ra]), float(self.store.flat_count[rb]),
                                  sig[0], sig[1], major, frame_d2, near))

    def _alike_pairs(self, cand, uniq, first, inverse, touched):
        a, b = super()._alike_pairs(cand, uniq, first, inverse, touched)
        if len(a) == 0:
            return a, b
        truth = self.observer.points
        pa = np.array([self.point_of.get(int(i), -1) for i in a])
        pb = np.array([self.point_of.get(int(i), -1) for i in b])
        known = (pa >= 0) & (pb >= 0)
        apart = np.full(len(a), np.nan)
        apart[known] = np.linalg.norm(truth[pa[known]] - truth[pb[known]], axis=1)
        look = np.linalg.norm(self._descriptors[a] - self._descriptors[b], axis=1)
        self.proposed += [(int(i), int(k), len(self.reports), float(g), float(d))
                          for i, k, g, d in zip(a, b, look, apart, strict=True)]
        self._pair_geometry(cand, a, b, pa, pb)
        if self.within is None:
            return a, b
        ok = known & (np.nan_to_num(apart, nan=np.inf) <= self.within)
        self.vetoed += int((~ok).sum())
        self.kept += int(ok.sum())
        return a[ok], b[ok]


def _sym(q6: np.ndarray) -> np.ndarray:
    """The 3×3 matrix of a landmark's six covariance components (xx, xy, xz, yy, yz, zz)."""
    xx, xy, xz, yy, yz, zz = q6
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])


def save_proposed(path: Path, slam: _OracleFastSLAM) -> None:
    """The proposed pairs as plain arrays (.npz, written atomically): each row's older / newer id, the update
    that proposed it, the descriptor distance, the true distance, and both landmarks' creation update and range."""
    rows = np.array(slam.proposed, float).reshape(-1, 5)
    made = np.array([[*slam.made_at.get(int(i), (-1, np.nan)), *slam.made_at.get(int(k), (-1, np.nan))]
                     for i, k in rows[:, :2]], float).reshape(-1, 4)
    buffer = io.BytesIO()
    np.savez(buffer, older=rows[:, 0].astype(np.int64), newer=rows[:, 1].astype(np.int64),
             update=rows[:, 2].astype(np.int64), descriptor=rows[:, 3], true_m=rows[:, 4],
             older_made=made[:, 0].astype(np.int64), older_range=made[:, 1],
             newer_made=made[:, 2].astype(np.int64), newer_range=made[:, 3],
             merged=np.array([(a, b) for a, b, _ in slam.merged_pairs], np.int64).reshape(-1, 2),
             **dict(zip(("d2_estimate", "d2_true", "codetected", "count_older", "count_newer", "sigma_older",
                         "sigma_newer", "majority_true_m", "frame_d2_max", "older_share_near_newer"),
                        np.array(slam.geometry, float).reshape(-1, 10).T, strict=True)))
    atomic_write_bytes(path, buffer.getvalue())


def breakdown(path: Path, gate: float = 7.815) -> dict:
    """What the merged pairs of a ``--pairs-out`` file are (each pair at its first proposal), by the distance between
    the true points of the two landmarks' first sightings (``true_m``, the score's) and between the points most of
    their sightings were of so far (``majority_true_m``):

    - ``right``: first sightings within 10 cm;
    - ``right_by_sightings``: first sightings > 10 cm apart, but the older landmark's sightings were mostly of a
      point within 10 cm of the newer's (it stood for that point: its first sighting slid, or it took over);
    - ``two_points``: > 10 cm apart by both; ``unattributed``: > 10 cm by the first sightings, no tally for one.

    Per class: how many, co-detected before the merge (the most probable particle detected both in one frame),
    those whose co-detected frames measured the two readings apart (d² ≥ ``gate`` under Q_a + Q_b in some
    frame), and the medians of d² between the estimates under Σ_a + Σ_b, of the true separation under the same
    Σ_a + Σ_b, of the true distance, of |ln(range ratio)| and of the updates between the two creations."""
    d = np.load(path)
    pairs = list(zip(d["older"].tolist(), d["newer"].tolist(), strict=True))
    first: dict[tuple[int, int], int] = {}
    for i, p in enumerate(pairs):
        first.setdefault(p, i)
    idx = np.array([first[(a, b)] for a, b in d["merged"].tolist() if (a, b) in first], np.int64)
    true_m, major = d["true_m"][idx], d["majority_true_m"][idx]
    classes = {"right": true_m <= 0.1, "right_by_sightings": (true_m > 0.1) & (major <= 0.1),
               "two_points": (true_m > 0.1) & (major > 0.1), "unattributed": (true_m > 0.1) & np.isnan(major)}

    def median(x) -> float:
        x = x[np.isfinite(x)]
        return round(float(np.median(x)), 3) if len(x) else float("nan")

    out = {"merged": len(idx)}
    for name, sel in classes.items():
        rows = idx[sel]
        frame = d["frame_d2_max"][rows]
        out[name] = {"n": int(sel.sum()), "codetected": int(np.sum(d["codetected"][rows] > 0)),
                     "measured_apart": int(np.sum(frame[np.isfinite(frame)] >= gate)),
                     "frame_d2_max_median": median(frame), "d2_estimate_median": median(d["d2_estimate"][rows]),
                     "d2_true_median": median(d["d2_true"][rows]), "true_m_median": median(d["true_m"][rows]),
                     "abs_ln_range_ratio_median": median(np.abs(np.log(d["newer_range"][rows] /
                                                                       d["older_range"][rows]))),
                     "updates_between_median": median((d["newer_made"][rows] - d["older_made"][rows]).astype(float))}
    return out


def nees_by_merge(slam: _OracleFastSLAM, landmark_map, start, truth: np.ndarray) -> dict:
    """Is a landmark that took two points in a merge confidently wrong? The exported map's landmark NEES (against
    the first sighting's true point, as ``landmark_nees_within_bound``), split by whether the landmark absorbed a
    merge of two points (first sightings and the sightings' majorities both > 10 cm apart, ``breakdown``)."""
    two = set()
    merged = {(a, b) for a, b, _ in slam.merged_pairs}
    for (a, b, _, _, true_m), g in zip(slam.proposed, slam.geometry, strict=True):
        if (a, b) in merged and true_m > 0.1 and g[7] > 0.1:   # nan (unknown) compares False
            two.add(a)
    ids = np.asarray(landmark_map.ids, np.int64)
    points = np.array([slam.point_of.get(int(i), -1) for i in ids], np.int64)
    known = points >= 0
    c, s = np.cos(start[2]), np.sin(start[2])
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    err = landmark_map.positions[known] - (truth[points[known]] - [start[0], start[1], 0.0]) @ rot
    nees = np.einsum("ni,ni->n", err, np.linalg.solve(landmark_map.covariances[known], err[..., None])[..., 0])
    took = np.array([int(i) in two for i in ids[known]], bool)
    out = {}
    for name, sel in (("took_two_points", took), ("other", ~took)):
        out[f"landmarks_{name}"] = int(sel.sum())
        out[f"nees_within_{name}"] = float(np.mean(nees[sel] < 7.815)) if sel.any() else float("nan")
        out[f"error_median_{name}_m"] = float(np.median(np.linalg.norm(err[sel], axis=1))) if sel.any() else \
            float("nan")
    return out


def absorbed_per_landmark(merged_pairs) -> dict:
    """How many newer landmarks each older one absorbed (``FastSLAM.merged_pairs``): a landmark that keeps
    absorbing fresh ones is re-made again and again beside itself (its look no longer matches the sightings)."""
    older = np.array([a for a, _, _ in merged_pairs], np.int64)
    if not len(older):
        return {"merged_older": 0}
    counts = np.unique(older, return_counts=True)[1]
    return {"merged_older": len(counts), "absorbed_median": float(np.median(counts)),
            "absorbed_p90": float(np.percentile(counts, 90)), "absorbed_max": int(counts.max()),
            "merges_into_repeat_absorbers": int(counts[counts >= 3].sum())}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="robot1")
    parser.add_argument("--seed", type=non_negative_int, default=0)
    parser.add_argument("--frame-rate", type=positive_float, default=3.75)
    parser.add_argument("--particles", type=positive_int, default=100)
    parser.add_argument("--frames-cache", type=Path, metavar="DIR", help="required unless --breakdown")
    parser.add_argument("--set", action="append", default=["max_observations=0"], metavar="KEY=VALUE",
                        help="override a FastSLAMConfig field (max_observations=0 is set first)")
    parser.add_argument("--oracle", choices=("right", "none"), default="right",
                        help="right: merge only pairs whose true points are within --within m; none: as configured")
    parser.add_argument("--within", type=positive_float, default=0.1, metavar="M")
    parser.add_argument("--filter-seed", type=non_negative_int, default=None, metavar="N",
                        help="draw the filter's particles from another seed (frames and odometry unchanged): the "
                             "spread of ATE over the filter's own randomness")
    parser.add_argument("--pairs-out", type=Path, default=None, metavar="FILE.npz",
                        help="write every pair the alike test proposed (ids, update, creation updates and ranges, "
                             "descriptor distance, true distance) for offline study")
    parser.add_argument("--breakdown", type=Path, default=None, metavar="FILE.npz",
                        help="print what the merged pairs of a --pairs-out file are (see breakdown) and exit")
    args = parser.parse_args(argv)
    if args.breakdown is not None:
        print(json.dumps(breakdown(args.breakdown), indent=2))
        return 0
    if args.frames_cache is None:
        parser.error("--frames-cache is required (unless --breakdown)")
    cv2.setNumThreads(1)
    from mocks.world import World

    config = replace(FastSLAMConfig(n_particles=args.particles), **config_overrides(args.set))
    if config.max_observations != 0:
        parser.error("--set max_observations must stay 0 (the oracle maps each reading to its truth)")
    _OracleFastSLAM.within = args.within if args.oracle == "right" else None
    _OracleFastSLAM.filter_seed = args.filter_seed
    _OracleFastSLAM.start_theta = float(World.load().start_poses[args.robot][2])
    captured = {}
    scores = rendered.landmark_scores

    def capture(landmark_map, start, *rest):   # the exported map the scores are of
        captured.update(map=landmark_map, start=np.asarray(start, float))
        return scores(landmark_map, start, *rest)

    rendered.landmark_scores = capture
    row = rendered.run_robot(World.load(), args.robot, seconds=300.0, seed=args.seed, config=config,
                             frame_rate=args.frame_rate, max_corners=150, diagnose=False,
                             frames_cache=args.frames_cache, filter_class=_OracleFastSLAM)
    slam = rendered._TimedFastSLAM.instances[-1]
    row.update(oracle=args.oracle, within_m=args.within, filter_seed=args.filter_seed, oracle_vetoed=slam.vetoed,
               oracle_kept=slam.kept,
               **absorbed_per_landmark(slam.merged_pairs),
               **nees_by_merge(slam, captured["map"], captured["start"], slam.observer.points))
    if args.pairs_out is not None:
        save_proposed(args.pairs_out, slam)
    print(json.dumps({"config": config.to_dict(), "row": row}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
