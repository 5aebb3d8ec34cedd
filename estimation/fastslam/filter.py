"""FastSLAM over 3-D point landmarks, vectorised over particles and observations.

Each particle is a planar pose (x, y, θ) and a map of 3-D point landmarks, each an EKF (mean, 3×3 covariance)
with a descriptor and counters. Maps live in a :class:`~estimation.fastslam.store.LandmarkStore` shared by all
particles (copy-on-write blocks), so resampling copies integers, not maps.

Observation model (stereo point in base_link, REP-103): with R = R_z(θ) and t = (x, y, 0),

    z = Rᵀ (m − t) + v,   v ~ N(0, Q)              (Q from the front end's triangulation, plus a floor)
    H_m = ∂z/∂m = Rᵀ,     H_x = ∂z/∂(x, y, θ) = [−Rᵀe_x, −Rᵀe_y, (ẑ_y, −ẑ_x, 0)]

One update (:meth:`FastSLAM.update`) reads as numbered steps:

0. With ``max_observations`` > 0, keep only that many observations, the most precise (smallest covariance trace).
1. Preselect, per particle, the landmark blocks whose bounding box meets the sensor's footprint (no scan of
   the whole map), then join observations to those landmarks by descriptor distance < ``descriptor_threshold``
   and an exact spatial bound decided once per landmark id.
2. Gate every (particle, observation, landmark) triple by the squared Mahalanobis distance of the innovation.
3. Mutual exclusion: each observation takes its nearest gated landmark; a landmark claimed by several
   observations keeps only the nearest; the losers are ambiguous (neither matched nor new).
4. FastSLAM 2.0 only: sample the pose from the Gaussian proposal that includes the matched observations.
5. EKF update of the matched landmarks (Joseph form), copy-on-write of the blocks written.
6. Negative evidence: provisional landmarks (seen < ``confirm_count`` times) predicted well inside the view and
   not matched count a miss; ``max_misses`` misses delete them.
7. New landmarks from observations with no gated candidate.
8. Weights, effective sample size, low-variance resampling when ESS < ``resample_threshold`` · M.

Importance weights. The textbook weight is the Gaussian likelihood N(z; ẑ, S) of every matched observation
and a constant p₀ for a new landmark. We use the robust form log w += −½ min(d², gate) per observation (an
unmatched or new observation costs the gate): it drops the log-det normalisers, which barely differ between
particles observing the same landmark but make p₀ scale-dependent, and it keeps one bad match from wiping out
a particle. FastSLAM 2.0 uses d² under S + H_x P H_xᵀ at the predicted pose (Montemerlo et al. 2003, eq. 27).

Descriptor threshold: the fusion paper's th₀ = 2 cannot be a Euclidean distance between *unit* U-SURF
descriptors (their distance is at most 2, so it would accept everything); it is presumably on unnormalised
descriptors. We gate unit descriptors at 0.5 by default (``FastSLAMConfig.descriptor_threshold``).
Descriptors are kept as first seen (the landmark's id indexes a shared, append-only descriptor table), so
copy-on-write never copies them; ``refresh_descriptors`` (off by default: on rendered frames it let landmarks
slide along textures) overwrites an id's descriptor with its latest match in the most probable particle.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..geometry import compose, rot_z, wrap_angle
from ..landmark_map import LandmarkMap
from ..observations import OdometryIncrement, StereoObservations
from .config import FastSLAMConfig
from .linalg import group_sum, inv3, matvec, quadratic_form, sandwich, symmetrise, transpose
from .motion import increment_variance, propagate_covariance, sample_motion
from .resampling import effective_sample_size, low_variance_resample, normalise_log_weights
from .store import LandmarkStore

_EYE3 = np.eye(3)
PRUNE_HISTORY_EVERY = 200  # updates between prunings of the trajectory history to the live ancestry


@dataclass(frozen=True)
class UpdateReport:
    """What one :meth:`FastSLAM.update` did.

    matched, new_landmarks, dropped: means over particles; ess: effective sample size before resampling;
    new_landmark_ids (N,): the landmark id observation j created (in any particle), -1 if none;
    best_matches (N,): the landmark id observation j matched in the most probable particle, -1 if none;
    pose_mean (3,), pose_covariance (3, 3): the weighted particle cloud before resampling.
    """

    n_observations: int
    matched: float
    new_landmarks: float
    dropped: float
    ess: float
    resampled: bool
    new_landmark_ids: np.ndarray
    best_matches: np.ndarray
    pose_mean: np.ndarray
    pose_covariance: np.ndarray


@dataclass
class _Pairs:
    """(particle, observation, candidate) triples, all arrays of one length P."""

    m: np.ndarray     # particle index
    j: np.ndarray     # observation index
    k: np.ndarray     # table position of the landmark's block in the particle's block table
    g: np.ndarray     # flat slot of the landmark (block * block_size + slot)

    def take(self, index) -> _Pairs:
        return _Pairs(self.m[index], self.j[index], self.k[index], self.g[index])


class FastSLAM:
    """Rao-Blackwellised particle filter SLAM (FastSLAM 1.0 / 2.0, unknown data association).

    ``FastSLAM(config, rng, initial_pose=(0, 0, 0))`` then, per odometry increment, :meth:`predict` and, per
    stereo frame, :meth:`update`. The map frame is the robot's start frame (``initial_pose`` in it).
    """

    def __init__(self, config: FastSLAMConfig, rng: np.random.Generator,
                 initial_pose=(0.0, 0.0, 0.0)) -> None:
        self.config = config
        self.rng = rng
        m = config.n_particles
        self.poses = np.tile(np.asarray(initial_pose, dtype=float), (m, 1))   # (M, 3)
        self.log_weights = np.zeros(m)                                        # (M,)
        self.store = LandmarkStore(m, config.block_size)
        self._descriptors = np.zeros((256, config.descriptor_size), np.float32)  # (ids, D) by landmark id
        self._n_ids = 0
        self._motion_cov = np.zeros((m, 3, 3))   # FastSLAM 2.0: covariance of the motion not yet sampled
        self._best = 0
        self._time = 0.0
        # ancestry, one entry per update: (t, poses (K, 3), parents (K,)) where parents index the previous
        # entry's rows; the newest entry holds all M particles, older ones only the live particles' ancestors
        self._history: list[tuple[float, np.ndarray, np.ndarray]] = [(0.0, self.poses.copy(), np.arange(m))]
        self._pruned_at = 0

    # == 0. motion ==========================================================================================
    def predict(self, increment: OdometryIncrement) -> None:
        """Move every particle by the odometry increment (robot frame at its start), with motion noise."""
        delta = increment.delta
        if not np.all(np.isfinite(delta)):
            raise ValueError(f"odometry increment {delta.tolist()} is not finite; the filter is unchanged")
        variance = increment_variance(delta, self.config)
        if self.config.version == 1:
            self.poses = sample_motion(self.poses, delta, variance, self.rng)
        else:  # keep the noise-free prediction and its covariance; the proposal samples in update()
            self._motion_cov = propagate_covariance(self.poses, self._motion_cov, delta, variance)
            self.poses = compose(self.poses, delta)
        self._time = max(self._time, float(increment.t1))

    # == update ==============================================================================================
    def update(self, observations: StereoObservations) -> UpdateReport:
        """Incorporate one frame of 3-D point observations in base_link (see the module docstring).

        With ``max_observations`` > 0, only that many observations are used: the most precise (smallest
        covariance trace, i.e. the nearest); the report's per-observation arrays still have one entry per
        given observation (-1 for those left out).
        """
        cap, n_given = self.config.max_observations, len(observations)
        if cap <= 0 or n_given <= cap:
            return self._update(observations)
        trace = np.trace(np.asarray(observations.covariances, float), axis1=1, axis2=2)
        keep = np.sort(np.argsort(trace, kind="stable")[:cap])
        pixels = observations.pixels[keep] if len(observations.pixels) else observations.pixels
        report = self._update(StereoObservations(
            observations.points[keep], observations.covariances[keep], observations.descriptors[keep], pixels,
            observations.timestamp, observations.frame))
        new_ids, best = np.full(n_given, -1, np.int64), np.full(n_given, -1, np.int64)
        new_ids[keep], best[keep] = report.new_landmark_ids, report.best_matches
        return replace(report, new_landmark_ids=new_ids, best_matches=best)

    def _update(self, observations: StereoObservations) -> UpdateReport:
        cfg = self.config
        n_particles, n_obs = len(self.poses), len(observations)
        z, q, desc = self._checked(observations)
        self._time = max(self._time, float(observations.timestamp))
        predicted = self.poses

        # 1-2. candidates, descriptor join, Mahalanobis gate
        cand = self._candidates(predicted)
        pairs = self._pregate(self._descriptor_join(cand, desc, predicted, z, q), predicted, z, q)
        rot = rot_z(predicted[pairs.m, 2])                                        # (P, 3, 3)
        z_hat, s_mat = self._predict_observation(pairs, predicted, rot, q)
        innovation = z[pairs.j] - z_hat
        s_gate = s_mat
        if cfg.version == 2:  # the pose is not sampled yet: its uncertainty widens the gate
            h_x = _pose_jacobian(rot, z_hat)
            s_gate = s_mat + sandwich(h_x, self._motion_cov[pairs.m])
        d2 = quadratic_form(innovation, inv3(s_gate))
        gated = d2 < cfg.mahalanobis_gate

        # 3. mutual exclusion
        win, had_candidate = self._exclusive_matches(pairs, d2, gated, n_obs)
        matched = pairs.take(win)
        log_lik = -0.5 * cfg.mahalanobis_gate * n_obs - 0.5 * np.bincount(
            matched.m, d2[win] - cfg.mahalanobis_gate, minlength=n_particles)
        s_inv = inv3(s_mat[win])

        # 4. pose: FastSLAM 2.0 samples from the observation proposal; 1.0 already sampled in predict()
        if cfg.version == 2:
            self.poses = self._sample_proposal(predicted, matched, h_x[win], s_inv, innovation[win])
            self._motion_cov = np.zeros_like(self._motion_cov)
        poses = self.poses

        # 5-6. writes: EKF updates of matched landmarks and misses of provisional ones (copy-on-write first)
        missed = self._missed_provisional(cand, poses, matched)
        self.store.make_writable(np.concatenate([matched.m, missed.m]), np.concatenate([matched.k, missed.k]))
        matched.g = self._remap(matched)
        missed.g = self._remap(missed)
        self._ekf_update(matched, poses, z, q, s_inv)
        dropped = self._count_miss(missed)

        self.store.include_in_bbox(matched.g)

        # 7. new landmarks from observations no landmark was a candidate for
        new_ids, n_new = self._add_landmarks(had_candidate, poses, z, q, desc)

        # 8. weights and resampling
        best_matches = np.full(n_obs, -1, np.int64)
        self.log_weights = self.log_weights + log_lik
        self.log_weights -= self.log_weights.max()
        weights = normalise_log_weights(self.log_weights)
        ess = effective_sample_size(weights)
        best = int(np.argmax(weights))
        in_best = matched.m == best
        best_matches[matched.j[in_best]] = self.store.flat_lid[matched.g[in_best]]
        if cfg.refresh_descriptors and cfg.descriptor_size > 0:
            # appearance drifts with distance (fixed-scale U-SURF): gate the next frame on the latest look
            self._descriptors[best_matches[matched.j[in_best]]] = desc[matched.j[in_best]]
        pose_mean, pose_cov = _weighted_pose_stats(self.poses, weights)
        parents = np.arange(n_particles)
        resampled = ess < cfg.resample_threshold * n_particles
        if resampled:
            parents = low_variance_resample(weights, self.rng)
            self.poses = self.poses[parents]
            self.store.resample(parents)
            self.log_weights = np.zeros(n_particles)
            best = int(np.flatnonzero(parents == best)[0])  # the heaviest (w ≥ 1/M) is always copied
        self._best = best
        self._history.append((self._time, self.poses.copy(), parents))
        if len(self._history) - self._pruned_at >= PRUNE_HISTORY_EVERY:
            self._prune_history()
        return UpdateReport(
            n_obs, len(win) / n_particles, n_new / n_particles,
            dropped / n_particles, ess, bool(resampled), new_ids, best_matches, pose_mean, pose_cov)

    # -- step helpers ----------------------------------------------------------------------------------------
    def _checked(self, observations: StereoObservations):
        cfg = self.config
        z = np.asarray(observations.points, float)
        q = symmetrise(np.asarray(observations.covariances, float)) + cfg.observation_var_floor * _EYE3
        desc = np.asarray(observations.descriptors, np.float32)
        if desc.ndim != 2:
            desc = desc.reshape(len(z), -1) if len(z) else np.zeros((0, cfg.descriptor_size), np.float32)
        if desc.shape[1] != cfg.descriptor_size:
            raise ValueError(f"observations carry {desc.shape[1]}-element descriptors; the filter was "
                             f"configured for descriptor_size={cfg.descriptor_size}")
        if observations.frame != "base_link":
            raise ValueError(f"observations are in frame {observations.frame!r}; FastSLAM needs 'base_link'")
        if not (np.all(np.isfinite(z)) and np.all(np.isfinite(q)) and np.all(np.isfinite(desc))):
            raise ValueError("observations hold non-finite points, covariances or descriptors")
        try:
            np.linalg.cholesky(q)
        except np.linalg.LinAlgError:
            raise ValueError("an observation covariance is not positive definite") from None
        return z, q, desc

    def _footprint(self, poses: np.ndarray) -> tuple[np.ndarray, float]:
        """Centres (M, 2) and radius of a circle around each particle's field of view (+ 1 m margin)."""
        cfg = self.config
        half = 0.5 * cfg.fov_horizontal
        ox, oy, _ = cfg.sensor_offset
        c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
        ahead = 0.0
        radius = cfg.max_range
        if half < np.pi / 3:  # the circle through the apex and the arc's ends is smaller than the apex circle
            ahead = cfg.max_range / (2.0 * np.cos(half))
            radius = ahead
        fx, fy = ox + ahead, oy
        centres = np.stack([poses[:, 0] + c * fx - s * fy, poses[:, 1] + s * fx + c * fy], axis=1)
        return centres, radius + 1.0

    def _candidates(self, poses: np.ndarray) -> _Pairs:
        """Every live landmark in a block near each particle's view: pairs with j = -1 (M·K·B at most)."""
        store = self.store
        centres, radius = self._footprint(poses)
        p, k = store.blocks_near(centres, radius)
        b = store.block_size
        g = (store.table[p, k][:, None] * b + np.arange(b)).ravel()
        p = np.repeat(p, b)
        k = np.repeat(k, b)
        alive = store.flat_lid[g] >= 0
        return _Pairs(p[alive], np.full(int(alive.sum()), -1, np.int64), k[alive], g[alive])

    def _descriptor_join(self, cand: _Pairs, desc: np.ndarray, poses: np.ndarray, z: np.ndarray,
                         q: np.ndarray) -> _Pairs:
        """(particle, observation, landmark) triples whose descriptors are closer than the threshold.

        Distances are computed once per distinct landmark id (particles share ids), not per particle; then
        (observation, id) pairs that no particle's :meth:`_pregate` could keep are dropped, also once per id
        (:meth:`_id_pregate`; poses (M, 3), z (N, 3), q (N, 3, 3)), before they are expanded to particles.
        """
        n_obs = len(desc)
        if len(cand.m) == 0 or n_obs == 0:
            return _Pairs(*(np.zeros(0, np.int64) for _ in range(4)))
        lids = self.store.flat_lid[cand.g]
        present = np.zeros(self._n_ids, bool)          # ids are dense: a lookup table beats np.unique
        present[lids] = True
        uniq = np.flatnonzero(present)
        if self.config.descriptor_size > 0:
            known = self._descriptors[uniq]
            d2 = (np.sum(desc * desc, 1)[:, None] + np.sum(known * known, 1)[None, :] - 2.0 * desc @ known.T)
            obs_j, uid = np.nonzero(d2 < self.config.descriptor_threshold ** 2)
        else:
            obs_j, uid = np.divmod(np.arange(n_obs * len(uniq)), len(uniq))
        rank = np.full(self._n_ids, -1, np.int64)
        rank[uniq] = np.arange(len(uniq))
        if len(obs_j):
            inverse = rank[lids]
            order = np.argsort(inverse, kind="stable")
            keep_pair = self._id_pregate(cand.g[order], inverse[order], len(uniq), obs_j, uid, poses, z, q)
            obs_j, uid = obs_j[keep_pair], uid[keep_pair]
        # keep only candidates whose landmark matched some observation's descriptor, then group them by id
        wanted = np.zeros(len(uniq), bool)
        wanted[uid] = True
        inverse = rank[lids]
        keep = np.flatnonzero(wanted[inverse])
        cand = cand.take(keep)
        inverse = inverse[keep]
        order = np.argsort(inverse, kind="stable")
        counts = np.bincount(inverse, minlength=len(uniq))
        starts = np.cumsum(counts) - counts
        reps = counts[uid]
        first = np.repeat(starts[uid], reps)
        within = np.arange(int(reps.sum())) - np.repeat(np.cumsum(reps) - reps, reps)
        c = order[first + within]
        return _Pairs(cand.m[c], np.repeat(obs_j, reps), cand.k[c], cand.g[c])

    def _id_pregate(self, g: np.ndarray, inverse: np.ndarray, n_uniq: int, obs_j: np.ndarray, uid: np.ndarray,
                    poses: np.ndarray, z: np.ndarray, q: np.ndarray) -> np.ndarray:
        """(L,) bool over (observation, id) pairs: False where :meth:`_pregate` would drop the pair in every
        particle, decided once per id (exact bound, so the association is unchanged, only faster).

        With a reference pose (mean position, θ of particle 0) and a reference mean μ̄ per id, for particle m:
        |ν_m| ≥ |w̄(z) − μ̄| − D − Δθ|z_xy| − E, where D, Δθ bound the particles' distance from the reference
        pose, E bounds |μ_m − μ̄| over the particles holding the id, w̄(z) = R̄z + t̄; and tr S_m ≤ T + tr Q
        (+ (2 + r_max²)·max tr P under 2.0), T = max tr Σ of the id. The pair goes when the bound fails the gate.
        g (C,): flat slots of the candidate landmarks sorted by their id's rank ``inverse`` (C,) in 0..n_uniq-1,
        every rank present.
        """
        store = self.store
        mean = store.flat_mean[g]
        starts = np.flatnonzero(np.r_[True, inverse[1:] != inverse[:-1]])
        ref_mean = mean[starts]                                            # the first particle's mean per id
        spread = np.maximum.reduceat(np.sum((mean - ref_mean[inverse]) ** 2, axis=1), starts) ** 0.5
        cov = store.flat_cov.reshape(-1, 9)
        cov_trace = np.maximum.reduceat(cov[g, 0] + cov[g, 4] + cov[g, 8], starts)
        ref_xy = poses[:, :2].mean(axis=0)
        ref_theta = poses[0, 2]
        d_pose = float(np.max(np.linalg.norm(poses[:, :2] - ref_xy, axis=1)))
        d_theta = float(np.max(np.abs(wrap_angle(poses[:, 2] - ref_theta))))
        c, s = np.cos(ref_theta), np.sin(ref_theta)
        zj = z[obs_j]
        world = np.stack([ref_xy[0] + c * zj[:, 0] - s * zj[:, 1], ref_xy[1] + s * zj[:, 0] + c * zj[:, 1],
                          zj[:, 2]], axis=1)
        lower = (np.linalg.norm(world - ref_mean[uid], axis=1) - d_pose - d_theta * np.hypot(zj[:, 0], zj[:, 1])
                 - spread[uid])
        trace = cov_trace[uid] + np.trace(q, axis1=1, axis2=2)[obs_j]
        if self.config.version == 2:
            r_max = np.linalg.norm(ref_mean[uid, :2] - ref_xy, axis=1) + spread[uid] + d_pose
            trace = trace + (2.0 + r_max ** 2) * float(np.max(np.trace(self._motion_cov, axis1=1, axis2=2)))
        return (lower <= 0) | (lower ** 2 <= self.config.mahalanobis_gate * trace * (1 + 1e-6))

    def _pregate(self, pairs: _Pairs, poses: np.ndarray, z: np.ndarray, q: np.ndarray) -> _Pairs:
        """Drop pairs that cannot pass the Mahalanobis gate, using only vector norms (exact, conservative).

        d² = νᵀS⁻¹ν ≥ |ν|²/λ_max(S) ≥ |ν|²/tr S, and tr S = tr Σ + tr Q (+ tr H_x P H_xᵀ ≤ (2 + r²) tr P under
        2.0, r the landmark's planar distance), all rotation-invariant; |ν| is measured in the world. Cheap
        where descriptors do not thin the candidates (range-bearing data has none).
        """
        if len(pairs.m) == 0:
            return pairs
        store = self.store
        c, s = np.cos(poses[pairs.m, 2]), np.sin(poses[pairs.m, 2])
        zj = z[pairs.j]
        world = np.stack([poses[pairs.m, 0] + c * zj[:, 0] - s * zj[:, 1],
                          poses[pairs.m, 1] + s * zj[:, 0] + c * zj[:, 1], zj[:, 2]], axis=1)
        mean = store.flat_mean[pairs.g]
        nu2 = np.sum((world - mean) ** 2, axis=1)
        trace = np.trace(store.flat_cov[pairs.g], axis1=1, axis2=2) + np.trace(q[pairs.j], axis1=1, axis2=2)
        if self.config.version == 2:
            r2 = np.sum((mean[:, :2] - poses[pairs.m, :2]) ** 2, axis=1)
            trace = trace + (2.0 + r2) * np.trace(self._motion_cov[pairs.m], axis1=1, axis2=2)
        return pairs.take(np.flatnonzero(nu2 <= self.config.mahalanobis_gate * trace * (1 + 1e-9)))

    def _predict_observation(self, pairs: _Pairs, poses: np.ndarray, rot: np.ndarray, q: np.ndarray):
        """ẑ = Rᵀ(μ − t) (P, 3) and S = Rᵀ Σ R + Q (P, 3, 3) for each pair."""
        store = self.store
        z_hat = _to_robot_frame(poses[pairs.m], rot, store.flat_mean[pairs.g])
        s_mat = sandwich(transpose(rot), store.flat_cov[pairs.g]) + q[pairs.j]
        return z_hat, s_mat

    @staticmethod
    def _exclusive_matches(pairs: _Pairs, d2: np.ndarray, gated: np.ndarray, n_obs: int):
        """Indices of winning pairs (one landmark per observation and vice versa, nearest first) and a
        (M·N,) bool over (particle, observation) telling which had any gated candidate."""
        idx = np.flatnonzero(gated)
        # one sort each: integer key + d² scaled into [0, 1) as the fraction (exact for keys < 2³⁰)
        tie = np.clip(d2 / gate_limit(d2), 0.0, 0.999)
        key_obs = pairs.m[idx] * max(n_obs, 1) + pairs.j[idx]
        order = np.argsort(key_obs + tie[idx])
        idx, key_obs = idx[order], key_obs[order]
        best = idx[np.r_[True, key_obs[1:] != key_obs[:-1]]] if len(idx) else idx
        key_lm = pairs.m[best] * (int(pairs.g.max(initial=0)) + 1) + pairs.g[best]
        order = np.argsort(key_lm + tie[best])
        best, key_lm = best[order], key_lm[order]
        win = best[np.r_[True, key_lm[1:] != key_lm[:-1]]] if len(best) else best
        return np.sort(win), np.unique(key_obs)

    def _sample_proposal(self, predicted, matched: _Pairs, h_x, s_inv, innovation) -> np.ndarray:
        """FastSLAM 2.0: x ~ N(μ, Σ), Σ = (P⁻¹ + Σ H_xᵀ S⁻¹ H_x)⁻¹, μ = x̂ + Σ Σ H_xᵀ S⁻¹ (z − ẑ).

        predicted (M, 3); h_x, s_inv (P, 3, 3) and innovation (P, 3) of the matched pairs -> poses (M, 3).
        """
        n = len(predicted)
        p_motion = self._motion_cov + 1e-12 * _EYE3
        ht_sinv = transpose(h_x) @ s_inv
        info = inv3(p_motion) + group_sum(matched.m, ht_sinv @ h_x, n)
        vec = group_sum(matched.m, matvec(ht_sinv, innovation), n)
        cov = symmetrise(inv3(info))
        mean = predicted + matvec(cov, vec)
        chol = np.linalg.cholesky(cov + 1e-15 * _EYE3)
        sample = mean + matvec(chol, self.rng.standard_normal(predicted.shape))
        sample[:, 2] = wrap_angle(sample[:, 2])
        return sample

    def _remap(self, pairs: _Pairs) -> np.ndarray:
        """Flat slots of pairs after copy-on-write moved their blocks."""
        b = self.store.block_size
        return self.store.table[pairs.m, pairs.k] * b + pairs.g % b

    def _ekf_update(self, matched: _Pairs, poses: np.ndarray, z: np.ndarray, q: np.ndarray,
                    s_inv: np.ndarray) -> None:
        """Per matched pair: K = Σ Hᵀ S⁻¹ (H = Rᵀ), μ += K (z − ẑ), Σ = (I − KH) Σ (I − KH)ᵀ + K Q Kᵀ.

        ``s_inv`` (P, 3, 3) is S⁻¹ from the gate, linearised at the predicted pose; under FastSLAM 2.0 the
        sampled pose differs slightly, which makes K slightly sub-optimal but the Joseph form keeps Σ the
        correct covariance for that K (and saves recomputing S and its inverse).
        """
        if len(matched.m) == 0:
            return
        store = self.store
        rot = rot_z(poses[matched.m, 2])
        z_hat = _to_robot_frame(poses[matched.m], rot, store.flat_mean[matched.g])
        sigma = store.flat_cov[matched.g]
        gain = sigma @ rot @ s_inv                                                 # K = Σ R S⁻¹
        store.flat_mean[matched.g] += matvec(gain, z[matched.j] - z_hat)
        i_kh = _EYE3 - gain @ transpose(rot)                                        # I − K Rᵀ
        joseph = sandwich(i_kh, sigma) + sandwich(gain, q[matched.j])
        store.flat_cov[matched.g] = symmetrise(joseph)
        store.flat_count[matched.g] += 1
        store.flat_misses[matched.g] = 0

    def _missed_provisional(self, cand: _Pairs, poses: np.ndarray, matched: _Pairs) -> _Pairs:
        """Candidate landmarks still provisional, predicted well inside the view, and not matched."""
        cfg = self.config
        store = self.store
        provisional = store.flat_count[cand.g] < cfg.confirm_count
        sel = cand.take(np.flatnonzero(provisional))
        if len(sel.m) == 0:
            return sel
        key_all = sel.m * (int(store.flat_lid.size) + 1) + sel.g
        key_matched = matched.m * (int(store.flat_lid.size) + 1) + matched.g
        sel = sel.take(np.flatnonzero(~np.isin(key_all, key_matched)))
        z_hat = _to_robot_frame(poses[sel.m], rot_z(poses[sel.m, 2]), store.flat_mean[sel.g])
        return sel.take(np.flatnonzero(self._well_in_view(z_hat)))

    def _well_in_view(self, z_hat: np.ndarray) -> np.ndarray:
        """(P,) bool: base_link points (P, 3) inside ``miss_fov_margin`` of the field of view and range."""
        cfg = self.config
        rel = z_hat - np.asarray(cfg.sensor_offset)
        margin = cfg.miss_fov_margin
        depth = rel[:, 0]
        ok = (depth > cfg.min_range) & (np.linalg.norm(rel, axis=1) < margin * cfg.max_range)
        if cfg.fov_horizontal < 2 * np.pi:
            ok &= depth > 0
            ok &= np.abs(np.arctan2(rel[:, 1], depth)) < margin * 0.5 * cfg.fov_horizontal
        if cfg.fov_vertical < np.pi:
            ok &= np.abs(np.arctan2(rel[:, 2], np.maximum(depth, 1e-9))) < margin * 0.5 * cfg.fov_vertical
        return ok

    def _count_miss(self, missed: _Pairs) -> int:
        """misses += 1 for missed provisional landmarks; drop those reaching ``max_misses``."""
        if len(missed.g) == 0:
            return 0
        store = self.store
        store.flat_misses[missed.g] += 1
        drop = missed.g[store.flat_misses[missed.g] >= self.config.max_misses]
        store.flat_lid[drop] = -1
        return len(drop)

    def _add_landmarks(self, had_candidate: np.ndarray, poses: np.ndarray, z, q, desc) -> tuple[np.ndarray, int]:
        """Landmarks (μ = R z + t, Σ = R Q Rᵀ) for every (particle, observation) with no gated candidate.

        Returns the id each observation's new landmarks got (N,) (-1: none) and how many were made in all.
        """
        n_particles, n_obs = len(poses), len(z)
        new_ids = np.full(n_obs, -1, np.int64)
        is_new = np.ones(n_particles * n_obs, bool)
        is_new[had_candidate] = False
        m, j = np.divmod(np.flatnonzero(is_new), max(n_obs, 1))
        if len(m) == 0:
            return new_ids, 0
        spawning = np.unique(j)
        new_ids[spawning] = self._n_ids + np.arange(len(spawning))
        self._append_descriptors(desc[spawning])
        g = self.store.append_slots(m)
        store = self.store
        rot = rot_z(poses[m, 2])
        store.flat_mean[g] = matvec(rot, z[j]) + _lifted_translation(poses[m])
        store.flat_cov[g] = symmetrise(sandwich(rot, q[j]))
        store.flat_lid[g] = new_ids[j]
        store.flat_count[g] = 1
        store.flat_misses[g] = 0
        store.include_in_bbox(g)
        return new_ids, len(m)

    def _append_descriptors(self, desc: np.ndarray) -> None:
        need = self._n_ids + len(desc)
        if need > len(self._descriptors):
            grown = np.zeros((max(need, 2 * len(self._descriptors)), self._descriptors.shape[1]), np.float32)
            grown[: self._n_ids] = self._descriptors[: self._n_ids]
            self._descriptors = grown
        self._descriptors[self._n_ids:need] = desc
        self._n_ids = need

    # == prior map ===========================================================================================
    def load_prior_map(self, landmark_map: LandmarkMap, cell_size: float = 4.0) -> np.ndarray:
        """Give every particle the same starting map (a previous session's, or a known one), stored once.

        The landmarks (in this filter's start frame) are laid out in blocks cell by cell of a ``cell_size``
        grid, so each block is spatially compact and association touches only the blocks in view. Must be
        called before the first update. Returns the ids (N,) the filter gave the map's landmarks, in order.
        """
        if self._n_ids or int(self.store.n_blocks.max(initial=0)):
            raise ValueError("load_prior_map must be called before the filter holds landmarks")
        if landmark_map.descriptor_size != self.config.descriptor_size and len(landmark_map):
            raise ValueError(f"the map's descriptors have {landmark_map.descriptor_size} elements; the filter "
                             f"was configured for descriptor_size={self.config.descriptor_size}")
        n = len(landmark_map)
        cells = np.floor(landmark_map.positions[:, :2] / cell_size).astype(np.int64)
        order = np.lexsort((cells[:, 1], cells[:, 0]))
        ids = np.arange(n, dtype=np.int64)
        self._append_descriptors(landmark_map.descriptors.astype(np.float32))
        store = self.store
        g = store.append_slots(np.zeros(n, np.int64))
        store.flat_mean[g] = landmark_map.positions[order]
        store.flat_cov[g] = landmark_map.covariances[order]
        store.flat_lid[g] = ids[order]
        store.flat_count[g] = landmark_map.counts[order]
        store.flat_misses[g] = 0
        store.refresh_bbox(g // store.block_size)
        store.resample(np.zeros(len(self.poses), np.intp))   # every particle shares particle 0's blocks
        return ids

    # == outputs =============================================================================================
    @property
    def weights(self) -> np.ndarray:
        """Normalised particle weights (M,)."""
        return normalise_log_weights(self.log_weights)

    @property
    def effective_sample_size(self) -> float:
        return effective_sample_size(self.weights)

    @property
    def best_index(self) -> int:
        """Index of the most probable particle (highest weight at the last update, followed through resampling)."""
        return self._best

    def best_pose(self) -> np.ndarray:
        """(3,) pose of the most probable particle, in the start frame."""
        return self.poses[self._best].copy()

    def pose_mean_and_covariance(self) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean (3,) and covariance (3, 3) of the particle poses (θ averaged on the circle)."""
        return _weighted_pose_stats(self.poses, self.weights)

    def trajectory(self, particle: int | None = None) -> np.ndarray:
        """(T, 4) rows (t, x, y, θ) of a particle's ancestry, one row per update (best particle by default)."""
        index = self._best if particle is None else int(particle)
        rows = []
        for t, poses, parents in reversed(self._history):
            rows.append((t, *poses[index]))
            index = parents[index]
        return np.array(rows[::-1], dtype=float).reshape(-1, 4)

    def _prune_history(self) -> None:
        """Keep only the ancestors of the live particles in the history (the lineages coalesce, so old
        entries shrink to a pose or two): memory grows with the run's length, not with length × M."""
        need = np.arange(len(self._history[-1][1]))
        for i in range(len(self._history) - 1, -1, -1):
            t, poses, parents = self._history[i]
            previous = np.unique(parents[need])
            self._history[i] = (t, poses[need], np.searchsorted(previous, parents[need]))
            need = previous
        self._pruned_at = len(self._history)

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
                     metadata: dict | None = None) -> LandmarkMap:
        """Landmarks of one particle seen at least ``min_count`` times, as a :class:`LandmarkMap`."""
        store = self.store
        g = store.particle_slots(int(particle))
        g = g[store.flat_count[g] >= min_count]
        lids = store.flat_lid[g]
        order = np.argsort(lids)
        g, lids = g[order], lids[order]
        return LandmarkMap(
            store.flat_mean[g].copy(), store.flat_cov[g].copy(), self._descriptors[lids].copy(), lids,
            store.flat_count[g].copy(), robot=robot, frame=frame, trajectory=self.trajectory(particle),
            metadata=dict(metadata or {}))

    def best_map(self, robot: str = "robot", metadata: dict | None = None, min_count: int | None = None,
                 frame: str = "start") -> LandmarkMap:
        """The most probable particle's map (landmarks seen ≥ ``min_count``, default ``confirm_count``)."""
        min_count = self.config.confirm_count if min_count is None else min_count
        meta = {"fastslam": self.config.to_dict()}
        meta.update(metadata or {})
        return self.particle_map(self._best, min_count, robot, frame, meta)


