"""A map's content as a digest: the key of every result computed from a map alone (:mod:`fusion.cache`) and the
seed of the random draws made on it, so that such a result depends on the map only, cached or not."""
from __future__ import annotations

import hashlib

import numpy as np

from estimation.landmark_map import LandmarkMap


def map_fingerprint(landmark_map: LandmarkMap) -> bytes:
    """16-byte digest of everything an alignment reads from a map (positions, covariances, descriptors,
    ``metadata["external_ids"]``); equal maps give equal digests, a changed landmark another."""
    h = hashlib.blake2b(digest_size=16)
    for arr in (landmark_map.positions, landmark_map.covariances, landmark_map.descriptors):
        a = np.ascontiguousarray(arr)
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    ids = landmark_map.metadata.get("external_ids")
    h.update(b"ids:" + (b"-" if ids is None else repr([int(v) for v in np.asarray(ids).reshape(-1)]).encode()))
    return h.digest()


def content_rng(landmark_map: LandmarkMap, fingerprint: bytes | None = None) -> np.random.Generator:
    """A generator seeded by the map's content: what is computed from one map alone depends on that map only."""
    fp = map_fingerprint(landmark_map) if fingerprint is None else fingerprint
    return np.random.default_rng(int.from_bytes(fp[:8], "little"))
