"""FastSLAM over 3-D point landmarks, vectorised over particles and observations.

Each particle is a planar pose (x, y, θ) and a map of 3-D point landmarks, each an EKF (mean, 3×3 covariance)
with a descriptor and counters. Maps live in a :class:`~estimation.fastslam.store.LandmarkStore` shared by all
particles (copy-on-write blocks), so resampling copies integers, not maps.

Observation model (stereo point in base_link, REP-103): with R = R_z(θ) and t = (x, y, 0),

    z = Rᵀ (m − t) + v,   v ~ N(0, Q)              (Q from the front end's triangulation, plus a floor)
    H_m = ∂z/∂m = Rᵀ,     H_x = ∂z/∂(x, y, θ) = [−Rᵀe_x, −Rᵀe_y, (ẑ_y, −ẑ_x, 0)]

The arithmetic is done in the world frame, which gives the same numbers with less work: ν_w = R z + t − m,
S_w = Σ + R Q Rᵀ (= R S Rᵀ, so d² is unchanged) and R H_x = [[−1, 0, w_y], [0, −1, −w_x], [0, 0, 0]] with
w = m − t (no rotation per pair). Symmetric 3×3s are six component rows and every product, inverse and
rotation is a closed form on them (``linalg``); gathers use ``np.take``; the landmark store keeps a slot's mean
and covariance in one 9-number record. On bench_pipeline's frames the filter gives the same particles and maps
as the dense robot-frame version it replaced (``benchmarks/profile_fastslam.py --fingerprint``), ~3× faster.

One update (:meth:`FastSLAM.update`) reads as numbered steps:

0. With ``max_observations`` > 0, keep only that many observations (``observation_selection``: the nearest,
   or spread over the image and over depth).
1. Preselect, per particle, the landmark blocks whose bounding box meets the sensor's footprint (no scan of
   the whole map), then join observations to those landmarks by descriptor distance < ``descriptor_threshold``
   and an exact spatial bound decided once per landmark id.
2. Gate every (particle, observation, landmark) triple by the squared Mahalanobis distance of the innovation.
3. Mutual exclusion: each observation takes its nearest gated landmark; a landmark claimed by several
   observations keeps only the nearest; the losers are ambiguous (neither matched nor new).
4. FastSLAM 2.0 only: sample the pose from the Gaussian proposal that includes the matched observations.
5. EKF update of the matched landmarks (Joseph form), copy-on-write of the blocks written.
6. Landmark existence (log-odds): a match adds ``existence_hit``; a landmark predicted well inside the view and
   not matched adds ``existence_miss``; below ``existence_remove`` it is removed. With the sensor's detection
   rates configured, both steps come from them and the range (``existence.py``).
7. New landmarks from observations with no gated candidate ("id" association: with no landmark of that id);
   every ``merge_every`` updates, duplicates among the landmarks touched since are merged (with
   ``merge_covisibility``, also pairs never detected in one frame although one was missed in view while the
   other was detected; pairs detected together never; ``merging.py``).
8. Weights, effective sample size, low-variance resampling when ESS < ``resample_threshold`` · M; the map
   frame's drift (``drift.py``) follows the best particle.

Association by identity (``association="id"``): the observation's id names the landmark (step 1 scans the
particles' tables instead of the view's blocks), step 2's gate only rejects outliers, step 3 is trivial.

Importance weights. The textbook weight is the Gaussian likelihood N(z; ẑ, S) of every matched observation
and a constant p₀ for a new landmark. We use the robust form log w += −½ min(d², gate) per observation (an
unmatched or new observation costs the gate): it drops the log-det normalisers, which barely differ between
particles observing the same landmark but make p₀ scale-dependent, and it keeps one bad match from wiping out
a particle. FastSLAM 2.0 uses d² under S + H_x P H_xᵀ at the predicted pose (Montemerlo et al. 2003, eq. 27).
With ``detection_in_weight`` ("unknown" association, an option) the weight also carries the map's detections and
misses in view, log P_D and log(1 − P_D) (``detection_term.py``).

Descriptor threshold: the fusion paper's th₀ = 2 cannot be a Euclidean distance between *unit* U-SURF
descriptors (their distance is at most 2, so it would accept everything); it is presumably on unnormalised
descriptors. We gate unit descriptors at 0.5 by default (``FastSLAMConfig.descriptor_threshold``).
Descriptors are kept as first seen (the landmark's id indexes a shared, append-only descriptor table), so
copy-on-write never copies them; ``refresh_descriptors`` (off by default: on rendered frames it let landmarks
slide along textures) overwrites an id's descriptor with its latest match in the most probable particle.

Parts of the filter in their own modules: step 7's duplicate merging (``merging.py``) and the maps it gives out
(``particle_maps.py``), each a base class of :class:`FastSLAM`; the (particle, observation, landmark) triples and
step 3's mutual exclusion (``pairs.py``); the array helpers of the vectorised steps (``arrays.py``).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, replace

import numpy as np

from ..geometry import compose, wrap_angle
from ..landmark_map import LandmarkMap
from ..observations import OdometryIncrement, StereoObservations
from . import association_rules, detection_term, id_gate, unknown_rescue
from .appearance import DescriptorBands
from .arrays import cos_sin, id_ranks, is_in, sorted_difference, take_cols, take_rows, within_angle
from .coincident import one_per_point, twins_of_matched
from .config import FastSLAMConfig
from .drift import DriftTracker
from .existence import hit_log_odds, miss_log_odds
from .export_drift import ExportLeverDriftTracker
from .lever_drift import LeverDriftTracker, with_empirical_position
from .linalg import (
    joseph_update,
    lower_matvec,
    pose_uncertainty,
    sym_adjugate,
    sym_cholesky,
    sym_components,
    sym_inverse,
    sym_matrices,
    sym_matvec,
    sym_product,
    sym_quadratic,
    sym_rotate_z,
    symmetrise,
)
from .merging import DuplicateMerging
from .motion import (
    heading_drift_decay,
    increment_variance,
    propagate_covariance,
    propagate_with_heading_drift,
    sample_motion,
    walk_heading_bias,
    with_heading_bias,
)
from .pairs import Pairs, exclusive_matches, no_pairs
from .particle_maps import ParticleMaps
from .resampling import effective_sample_size, low_variance_resample, normalise_log_weights
from .selection import select_observations
from .self_check import SelfCheck, slot_view
from .shared_evidence import CreationTokens
from .store import LandmarkStore

_EYE3 = np.eye(3)
_TINY_POSE_VAR = np.array([1e-12, 0.0, 0.0, 1e-12, 0.0, 1e-12])[:, None]   # keeps P⁻¹ finite right after an update
PRUNE_HISTORY_EVERY = 200  # updates between prunings of the trajectory history to the live ancestry


@dataclass(frozen=True)
class UpdateReport:
    """What one :meth:`FastSLAM.update` did.

    matched, new_landmarks, dropped: means over particles; ess: effective sample size before resampling;
    new_landmark_ids (N,): the landmark id observation j created (in any particle), -1 if none;
    best_matches (N,): the landmark id observation j matched in the most probable particle, -1 if none;
    pose_mean (3,), pose_covariance (3, 3): the weighted particle cloud before resampling;
    proposal_fallbacks: particles of this update that drew from the motion model (see :class:`FilterStats`).
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
    proposal_fallbacks: int = 0


@dataclass
class FilterStats:
    """Counters over the filter's life (``FastSLAM.stats``).

    proposal_fallbacks: FastSLAM 2.0 particles whose observation proposal was numerically not positive definite
    and which drew from the motion model instead (0 in a healthy run; see ``_sample_proposal``). The other
    counters count (particle, landmark) or (particle, observation) events, summed over particles.
    """

    proposal_fallbacks: int = 0
    id_outliers: int = 0          # "id" association: (particle, observation) pairs rejected by the gate
    id_rescued: int = 0           # "id", ``id_relative_drift``: pairs accepted only under the drift-widened gate
    unknown_rescued: int = 0      # "unknown", ``unknown_relative_drift``: old landmarks re-associated jointly
    unknown_drawn_new: int = 0    # "unknown", ``unknown_association_rule="sampled"``: pairs that drew a new landmark
    #                             #   although a landmark was inside the gate
    unknown_unused: int = 0       # "unknown", ``unknown_association_rule="unambiguous"``: pairs left unused, no
    #                             #   gated landmark being probable enough (association_rules.py)
    landmarks_removed: int = 0    # (particle, landmark) removals: existence fell below ``existence_remove``
    landmarks_merged: int = 0     # (particle, landmark) merges of duplicates (``merge_gate``)