def _lifted_translation(poses: np.ndarray) -> np.ndarray:
    """t = (x, y, 0) (P, 3) of planar poses (P, 3)."""
    t = np.zeros((len(poses), 3))
    t[:, :2] = poses[:, :2]
    return t


def _to_robot_frame(poses: np.ndarray, rot: np.ndarray, points: np.ndarray) -> np.ndarray:
    """ẑ = Rᵀ(m − t) (P, 3): world points (P, 3) in the frames of poses (P, 3) with rotations rot (P, 3, 3)."""
    return matvec(transpose(rot), points - _lifted_translation(poses))


def _weighted_pose_stats(poses: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean (3,) and covariance (3, 3) of poses (M, 3) with weights (M,), θ on the circle."""
    theta = np.arctan2(w @ np.sin(poses[:, 2]), w @ np.cos(poses[:, 2]))
    mean = np.array([w @ poses[:, 0], w @ poses[:, 1], theta])
    dev = poses - mean
    dev[:, 2] = wrap_angle(dev[:, 2])
    return mean, (dev * w[:, None]).T @ dev


def gate_limit(d2: np.ndarray) -> float:
    """A bound above every finite d² (for scaling d² into a sort key's fraction)."""
    finite = d2[np.isfinite(d2)]
    return float(finite.max()) * 1.001 + 1e-12 if len(finite) else 1.0


def _pose_jacobian(rot: np.ndarray, z_hat: np.ndarray) -> np.ndarray:
    """H_x (P, 3, 3) = ∂z/∂(x, y, θ) = [−Rᵀe_x, −Rᵀe_y, (ẑ_y, −ẑ_x, 0)] for z = Rᵀ(m − t)."""
    h = np.zeros((len(rot), 3, 3))
    h[:, :, 0] = -rot[:, 0, :]   # −Rᵀ e_x: row 0 of R as a column
    h[:, :, 1] = -rot[:, 1, :]
    h[:, 0, 2] = z_hat[:, 1]
    h[:, 1, 2] = -z_hat[:, 0]
    return h
