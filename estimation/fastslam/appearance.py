"""A landmark's appearance from several viewpoints: descriptors kept with the range (and the direction) each was
made from.

Fixed-scale U-SURF changes with the viewing distance: on rendered frames the median distance between two
sightings of one true point grows from 0.17 (same range) to 0.52 (one 1.5–1.8× the other's range) and 0.67
(farther still), against the association's threshold of 0.5 (``benchmarks/descriptor_scale.py``). A landmark
that keeps only its first descriptor is therefore not recognised from another distance, and a second landmark
is made for the same point: most rendered duplicates (docs/fastslam-history.md, "Duplicates"). Upright U-SURF
also changes with the viewing *direction*: after a turn on the spot the rendered demo's robot 2 sees its old
points from a median 0.45 rad away from where it first saw them, and the descriptor refuses 20–24 % of the
re-sightings at the same angle, 43–48 % at 0.1–0.6 rad, 84 % beyond 1 rad (docs/fusion-history.md, "Session 27").

:class:`DescriptorBands` keeps up to ``slots`` descriptors per landmark id, each with the view it was made from:
the sensor range r and the world-frame bearing φ of the line of sight (camera to point, in the map frame). Views
are compared by a normalised gap, chosen by ``key``: "range" |ln r/r_k| / ln ``ratio``; "direction"
|φ − φ_k| / ``angle`` (wrapped); "range+direction" the larger of the two. An observation is compared only with the
descriptor made from the nearest view, so the comparison is at comparable scale and angle and a landmark has no
more chances of matching a wrong observation than with one descriptor. A landmark learns its look from a new view
(gap > 1 to every view it keeps) only from an observation the filter matched to it, while a slot is free: it
follows a robot that approaches, backs away or walks round it, view by view, and never overwrites what it has
(``refresh_descriptors``, which overwrites, let landmarks slide along textures). Which matches may teach is the
filter's rule (``FastSLAMConfig.descriptor_learn_gate``). Ids are global, as the filter's descriptor table: all
particles share one landmark's descriptors.
"""
from __future__ import annotations

import numpy as np

from .config import DESCRIPTOR_SLOT_KEYS as SLOT_KEYS