@dataclass
class _FrameGeometry:
    """Every observation seen from every particle, indexed m·N + j: world points (3, M·N) w = R z + t and
    world-frame observation covariances (6, M·N) R Q Rᵀ (symmetric components, see ``linalg``)."""

    world: np.ndarray
    noise: np.ndarray

    @classmethod
    def of(cls, poses: np.ndarray, z: np.ndarray, q6: np.ndarray) -> _FrameGeometry:
        """poses (M, 3), z (N, 3), q6 (6, N)."""
        c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
        zx, zy, zz = z[:, 0], z[:, 1], z[:, 2]
        world = np.empty((3, len(poses), len(z)))                # filled row by row: no broadcast copies stacked
        world[0] = c * zx - s * zy + poses[:, :1]
        world[1] = s * zx + c * zy + poses[:, 1:2]
        world[2] = zz
        return cls(world.reshape(3, -1), sym_rotate_z(c, s, q6[:, None, :]).reshape(6, -1))


def _clearly_positive_definite(q: np.ndarray) -> bool:
    """True when every symmetric (N, 3, 3) matrix of ``q`` (finite) has all three Cholesky pivots above 10⁻⁶ of its
    largest diagonal entry (closed form): positive definite whatever the rounding of the pivots (each term of a
    pivot is at most that diagonal entry, and a pivot divided by is ≥ 10⁻⁶ of it: the rounding moves a pivot by
    ~10⁻¹⁰ of it, here as in LAPACK), so ``np.linalg.cholesky`` (one LAPACK call per frame: 5 % of the known-id
    filter's time) accepts it too. False decides nothing: the caller asks LAPACK."""
    a, b, c, d, e, f = (q[:, i, j] for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)))
    with np.errstate(invalid="ignore", divide="ignore"):
        p11 = d - b * b / a
        p22 = f - c * c / a - (e - b * c / a) ** 2 / p11
        floor = 1e-6 * np.maximum(np.maximum(a, d), f)
        return bool(np.all((a > floor) & (p11 > floor) & (p22 > floor)))


