"""A batch of merges judged at the best of two starts: the current solution and a fresh one (session 31, A).

The unknown-association chain (``benchmarks.mrclam_constellation``) merges names in batches and keeps a batch when
the smoother's truncated cost rises by no more than χ² 99 % for 2 per absorbed name. The merged names are smoothed
from the current solution. When that solution holds a stretch far off — MRCLAM robot 5 seed 2 after round 1: the log
after ≈1,050 s 1.5–2.5 m off, its posts named by duplicates that nothing ties to the first half — the batch that
closes the loop must move the stretch metres, and the smoother (Gauss–Newton from the bent solution) stops in a local
minimum: round 2's batch of 76 right merges rose 202.3 against the bound 195.5 and was refused. The same merged names
smoothed from the known-ID filter run with them as identities rise 166.1 (ATE 0.345 m, NEES within 94 %). The guard
then kept the batch without its loop closures (the groups of largest linear d²: 2 names at d² 236 on 2 dof), which
locked the far stretch in place: every later round left the map 1.06–1.24 m off with 0 wrong merges and NEES within
35–49 %.

The cost check compares the batch's minimum with the current one; a local minimum of the merged names only makes the
rise look larger, so the least cost over several starts is the better estimate of the rise the check means. The
second start is :func:`names_guess`: the filter and smoother of :mod:`estimation.dataset_slam` with the names as the
landmarks' identities (no barcode, no descriptor: a name is only a label), which does not inherit the current
solution's bend. No threshold is added: the bound is the cost check's own.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from estimation.dataset_slam import run_landmark_log
from estimation.datasets import RangeBearingLog
from estimation.fastslam.config import FastSLAMConfig
from estimation.noise_model import NoiseModel


@dataclass(frozen=True)
class StartsVerdict:
    """A batch judged at several starts: each start's cost, the least one's index, its rise over the cost before
    the batch, and whether that rise is within the bound."""

    costs: tuple[float, ...]
    best: int
    rise: float
    accepted: bool


def judge_at_starts(cost_before: float, costs: Sequence[float], bound: float) -> StartsVerdict:
    """The cost check at the least of ``costs`` (the merged names smoothed from each start; the first is the
    current solution's): rise = min(costs) − ``cost_before``, accepted when rise ≤ ``bound``. A non-finite cost (a
    start that failed) never wins."""
    values = np.asarray(costs, float)
    if values.size == 0:
        raise ValueError("judge_at_starts needs at least one start's cost")
    finite = np.where(np.isfinite(values), values, np.inf)
    best = int(np.argmin(finite))
    rise = float(finite[best] - cost_before)
    return StartsVerdict(tuple(float(c) for c in values), best, rise, bool(rise <= bound))


def names_guess(log: RangeBearingLog, names: np.ndarray, noise: NoiseModel, config: FastSLAMConfig,
                rng: np.random.Generator) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """A fresh start for smoothing ``names`` (N,) (one per sighting of ``log``, −1: unnamed, left out): the known-ID
    filter and smoother of :func:`estimation.dataset_slam.run_landmark_log` with the names in place of the log's
    identities. Returns the poses (T + 1, 3) of its trajectory (start frame) and each name's position (2,). The log's
    ground truth only scores that run; the guess does not depend on it."""
    names = np.asarray(names, np.int64)
    if names.shape != log.sighting_times.shape:
        raise ValueError(f"names: one per sighting ({log.sighting_times.shape[0]}), not {names.shape}")
    keep = names >= 0
    named_log = log.with_sightings(keep, names)
    run = run_landmark_log(named_log, config, rng, noise=noise, association="id", smooth=True)
    ids = np.asarray(run.map.metadata["external_ids"], np.int64)
    positions = np.asarray(run.map.positions)[:, :2]
    return run.map.trajectory[:, 1:], dict(zip(ids.tolist(), positions, strict=True))
