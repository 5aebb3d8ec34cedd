"""Names that several runs agree on: a vote, sighting pair by sighting pair, over the partitions that runs of one
log made (issue 13, MRCLAM without barcodes; session 33).

A chain of association decisions made on a particle filter's output depends on the filter's random draws. On
MRCLAM the unknown-association chain (``benchmarks.mrclam_constellation``) makes its wrong merges on different
robots with different seeds (session 32: seed 0 robot 5, seed 1 robots 2 and 3, seed 2 robot 1), and its left-over
duplicates likewise. A merge the data decides should not depend on the draw; one that only some runs make is not
decided by the data. :func:`voted_names` keeps two sightings under one name when a majority of the runs does, and
never puts together two sightings that a majority of the runs keeps apart: a wrong merge one run of three makes is
out-voted, and so is a duplicate one run of three leaves.

It has no parameter beyond the runs themselves (a strict majority of them). What it costs is the runs: K times one
run's work.
"""
from __future__ import annotations

import numpy as np

__all__ = ["voted_names"]


def voted_names(runs: np.ndarray) -> np.ndarray:
    """The names (N,) that a strict majority of ``runs`` (K, N) agrees on; each row one run's name per sighting,
    −1 for a sighting that run left unnamed. The labels of different runs are unrelated.

    - A sighting that a majority of the runs leaves unnamed is unnamed (−1).
    - Sightings that every run names alike form *atoms* (the runs' common refinement); two sightings that every run
      holds under one name are always in one voted name.
    - Atoms are joined, most agreeing pairs first, when a majority of the runs holds them under one name; a join is
      refused when it would put together two atoms that a majority of the runs holds under different names.
      So no voted name holds two sightings that a majority keeps apart.

    Names are numbered 0.. in the order of their first sighting. The result does not depend on the order of the
    runs or on any run's labels (ties between equally agreeing joins go to the pair whose first sightings come
    first)."""
    runs = np.asarray(runs)
    if runs.ndim != 2:
        raise ValueError(f"runs must be (K, N), not shape {runs.shape}")
    k, n = runs.shape
    if k == 0:
        raise ValueError("no runs to vote")
    majority = k // 2 + 1
    names = np.full(n, -1, np.int64)
    voted = np.flatnonzero((runs >= 0).sum(axis=0) >= majority)
    if not len(voted):
        return names
    atoms, atom_of = np.unique(runs[:, voted].T, axis=0, return_inverse=True)
    atom_of = atom_of.reshape(-1)
    first = np.full(len(atoms), n, np.int64)
    np.minimum.at(first, atom_of, voted)
    size = np.bincount(atom_of, minlength=len(atoms))
    named = atoms >= 0                                                   # (A, K)
    both = named[:, None, :] & named[None, :, :]
    same = atoms[:, None, :] == atoms[None, :, :]
    agree = (both & same).sum(axis=2)
    apart = (both & ~same).sum(axis=2)
    a, b = np.nonzero(np.triu(agree >= majority, 1))
    # most agreeing first, then the heavier pair, then the earlier first sightings (independent of the runs' order)
    order = np.lexsort((np.maximum(first[a], first[b]), np.minimum(first[a], first[b]), -(size[a] + size[b]),
                        -agree[a, b]))
    members = {i: [i] for i in range(len(atoms))}
    root = np.arange(len(atoms))
    for e in order:
        ra, rb = root[a[e]], root[b[e]]
        if ra == rb:
            continue
        if (apart[np.ix_(members[ra], members[rb])] >= majority).any():
            continue                                   # a majority keeps two of their sightings apart
        members[ra] += members.pop(rb)
        root[members[ra]] = ra
    component = root[atom_of]
    starts = {int(r): int(first[members[r]].min()) for r in members}
    number = {r: i for i, r in enumerate(sorted(starts, key=starts.get))}
    names[voted] = [number[int(c)] for c in component]
    return names
