"""Duplicate landmarks merged, per particle: the pairs' evidence (alike, co-visibility, drift) and the merge itself.

Step 7 of an update (``filter.py``'s module docstring): every ``merge_every`` updates the landmarks touched since are
tested against their neighbours (:meth:`DuplicateMerging._merge_duplicates`), and each frame of the most probable
particle adds co-visibility evidence (:meth:`DuplicateMerging._count_covisibility`). :class:`DuplicateMerging` is a
part of :class:`~estimation.fastslam.filter.FastSLAM` (its base class): its methods read and write the filter's
state (``config``, ``store``, ``drift``, ``stats``, the descriptors, ``_candidates`` and ``_remap``) and keep the
pairs' memory (``_pair_evidence``, ``_codetected``, ``_merge_ready``, ``_merged``, made in ``FastSLAM.__init__``).
A subclass may override a test (``benchmarks/merge_oracle.py`` overrides :meth:`DuplicateMerging._alike_pairs`).
"""
from __future__ import annotations

import numpy as np

from . import drift_merge
from .arrays import first_minimum, rows_with_id, take_cols, take_rows, unique_ids, x_window_pairs
from .existence import exclusive_log_odds
from .linalg import sym_adjugate, sym_components, sym_inverse, sym_matvec, sym_quadratic, sym_rotate_z
from .pairs import Pairs

PAIR_SHIFT = 32            # a pair of landmark ids (a < b) as one int64 key: a << 32 | b
MERGED_PAIRS_KEPT = 10_000  # FastSLAM.merged_pairs keeps the latest this many distinct pairs (a route makes ~60-70)