class DescriptorBands:
    """Descriptors (ids, slots, D) with their ranges (ids, slots) (inf: empty slot; nan: range unknown) and world
    bearings (ids, slots) (nan: unknown or empty)."""

    def __init__(self, slots: int, ratio: float, size: int, capacity: int = 256, key: str = "range",
                 angle: float = 0.3) -> None:
        if slots < 2:
            raise ValueError(f"DescriptorBands needs at least 2 slots, not {slots}")
        if not ratio > 1.0:
            raise ValueError(f"the range ratio between kept descriptors must be > 1, not {ratio}")
        if key not in SLOT_KEYS:
            raise ValueError(f"the view key must be one of {', '.join(SLOT_KEYS)}, not {key!r}")
        if not 0.0 < angle <= np.pi:
            raise ValueError(f"the angle between kept descriptors must be in (0, π], not {angle}")
        self.slots, self.log_ratio, self.size = int(slots), float(np.log(ratio)), int(size)
        self.key, self.angle = key, float(angle)
        self.desc = np.zeros((capacity, self.slots, self.size), np.float32)
        self.range = np.full((capacity, self.slots), np.inf)
        self.bearing = np.full((capacity, self.slots), np.nan)
        self.n_ids = 0

    def append(self, desc: np.ndarray, ranges: np.ndarray | None = None, bearings: np.ndarray | None = None) -> None:
        """New ids (in order) with their first descriptor (n, D) made at ``ranges`` (n,) m and world ``bearings``
        (n,) rad (None: unknown)."""
        n = len(desc)
        need = self.n_ids + n
        if need > len(self.desc):
            capacity = max(need, 2 * len(self.desc))
            desc_grown = np.zeros((capacity, self.slots, self.size), np.float32)
            range_grown = np.full((capacity, self.slots), np.inf)
            bearing_grown = np.full((capacity, self.slots), np.nan)
            desc_grown[: self.n_ids], range_grown[: self.n_ids] = self.desc[: self.n_ids], self.range[: self.n_ids]
            bearing_grown[: self.n_ids] = self.bearing[: self.n_ids]
            self.desc, self.range, self.bearing = desc_grown, range_grown, bearing_grown
        self.desc[self.n_ids:need, 0] = desc
        self.range[self.n_ids:need, 0] = np.nan if ranges is None else ranges
        self.bearing[self.n_ids:need, 0] = np.nan if bearings is None or ranges is None else bearings
        self.n_ids = need

    def _gap(self, ranges: np.ndarray, bearings: np.ndarray | None, kept_range: np.ndarray,
             kept_bearing: np.ndarray) -> np.ndarray:
        """Normalised gap between views (r, φ) and kept views broadcast against them (inf: empty slot; nan: a view
        unknown). ``bearings`` None: directions unknown (nan)."""
        with np.errstate(invalid="ignore"):                                       # inf − inf, nan
            gap_r = np.abs(np.log(ranges) - np.log(kept_range))
            if self.key == "range":
                return gap_r
            gap_r = gap_r / self.log_ratio
            phi = np.nan if bearings is None else bearings
            gap_phi = np.abs((phi - kept_bearing + np.pi) % (2.0 * np.pi) - np.pi) / self.angle
            gap_phi = np.where(np.isinf(kept_range), np.inf, gap_phi)            # an empty slot stays empty
            return gap_phi if self.key == "direction" else np.maximum(gap_r, gap_phi)

    def _nearest_slot(self, ids: np.ndarray, ranges: np.ndarray, bearings: np.ndarray | None) -> np.ndarray:
        """(N, U) the slot of each id (U,) whose view is nearest each view (N,) (slot 0 if unknown)."""
        b = None if bearings is None else bearings[:, None, None]
        gap = self._gap(ranges[:, None, None], b, self.range[ids][None], self.bearing[ids][None])   # (N, U, K)
        return np.argmin(np.nan_to_num(gap, nan=0.0, posinf=np.inf), axis=2)

    def matches(self, ids: np.ndarray, desc: np.ndarray, ranges: np.ndarray, threshold: float,
                bearings: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(observation, id position) pairs whose descriptors (N, D) seen from ``ranges`` (N,) and ``bearings`` (N,)
        are closer than ``threshold`` to the id's (``ids`` (U,)) descriptor made from the nearest view."""
        if len(ids) == 0 or len(desc) == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        chosen = self._chosen_dots(ids, desc, ranges, bearings)
        return np.nonzero(2.0 - 2.0 * chosen < threshold ** 2)   # unit vectors: |a − b|² = 2 − 2 a·b

    def _chosen_dots(self, ids: np.ndarray, desc: np.ndarray, ranges: np.ndarray, bearings: np.ndarray | None
                     ) -> np.ndarray:
        known = self.desc[ids]                                                     # (U, K, D)
        slot = self._nearest_slot(ids, ranges, bearings)                           # (N, U)
        dots = (desc @ known.reshape(-1, self.size).T).reshape(len(desc), len(ids), self.slots)   # (N, U, K)
        return np.take_along_axis(dots, slot[..., None], axis=2)[..., 0]

    def distance(self, ids: np.ndarray, desc: np.ndarray, ranges: np.ndarray, bearings: np.ndarray | None = None
                 ) -> np.ndarray:
        """Distance (N,) of each observation (desc (N, D) from its view) to its id's (``ids`` (N,)) descriptor made
        from the nearest view: what :meth:`matches` compares with the threshold."""
        if len(ids) == 0:
            return np.zeros(0)
        chosen = np.array([self._chosen_dots(ids[i:i + 1], desc[i:i + 1], ranges[i:i + 1],
                                             None if bearings is None else bearings[i:i + 1])[0, 0]
                           for i in range(len(ids))])
        return np.sqrt(np.maximum(2.0 - 2.0 * chosen, 0.0))

    def pair_distance2(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Squared distance (P,) between ids a (P,) and b (P,) at comparable views: their two descriptors made
        from the nearest views (slot 0 of each where a view is unknown)."""
        gap = self._gap(self.range[a][:, :, None], self.bearing[a][:, :, None], self.range[b][:, None, :],
                        self.bearing[b][:, None, :])                              # (P, K, K)
        gap = np.nan_to_num(gap, nan=np.inf, posinf=np.inf)
        gap[:, 0, 0] = np.where(np.isfinite(gap[:, 0, 0]), gap[:, 0, 0], 0.0)    # unknown: first against first
        best = np.argmin(gap.reshape(len(a), -1), axis=1)
        ka, kb = np.divmod(best, self.slots)
        dot = np.einsum("pd,pd->p", self.desc[a, ka], self.desc[b, kb])
        return 2.0 - 2.0 * dot

    def learn(self, ids: np.ndarray, desc: np.ndarray, ranges: np.ndarray, bearings: np.ndarray | None = None) -> int:
        """Keep observations (n, D) matched to ``ids`` (n,) (distinct) from views (``ranges`` (n,), ``bearings``
        (n,)) farther than one step (gap > 1: the range ratio, the angle) from every view the id keeps, in its first
        free slot. Returns how many were kept."""
        if len(ids) == 0:
            return 0
        kept = self.range[ids]                                                     # (n, K)
        known = np.isfinite(kept[:, 0])
        if self.key != "range":   # a direction is needed: unknown ones (a prior map's, no bearing) never learn
            known &= np.isfinite(self.bearing[ids, 0]) & (bearings is not None)
            if bearings is not None:
                known &= np.isfinite(bearings)
        free = np.isinf(kept).argmax(axis=1)                                       # first empty slot (0: none)
        gap = self._gap(ranges[:, None], None if bearings is None else bearings[:, None], kept, self.bearing[ids])
        step = 1.0 if self.key != "range" else self.log_ratio
        new_view = np.min(np.where(np.isinf(kept), np.inf, gap), axis=1) > step
        take = np.flatnonzero(known & (free > 0) & new_view)
        self.desc[ids[take], free[take]] = desc[take]
        self.range[ids[take], free[take]] = ranges[take]
        if bearings is not None:
            self.bearing[ids[take], free[take]] = bearings[take]
        return len(take)

    def absorb(self, into: np.ndarray, source: np.ndarray) -> None:
        """After merging landmark ``source`` (P,) into ``into`` (P,): ``into`` also keeps the looks of ``source``
        from views it has none of (free slots permitting), so that sightings from there find it."""
        for a, b in zip(into.tolist(), source.tolist(), strict=True):
            for k in np.flatnonzero(np.isfinite(self.range[b])):
                self.learn(np.array([a]), self.desc[b, k][None], self.range[b, k:k + 1], self.bearing[b, k:k + 1])
