"""Several seeds' runs of the unknown-association chain voted into one naming and smoothed into one map.

:func:`vote_runs` is what ``benchmarks/mrclam_seed_vote.py`` (from the runs' saved states) and ``p3at slam dataset
--association unknown --chain --seeds S,S,...`` (from the runs it makes) share, moved out of that benchmark's
``vote_robot`` in session 36 (A). :func:`estimation.name_vote.voted_names` keeps groups of sightings under one name
when a majority of the runs does and leaves unnamed the fragments no majority has as a name; the voted names are
smoothed as the chain's last state is, from the poses of the run nearest the vote (fewest sighting pairs named
otherwise, :func:`pairs_apart`), with the runs' heading drift, path step, heading loss and a sighting offset per
group of sightings every run's chain put under one round-0 name (:func:`offset_groups`); last the chain's own step
names the sightings exactly one name explains (:func:`estimation.unnamed_sightings.name_unnamed`).
:func:`voted_landmark_map` is the map, recording the seeds and each landmark's support in ``metadata["vote"]``
(``p3at fuse`` reads it: ``runtime/map_vote.py``). The barcodes and the ground truth take no part.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from estimation.chain_map import chain_landmark_map
from estimation.dataset_smoothing import planar_landmarks
from estimation.datasets import RangeBearingLog
from estimation.fastslam import FastSLAMConfig
from estimation.landmark_map import LandmarkMap
from estimation.landmark_smoother import HeadingDrift, HeadingLoss, SightingOffset
from estimation.name_chain import ChainObserver, ChainResult, ChainSettings, run_chain
from estimation.name_merging import NamedSmoother, resmoothed
from estimation.name_vote import VOTE_KEY, name_support, vote_metadata, voted_names
from estimation.named_smoothing import MergeRound
from estimation.noise_model import NoiseModel
from estimation.unnamed_sightings import name_unnamed, visits

__all__ = ["SeedVote", "chain_vote", "offset_groups", "pairs_apart", "vote_runs", "voted_landmark_map"]


@dataclass(frozen=True)
class SeedVote:
    """A vote of runs: the voted ``names`` (S,) (before the last step), each voted name's ``support`` (runs holding
    it), each run's sighting pairs named otherwise (``apart``), the run the smoothing started from (``nearest``), the
    voted names smoothed (``voted``), the final state after the last step (``state``) and what that step proposed."""

    names: np.ndarray
    support: np.ndarray
    apart: list[int]
    nearest: int
    voted: MergeRound
    state: MergeRound
    proposed: dict[int, int]


def pairs_apart(a: np.ndarray, b: np.ndarray) -> int:
    """Sighting pairs that one of the two namings puts under one name and the other does not (both named)."""
    both = (a >= 0) & (b >= 0)
    a, b = a[both], b[both]

    def together(*labels):
        counts = np.unique(np.stack(labels), axis=1, return_counts=True)[1]
        return int(np.sum(counts * (counts - 1) // 2))
    return together(a) + together(b) - 2 * together(a, b)


def offset_groups(round0: np.ndarray, names: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Each sighting's offset group: the sightings every run's chain put under one round-0 name share one; a
    sighting no chain named gets its name's visit (its name's sightings less than a visit gap apart), as the chain
    gives the sightings it names late."""
    groups = np.unique(round0.T, axis=0, return_inverse=True)[1].reshape(-1).astype(np.int64)
    loose = np.flatnonzero((round0 < 0).all(axis=0) & (names >= 0))
    if len(loose):
        order, visit = visits(loose, names, times)
        groups[order] = groups.max() + visit
    return groups


def vote_runs(log: RangeBearingLog, noise: NoiseModel, config: FastSLAMConfig, finals: list[MergeRound],
              round0: np.ndarray, drift: HeadingDrift | None, path_step_s: float | None, offset_m: float, *,
              heading_loss: HeadingLoss | None = None) -> SeedVote:
    """The runs' final states ``finals`` voted (module docstring); ``round0`` (runs, S): each run's chained names
    (its round-0 state's); ``drift``, ``path_step_s``, ``offset_m`` (σ of the sighting offsets, 0: none) and
    ``heading_loss`` (None: Gaussian): the smoother's settings the runs had."""
    runs = np.stack([s.names for s in finals])
    names = voted_names(runs)
    support = name_support(runs, names)
    # the smoothing starts from the run nearest the vote: fewest pairs named otherwise, then fewest sightings
    # named where the vote leaves them unnamed or the other way round
    apart = [pairs_apart(run.names, names) for run in finals]
    nearest = min(range(len(finals)), key=lambda i: (apart[i], int(np.sum((finals[i].names >= 0) != (names >= 0)))))
    smoother = NamedSmoother(log, noise, config, drift, path_step_s or None,
                             SightingOffset(offset_m) if offset_m > 0 else None,
                             offset_groups(np.asarray(round0), names, log.sighting_times), heading_loss)
    # the poses from the nearest run, its landmarks not: its labels are not the vote's
    voted = resmoothed(smoother, finals[nearest], names, same_labels=False)
    state, proposed, _ = name_unnamed(smoother, voted)
    return SeedVote(names, support, apart, nearest, voted, state, proposed)


def voted_landmark_map(log: RangeBearingLog, vote: SeedVote, seeds: list[int], robot: str) -> LandmarkMap:
    """The vote's final state as :func:`estimation.chain_map.chain_landmark_map` writes a run's, with the seeds and
    each landmark's support in ``metadata["vote"]`` (:func:`estimation.name_vote.vote_metadata`)."""
    state = vote.state
    voted_map = chain_landmark_map(log, state, robot)
    # each landmark's support: the map's rows are the solution's landmarks that have sightings, in order
    rows = state.named.names[planar_landmarks(state.solution)[0]]
    voted_map.metadata[VOTE_KEY] = vote_metadata(seeds, vote.support[rows])
    return voted_map


class _Round0(ChainObserver):
    """Keeps a run's chained names (its round-0 state's), which the vote's sighting offsets are grouped by."""

    names: np.ndarray | None = None

    def state_kept(self, tag, state, round_done, smoother, before=None) -> None:
        if tag == "round0":
            self.names = state.names.copy()


def chain_vote(log: RangeBearingLog, noise: NoiseModel, config: FastSLAMConfig, seeds: list[int],
               settings: ChainSettings | None = None) -> tuple[list[ChainResult], SeedVote]:
    """The chain run once per seed (``settings`` with each seed, None: session 30's recipe;
    :func:`estimation.name_chain.run_chain`) and the runs voted (:func:`vote_runs`, with the smoother's settings the
    runs ended with)."""
    settings = settings or ChainSettings()
    results, round0 = [], []
    for seed in seeds:
        kept = _Round0()
        results.append(run_chain(log, noise, config, dataclasses.replace(settings, seed=seed), observer=kept))
        round0.append(kept.names)
    smoother = results[0].smoother
    offset = smoother.sighting_offset
    vote = vote_runs(log, noise, config, [r.state for r in results], np.stack(round0), smoother.heading_drift,
                     smoother.path_step_s, offset.sigma_m if offset is not None else 0.0,
                     heading_loss=smoother.heading_loss)
    return results, vote