class DuplicateMerging:
    """The duplicate-merging part of :class:`~estimation.fastslam.filter.FastSLAM` (see the module docstring)."""

    def _merge_duplicates(self, touched: np.ndarray) -> int:
        """Merge, in each particle, landmarks that are one point. Two kinds of evidence (pairs of ids):

        - *alike* (:meth:`_alike_pairs`): statistically one point given the particle's trajectory,
          (μ_a − μ_b)ᵀ(Σ_a + Σ_b)⁻¹(μ_a − μ_b) < ``merge_gate``, and (with descriptors) descriptors closer than
          ``merge_descriptor_threshold``; one of them matched or made since the last pass (``touched``);
        - *co-visibility* (``merge_covisibility``, :meth:`_count_covisibility`): never detected in one frame
          although, again and again, one was detected while the other was predicted well in view, worth
          ``merge_log_odds``; and one point within the covariance the landmarks really have in the map frame,
          Σ_a + Σ_b + C_a + C_b (C: the map frame's drift at each one's creation, ``drift.py``), since a
          landmark made again after the pose drifted sits off by that drift, not by its EKF's σ.

        With ``merge_covisibility``, a pair ever detected in one frame is two points and is never merged. The
        newer landmark (higher id) goes into the older one: μ, Σ fused as two independent estimates (given the
        particle's trajectory they are: each observation updated only one of them), counts added, the larger
        existence kept. Only landmarks near some particle's view are considered. Returns the number of
        (particle, landmark) merges; the id pairs go to ``merged_pairs``."""
        cfg, store = self.config, self.store
        cand, lids = self._candidates(self.poses)
        if len(cand.m) == 0:
            return 0
        uniq, first, inverse = unique_ids(lids, self._n_ids)
        a, b = np.zeros(0, np.int64), np.zeros(0, np.int64)
        if cfg.descriptor_size > 0 or not cfg.merge_covisibility:
            # without descriptors "statistically one point" is geometry alone, which cannot tell one landmark
            # from two neighbours within a few σ (MRCLAM: posts 0.7-1.9 m apart, σ 0.3-0.6 m): co-visibility must
            # then supply the second piece of evidence
            a, b = self._alike_pairs(cand, uniq, first, inverse, touched)
        by_evidence = np.zeros(len(a), bool)
        if cfg.merge_covisibility:
            if len(a) and self._codetected:
                keep = np.array([k not in self._codetected for k in ((a << PAIR_SHIFT) | b).tolist()], bool)
                a, b, by_evidence = a[keep], b[keep], by_evidence[keep]
            if self._merge_ready:
                ready = np.fromiter(self._merge_ready, np.int64, len(self._merge_ready))
                ra, rb = ready >> PAIR_SHIFT, ready & ((1 << PAIR_SHIFT) - 1)
                present = np.zeros(self._n_ids, bool)
                present[uniq] = True
                near = present[ra] & present[rb]
                a = np.concatenate([a, ra[near]])
                b = np.concatenate([b, rb[near]])
                by_evidence = np.concatenate([by_evidence, np.ones(int(near.sum()), bool)])
        by_relative = np.zeros(len(a), bool)
        if cfg.merge_relative_drift:   # made again after a drift, never detected in one frame (drift_merge.py)
            ra, rb = drift_merge.candidate_pairs(self.drift, uniq, inverse, take_rows(store.flat_state, cand.g),
                                                 touched, self._codetected, cfg.merge_gate, PAIR_SHIFT)
            a, b = np.concatenate([a, ra]), np.concatenate([b, rb])
            by_evidence = np.concatenate([by_evidence, np.zeros(len(ra), bool)])
            by_relative = np.concatenate([by_relative, np.ones(len(ra), bool)])
        if len(a) == 0:
            return 0
        # one row per id pair (a pair on both lists may pass either test)
        pair_key, at = np.unique(a * self._n_ids + b, return_inverse=True)
        evidence = np.zeros(len(pair_key), bool)
        np.logical_or.at(evidence, at, by_evidence)
        alike, relative = np.zeros(len(pair_key), bool), np.zeros(len(pair_key), bool)
        np.logical_or.at(alike, at, ~(by_evidence | by_relative))
        np.logical_or.at(relative, at, by_relative)
        a, b = np.divmod(pair_key, self._n_ids)
        # expand to the particles holding both (rows of the candidate list, looked up by particle and id)
        key = cand.m * self._n_ids + lids
        order = np.argsort(key, kind="stable")
        sorted_key = key[order]
        rows_a, pair = rows_with_id(lids, a)                                       # candidate rows holding a
        m = cand.m[rows_a]
        pos = np.searchsorted(sorted_key, m * self._n_ids + b[pair])
        pos = np.minimum(pos, len(sorted_key) - 1)
        found = sorted_key[pos] == m * self._n_ids + b[pair]
        rows_a, rows_b, pair = rows_a[found], order[pos[found]], pair[found]
        if len(rows_a) == 0:
            return 0
        sa, sb = take_rows(store.flat_state, cand.g[rows_a]).T, take_rows(store.flat_state, cand.g[rows_b]).T
        diff = sa[:3] - sb[:3]
        adj, det = sym_adjugate(sa[3:] + sb[3:])
        d2 = sym_quadratic(adj, diff) / det
        ok = alike[pair] & (d2 < cfg.merge_gate)
        if evidence.any():
            drift = sym_components(self.drift.landmark_covariances(a[pair])) + sym_components(
                self.drift.landmark_covariances(b[pair]))
            adj, det = sym_adjugate(sa[3:] + sb[3:] + drift)
            d2_drift = sym_quadratic(adj, diff) / det
            by_drift = evidence[pair] & (d2_drift < cfg.merge_gate) & ~ok
            ok |= by_drift
            d2 = np.where(by_drift, d2_drift, d2)
        if relative.any():   # Σ_a + Σ_b + the drift between their creations, one candidate each (drift_merge.py)
            r = np.flatnonzero(relative[pair])
            adj, det = sym_adjugate(take_cols(sa[3:], r) + take_cols(sb[3:], r)
                                    + drift_merge.relative_drift(self.drift, a[pair[r]], b[pair[r]], sb[:3, r].T))
            d2_rel = sym_quadratic(adj, diff[:, r]) / det
            hit = d2_rel < cfg.merge_gate
            r, d2_rel = r[hit], d2_rel[hit]
            one = drift_merge.mutually_unique(cand.m[rows_a[r]], a[pair[r]], b[pair[r]]) & ~ok[r]
            ok[r[one]], d2[r[one]] = True, d2_rel[one]
        ok = np.flatnonzero(ok)
        if len(ok) == 0:
            return 0
        rows_a, rows_b, d2, pair = rows_a[ok], rows_b[ok], d2[ok], pair[ok]
        # one merge per landmark and frame: each newer landmark goes into its nearest older one, each older one
        # takes its nearest newer one, and a landmark on both sides of chosen pairs waits for the next frame
        n_rows = len(cand.m)
        pick = first_minimum(rows_b, d2, n_rows, np.arange(len(rows_b)))
        pick = pick[first_minimum(rows_a[pick], d2[pick], n_rows, pick)]
        rows_a, rows_b, pair, d2 = rows_a[pick], rows_b[pick], pair[pick], d2[pick]
        clash = np.isin(rows_a, rows_b)
        rows_a, rows_b, pair, d2 = rows_a[~clash], rows_b[~clash], pair[~clash], d2[~clash]
        if len(rows_a) == 0:
            return 0
        ma, mb = cand.take(rows_a), cand.take(rows_b)
        store.make_writable(np.concatenate([ma.m, mb.m]), np.concatenate([ma.k, mb.k]))
        ga, gb = self._remap(ma), self._remap(mb)
        sa, sb = take_rows(store.flat_state, ga).T, take_rows(store.flat_state, gb).T
        ia, ib = sym_inverse(sa[3:]), sym_inverse(sb[3:])
        cov = sym_inverse(ia + ib)                                                  # Σ = (Σ_a⁻¹ + Σ_b⁻¹)⁻¹
        mean = sym_matvec(cov, sym_matvec(ia, sa[:3]) + sym_matvec(ib, sb[:3]))     # μ = Σ (Σ_a⁻¹μ_a + Σ_b⁻¹μ_b)
        # a pair merged on co-visibility alone is one point seen from two drifted stretches of the trajectory, not
        # two independent measurements of it: the older landmark keeps its estimate, consistent with the map made
        # with it, and takes the newer one's sightings
        drifted = ~alike[pair] | (d2 >= cfg.merge_gate)
        if cfg.merge_estimate == "older":   # so is an alike pair made apart in time (docs "Session 10")
            drifted[:] = True
        mean[:, drifted], cov[:, drifted] = sa[:3, drifted], sa[3:, drifted]
        store.put_state(ga, np.vstack([mean, cov]).T)
        store.flat_count[ga] += store.flat_count[gb]
        store.flat_logodds[ga] = np.maximum(store.flat_logodds[ga], store.flat_logodds[gb])
        store.flat_lid[gb] = -1
        store.include_in_bbox(ga, mean[:2].T)
        self.stats.landmarks_merged += len(ga)
        for p in np.unique(pair).tolist():   # a pair merged again (in other particles) keeps its place
            self._merged[int(a[p]), int(b[p])] = bool(evidence[p] and not alike[p])
        while len(self._merged) > MERGED_PAIRS_KEPT:
            del self._merged[next(iter(self._merged))]
        if self._bands is not None:   # the older landmark also keeps the newer one's looks at other ranges
            self._bands.absorb(a[np.unique(pair)], b[np.unique(pair)])
        if cfg.merge_look == "newer" and cfg.descriptor_size > 0:   # the look it is seen with now, from nearer
            self._descriptors[a[np.unique(pair)]] = self._descriptors[b[np.unique(pair)]]
        return len(ga)

    @property
    def merged_pairs(self) -> list[tuple[int, int, bool]]:
        """The id pairs merged so far, each once, in the order first merged (the latest ``MERGED_PAIRS_KEPT``):
        (older id, newer id, by co-visibility alone in its latest merge)."""
        return [(a, b, e) for (a, b), e in self._merged.items()]

    def _alike_pairs(self, cand: Pairs, uniq: np.ndarray, first: np.ndarray, inverse: np.ndarray,
                     touched: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Id pairs (a < b) near enough to pass ``merge_gate`` under Σ_a + Σ_b in some particle and alike in
        descriptors, one of them in ``touched``. Vectorised: pairs of ids are first kept only if their means (in
        one particle) are within ``merge_radius``, by an exact bound: |μ_a − μ_b| ≥ |ref_a − ref_b| − spread_a −
        spread_b in every particle and d² ≥ |μ_a − μ_b|² / tr(Σ_a + Σ_b), with spread and tr Σ maximised over
        the particles holding the id."""
        cfg, store = self.config, self.store
        none = np.zeros(0, np.int64), np.zeros(0, np.int64)
        t = np.flatnonzero(np.isin(uniq, touched))
        if len(t) == 0:
            return none
        state = take_rows(store.flat_state, cand.g)
        ref = np.ascontiguousarray(state[first, :3])                              # (U, 3) one particle's mean
        # (not np.take of store.flat_mean: a strided view, which np.take first copies whole: every slot's mean)
        spread2, trace = np.zeros(len(uniq)), np.zeros(len(uniq))
        # |μ − ref|² per candidate row, column by column: the same sums as np.sum(..., axis=1) (one row's three
        # terms added in order), without numpy's slow reduction over a length-3 axis and fancy row indexing
        at_ref, rows = take_rows(ref, inverse).T, state.T
        np.maximum.at(spread2, inverse, (rows[0] - at_ref[0]) ** 2 + (rows[1] - at_ref[1]) ** 2
                      + (rows[2] - at_ref[2]) ** 2)
        np.maximum.at(trace, inverse, state[:, 3] + state[:, 6] + state[:, 8])
        spread = np.sqrt(spread2)
        ti, ui = x_window_pairs(ref[:, 0], t, cfg.merge_radius + spread[t] + spread.max())
        gap = (take_rows(ref, t[ti]) - take_rows(ref, ui)).T   # |gap| column by column: np.linalg.norm's sums, in order
        d = np.sqrt(gap[0] * gap[0] + gap[1] * gap[1] + gap[2] * gap[2]) - spread[t[ti]] - spread[ui]
        bound = cfg.merge_gate * (trace[t[ti]] + trace[ui])
        close = (d < cfg.merge_radius) & (np.maximum(d, 0.0) ** 2 < bound)
        ti, ui = ti[close], ui[close]
        if cfg.descriptor_size > 0 and len(ti):   # unit descriptors: |a − b|² = 2 − 2 a·b
            if self._bands is None:
                dot = np.einsum("ij,ij->i", self._descriptors[uniq[t[ti]]], self._descriptors[uniq[ui]])
                alike = 2.0 - 2.0 * dot < cfg.merge_descriptor_threshold ** 2
            else:   # the two descriptors made at the most similar ranges
                alike = self._bands.pair_distance2(uniq[t[ti]], uniq[ui]) < cfg.merge_descriptor_threshold ** 2
            ti, ui = ti[alike], ui[alike]
        a, b = uniq[t[ti]], uniq[ui]
        keep = a != b
        if not keep.any():
            return none
        return np.minimum(a, b)[keep], np.maximum(a, b)[keep]                    # a older, b newer

    def _best_particle_view(self, best: int, matched: Pairs, missed: Pairs, missed_ranges: np.ndarray,
                            had_candidate: np.ndarray, new_ids: np.ndarray, poses: np.ndarray, z: np.ndarray,
                            q6: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """What particle ``best`` saw this frame, copied before merges move blocks: the ids (D,) and states
        (D, 9) of the landmarks it detected (matched or made now), and of those it missed well in view (K,),
        (K, 9), with their ranges (K,)."""
        store = self.store
        det = matched.g[matched.m == best]
        n_obs = len(z)
        j = np.flatnonzero(~had_candidate[best * n_obs:(best + 1) * n_obs])
        j = j[new_ids[j] >= 0]
        x, y, theta = poses[best]
        c, s = np.full(len(j), np.cos(theta)), np.full(len(j), np.sin(theta))
        zx, zy, zz = take_rows(z, j).T
        made = np.vstack([c * zx - s * zy + x, s * zx + c * zy + y, zz, sym_rotate_z(c, s, take_cols(q6, j))]).T
        in_best = missed.m == best
        miss = missed.g[in_best]
        alive = store.flat_lid[miss] >= 0
        miss = miss[alive]
        return (np.concatenate([store.flat_lid[det], new_ids[j]]),
                np.concatenate([take_rows(store.flat_state, det), made.reshape(-1, 9)]),
                store.flat_lid[miss].copy(), take_rows(store.flat_state, miss), missed_ranges[in_best][alive])

    def _count_covisibility(self, det_lids: np.ndarray, det_state: np.ndarray, miss_lids: np.ndarray,
                            miss_state: np.ndarray, miss_ranges: np.ndarray) -> None:
        """Co-visibility evidence of one frame of the most probable particle (see :meth:`_merge_duplicates` and
        ``existence.exclusive_log_odds``), over the pairs (detected, detected or missed in view) that could be
        one point, d² < ``merge_gate`` under Σ_a + Σ_b + C_a + C_b: a pair both detected is two points for good;
        a pair with one missed gains the frame's log-likelihood ratio for "one point", and is ready to merge
        once its sum reaches ``merge_log_odds``."""
        n_det = len(det_lids)
        if n_det == 0:
            return
        cfg = self.config
        lids = np.concatenate([det_lids, miss_lids])
        state = np.concatenate([det_state, miss_state])
        cov = state[:, 3:].T + sym_components(self.drift.landmark_covariances(lids))          # (6, V)
        trace = cov[0] + cov[3] + cov[5]
        dist2 = np.sum((det_state[:, None, :3] - state[None, :, :3]) ** 2, axis=2)             # (D, V)
        di, vi = np.nonzero((dist2 < cfg.merge_gate * (trace[:n_det, None] + trace[None, :]))
                            & (det_lids[:, None] != lids[None, :]))                       # d² ≥ |Δ|²/tr S
        if len(di) == 0:
            return
        adj, det = sym_adjugate(take_cols(cov, di) + take_cols(cov, vi))
        d2 = sym_quadratic(adj, (state[di, :3] - state[vi, :3]).T) / det
        near = d2 < cfg.merge_gate
        di, vi = di[near], vi[near]
        a, b = np.minimum(det_lids[di], lids[vi]), np.maximum(det_lids[di], lids[vi])
        key = (a << PAIR_SHIFT) | b
        both = vi < n_det
        if both.any():
            co = set(np.unique(key[both]).tolist())
            self._codetected |= co
            self._merge_ready -= co
        keys, at = np.unique(key[~both], return_inverse=True)
        if len(keys) == 0:
            return
        gain = np.bincount(at, exclusive_log_odds(cfg, miss_ranges[vi[~both] - n_det]), minlength=len(keys))
        evidence, ready, codetected = self._pair_evidence, self._merge_ready, self._codetected
        for k, g in zip(keys.tolist(), gain.tolist(), strict=True):
            if k in codetected:
                continue
            total = evidence.get(k, 0.0) + g
            evidence[k] = total
            if total >= cfg.merge_log_odds:
                ready.add(k)

    def _prune_pairs(self) -> None:
        """Forget the co-visibility of pairs with an id no particle holds any more (memory follows the map)."""
        if not (self._pair_evidence or self._codetected):
            return
        store = self.store
        alive = np.zeros(self._n_ids, bool)
        held = store.lid[store.refcount > 0]
        alive[held[held >= 0]] = True
        mask = (1 << PAIR_SHIFT) - 1

        def live(keys) -> set[int]:
            k = np.fromiter(keys, np.int64, len(keys))
            return set(k[alive[k >> PAIR_SHIFT] & alive[k & mask]].tolist())

        kept = live(self._pair_evidence)
        self._pair_evidence = {k: v for k, v in self._pair_evidence.items() if k in kept}
        self._codetected = live(self._codetected)
        self._merge_ready &= kept
