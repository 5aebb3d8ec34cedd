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
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from benchmarks import eval_slam_rendered as rendered
from drivers.fileio import atomic_write_bytes
from estimation.fastslam import FastSLAMConfig
from runtime.commands.options import non_negative_int, positive_float, positive_int


class _OracleFastSLAM(rendered._TimedFastSLAM):
    """The timed filter whose alike pairs pass only if their true points are within ``within`` m."""

    within: float | None = None
    filter_seed: int | None = None   # another draw of the filter's own randomness (the run-to-run spread)

    def __init__(self, config, rng, *args, **kwargs) -> None:
        if self.filter_seed is not None:
            rng = np.random.default_rng([self.filter_seed, 10])
        super().__init__(config, rng, *args, **kwargs)
        self.point_of: dict[int, int] = {}      # landmark id -> true point behind its first sighting (-1: none)
        self.made_at: dict[int, tuple[int, float]] = {}   # landmark id -> (update, range of its first sighting)
        self.vetoed = self.kept = 0
        self.proposed: list[tuple] = []          # (older, newer, update, descriptor distance, true distance)

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
        if self.within is None:
            return a, b
        ok = known & (np.nan_to_num(apart, nan=np.inf) <= self.within)
        self.vetoed += int((~ok).sum())
        self.kept += int(ok.sum())
        return a[ok], b[ok]


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
             merged=np.array([(a, b) for a, b, _ in slam.merged_pairs], np.int64).reshape(-1, 2))
    atomic_write_bytes(path, buffer.getvalue())


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
    parser.add_argument("--frames-cache", type=Path, required=True, metavar="DIR")
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
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    from mocks.world import World

    config = replace(FastSLAMConfig(n_particles=args.particles), **rendered._parse_set(args.set))
    if config.max_observations != 0:
        parser.error("--set max_observations must stay 0 (the oracle maps each reading to its truth)")
    _OracleFastSLAM.within = args.within if args.oracle == "right" else None
    _OracleFastSLAM.filter_seed = args.filter_seed
    row = rendered.run_robot(World.load(), args.robot, seconds=300.0, seed=args.seed, config=config,
                             frame_rate=args.frame_rate, max_corners=150, diagnose=False,
                             frames_cache=args.frames_cache, filter_class=_OracleFastSLAM)
    slam = rendered._TimedFastSLAM.instances[-1]
    row.update(oracle=args.oracle, within_m=args.within, filter_seed=args.filter_seed, oracle_vetoed=slam.vetoed,
               oracle_kept=slam.kept,
               **absorbed_per_landmark(slam.merged_pairs))
    if args.pairs_out is not None:
        save_proposed(args.pairs_out, slam)
    print(json.dumps({"config": config.to_dict(), "row": row}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
