"""A landmark's appearance at several viewing distances: descriptors kept with the range each was made at.

Fixed-scale U-SURF changes with the viewing distance: on rendered frames the median distance between two
sightings of one true point grows from 0.17 (same range) to 0.52 (one 1.5–1.8× the other's range) and 0.67
(farther still), against the association's threshold of 0.5 (``benchmarks/descriptor_scale.py``). A landmark
that keeps only its first descriptor is therefore not recognised from another distance, and a second landmark
is made for the same point: most rendered duplicates (docs/fastslam-history.md, "Duplicates").

:class:`DescriptorBands` keeps up to ``slots`` descriptors per landmark id, each with the sensor range it was
made at. An observation is compared only with the descriptor made at the most similar range (|ln r/r_k|
smallest), so the comparison is at comparable scale and a landmark has no more chances of matching a wrong
observation than with one descriptor. A landmark learns its look at a new range only from an observation that
matched it (the most probable particle's match) from a range more than ``ratio`` away from every range it
keeps, while a slot is free: it follows a robot that approaches or backs away, band by band, and never
overwrites what it has (``refresh_descriptors``, which overwrites, let landmarks slide along textures). Ids
are global, as the filter's descriptor table: all particles share one landmark's descriptors.
"""
from __future__ import annotations

import numpy as np


class DescriptorBands:
    """Descriptors (ids, slots, D) with their ranges (ids, slots) (inf: empty slot; nan: range unknown)."""

    def __init__(self, slots: int, ratio: float, size: int, capacity: int = 256) -> None:
        if slots < 2:
            raise ValueError(f"DescriptorBands needs at least 2 slots, not {slots}")
        if not ratio > 1.0:
            raise ValueError(f"the range ratio between kept descriptors must be > 1, not {ratio}")
        self.slots, self.log_ratio, self.size = int(slots), float(np.log(ratio)), int(size)
        self.desc = np.zeros((capacity, self.slots, self.size), np.float32)
        self.range = np.full((capacity, self.slots), np.inf)
        self.n_ids = 0

    def append(self, desc: np.ndarray, ranges: np.ndarray | None = None) -> None:
        """New ids (in order) with their first descriptor (n, D) made at ``ranges`` (n,) m (None: unknown)."""
        n = len(desc)
        need = self.n_ids + n
        if need > len(self.desc):
            capacity = max(need, 2 * len(self.desc))
            desc_grown = np.zeros((capacity, self.slots, self.size), np.float32)
            range_grown = np.full((capacity, self.slots), np.inf)
            desc_grown[: self.n_ids], range_grown[: self.n_ids] = self.desc[: self.n_ids], self.range[: self.n_ids]
            self.desc, self.range = desc_grown, range_grown
        self.desc[self.n_ids:need, 0] = desc
        self.range[self.n_ids:need, 0] = np.nan if ranges is None else ranges
        self.n_ids = need

    def _nearest_slot(self, ids: np.ndarray, ranges: np.ndarray) -> np.ndarray:
        """(N, U) the slot of each id (U,) whose range is nearest each range (N,) in ratio (slot 0 if unknown)."""
        log_gap = np.abs(np.log(ranges)[:, None, None] - np.log(self.range[ids])[None])     # (N, U, K)
        return np.argmin(np.nan_to_num(log_gap, nan=0.0, posinf=np.inf), axis=2)

    def matches(self, ids: np.ndarray, desc: np.ndarray, ranges: np.ndarray, threshold: float
                ) -> tuple[np.ndarray, np.ndarray]:
        """(observation, id position) pairs whose descriptors (N, D) at ``ranges`` (N,) are closer than
        ``threshold`` to the id's (``ids`` (U,)) descriptor made at the most similar range."""
        if len(ids) == 0 or len(desc) == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        known = self.desc[ids]                                                     # (U, K, D)
        slot = self._nearest_slot(ids, ranges)                                     # (N, U)
        dots = (desc @ known.reshape(-1, self.size).T).reshape(len(desc), len(ids), self.slots)   # (N, U, K)
        chosen = np.take_along_axis(dots, slot[..., None], axis=2)[..., 0]
        return np.nonzero(2.0 - 2.0 * chosen < threshold ** 2)   # unit vectors: |a − b|² = 2 − 2 a·b

    def pair_distance2(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Squared distance (P,) between ids a (P,) and b (P,) at comparable range: their two descriptors made
        at the most similar ranges (slot 0 of each where a range is unknown)."""
        ra, rb = self.range[a], self.range[b]                                      # (P, K)
        with np.errstate(invalid="ignore"):                                      # empty against empty: nan
            gap = np.abs(np.log(ra)[:, :, None] - np.log(rb)[:, None, :])          # (P, K, K)
        gap = np.nan_to_num(gap, nan=np.inf, posinf=np.inf)
        gap[:, 0, 0] = np.where(np.isfinite(gap[:, 0, 0]), gap[:, 0, 0], 0.0)    # unknown: first against first
        best = np.argmin(gap.reshape(len(a), -1), axis=1)
        ka, kb = np.divmod(best, self.slots)
        dot = np.einsum("pd,pd->p", self.desc[a, ka], self.desc[b, kb])
        return 2.0 - 2.0 * dot

    def learn(self, ids: np.ndarray, desc: np.ndarray, ranges: np.ndarray) -> int:
        """Keep observations (n, D) matched to ``ids`` (n,) (distinct) from ``ranges`` (n,) more than the ratio
        away from every range the id keeps, in its first free slot. Returns how many were kept."""
        if len(ids) == 0:
            return 0
        kept = self.range[ids]                                                     # (n, K)
        known = np.isfinite(kept[:, 0])
        free = np.isinf(kept).argmax(axis=1)                                       # first empty slot (0: none)
        gap = np.abs(np.log(ranges)[:, None] - np.log(kept))
        new_band = np.min(np.where(np.isinf(kept), np.inf, gap), axis=1) > self.log_ratio
        take = np.flatnonzero(known & (free > 0) & new_band)
        self.desc[ids[take], free[take]] = desc[take]
        self.range[ids[take], free[take]] = ranges[take]
        return len(take)

    def absorb(self, into: np.ndarray, source: np.ndarray) -> None:
        """After merging landmark ``source`` (P,) into ``into`` (P,): ``into`` also keeps the looks of ``source``
        at ranges it has none of (free slots permitting), so that sightings from there find it."""
        for a, b in zip(into.tolist(), source.tolist(), strict=True):
            for k in np.flatnonzero(np.isfinite(self.range[b])):
                self.learn(np.array([a]), self.desc[b, k][None], self.range[b, k:k + 1])
