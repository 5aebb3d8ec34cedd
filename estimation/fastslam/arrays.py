"""Array helpers of the filter's vectorised steps: gathers, dense-id ranks, windows and minima without sorting.

Each gives what a plainer numpy expression (named in its docstring) gives, without what makes that slow on the
filter's (particle, observation, landmark) rows every frame: ``np.take`` for fancy indexing, lookup tables over the
dense landmark ids for ``np.unique``, counting before scattered minima, a sorted window for a pairwise matrix. Used
by ``filter.py``, ``pairs.py`` and ``merging.py``.
"""
from __future__ import annotations

import numpy as np


def take_rows(a: np.ndarray, index: np.ndarray) -> np.ndarray:
    """a[index] along the first axis (np.take: several times faster than fancy indexing of rows)."""
    return np.take(a, index, axis=0)


def take_cols(a: np.ndarray, index: np.ndarray) -> np.ndarray:
    """a[:, index] (np.take along the second axis: several times faster than fancy indexing)."""
    return np.take(a, index, axis=1)


def id_ranks(lids: np.ndarray, n_ids: int) -> tuple[np.ndarray, np.ndarray]:
    """np.unique(lids, return_inverse=True) for ids in [0, n_ids) (ids ascending, each row's rank among them)
    through lookup tables: ids are dense, so this beats sorting the rows."""
    present = np.zeros(n_ids, bool)
    present[lids] = True
    uniq = np.flatnonzero(present)
    rank = np.full(n_ids, -1, np.int64)
    rank[uniq] = np.arange(len(uniq))
    return uniq, rank[lids]


def unique_ids(lids: np.ndarray, n_ids: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """np.unique(lids, return_index=True, return_inverse=True) for ids in [0, n_ids) (the same three arrays: ids
    ascending, each one's first row, each row's rank; :func:`id_ranks`), without sorting the rows."""
    uniq, inverse = id_ranks(lids, n_ids)
    first = np.full(len(uniq), len(lids), np.int64)
    np.minimum.at(first, inverse, np.arange(len(lids)))
    return uniq, first, inverse


def x_window_pairs(x: np.ndarray, rows: np.ndarray, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(i, u) with |x[rows[i]] − x[u]| ≤ half[i] (+ a rounding margin), in row-major order (i, then u ascending):
    the nonzero entries of the (len(rows), len(x)) matrix |Δx| ≤ half, found through x sorted, without the matrix.
    A superset of any pairs whose distance (of which |Δx| is a lower bound) is below half."""
    order = np.argsort(x, kind="stable")
    xs = x[order]
    half = half + 1e-6 * (1.0 + np.max(np.abs(x), initial=0.0) + np.abs(half))   # never lose a pair to rounding
    lo = np.searchsorted(xs, x[rows] - half, "left")
    n = np.searchsorted(xs, x[rows] + half, "right") - lo
    n = np.maximum(n, 0)
    i = np.repeat(np.arange(len(rows)), n)
    u = order[np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n - lo, n)]
    key = np.argsort(i * len(x) + u, kind="stable")
    return i[key], u[key]


def is_in(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """np.isin(a, b) for integer arrays (the same booleans): ``b`` sorted once and ``a`` looked up in it, a few
    calls instead of isin's merge of both arrays (a frame's (particle, slot) keys: isin was 8 % of the known-id
    filter's time)."""
    if len(b) == 0:
        return np.zeros(np.shape(a), bool)
    ordered = np.sort(b)
    at = np.searchsorted(ordered, a)
    return np.take(ordered, np.minimum(at, len(ordered) - 1)) == a


def sorted_difference(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """np.setdiff1d(a, b) for small integer arrays (the same: the values of ``a`` not in ``b``, unique and
    ascending, ``a``'s dtype), through Python sets: a frame's few slots, where setdiff1d's sorts cost more."""
    a = np.asarray(a)
    return np.array(sorted(set(a.tolist()).difference(np.asarray(b).tolist())), dtype=a.dtype)


def cos_sin(poses: np.ndarray, index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cos θ, sin θ (P,) of poses[index]: computed once per particle (M) and gathered, not once per pair."""
    return np.cos(poses[:, 2])[index], np.sin(poses[:, 2])[index]


def within_angle(lateral: np.ndarray, depth: np.ndarray, half_angle: float) -> np.ndarray:
    """|atan2(lateral, depth)| < half_angle for depth > 0 (a tangent comparison, no arctan per point)."""
    if half_angle >= 0.5 * np.pi:
        return np.abs(np.arctan2(lateral, depth)) < half_angle
    return np.abs(lateral) < np.tan(half_angle) * depth


def rows_with_id(lids: np.ndarray, wanted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows r of ``lids`` (C,) whose id is in ``wanted`` (K,), once per (row, k) with lids[r] == wanted[k]:
    returns (rows, k), both (L,)."""
    order = np.argsort(lids, kind="stable")
    sorted_lids = lids[order]
    lo = np.searchsorted(sorted_lids, wanted, side="left")
    hi = np.searchsorted(sorted_lids, wanted, side="right")
    reps = hi - lo
    k = np.repeat(np.arange(len(wanted)), reps)
    within = np.arange(int(reps.sum())) - np.repeat(np.cumsum(reps) - reps, reps)
    return order[np.repeat(lo, reps) + within], k


def first_minimum(key: np.ndarray, value: np.ndarray, n_keys: int, rank: np.ndarray) -> np.ndarray:
    """Positions (K,), in no particular order, of the smallest ``value`` of each distinct ``key`` (L,) in
    [0, n_keys); ties go to the smallest ``rank`` (L,) (distinct, < 2⁶², e.g. the position).

    Most keys occur once (one gated candidate): those are found by counting, and only the rest take the slower
    scattered minima."""
    count = np.bincount(key, minlength=n_keys)
    several = count[key] > 1
    alone = np.flatnonzero(~several)
    if len(alone) == len(key):
        return alone
    sub = np.flatnonzero(several)
    sub_key, sub_value = key[sub], value[sub]
    smallest = np.full(n_keys, np.inf)
    np.minimum.at(smallest, sub_key, sub_value)
    limit = np.iinfo(np.int64).max
    best_rank = np.full(n_keys, limit)
    np.minimum.at(best_rank, sub_key, np.where(sub_value == smallest[sub_key], rank[sub], limit))
    winners = sub[(sub_value == smallest[sub_key]) & (rank[sub] == best_rank[sub_key])]
    return np.concatenate([alone, winners])
