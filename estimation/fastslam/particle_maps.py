"""The maps a filter gives out: one particle's landmarks as a :class:`~estimation.landmark_map.LandmarkMap`, their
covariances over the particle cloud, and the most probable particle's map for export.

:class:`ParticleMaps` is a part of :class:`~estimation.fastslam.filter.FastSLAM` (its base class): its methods read
the filter's state (``config``, ``store``, ``poses``, ``weights``, ``drift``, ``self_check``, the descriptors, the
external ids and the trajectory) and change none of it.
"""
from __future__ import annotations

import numpy as np

from ..landmark_map import LandmarkMap
from .arrays import take_rows
from .export_merge import merge_coincident
from .lever_drift import correlated_mean_factor
from .linalg import sym_matrices

COVARIANCE_KINDS = ("particle", "mixture", "mixture+drift")   # what a map's landmark covariances are (particle_map)


class ParticleMaps:
    """The map-output part of :class:`~estimation.fastslam.filter.FastSLAM` (see the module docstring)."""

    def particle_landmark_count(self) -> np.ndarray:
        """(M,) number of landmarks each particle holds."""
        store = self.store
        counts = np.zeros(len(self.poses), np.int64)
        k = int(store.n_blocks.max(initial=0))
        if k:
            phys = store.table[:, :k]
            alive = (store.lid[np.where(phys >= 0, phys, 0)] >= 0) & (phys >= 0)[..., None]
            counts = alive.sum(axis=(1, 2))
        return counts

    def particle_map(self, particle: int, min_count: int = 1, robot: str = "robot", frame: str = "start",
                     metadata: dict | None = None, covariance: str = "particle") -> LandmarkMap:
        """Landmarks of one particle seen at least ``min_count`` times, as a :class:`LandmarkMap`.

        ``covariance``: "particle" = the particle's own EKF covariances (conditional on its trajectory);
        "mixture" = each landmark's covariance over the whole particle cloud about this particle's mean (see
        :meth:`mixture_covariances`); "mixture+drift" adds the map frame's drift at the landmark's creation
        (:mod:`estimation.fastslam.drift`), which the resampled cloud forgets: the honest one for export.
        """
        if covariance not in COVARIANCE_KINDS:
            raise ValueError(f"covariance must be one of {', '.join(COVARIANCE_KINDS)}, not {covariance!r}")
        store = self.store
        g = store.particle_slots(int(particle))
        g = g[store.flat_count[g] >= min_count]
        lids = store.flat_lid[g]
        order = np.argsort(lids)
        g, lids = g[order], lids[order]
        means = store.flat_mean[g].copy()
        covs = sym_matrices(store.flat_cov[g].T)
        meta = dict(metadata or {})
        if covariance.startswith("mixture"):
            covs = self.mixture_covariances(lids, means)
        if self.config.observation_correlation > 0:   # successive observations' errors are correlated
            covs = covs * correlated_mean_factor(store.flat_count[g], self.config.observation_correlation)[:, None,
                                                                                                           None]
        drift, origins = None, None
        if covariance.endswith("drift"):   # the drift is also kept apart: which landmarks share it (landmark_map.py)
            covs = covs + self.drift.landmark_covariances(lids)
            drift = sym_matrices(self.drift.landmark_pose_covariances(lids))
            origins = self.drift.landmark_origins(lids)
        meta["landmark_covariance"] = covariance
        if self._lid_of_external:
            meta["external_ids"] = self.external_ids(lids).tolist()
        return LandmarkMap(
            means, covs, self._descriptors[lids].copy(), lids,
            store.flat_count[g].copy(), robot=robot, frame=frame, trajectory=self.trajectory(particle),
            metadata=meta, drift_covariances=drift, drift_origins=origins)

    def mixture_covariances(self, lids: np.ndarray, about: np.ndarray) -> np.ndarray:
        """(L, 3, 3) covariances of landmarks ``lids`` (L,) over the weighted particle cloud, about the points
        ``about`` (L, 3): Σ̃ = Σ_m w_m [Σ_m + (μ_m − a)(μ_m − a)ᵀ] / Σ_m w_m over the particles m holding the
        landmark. A particle's Σ_m is conditional on its own trajectory; the spread of the μ_m over the
        particles adds the trajectory's uncertainty, which the exported map's landmarks share."""
        store = self.store
        n_particles = len(self.poses)
        width, b = store.table.shape[1], store.block_size
        phys = store.table
        held = take_rows(store.lid, np.maximum(phys, 0).ravel()).reshape(n_particles, width, b)
        held = np.where((phys >= 0)[..., None], held, -1)
        rank = np.full(self._n_ids, -1, np.int64)
        rank[lids] = np.arange(len(lids))
        flat = np.flatnonzero(held.ravel() >= 0)
        r = rank[held.ravel()[flat]]
        flat, r = flat[r >= 0], r[r >= 0]
        m, rest = np.divmod(flat, width * b)
        k, slot = np.divmod(rest, b)
        state = take_rows(store.flat_state, phys[m, k] * b + slot)
        w = self.weights[m]
        dev = state[:, :3] - about[r]
        n = len(lids)
        total = np.bincount(r, w, minlength=n)
        second = np.empty((6, n))
        for c, (i, j) in enumerate(((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))):
            second[c] = np.bincount(r, w * (state[:, 3 + c] + dev[:, i] * dev[:, j]), minlength=n)
        return sym_matrices(second / np.maximum(total, 1e-300))

    def best_map(self, robot: str = "robot", metadata: dict | None = None, min_count: int | None = None,
                 frame: str = "start", covariance: str = "mixture+drift") -> LandmarkMap:
        """The most probable particle's map (landmarks seen ≥ ``min_count``, default ``confirm_count``), with
        the landmarks' covariances over the particle cloud by default (``covariance``, see :meth:`particle_map`).
        With ``export_merge_coincident`` ("unknown" association), landmarks that coincide under the particle's own
        covariances are merged (export_merge.py); a particle's own map (:meth:`particle_map`) is never merged."""
        min_count = self.config.confirm_count if min_count is None else min_count
        meta = {"fastslam": self.config.to_dict(), "self_check": self.self_check.verdict()}
        meta.update(metadata or {})
        exported = self.particle_map(self._best, min_count, robot, frame, meta, covariance)
        if self.config.export_merge_coincident and self.config.association == "unknown":
            conditional = self.particle_map(self._best, min_count, robot, frame, covariance="particle").covariances
            exported = merge_coincident(exported, conditional)
        return exported