class FastSLAM(DuplicateMerging, ParticleMaps):
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
        # a drifting heading bias per metre, one per particle (rad/m; config.odom_heading_drift_*, see predict):
        # drawn N(0, σ_b²) here, walked at every predict, carried by resampling; zeros (and no draw) without it
        sigma_b = config.odom_heading_drift_sigma_per_m
        self.heading_bias = sigma_b * rng.standard_normal(m) if sigma_b > 0 else np.zeros(m)
        self._drift_bias_cross = np.zeros(3)     # the drift tracker's D_r: its covariance with the bias (predict)
        self._best = 0
        self._time = 0.0
        # ancestry, one entry per update: (t, poses (K, 3), parents (K,)) where parents index the previous
        # entry's rows; the newest entry holds all M particles, older ones only the live particles' ancestors
        self._history: list[tuple[float, np.ndarray, np.ndarray]] = [(0.0, self.poses.copy(), np.arange(m))]
        self._pruned_at = 0
        self.stats = FilterStats()
        # drift_export is the known-ID path's export: in "unknown" association merges read the exported
        # covariances, so the export's tracker would change estimates there; that path keeps the plain one
        export_only = config.drift_export != "plain" and config.association == "id"
        self.drift = (LeverDriftTracker(config.drift_translation_per_m) if config.drift_lever   # the map frame's
                      else ExportLeverDriftTracker(config.drift_export.startswith("lever+heading"),
                                                   relative=config.drift_export.endswith("+relative"))
                      if export_only else DriftTracker())                                       # drift
        self._proposal_cov: np.ndarray | None = None                    # 2.0: mean proposal covariance (3, 3)
        self._touched: list[np.ndarray] = []                            # landmark ids touched since the last merge
        # co-visibility of landmark pairs in the most probable particle (merging.py, _merge_duplicates): evidence
        # "one point" per pair key, the keys ever detected in one frame (never merged), those ready to merge
        self._pair_evidence: dict[int, float] = {}
        self._codetected: set[int] = set()
        self._merge_ready: set[int] = set()
        self._merged: dict[tuple[int, int], bool] = {}                 # (older id, newer id) -> by co-visibility
        # descriptors per viewing range (appearance.py); None: each landmark keeps its first descriptor only
        self._bands = (DescriptorBands(config.descriptor_slots, config.descriptor_slot_ratio, config.descriptor_size,
                                       key=config.descriptor_slot_key, angle=config.descriptor_slot_angle)
                       if config.descriptor_slots > 1 and config.descriptor_size > 0 else None)
        self._lid_of_external: dict[int, int] = {}                     # "id" association: external id -> id
        self._external_of_lid = np.zeros(0, np.int64)                  # and back (-1: none)
        self.self_check = SelfCheck(config)                            # has the map lost its place? (read only)
        self._creations = (CreationTokens(m) if config.weight_evidence == "shared_creation"   # which particles
                           and config.association == "id" else None)   # made each landmark together

    # == 0. motion ==========================================================================================
    def predict(self, increment: OdometryIncrement, extra_variance: np.ndarray | None = None) -> None:
        """Move every particle by the odometry increment (robot frame at its start), with motion noise: the
        config's random walk, plus ``extra_variance`` (3,) of (dx, dy, dθ) if given (a noise model's term the
        increment alone does not show: a stall after a dip of the command, ``estimation.odometry_stall``)."""
        delta = increment.delta
        if not np.all(np.isfinite(delta)):
            raise ValueError(f"odometry increment {delta.tolist()} is not finite; the filter is unchanged")
        variance = increment_variance(delta, self.config, max(float(increment.t1 - increment.t0), 0.0))
        if extra_variance is not None:
            variance = variance + np.asarray(extra_variance, float)
        sigma_b = self.config.odom_heading_drift_sigma_per_m
        if sigma_b > 0:   # a drifting heading bias per metre (config): each particle's own, then walked
            decay = heading_drift_decay(increment.t1 - increment.t0, self.config.odom_heading_drift_tau_s)
            self.drift.robot, self._drift_bias_cross = propagate_with_heading_drift(
                self.poses[self._best], self.drift.robot, self._drift_bias_cross, delta, variance, sigma_b, decay)
            moved = with_heading_bias(delta, self.heading_bias)   # (M, 3): the random walk's noise comes on top
        else:
            self.drift.robot = propagate_covariance(self.poses[self._best][None], self.drift.robot[None], delta,
                                                    variance)[0]
            moved = delta
        if self.config.version == 1:
            self.poses = sample_motion(self.poses, moved, variance, self.rng)
        else:  # keep the noise-free prediction and its covariance; the proposal samples in update()
            # (with a heading drift, each particle's prediction takes its own bias: b is sampled, not in P)
            self._motion_cov = propagate_covariance(self.poses, self._motion_cov, delta, variance)
            self.poses = compose(self.poses, moved)
        if sigma_b > 0:
            self.heading_bias = walk_heading_bias(self.heading_bias, decay, sigma_b, self.rng)
        self._time = max(self._time, float(increment.t1))

    # == update ==============================================================================================
    def update(self, observations: StereoObservations) -> UpdateReport:
        """Incorporate one frame of 3-D point observations in base_link (see the module docstring).

        With ``max_observations`` > 0, only that many observations are used, chosen by
        ``observation_selection`` (see :mod:`estimation.fastslam.selection`); with ``association="id"`` only
        those with an id ≥ 0, one per id (the first). The report's per-observation arrays still have one entry
        per given observation (-1 for those left out).
        """
        cfg = self.config
        cap, n_given = cfg.max_observations, len(observations)
        usable = np.ones(n_given, bool)
        if cfg.association == "id":   # only observations that carry an identity can be associated by it
            usable = np.zeros(n_given, bool)
            if observations.ids is not None:   # one observation per identity and frame (the first)
                ids = observations.ids.tolist()
                if len(set(ids)) == len(ids):   # the usual frame, each id once: np.unique's sort would keep all
                    usable[:] = True
                else:
                    usable[np.unique(observations.ids, return_index=True)[1]] = True
                usable &= observations.ids >= 0
        if cfg.coincident_readings == "one_per_point":   # one physical point, one reading a frame (coincident.py)
            usable &= one_per_point(observations.points, cfg.observation_cov_scale * np.asarray(
                observations.covariances, float) + cfg.observation_var_floor * _EYE3)
        if (cap <= 0 or usable.sum() <= cap) and usable.all():
            return self._update(observations)
        keep = np.flatnonzero(usable)
        if 0 < cap < len(keep):
            keep = keep[select_observations(observations.points[keep], observations.covariances[keep], cap,
                                            cfg.observation_selection, cfg.sensor_offset, cfg.fov_horizontal)]
        pixels = observations.pixels[keep] if len(observations.pixels) else observations.pixels
        ids = observations.ids[keep] if observations.ids is not None else None
        capped = 0 < cap < usable.sum()
        # a capped frame says nothing about landmarks beyond its farthest kept observation ("nearest" keeps the
        # near ones), and less about those within it: misses count only there, weighted by the share kept
        reach = float(np.max(np.linalg.norm(observations.points[keep] - cfg.sensor_offset, axis=1), initial=0.0))
        report = self._update(StereoObservations(
            observations.points[keep], observations.covariances[keep], observations.descriptors[keep], pixels,
            observations.timestamp, observations.frame, ids),
            miss_reach=reach if capped else None, miss_weight=len(keep) / max(int(usable.sum()), 1))
        new_ids, best = np.full(n_given, -1, np.int64), np.full(n_given, -1, np.int64)
        new_ids[keep], best[keep] = report.new_landmark_ids, report.best_matches
        return replace(report, new_landmark_ids=new_ids, best_matches=best)

    def _update(self, observations: StereoObservations, miss_reach: float | None = None,
                miss_weight: float = 1.0) -> UpdateReport:
        cfg = self.config
        n_particles, n_obs = len(self.poses), len(observations)
        z, q, desc = self._checked(observations)
        self._time = max(self._time, float(observations.timestamp))
        predicted = self.poses
        fallbacks_before = self.stats.proposal_fallbacks
        q6 = sym_components(q)                                                     # (6, N)
        frame = _FrameGeometry.of(predicted, z, q6)

        # 1-2. candidates, descriptor join, Mahalanobis gate (in the world frame: d² is frame-invariant, and
        # there H_x = ∂(R z + t − μ)/∂(x, y, θ) needs no rotation; see _sample_proposal)
        cand, cand_lids = self._candidates(predicted)
        by_id = cfg.association == "id"
        if by_id:      # the observation's identity names the landmark; the gate below only rejects outliers
            obs_lids = self._lids_of_external(observations.ids)
            pairs, mean, cov, holds = self._id_join(obs_lids)
        else:
            pairs, mean, cov = self._descriptor_join(cand, cand_lids, desc, predicted, z, q6)
            if cfg.descriptor_size == 0:   # no descriptors thin the candidates: a cheap exact pre-gate first
                pairs, mean, cov = self._pregate(pairs, mean, cov, frame, predicted, q6)
        mj = pairs.m * n_obs + pairs.j
        innovation, s_obs, s_gate, d2, _ = self._gate(frame, predicted, pairs.m, mj, mean, cov)
        gated = d2 < cfg.mahalanobis_gate
        relative = None
        if by_id and cfg.id_relative_drift != "off" and cfg.version == 2:   # the pose's drift since the landmark
            lever = mean[:2] - take_cols(predicted[:, :2].T, pairs.m)            # was made (id_gate.py)
            relative = id_gate.judge(cfg.id_relative_drift, self.drift, pairs.m, obs_lids[pairs.j], d2, s_gate,
                                     innovation, lever, cfg.mahalanobis_gate)
            d2, gated = relative.d2, relative.gated
            self.stats.id_rescued += int(np.count_nonzero(relative.rescued))
        elif not by_id and cfg.unknown_relative_drift != "off" and cfg.version == 2:
            # old landmarks re-sighted after a drift: readings no landmark gated, judged again (unknown_rescue.py)
            held = np.zeros(n_particles * n_obs, bool)
            held[mj[gated]] = True
            extra = unknown_rescue.rescue(self.drift, ~held, cand.m, cand_lids, cand.g, self.store.flat_state,
                                          frame.world, frame.noise, self._motion_cov, predicted,
                                          cfg.mahalanobis_gate, desc, self._descriptors, cfg.descriptor_threshold)
            if extra is not None:
                found = cand.take(extra.rows)
                pairs = Pairs(*(np.concatenate([a, b]) for a, b in zip(
                    (pairs.m, pairs.j, pairs.k, pairs.g, pairs.c), (found.m, extra.j, found.k, found.g, found.c),
                    strict=True)))
                mean, cov, innovation, s_obs = (np.concatenate(ab, axis=1) for ab in (
                    (mean, extra.mean), (cov, extra.cov), (innovation, extra.innovation), (s_obs, extra.s_obs)))
                mj, lever = pairs.m * n_obs + pairs.j, mean[:2] - take_cols(predicted[:, :2].T, pairs.m)
                relative = extra.relative_gate(self.drift, cand_lids[pairs.c], d2, gated, cfg.mahalanobis_gate)
                d2, gated = relative.d2, relative.gated
                self.stats.unknown_rescued += len(extra.rows)

        # 3. mutual exclusion
        n_slots = n_particles * self.store.table.shape[1] * self.store.block_size if by_id else len(cand.m)
        drawn = None
        if not by_id and cfg.unknown_association_rule != "nearest":   # beyond maximum likelihood (association_rules)
            if cfg.unknown_association_rule == "sampled":
                drawn = association_rules.sample_associations(mj, d2, gated, n_particles, n_obs,
                                                              cfg.mahalanobis_gate, self.rng)
            else:
                drawn = association_rules.unambiguous_associations(mj, d2, gated, n_particles, n_obs,
                                                                   cfg.mahalanobis_gate)
            gated = drawn.gated
            self.stats.unknown_drawn_new += int(np.count_nonzero(drawn.new))
            self.stats.unknown_unused += int(np.count_nonzero(drawn.unused))
        win, had_candidate = exclusive_matches(pairs, d2, gated, n_particles, n_obs, n_slots)
        if drawn is not None:   # a reading left unused is no new landmark
            had_candidate |= drawn.unused
        matched = pairs.take(win)
        if cfg.coincident_readings == "no_twin_landmark" and not by_id:   # a matched reading's twin is no new
            had_candidate |= twins_of_matched(z, q, matched.m, matched.j, n_particles)   # landmark (coincident.py)
        if by_id:      # a new landmark only where the particle has none of that id; a gated-out one is an outlier
            self.stats.id_outliers += int(np.count_nonzero(~gated))
            had_candidate = holds
        log_lik = -0.5 * cfg.mahalanobis_gate * n_obs - 0.5 * np.bincount(
            matched.m, d2[win] - cfg.mahalanobis_gate, minlength=n_particles)
        if drawn is not None:   # the weight does not depend on the choice: the largest term per reading
            log_lik = drawn.log_lik
        if self._creations is not None:   # a reading compares only particles that made its landmark together
            terms = np.full((n_particles, n_obs), -0.5 * cfg.mahalanobis_gate)
            terms[matched.m, matched.j] = -0.5 * d2[win]
            log_lik = self._creations.log_likelihood(self.log_weights, terms, obs_lids,
                                                     holds.reshape(n_particles, n_obs))
        mean, cov = take_cols(mean, win), take_cols(cov, win)

        s_inv = sym_inverse(take_cols(s_obs, win))                                    # S⁻¹ without the pose term
        if relative is not None:   # proposal and EKF relative to each particle's oldest landmark (id_gate.py)
            cov, self._motion_cov = relative.anchor(win, matched.m, cov, take_cols(lever, win), self._motion_cov)
            s_inv = sym_inverse(cov + take_cols(frame.noise, mj[win]))

        # 4. pose: FastSLAM 2.0 samples from the observation proposal; 1.0 already sampled in predict()
        if cfg.version == 2:
            sampled = self._sample_proposal(predicted, matched, mean, s_inv, take_cols(innovation, win))
            if cfg.anchor_first_frame:
                # the frame that starts a particle's map fixes its gauge: no later observation can tell a heading
                # sampled there from the truth, so a draw only adds a permanent offset; keep the mean instead
                empty = self.store.n_blocks == 0
                if cfg.anchor_unmatched:
                    empty |= np.bincount(matched.m, minlength=n_particles) == 0
                sampled[empty] = predicted[empty]
            self.poses = sampled
            self._motion_cov = np.zeros_like(self._motion_cov)
        poses = self.poses

        # 5-6. writes: EKF updates of matched landmarks and misses of provisional ones (copy-on-write first)
        # ("id": a landmark its identity named this frame was detected, even if the gate rejected the reading)
        missed, missed_ranges = self._missed_in_view(cand, poses, pairs if by_id else matched, by_id, miss_reach)
        if cfg.detection_in_weight and not by_id:   # the map's detections and misses in the weight (detection_term)
            ox, oy, _ = cfg.sensor_offset
            log_lik = log_lik + detection_term.detection_log_likelihood(
                cfg, n_particles, matched.m, np.hypot(z[matched.j, 0] - ox, z[matched.j, 1] - oy), missed.m,
                missed_ranges, miss_weight)
        best_now = int(np.argmax(self.log_weights + log_lik))   # the particle step 8 picks
        self._check_self(best_now, matched, missed, pairs if by_id else None, z, miss_weight)
        self.store.make_writable(np.concatenate([matched.m, missed.m]), np.concatenate([matched.k, missed.k]))
        matched.g = self._remap(matched)
        missed.g = self._remap(missed)
        moved = self._ekf_update(matched, predicted, poses, z, q6, mean, cov, s_inv)
        dropped = self._count_miss(missed, missed_ranges, miss_weight)
        self.store.include_in_bbox(matched.g, moved)

        # 7. new landmarks from observations no landmark was a candidate for
        new_ids, n_new = self._add_landmarks(had_candidate, poses, z, q6, desc,
                                             self._lids_for_new(observations.ids, obs_lids) if by_id else None)
        if self._creations is not None:
            m_new, j_new = np.divmod(np.flatnonzero(~had_candidate), max(n_obs, 1))
            self._creations.made(new_ids[j_new], m_new, poses)
        self.self_check.made(new_ids, z, poses[best_now])
        if cfg.merge_gate > 0 and not by_id and cfg.merge_covisibility:
            # what the most probable particle (the one step 8 picks) detected and missed in view, counted before
            # any merge: two landmarks detected in this frame are two points from now on
            self._count_covisibility(*self._best_particle_view(
                int(np.argmax(self.log_weights + log_lik)), matched, missed, missed_ranges, had_candidate, new_ids,
                poses, z, q6))
        if cfg.merge_gate > 0 and not by_id:   # duplicates: only the landmarks touched since the last pass
            self._touched.append(np.concatenate([self.store.flat_lid[matched.g], new_ids[new_ids >= 0]]))
            if len(self._touched) >= cfg.merge_every:
                self._merge_duplicates(np.unique(np.concatenate(self._touched)))
                self._touched = []

        # 8. weights and resampling
        best_matches = np.full(n_obs, -1, np.int64)
        self.log_weights = self.log_weights + log_lik
        self.log_weights -= self.log_weights.max()
        weights = normalise_log_weights(self.log_weights)
        ess = effective_sample_size(weights)
        best = int(np.argmax(weights))
        in_best = matched.m == best
        best_matches[matched.j[in_best]] = self.store.flat_lid[matched.g[in_best]]
        if self._bands is not None:   # the best particle's matches teach their landmarks the look from new views
            teach = in_best
            if cfg.descriptor_learn_gate > 0:   # strong evidence only: in place, confirmed, the only candidate
                candidates = np.bincount(pairs.j[gated & (pairs.m == best)], minlength=n_obs)
                teach = in_best & (d2[win] < cfg.descriptor_learn_gate) & (candidates[matched.j] == 1) \
                    & (self.store.flat_count[matched.g] > cfg.confirm_count)
            j = matched.j[teach]
            j = j[best_matches[j] >= 0]   # not merged away since the match
            self._bands.learn(best_matches[j], desc[j], self._sensor_range(z[j]),
                              self._sight_bearing(z[j], self.poses[best, 2]))
        if cfg.refresh_descriptors and cfg.descriptor_size > 0:
            # appearance drifts with distance (fixed-scale U-SURF): gate the next frame on the latest look
            self._descriptors[best_matches[matched.j[in_best]]] = desc[matched.j[in_best]]
        pose_mean, pose_cov = _weighted_pose_stats(self.poses, weights)
        spawned = np.flatnonzero(new_ids >= 0)
        c, s_ = np.cos(self.poses[best, 2]), np.sin(self.poses[best, 2])
        new_xy = z[spawned, :2] @ np.array([[c, s_], [-s_, c]]) + self.poses[best, :2]    # R z + t, best particle
        # the local pose uncertainty given the map: FastSLAM 2.0's proposal (analytic, before sampling and
        # resampling shrink it) or else the weighted cloud, whichever is larger
        local = pose_cov
        if cfg.version == 2 and self._proposal_cov is not None and np.trace(self._proposal_cov) > np.trace(pose_cov):
            local = self._proposal_cov
        if cfg.drift_local_empirical and in_best.any():   # the frame's own residuals, not the claimed Q
            j = matched.j[in_best]
            seen_xy = z[j, :2] @ np.array([[c, s_], [-s_, c]]) + self.poses[best, :2]
            local = with_empirical_position(local, seen_xy - self.store.flat_state[matched.g[in_best], :2],
                                            self.store.flat_count[matched.g[in_best]], cfg.observation_correlation)
        if relative is not None and cfg.id_drift_inherit:   # re-measured relative to an anchor: its pose's drift
            relative.inherit(self.drift, best, np.unique(best_matches[best_matches >= 0]), local)
        self.drift.update(np.unique(best_matches[best_matches >= 0]), new_ids[spawned], new_xy,
                          self.poses[best], local, self._n_ids)
        if in_best.any():   # D_r pinned to old landmarks: its error is theirs, no longer the current bias's
            self._drift_bias_cross = np.zeros(3)
        parents = np.arange(n_particles)
        resampled = ess < cfg.resample_threshold * n_particles
        if resampled:
            parents = low_variance_resample(weights, self.rng)
            self.poses = self.poses[parents]
            self.heading_bias = self.heading_bias[parents]
            self.store.resample(parents)
            if self._creations is not None:
                self._creations.resampled(parents)
            self.log_weights = np.zeros(n_particles)
            best = int(np.flatnonzero(parents == best)[0])  # the heaviest (w ≥ 1/M) is always copied
        self._best = best
        self._history.append((self._time, self.poses.copy(), parents))
        if len(self._history) - self._pruned_at >= PRUNE_HISTORY_EVERY:
            self._prune_history()
            self._prune_pairs()
        return UpdateReport(
            n_obs, len(win) / n_particles, n_new / n_particles,
            dropped / n_particles, ess, bool(resampled), new_ids, best_matches, pose_mean, pose_cov,
            self.stats.proposal_fallbacks - fallbacks_before)

    def candidate_gate(self, observations: StereoObservations) -> association_rules.CandidateGate:
        """The plain gate of step 2 for every (particle, reading, landmark in a block near the particle's view),
        at the predicted poses, before the descriptor join and the exact pre-gates (those only drop triples that
        fail): what the filter would decide between. Read only (the filter is unchanged); for diagnoses of the
        association (``benchmarks/mrclam_wrong_matches.py``, ``mrclam_unknown_creations.py``)."""
        z, q, _ = self._checked(observations)
        poses, n_obs = self.poses, len(z)
        frame = _FrameGeometry.of(poses, z, sym_components(q))
        cand, lids = self._candidates(poses)
        c = np.repeat(np.arange(len(cand.m)), n_obs)
        j = np.tile(np.arange(n_obs), len(cand.m))
        m = cand.m[c]
        state = self.store.flat_state[cand.g[c]].T
        mean, cov = state[:3], state[3:]
        innovation, _, s, d2, det = self._gate(frame, poses, m, m * n_obs + j, mean, cov)
        lever = mean[:2] - take_cols(poses[:, :2].T, m)
        return association_rules.CandidateGate(m, j, lids[c], innovation, s, lever, d2, np.log(det))

    def _gate(self, frame: _FrameGeometry, poses: np.ndarray, m: np.ndarray, mj: np.ndarray, mean: np.ndarray,
              cov: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Step 2's Mahalanobis gate for (particle m, reading, landmark (mean (3, P), cov (6, P))) pairs, mj =
        m·N + j: ν = R z + t − μ (3, P), S = Σ + R Q Rᵀ (6, P), the gate's S (with FastSLAM 2.0's pose term
        H_x P H_xᵀ: the pose is not sampled yet), d² = νᵀ S⁻¹ ν and |S| (P,). One place for the update and
        :meth:`candidate_gate`, so the diagnoses see the gate the filter uses."""
        innovation = take_cols(frame.world, mj) - mean
        s_obs = cov + take_cols(frame.noise, mj)
        s_gate = s_obs
        if self.config.version == 2:
            s_gate = s_obs + pose_uncertainty(take_cols(sym_components(self._motion_cov), m),
                                               mean[:2] - take_cols(poses[:, :2].T, m))
        adj, det = sym_adjugate(s_gate)
        return innovation, s_obs, s_gate, sym_quadratic(adj, innovation) / det, det

    # -- step helpers ----------------------------------------------------------------------------------------
    def _checked(self, observations: StereoObservations):
        cfg = self.config
        z = np.asarray(observations.points, float)
        q = cfg.observation_cov_scale * symmetrise(np.asarray(observations.covariances, float))
        q = q + cfg.observation_var_floor * _EYE3
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
        if not _clearly_positive_definite(q):   # LAPACK decides the rest (its pivots' rounding, not ours)
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

    def _candidates(self, poses: np.ndarray) -> tuple[Pairs, np.ndarray]:
        """Every live landmark in a block near each particle's view: pairs with j = -1 (M·K·B at most), with
        their landmark ids (C,) (read block by block: whole rows, not scattered slots)."""
        store = self.store
        centres, radius = self._footprint(poses)
        p, k = store.blocks_near(centres, radius)
        b = store.block_size
        phys = store.table[p, k]
        lid = take_rows(store.lid, phys)                                           # (pairs, B)
        alive = lid >= 0
        live = np.flatnonzero(alive)
        g = (phys[:, None] * b + np.arange(b)).ravel()[live]    # each block's slots, no division per candidate
        per_block = np.count_nonzero(alive, axis=1)
        cand = Pairs(np.repeat(p, per_block), np.full(len(g), -1, np.int64), np.repeat(k, per_block), g,
                      np.arange(len(g)))
        return cand, lid.ravel()[live]

    def _descriptor_join(self, cand: Pairs, lids: np.ndarray, desc: np.ndarray, poses: np.ndarray, z: np.ndarray,
                         q6: np.ndarray) -> tuple[Pairs, np.ndarray, np.ndarray]:
        """(particle, observation, landmark) triples whose descriptors are closer than the threshold, with
        the landmarks' means (3, P) and covariances (6, P).

        Distances are computed once per distinct landmark id (particles share ids), not per particle; then
        (observation, id) pairs that no particle could gate are dropped, also once per id
        (:meth:`_id_pregate`; poses (M, 3), z (N, 3), q6 (6, N)), before they are expanded to particles.
        """
        n_obs = len(desc)
        if len(cand.m) == 0 or n_obs == 0:
            return no_pairs(), np.zeros((3, 0)), np.zeros((6, 0))
        store = self.store
        uniq, inverse = id_ranks(lids, self._n_ids)
        if self._bands is not None:   # compare at comparable scale: the descriptor made at the nearest range
            obs_j, uid = self._bands.matches(uniq, desc, self._sensor_range(z), self.config.descriptor_threshold,
                                             self._sight_bearing(z, poses[self._best, 2]))
        elif self.config.descriptor_size > 0:
            known = take_rows(self._descriptors, uniq)
            d2 = (np.sum(desc * desc, 1)[:, None] + np.sum(known * known, 1)[None, :] - 2.0 * desc @ known.T)
            obs_j, uid = np.nonzero(d2 < self.config.descriptor_threshold ** 2)
        else:
            obs_j, uid = np.divmod(np.arange(n_obs * len(uniq)), len(uniq))
        # only candidates whose landmark some observation's descriptor matched are read from the store
        wanted = np.zeros(len(uniq), bool)
        wanted[uid] = True
        keep = np.flatnonzero(wanted[inverse])
        g, inverse = cand.g[keep], inverse[keep]
        state = take_rows(store.flat_state, g)                    # (C, 9): means (3), covariances (6)
        mean = state[:, :3]
        trace = state[:, 3] + state[:, 6] + state[:, 8]            # (C,) tr Σ
        if len(obs_j):
            keep_pair = self._id_pregate(mean, trace, inverse, len(uniq), obs_j, uid, poses, z, q6)
            obs_j, uid = obs_j[keep_pair], uid[keep_pair]
        # group the candidates by id (a stable radix sort on small integers), then expand every surviving
        # (observation, id) pair to the candidates holding that id: one triple per particle
        order = np.argsort(inverse.astype(np.uint16 if len(uniq) <= 0xFFFF else np.int64), kind="stable")
        counts = np.bincount(inverse, minlength=len(uniq))
        starts = np.cumsum(counts) - counts
        reps = counts[uid]
        first = np.repeat(starts[uid], reps)
        within = np.arange(int(reps.sum())) - np.repeat(np.cumsum(reps) - reps, reps)
        ci = order[first + within]
        c = keep[ci]
        pairs = Pairs(cand.m[c], np.repeat(obs_j, reps), cand.k[c], g[ci], c)
        state = take_rows(state, ci).T
        return pairs, np.ascontiguousarray(state[:3]), np.ascontiguousarray(state[3:])

    def _id_pregate(self, mean: np.ndarray, trace: np.ndarray, inverse: np.ndarray, n_uniq: int, obs_j: np.ndarray,
                    uid: np.ndarray, poses: np.ndarray, z: np.ndarray, q6: np.ndarray) -> np.ndarray:
        """(L,) bool over (observation, id) pairs: False where the Mahalanobis gate would fail in every
        particle, decided once per id (an exact bound, so the association is unchanged, only faster).

        With a reference pose (mean position, θ of particle 0) and a reference mean μ̄ per id, for particle m:
        |ν_m| ≥ |w̄(z) − μ̄| − D − Δθ|z_xy| − E, where D, Δθ bound the particles' distance from the reference
        pose, E bounds |μ_m − μ̄| over the particles holding the id, w̄(z) = R̄z + t̄; and d² ≥ |ν|²/tr S with
        tr S_m ≤ T + tr Q (+ (2 + r_max²)·max tr P under 2.0), T = max tr Σ of the id.
        mean (C, 3), trace (C,): the candidates' landmarks and tr Σ, ``inverse`` (C,) their id's rank in
        0..n_uniq-1.
        """
        n = len(inverse)
        first = np.full(n_uniq, n)
        np.minimum.at(first, inverse, np.arange(n))
        ref_mean = mean[np.minimum(first, n - 1)]                          # the first particle's mean per id
        dx, dy, dz = (mean[:, i] - ref_mean[:, i][inverse] for i in range(3))   # column by column: no row gathers
        spread2 = np.zeros(n_uniq)
        np.maximum.at(spread2, inverse, dx * dx + dy * dy + dz * dz)
        spread = np.sqrt(spread2)
        cov_trace = np.zeros(n_uniq)
        np.maximum.at(cov_trace, inverse, trace)
        ref_xy = poses[:, :2].mean(axis=0)
        ref_theta = poses[0, 2]
        d_pose = float(np.max(np.linalg.norm(poses[:, :2] - ref_xy, axis=1)))
        d_theta = float(np.max(np.abs(wrap_angle(poses[:, 2] - ref_theta))))
        c, s = np.cos(ref_theta), np.sin(ref_theta)
        zj = z[obs_j]
        at_ref = ref_mean[uid].T
        ex = ref_xy[0] + c * zj[:, 0] - s * zj[:, 1] - at_ref[0]   # w̄(z) − μ̄, column by column: |·| adds the
        ey = ref_xy[1] + s * zj[:, 0] + c * zj[:, 1] - at_ref[1]   # squares in np.linalg.norm's order
        ez = zj[:, 2] - at_ref[2]
        lower = np.sqrt(ex * ex + ey * ey + ez * ez) - d_pose - d_theta * np.hypot(zj[:, 0], zj[:, 1]) - spread[uid]
        trace = cov_trace[uid] + (q6[0] + q6[3] + q6[5])[obs_j]
        if self.config.version == 2:
            r_max = np.linalg.norm(ref_mean[uid, :2] - ref_xy, axis=1) + spread[uid] + d_pose
            trace = trace + (2.0 + r_max ** 2) * float(np.max(np.trace(self._motion_cov, axis1=1, axis2=2)))
        return (lower <= 0) | (lower ** 2 <= self.config.mahalanobis_gate * trace * (1 + 1e-6))

    def _pregate(self, pairs: Pairs, mean: np.ndarray, cov: np.ndarray, frame: _FrameGeometry,
                 poses: np.ndarray, q6: np.ndarray) -> tuple[Pairs, np.ndarray, np.ndarray]:
        """Drop pairs that cannot pass the Mahalanobis gate, using only vector norms (exact, conservative).

        d² = νᵀS⁻¹ν ≥ |ν|²/λ_max(S) ≥ |ν|²/tr S, and tr S = tr Σ + tr Q (+ tr H_x P H_xᵀ ≤ (2 + r²) tr P under
        2.0, r the landmark's planar distance), all rotation-invariant. Cheap where descriptors do not thin
        the candidates (range-bearing data has none). mean (3, P), cov (6, P) of the pairs' landmarks.
        """
        if len(pairs.m) == 0:
            return pairs, mean, cov
        nu2 = np.sum((frame.world[:, pairs.m * q6.shape[1] + pairs.j] - mean) ** 2, axis=0)
        trace = cov[0] + cov[3] + cov[5] + (q6[0] + q6[3] + q6[5])[pairs.j]
        if self.config.version == 2:
            r2 = np.sum((mean[:2] - poses[pairs.m, :2].T) ** 2, axis=0)
            trace = trace + (2.0 + r2) * np.trace(self._motion_cov, axis1=1, axis2=2)[pairs.m]
        keep = np.flatnonzero(nu2 <= self.config.mahalanobis_gate * trace * (1 + 1e-9))
        return pairs.take(keep), mean[:, keep], cov[:, keep]

    def _sample_proposal(self, predicted: np.ndarray, matched: Pairs, mean: np.ndarray, s_inv: np.ndarray,
                         innovation: np.ndarray) -> np.ndarray:
        """FastSLAM 2.0: x ~ N(μ, Σ), Σ = (P⁻¹ + Σ H_xᵀ S⁻¹ H_x)⁻¹, μ = x̂ + Σ Σ H_xᵀ S⁻¹ (z − ẑ).

        In the world frame (ν = R z + t − μ_m, S = Σ_m + R Q Rᵀ, the same d² and the same sums) the pose
        Jacobian is H = [[−1, 0, a], [0, −1, b], [0, 0, 0]] with (a, b) = (w_y, −w_x), w = μ_m − t: the height
        says nothing about a planar pose, so only the xy block U of S⁻¹ enters. predicted (M, 3); mean (3, P),
        s_inv (6, P) and innovation (3, P) of the matched pairs -> poses (M, 3).
        """
        n = len(predicted)
        a = mean[1] - predicted[:, 1][matched.m]
        b = predicted[:, 0][matched.m] - mean[0]
        u00, u01, u11 = s_inv[0], s_inv[1], s_inv[3]
        y0 = s_inv[0] * innovation[0] + s_inv[1] * innovation[1] + s_inv[2] * innovation[2]   # (S⁻¹ν)_x
        y1 = s_inv[1] * innovation[0] + s_inv[3] * innovation[1] + s_inv[4] * innovation[2]   # (S⁻¹ν)_y
        ua, ub = u00 * a + u01 * b, u01 * a + u11 * b
        terms = (u00, u01, -ua, u11, -ub, a * ua + b * ub, -y0, -y1, a * y0 + b * y1)   # HᵀS⁻¹H (6), HᵀS⁻¹ν (3)
        sums = np.stack([np.bincount(matched.m, t, minlength=n) for t in terms])
        p_motion = sym_components(self._motion_cov) + _TINY_POSE_VAR                 # P (6, M), never singular
        cov6 = sym_inverse(sym_inverse(p_motion) + sums[:6])                         # Σ = (P⁻¹ + ΣHᵀS⁻¹H)⁻¹
        mean_pose = predicted + sym_matvec(cov6, sums[6:]).T
        chol, ok = sym_cholesky(cov6)
        self._proposal_cov = sym_matrices(np.mean(cov6[:, ok], axis=1)[:, None])[0] if ok.any() else None
        ok &= np.all(np.isfinite(mean_pose), axis=1)
        if not np.all(ok):
            # a numerically indefinite proposal (an ill-conditioned S⁻¹ among the matches): that particle draws
            # from its motion model instead, which is always a valid (if less informed) proposal
            bad = np.flatnonzero(~ok)
            chol[:, bad] = sym_cholesky(p_motion[:, bad])[0]
            mean_pose[bad] = predicted[bad]
            self.stats.proposal_fallbacks += len(bad)
        sample = mean_pose + lower_matvec(chol, self.rng.standard_normal(predicted.shape).T).T
        sample[:, 2] = wrap_angle(sample[:, 2])
        return sample

    def _remap(self, pairs: Pairs) -> np.ndarray:
        """Flat slots of pairs after copy-on-write moved their blocks."""
        b = self.store.block_size
        table = self.store.table
        return np.take(table, pairs.m * table.shape[1] + pairs.k) * b + pairs.g % b

    def _ekf_update(self, matched: Pairs, predicted: np.ndarray, poses: np.ndarray, z: np.ndarray,
                    q6: np.ndarray, mean: np.ndarray, sigma: np.ndarray, s_inv: np.ndarray) -> np.ndarray:
        """Per matched pair: K = Σ Hᵀ S⁻¹ (H = Rᵀ), μ += K (z − ẑ), Σ = (I − KH) Σ (I − KH)ᵀ + K Q Kᵀ.

        mean (3, P), sigma (6, P): the landmarks before the update; ``s_inv`` (6, P): S⁻¹ from the gate, in the
        world frame at the predicted pose (S_w = Σ + R̂ Q R̂ᵀ), used as is by FastSLAM 1.0 (there the pose is the
        predicted one). FastSLAM 2.0 forms S_w = Σ + R Q Rᵀ afresh at the sampled pose (the paper's update), so
        K_w = Σ S_w⁻¹ is the optimal gain there: ‖K_w‖ ≤ 1 and Σ only shrinks. (An earlier shortcut reused the
        gate's S⁻¹ rotated by the proposal's turn, A = Δ S_w⁻¹ Δᵀ: for an elongated Σ (a landmark first seen
        from afar, depth σ ≫ lateral σ) a turn of 0.1 rad made K_w ≈ 10–20, moved landmarks metres and grew Σ
        a hundredfold per update until S⁻¹ was numerically indefinite and the proposal's Cholesky failed.)
        Computed in the world frame, ν_w = R z + t − μ at the sampled pose; K Q Kᵀ = K_w (R Q Rᵀ) K_wᵀ.
        Returns the landmarks' new planar positions (P, 2).
        """
        if len(matched.m) == 0:
            return np.zeros((0, 2))
        store = self.store
        pose = take_rows(poses, matched.m)
        c, s = cos_sin(poses, matched.m)
        zx, zy, zz = take_rows(z, matched.j).T
        nx, ny, nz = c * zx - s * zy + pose[:, 0] - mean[0], s * zx + c * zy + pose[:, 1] - mean[1], zz - mean[2]
        noise = sym_rotate_z(c, s, take_cols(q6, matched.j))       # R Q Rᵀ at the pose the update uses
        if self.config.version == 2:                                # S_w = Σ + R Q Rᵀ afresh at the sampled pose
            s_inv = sym_inverse(sigma + noise)
        gain = sym_product(sigma, s_inv)                            # K_w = Σ S_w⁻¹
        updated = np.empty((len(pose), 9))                          # mean (3) and covariance (6), one write
        for i in range(3):
            updated[:, i] = mean[i] + gain[i][0] * nx + gain[i][1] * ny + gain[i][2] * nz
        updated[:, 3:] = joseph_update(sigma, gain, noise).T
        store.put_state(matched.g, updated)
        store.flat_count[matched.g] += 1
        store.flat_misses[matched.g] = 0
        cfg = self.config
        ox, oy, _ = cfg.sensor_offset
        hit = hit_log_odds(cfg, np.hypot(zx - ox, zy - oy))        # the reading's own range (existence.py)
        store.flat_logodds[matched.g] = np.minimum(store.flat_logodds[matched.g] + hit, cfg.existence_max)
        return updated[:, :2]

    def _missed_in_view(self, cand: Pairs, poses: np.ndarray, matched: Pairs, by_id: bool = False,
                        reach: float | None = None) -> tuple[Pairs, np.ndarray]:
        """Candidate landmarks predicted well inside the view (``miss_fov_margin`` of the field of view and of
        the range) and not matched: negative evidence for their existence, with their predicted ranges from the
        sensor (P,). (``by_id``: ``matched`` are all the pairs of the id join, gated or not, whose ``c`` is not a
        candidate index; found by (particle, slot).)"""
        store = self.store
        if by_id:
            n = len(store.flat_lid)
            candidate = ~is_in(cand.m * n + cand.g, matched.m * n + matched.g)
        else:
            candidate = np.ones(len(cand.m), bool)
            candidate[matched.c] = False
        if len(cand.m) == 0:
            return cand.take(np.zeros(0, np.int64)), np.zeros(0)
        m, at = cand.m, cand.g * 9           # 1-D gathers of x, y, z from the 9-number slot records
        flat = store.state.reshape(-1)
        c, s = cos_sin(poses, m)
        dx, dy = np.take(flat, at) - np.take(poses[:, 0], m), np.take(flat, at + 1) - np.take(poses[:, 1], m)
        x, y = c * dx + s * dy, c * dy - s * dx
        # the planar half of the test first: most candidates are behind or beside the view (in bench_fastslam's
        # 10,000-landmark map ~2 % of them are well in view), and only those ahead need their height and range
        # (the matched ones are dropped here too: cheaper than selecting the others before any arithmetic)
        idx = np.flatnonzero(self._ahead_in_view(x, y) & candidate)
        x, y, at = x[idx], y[idx], at[idx]
        inside = np.flatnonzero(self._near_in_view(x, y, np.take(flat, at + 2), reach))
        ox, oy, _ = self.config.sensor_offset
        return cand.take(idx[inside]), np.hypot(x[inside] - ox, y[inside] - oy)

    def _check_self(self, best: int, matched: Pairs, missed: Pairs, named: Pairs | None, z: np.ndarray,
                    miss_weight: float) -> None:
        """The self-check's frame (self_check.py): the old landmarks particle ``best`` (the one step 8 picks)
        re-detected and missed well in view, before this frame's writes; "in view" within the frame's farthest
        observation ``z`` (N, 3) (a frame sees nothing beyond it: a near wall, a blind frame). ``named`` ("id"):
        every pair the readings' identities named; one the gate refused is a miss."""
        in_view = functools.partial(self._well_in_view, reach=float(np.max(self._sensor_range(z), initial=0.0)))
        hit = matched.g[matched.m == best]
        lost = missed.g[missed.m == best]
        if named is not None:
            lost = np.concatenate([lost, sorted_difference(named.g[named.m == best], hit)])
        pose, offset = self.poses[best], self.config.sensor_offset
        self.self_check.observe(self._time, slot_view(self.store, pose, hit, in_view, offset),
                                slot_view(self.store, pose, lost, in_view, offset), len(hit), self._n_ids, miss_weight)

    def _well_in_view(self, x: np.ndarray, y: np.ndarray, z: np.ndarray, reach: float | None = None) -> np.ndarray:
        """(P,) bool: base_link points (x, y, z each (P,)) inside ``miss_fov_margin`` of the field of view and
        of the range (:meth:`_ahead_in_view` and :meth:`_near_in_view`)."""
        return self._ahead_in_view(x, y) & self._near_in_view(x, y, z, reach)

    def _ahead_in_view(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """(P,) bool, the planar half of :meth:`_well_in_view`: beyond ``min_range`` in depth and inside
        ``miss_fov_margin`` of the horizontal field of view."""
        cfg = self.config
        ox, oy, _ = cfg.sensor_offset
        depth = x - ox
        ok = depth > cfg.min_range
        if cfg.fov_horizontal < 2 * np.pi:
            ok &= depth > 0
            ok &= within_angle(y - oy, depth, cfg.miss_fov_margin * 0.5 * cfg.fov_horizontal)
        return ok

    def _near_in_view(self, x: np.ndarray, y: np.ndarray, z: np.ndarray, reach: float | None = None) -> np.ndarray:
        """(P,) bool, the other half of :meth:`_well_in_view`: inside ``miss_fov_margin`` of the range (or of
        ``reach``) and of the vertical field of view."""
        cfg = self.config
        ox, oy, oz = cfg.sensor_offset
        depth, lateral, height = x - ox, y - oy, z - oz
        margin = cfg.miss_fov_margin
        max_range = cfg.max_range if reach is None else min(cfg.max_range, reach)
        ok = depth * depth + lateral * lateral + height * height < (margin * max_range) ** 2
        if cfg.fov_vertical < np.pi:
            ok &= within_angle(height, np.maximum(depth, 1e-9), margin * 0.5 * cfg.fov_vertical)
        return ok

    def _count_miss(self, missed: Pairs, ranges: np.ndarray, weight: float = 1.0) -> int:
        """Existence log-odds += a miss's worth (``existence.miss_log_odds`` at the landmarks' ranges (P,)) for
        landmarks missed in view; those falling below ``existence_remove`` are removed. Returns how many
        (particle, landmark) were removed."""
        if len(missed.g) == 0:
            return 0
        store, cfg = self.store, self.config
        store.flat_misses[missed.g] += 1
        store.flat_logodds[missed.g] += weight * miss_log_odds(cfg, ranges)
        drop = missed.g[store.flat_logodds[missed.g] < cfg.existence_remove]
        store.flat_lid[drop] = -1
        self.stats.landmarks_removed += len(drop)
        return len(drop)

    def _add_landmarks(self, had_candidate: np.ndarray, poses: np.ndarray, z, q6, desc,
                       lids: np.ndarray | None = None) -> tuple[np.ndarray, int]:
        """Landmarks (μ = R z + t, Σ = R Q Rᵀ) for every (particle, observation) with no gated candidate
        (``had_candidate`` (M·N,) bool, indexed m·N + j). ``lids`` (N,): the ids to give them ("id"
        association: the id its identity already has); None: fresh ids, one per spawning observation.

        Returns the id each observation's new landmarks got (N,) (-1: none) and how many were made in all.
        """
        n_obs = len(z)
        new_ids = np.full(n_obs, -1, np.int64)
        m, j = np.divmod(np.flatnonzero(~had_candidate), max(n_obs, 1))
        if len(m) == 0:
            return new_ids, 0
        spawning = np.flatnonzero(np.bincount(j, minlength=n_obs))   # np.unique(j) for j in [0, N), no sort
        if lids is None:
            new_ids[spawning] = self._n_ids + np.arange(len(spawning))
            self._append_descriptors(desc[spawning], z[spawning], float(poses[self._best, 2]))
        else:
            new_ids[spawning] = lids[spawning]
        g = self.store.append_slots(m)
        store = self.store
        pose = take_rows(poses, m)
        c, s = cos_sin(poses, m)
        zx, zy, zz = take_rows(z, j).T
        store.put_state(g, np.vstack([c * zx - s * zy + pose[:, 0], s * zx + c * zy + pose[:, 1], zz,
                                      sym_rotate_z(c, s, take_cols(q6, j))]).T)
        store.flat_lid[g] = new_ids[j]
        store.flat_count[g] = 1
        store.flat_misses[g] = 0
        cfg = self.config
        # the prior, plus (with the sensor's rates) the worth of the detection that made it (existence.py)
        first = 0.0 if not cfg.detection_probabilities else hit_log_odds(cfg, np.hypot(zx - cfg.sensor_offset[0],
                                                                                       zy - cfg.sensor_offset[1]))
        store.flat_logodds[g] = np.minimum(cfg.existence_initial + first, cfg.existence_max)
        store.include_in_bbox(g)
        return new_ids, len(m)

    # -- "id" association ------------------------------------------------------------------------------------
    def _lids_of_external(self, ids: np.ndarray) -> np.ndarray:
        """Internal landmark ids (N,) of observations' external ids (N,) (-1: not seen before)."""
        return np.array([self._lid_of_external.get(int(i), -1) for i in ids], np.int64)

    def _lids_for_new(self, ids: np.ndarray, lids: np.ndarray) -> np.ndarray:
        """``lids`` (N,) with a fresh internal id for every external id seen for the first time."""
        lids = lids.copy()
        fresh = np.flatnonzero(lids < 0)
        if len(fresh):
            lids[fresh] = self._n_ids + np.arange(len(fresh))
            for i, lid in zip(ids[fresh], lids[fresh], strict=True):
                self._lid_of_external[int(i)] = int(lid)
            self._append_descriptors(np.zeros((len(fresh), self.config.descriptor_size), np.float32))
            self._external_of_lid[lids[fresh]] = ids[fresh]
        return lids

    def _id_join(self, obs_lids: np.ndarray) -> tuple[Pairs, np.ndarray, np.ndarray, np.ndarray]:
        """"id" association: every (particle, observation) pair whose particle holds the landmark the observation
        names (``obs_lids`` (N,), -1: none yet), with the landmarks' means (3, P) and covariances (6, P), and
        ``holds`` (M·N,) bool indexed m·N + j. Scans the particles' block tables: no spatial preselection, so a
        named landmark is found however far the particle has drifted (the gate then judges it)."""
        store = self.store
        n_particles, n_obs = len(self.poses), len(obs_lids)
        holds = np.zeros(n_particles * n_obs, bool)
        width, b = store.table.shape[1], store.block_size
        known = obs_lids[obs_lids >= 0]
        if len(known) == 0 or int(store.n_blocks.max(initial=0)) == 0:
            return no_pairs(), np.zeros((3, 0)), np.zeros((6, 0)), holds
        obs_of_lid = np.full(self._n_ids, -1, np.int64)
        obs_of_lid[obs_lids[obs_lids >= 0]] = np.flatnonzero(obs_lids >= 0)   # update() keeps one per id
        phys = store.table                                                      # (M, W)
        lid = np.where((phys >= 0)[..., None], take_rows(store.lid, np.maximum(phys, 0).ravel()).reshape(
            n_particles, width, b), -1)
        flat = np.flatnonzero((lid >= 0).ravel())
        j = obs_of_lid[lid.ravel()[flat]]
        flat, j = flat[j >= 0], j[j >= 0]
        m, rest = np.divmod(flat, width * b)
        k, slot = np.divmod(rest, b)
        g = phys[m, k] * b + slot
        holds[m * n_obs + j] = True
        state = take_rows(store.flat_state, g).T
        pairs = Pairs(m, j, k, g, flat)
        return pairs, np.ascontiguousarray(state[:3]), np.ascontiguousarray(state[3:]), holds

    def external_ids(self, lids) -> np.ndarray:
        """External ids (L,) ("id" association: the observations' identities) of internal landmark ids (L,);
        -1 where a landmark has none (made in "unknown" association)."""
        lids = np.asarray(lids, np.int64)
        out = np.full(len(lids), -1, np.int64)
        inside = (lids >= 0) & (lids < len(self._external_of_lid))
        out[inside] = self._external_of_lid[lids[inside]]
        return out

    def _sensor_range(self, z: np.ndarray) -> np.ndarray:
        """Distance (N,) of points z (N, 3) in base_link from the sensor (sets a fixed-scale descriptor's scale)."""
        return np.linalg.norm(z - np.asarray(self.config.sensor_offset), axis=1)

    def _sight_bearing(self, z: np.ndarray, heading: float) -> np.ndarray:
        """World bearing (N,) of the lines of sight from the sensor to points z (N, 3) in base_link, for a robot
        heading ``heading`` (a descriptor's viewing direction; the sensor looks along the robot's x axis)."""
        ox, oy, _ = self.config.sensor_offset
        return heading + np.arctan2(z[:, 1] - oy, z[:, 0] - ox)

    def _append_descriptors(self, desc: np.ndarray, z: np.ndarray | None = None, heading: float = 0.0) -> None:
        """Descriptors (n, D) of n new ids, made from points ``z`` (n, 3) in base_link (None: view unknown) by a
        robot at ``heading``."""
        if self._bands is not None:   # only the bands need the view a descriptor was made from
            self._bands.append(desc, None if z is None else self._sensor_range(z),
                               None if z is None else self._sight_bearing(z, heading))
        need = self._n_ids + len(desc)
        if need > len(self._descriptors):
            grown = np.zeros((max(need, 2 * len(self._descriptors)), self._descriptors.shape[1]), np.float32)
            grown[: self._n_ids] = self._descriptors[: self._n_ids]
            self._descriptors = grown
        self._descriptors[self._n_ids:need] = desc
        self._external_of_lid = np.concatenate([self._external_of_lid, np.full(len(desc), -1, np.int64)])
        self._n_ids = need

    # == prior map ===========================================================================================
    def load_prior_map(self, landmark_map: LandmarkMap, cell_size: float = 4.0, external_ids=None) -> np.ndarray:
        """Give every particle the same starting map (a previous session's, or a known one), stored once.

        The landmarks (in this filter's start frame) are laid out in blocks cell by cell of a ``cell_size``
        grid, so each block is spatially compact and association touches only the blocks in view. Must be
        called before the first update. Returns the ids (N,) the filter gave the map's landmarks, in order.
        ``external_ids`` (N,) optional: each landmark's identity for ``association="id"`` (barcode, tag).
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
        if external_ids is not None:
            self._external_of_lid[ids] = np.asarray(external_ids, np.int64).reshape(n)
            self._lid_of_external.update({int(e): int(i) for i, e in zip(ids, self._external_of_lid[ids], strict=True)})
        store = self.store
        g = store.append_slots(np.zeros(n, np.int64))
        store.flat_mean[g] = landmark_map.positions[order]
        store.flat_cov[g] = sym_components(symmetrise(landmark_map.covariances[order])).T
        store.flat_lid[g] = ids[order]
        store.flat_count[g] = landmark_map.counts[order]
        store.flat_misses[g] = 0
        store.flat_logodds[g] = self.config.existence_max   # a given map's landmarks are established
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


def _weighted_pose_stats(poses: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean (3,) and covariance (3, 3) of poses (M, 3) with weights (M,), θ on the circle."""
    theta = np.arctan2(w @ np.sin(poses[:, 2]), w @ np.cos(poses[:, 2]))
    mean = np.array([w @ poses[:, 0], w @ poses[:, 1], theta])
    dev = poses - mean
    dev[:, 2] = wrap_angle(dev[:, 2])
    return mean, (dev * w[:, None]).T @ dev
