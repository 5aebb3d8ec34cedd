"""Names that several runs agree on: a vote, sighting pair by sighting pair, over the partitions that runs of one
log made (issue 13, MRCLAM without barcodes; session 33).

A chain of association decisions made on a particle filter's output depends on the filter's random draws. On
MRCLAM the unknown-association chain (``benchmarks.mrclam_constellation``) makes its wrong merges on different
robots with different seeds (session 32: seed 0 robot 5, seed 1 robots 2 and 3, seed 2 robot 1), and its left-over
duplicates likewise. A merge the data decides should not depend on the draw; one that only some runs make is not
decided by the data. :func:`voted_names` keeps groups of sightings under one name when a majority of the runs does
(on average over their pairs): a wrong merge one run of three makes is out-voted, and so is a duplicate one run of
three leaves.

It has no parameter beyond the runs themselves (a strict majority of them). What it costs is the runs: K times one
run's work.
"""
from __future__ import annotations

import numpy as np

__all__ = ["VOTE_KEY", "majority_named", "name_support", "vote_metadata", "voted_names"]

VOTE_KEY = "vote"        # a voted map's metadata key (read by runtime/map_vote.py for ``p3at fuse``)


def voted_names(runs: np.ndarray) -> np.ndarray:
    """The names (N,) that a strict majority of ``runs`` (K, N) agrees on; each row one run's name per sighting,
    −1 for a sighting that run left unnamed. The labels of different runs are unrelated.

    - A sighting that a majority of the runs leaves unnamed is unnamed (−1), and so is one of a fragment (below).
    - Two groups' *co-association* is, over their sighting pairs, the share of the runs naming both sightings of a
      pair that name them alike (a run that leaves a sighting unnamed abstains: consensus clustering's rule for
      items a run did not cluster, Monti et al., Machine Learning 2003). Sightings that every run names alike form
      *atoms* (the runs' common refinement); two sightings that every run holds under one name are named alike
      (one voted name, or both unnamed as a fragment).
    - Groups are joined by average linkage on the co-association (evidence accumulation, Fred & Jain, IEEE PAMI
      2005): the two groups with the highest co-association, while it is above 1/2. So every voted name's pairs
      are, taken together, held together by a majority of the runs that name them, and no two voted names are.
      Session 33, robot 5 seeds 0–2: with an unnamed sighting counted as "not alike", post 19's two halves stayed
      two names (one run had left 131 of the later half's 276 sightings unnamed; 16 names); abstaining, 15. That
      was changed after seeing robot 5; the other eight votes measured kept their number of names.
    - A group stands as a name only when more than half of the runs have a name that is that group, by mutual
      majority of sightings; the rest are *fragments* the runs name but disagree about, and are left unnamed.
      Session 33, robot 1 seeds 3–5: ten sightings that one run named with post 8 and another with post 9, and
      two that each run named with a different post, each stood as a name of their own (18 names where every run
      had 15).

    Why the mean and not every pair: a majority is not transitive. Session 33, robot 1: five sightings that one run
    names apart from their post would, pair by pair, have kept six others that another run names apart from that
    post out of it (two duplicates of 2 and 6 sightings, 17 names); on average both belong to their post.

    Names are numbered 0.. in the order of their first sighting. The result does not depend on the order of the
    runs or on any run's labels (ties between equal means go to the pair whose first sightings come first)."""
    runs = np.asarray(runs)
    if runs.ndim != 2:
        raise ValueError(f"runs must be (K, N), not shape {runs.shape}")
    k, n = runs.shape
    if k == 0:
        raise ValueError("no runs to vote")
    names = np.full(n, -1, np.int64)
    voted = np.flatnonzero(majority_named(runs))
    if not len(voted):
        return names
    atoms, atom_of = np.unique(runs[:, voted].T, axis=0, return_inverse=True)
    atom_of = atom_of.reshape(-1)
    first = np.full(len(atoms), n, np.int64)
    np.minimum.at(first, atom_of, voted)
    size = np.bincount(atom_of, minlength=len(atoms)).astype(float)
    named = atoms >= 0                                                   # (A, K)
    both = named[:, None, :] & named[None, :, :]
    agree = ((atoms[:, None, :] == atoms[None, :, :]) & both).sum(axis=2)
    # over the groups' sighting pairs: runs naming a pair alike, and runs naming both of it (Lance–Williams: a
    # joined group's row is the sum of its parts)
    alike_sums = size[:, None] * size[None, :] * agree
    both_sums = size[:, None] * size[None, :] * both.sum(axis=2)
    alive = np.ones(len(atoms), bool)
    while True:
        mean = np.divide(alike_sums, both_sums, out=np.zeros_like(alike_sums), where=both_sums > 0)
        mean[~alive] = -1.0
        mean[:, ~alive] = -1.0
        np.fill_diagonal(mean, -1.0)
        best = mean.max()
        if best <= 0.5:
            break
        a, b = np.nonzero(mean == best)
        pick = np.lexsort((np.maximum(first[a], first[b]), np.minimum(first[a], first[b])))[0]
        a, b = (int(a[pick]), int(b[pick])) if first[a[pick]] < first[b[pick]] else (int(b[pick]), int(a[pick]))
        for sums in (alike_sums, both_sums):
            sums[a] += sums[b]
            sums[:, a] += sums[:, b]
        size[a] += size[b]
        first[a] = min(first[a], first[b])
        alive[b] = False
        atom_of[atom_of == b] = a
    groups = np.full(n, -1, np.int64)
    groups[voted] = atom_of
    standing = [g for g in np.flatnonzero(alive) if _runs_holding(runs, groups == g, groups >= 0) > k / 2]
    starts = {int(g): int(first[g]) for g in standing}
    for number, g in enumerate(sorted(starts, key=starts.get)):
        names[groups == g] = number
    return names


