"""Alignments of unchanged maps are not computed twice.

A mission fuses its robots' maps every few seconds, and between two fusions most maps have not changed:
re-aligning every pair and matching every map against itself (``self_structure``) cost about 1 s on the
rendered demo's 1,000-landmark maps.  :class:`AlignmentCache` keys each result by the content of the maps it
depends on (:func:`map_fingerprint`: positions, covariances, descriptors and identities — everything
``align`` reads), so a changed map is always recomputed and an unchanged one never is.

A cached pair alignment is the one computed when that pair of maps was first seen; a later call with
another random generator returns it instead of a new RANSAC run (an equally valid answer, and a fused map
that does not jitter between fusions of the same maps).  A map's self-repeat count is drawn from a
generator seeded by the map's content, in :func:`fusion.align` as here, so it is the same cached or not.
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import astuple

import numpy as np

from estimation.landmark_map import LandmarkMap

from .alignment import align
from .alignment_config import resolve_preset
from .evidence import self_structure
from .fingerprint import content_rng, map_fingerprint


class AlignmentCache:
    """Bounded (least recently used) memory of pair alignments and of each map's self-repeat count.

    ``align(map1, map2, preset, rng)`` is :func:`fusion.align` that returns the stored alignment when both maps
    and the preset are unchanged.  ``hits`` / ``misses`` count pair look-ups, ``self_hits`` / ``self_misses``
    the maps' self-structure look-ups.
    """

    def __init__(self, max_pairs: int = 256, max_maps: int = 64) -> None:
        self.max_pairs, self.max_maps = int(max_pairs), int(max_maps)
        self._pairs: OrderedDict = OrderedDict()
        self._self: OrderedDict = OrderedDict()
        self.hits = self.misses = self.self_hits = self.self_misses = 0

    @staticmethod
    def _remember(store: OrderedDict, key, value, limit: int) -> None:
        store[key] = value
        store.move_to_end(key)
        while len(store) > limit:
            store.popitem(last=False)

    def self_structure(self, landmark_map: LandmarkMap, config, inflation: float | None = None) -> int:
        """``fusion.evidence.self_structure`` of the map, computed once per map content, configuration and gate scale
        (``inflation``: the pair's, with ``self_repeat_gate="pair"``)."""

        fp = map_fingerprint(landmark_map)
        key = (fp, astuple(config), inflation)
        if key in self._self:
            self.self_hits += 1
            self._self.move_to_end(key)
            return self._self[key]
        self.self_misses += 1
        value = self_structure(landmark_map, config, content_rng(landmark_map, fp), inflation)
        self._remember(self._self, key, value, self.max_maps)
        return value

    def align(self, map1: LandmarkMap, map2: LandmarkMap, preset="robust", rng: np.random.Generator | None = None,
              prior=None):
        """:func:`fusion.align`, or the alignment stored for these two maps' contents, this preset and this start
        prior (``fusion.prior.StartPrior`` or None)."""
        config = resolve_preset(preset)
        prior_key = None if prior is None else (prior.mean.tobytes(), prior.covariance.tobytes(), prior.level)
        key = (map_fingerprint(map1), map_fingerprint(map2), astuple(config), prior_key)
        if key in self._pairs:
            self.hits += 1
            self._pairs.move_to_end(key)
            return self._pairs[key]
        self.misses += 1
        result = align(map1, map2, config, rng, cache=self, prior=prior)
        self._remember(self._pairs, key, result, self.max_pairs)
        return result

    def __len__(self) -> int:
        return len(self._pairs)