def name_support(runs: np.ndarray, names: np.ndarray) -> np.ndarray:
    """How many of ``runs`` (K, N) have each of ``names``' names (0..M−1, −1 unnamed; :func:`voted_names`' result)
    as one of theirs, by the mutual majority that lets a voted name stand: (M,) integers in (K/2, K].

    A name held by fewer than all K runs is *contested*: a run dissents, by splitting it, by joining it to another
    name, or by leaving it mostly unnamed. Session 34, robots 1–4, the 80 votes of three of seeds 0–5 (session 30's
    runs): each of the 8 votes that kept a duplicate (16 names; none kept a wrong merge) had exactly one contested
    name, the duplicate itself (held by 2 of 3); so had 10 of the 72 right votes (robot 4, every triple with seed 3,
    which leaves most of one post's sightings unnamed; there the name is right)."""
    runs, names = np.asarray(runs), np.asarray(names)
    if runs.ndim != 2 or names.shape != runs.shape[1:]:
        raise ValueError(f"runs (K, N) and names (N,) needed, not shapes {runs.shape} and {names.shape}")
    voted = majority_named(runs)
    return np.array([_runs_holding(runs, names == x, voted) for x in range(int(names.max(initial=-1)) + 1)],
                    np.int64)


def _runs_holding(runs: np.ndarray, group: np.ndarray, voted: np.ndarray) -> int:
    """How many runs have a name that is ``group`` by mutual majority: more than half of the group's sightings are
    under that name, and more than half of that name's ``voted`` sightings (those a majority names) are in the
    group. A run's name stretched over sightings most runs leave unnamed is still that name."""
    size = int(group.sum())
    held = 0
    for run in runs:
        labels, counts = np.unique(run[group & (run >= 0)], return_counts=True)
        if len(labels) and counts.max() > size / 2:
            held += bool(counts.max() > np.sum((run == labels[np.argmax(counts)]) & voted) / 2)
    return held


def majority_named(runs: np.ndarray) -> np.ndarray:
    """The sightings (N,) that a strict majority of ``runs`` (K, N) names: the only ones a vote can name, and the
    ones over which a run's name is counted when it is checked against a voted name."""
    runs = np.asarray(runs)
    return (runs >= 0).sum(axis=0) > len(runs) / 2


def vote_metadata(seeds: list[int], held_by: np.ndarray) -> dict:
    """A voted map's ``metadata[VOTE_KEY]``: the seeds of its runs and, per landmark of the map (in its order), how
    many of those runs hold it (:func:`name_support`). A landmark held by fewer than all of them is contested."""
    held_by = np.asarray(held_by, np.int64).reshape(-1)
    if len(seeds) == 0 or held_by.min(initial=0) < 0 or held_by.max(initial=0) > len(seeds):
        raise ValueError(f"each landmark is held by 0 to {len(seeds)} runs (the seeds {seeds}), not {held_by}")
    return {"seeds": [int(s) for s in seeds], "held_by": held_by.tolist()}
