"""Settings of the FastSLAM filter (a frozen dataclass that can be dumped to JSON and read back)."""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

# FastSLAMConfig.id_relative_drift: how known-ID readings the gate rejects are judged again (id_gate.py)
ID_RELATIVE_DRIFT_MODES = ("off", "rescue", "consistent")
# FastSLAMConfig.unknown_relative_drift: re-association of old landmarks in "unknown" association (unknown_rescue.py)
UNKNOWN_RELATIVE_DRIFT_MODES = ("off", "consistent")
# FastSLAMConfig.unknown_association_rule: which gated landmark a reading takes in "unknown" association
UNKNOWN_ASSOCIATION_RULES = ("nearest", "sampled", "unambiguous")
# FastSLAMConfig.descriptor_slot_key: what a landmark's descriptor slots are kept by (appearance.SLOT_KEYS)
DESCRIPTOR_SLOT_KEYS = ("range", "direction", "range+direction")
# FastSLAMConfig.coincident_readings: readings of one frame that are one point (coincident.py)
COINCIDENT_RULES = ("all", "one_per_point", "no_twin_landmark")
# FastSLAMConfig.merge_estimate / merge_look: what a merge of two alike landmarks keeps (merging._merge_duplicates)
MERGE_ESTIMATES = ("fuse", "older")
MERGE_LOOKS = ("older", "newer")
# FastSLAMConfig.weight_evidence: which particles a reading's likelihood compares (shared_evidence.py)
WEIGHT_EVIDENCE_RULES = ("all", "shared_creation")
# FastSLAMConfig.drift_export: the known-ID range-bearing path's exported drift term (export_drift.py)
DRIFT_EXPORTS = ("plain", "lever", "lever+heading", "lever+heading+relative")

# Default virtual STH-MDCS2 (docs: STEREO_DEFAULTS): 640×480, f = 520 px, head at (0.12, 0, 0.50) in base_link.
_HFOV = 2.0 * math.atan(320.0 / 520.0)
_VFOV = 2.0 * math.atan(240.0 / 520.0)


@dataclass(frozen=True)
class FastSLAMConfig:
    """Every tunable of :class:`~estimation.fastslam.FastSLAM`.

    Motion noise is a random walk: the variance of each odometry increment grows linearly with the distance
    travelled and the angle turned (and, with ``odom_theta_var_per_s``, the heading's with the time it takes), so
    splitting one increment into several gives the same spread.
    """

    n_particles: int = 100
    version: int = 2                      # 1: FastSLAM 1.0 (motion proposal); 2: FastSLAM 2.0 (observation proposal)
    # -- motion model (odometry increments) --------------------------------------------------------------------
    odom_xy_var_per_m: float = 0.03 ** 2          # m² of along/across-track error per metre driven
    odom_theta_var_per_rad: float = 0.05 ** 2     # rad² of heading error per radian turned
    odom_theta_var_per_m: float = 0.02 ** 2       # rad² of heading error per metre driven
    odom_theta_var_per_s: float = 0.0             # rad² of heading error per second, moving or not (motion.py: needs
                                                  #   each increment's duration; noise_estimation fits it); 0: none
    odom_var_floor: float = 1e-8                  # added to every variance (keeps FastSLAM 2.0's P invertible)
    odom_turn_xy_inflation: float = 1.0           # × the x/y variance of an increment in a turn (motion.py: the
                                                  #   forward error of a turn is correlated; noise_estimation fits it)
    odom_heading_drift_sigma_per_m: float = 0.0   # σ_b rad/m: each particle carries a heading bias per metre b, a
    odom_heading_drift_tau_s: float = 0.0         #   Gauss–Markov process (stationary σ_b, correlation time τ s):
    #                                             #   b ← e^(−Δt/τ) b + σ_b √(1 − e^(−2Δt/τ)) ε per predict, the
    #                                             #   increment's heading + b × its distance (motion.py); 0: none
    anchor_first_frame: bool = True               # 2.0: a particle with an empty map takes the mean pose (see filter)
    anchor_unmatched: bool = False                # 2.0, with anchor_first_frame: so does one that matched nothing
    # -- data association -----------------------------------------------------------------------------------
    association: str = "unknown"                  # "unknown": descriptors + position; "id": observations' ids decide
    mahalanobis_gate: float = 11.345              # χ²(3 dof) at 99 %: squared Mahalanobis distance gate
    descriptor_threshold: float = 0.5             # max Euclidean distance between unit descriptors (paper's th)
    observation_var_floor: float = 0.02 ** 2      # m² added to each observation covariance (model error)
    observation_cov_scale: float = 1.0            # multiplies each observation covariance before the floor
    refresh_descriptors: bool = False             # a landmark's descriptor follows its latest match (best particle)
    max_observations: int = 40                    # per frame, keep only this many (see selection.py); 0: all
    coincident_readings: str = "all"              # readings of one frame that are one point (d² < χ²₃ 95 % under
    #                                             #   Q_i + Q_j): "all" used; "one_per_point": the most precise only;
    #                                             #   "no_twin_landmark": a twin of a matched one makes no landmark
    #                                             #   (coincident.py, docs "Session 9")
    observation_selection: str = "nearest"        # which: "nearest" (most precise) or "spread" (bearing × depth)
    # -- sensor footprint: landmark preselection and negative evidence --------------------------------------
    sensor_offset: tuple[float, float, float] = (0.12, 0.0, 0.50)  # head in base_link, metres
    fov_horizontal: float = _HFOV                 # rad; ≥ 2π means all round (range-bearing sensors)
    fov_vertical: float = _VFOV                   # rad
    min_range: float = 0.3                        # m, depth along the optical axis
    max_range: float = 12.0                       # m
    # -- landmark management: existence in log-odds (see filter.py, "Landmark management") ---------------------
    confirm_count: int = 3                        # maps export landmarks seen at least this often
    max_misses: int = 3                           # unused since existence log-odds (kept: old maps' settings load)
    miss_fov_margin: float = 0.85                 # only landmarks well inside the view (this fraction) count misses
    existence_initial: float = 0.0                # log-odds of a new landmark (p = 0.5: one sighting proves little)
    existence_hit: float = 1.0                    # added per detection (matched observation)
    existence_miss: float = -0.5                  # added per frame it was well in view and not detected
    existence_max: float = 4.0                    # clamp: a long-seen landmark that is gone is still removed in time
    existence_remove: float = -1.4                # removed below this (a new landmark: 3 misses, no detection)
    # the sensor's rates instead of existence_hit/miss (see existence.py): P_D per range band, P_FA
    detection_probabilities: tuple[float, ...] = ()   # P_D per band; () = use existence_hit / existence_miss
    detection_range_edges: tuple[float, ...] = ()     # m, ascending: len(detection_probabilities) - 1 edges
    false_alarm_probability: float = 0.05             # P_FA: share of reports that are no landmark
    detection_correlation: float = 0.0                # lag-1 correlation of a landmark's detected/missed frames
    merge_gate: float = 7.815                     # merge a particle's landmarks closer than this squared
    #                                             #   Mahalanobis distance (χ²₃ 95 %; and alike, see below); 0: off
    merge_radius: float = 1.0                     # m: ids whose means are farther apart are never tested
    merge_every: int = 5                          # updates between merge passes (over the ids touched since)
    merge_descriptor_threshold: float = 0.5       # descriptor distance allowed between merged landmarks (0.8
    #                                             #   merged more duplicates but also distinct corners: docs)
    merge_covisibility: bool = False              # two landmarks ever detected in one frame are never merged, and
    #                                             #   two never co-detected are merged on that evidence (filter);
    #                                             #   for sensors that report an object once a frame (posts, tags),
    #                                             #   not corners: one texture blob gives two (docs, "Duplicates")
    merge_log_odds: float = 2.944                 # evidence "one point" needed for that merge: log 19 (P = 0.95
    #                                             #   from even odds), in existence.exclusive_log_odds units
    merge_estimate: str = "fuse"                  # a merge of alike landmarks: "fuse" them as two independent
    #                                             #   estimates; "older": the older keeps its estimate (the newer
    #                                             #   sits off by the pose's drift since, docs "Session 10")
    merge_look: str = "older"                     # the merged landmark's descriptor: the older one's, or "newer":
    #                                             #   the look at the range it is seen from now (U-SURF changes)
    export_merge_coincident: bool = True          # "unknown": the exported map merges landmarks that coincide
    #                                             #   under the particle's own covariances (export_merge.py; the
    #                                             #   filter untouched). Default since session 17 (rendered: 22-25 %
    #                                             #   duplicates -> 4-8 %, NEES unchanged; demo found 5 -> 6 of 10)
    merge_relative_drift: bool = False            # "unknown", with merge_covisibility: also merge two landmarks never
    #                                             #   detected in one frame that are one point under Σ_a + Σ_b plus
    #                                             #   the pose's drift between their creations (drift_merge.py)
    id_relative_drift: str = "off"                # "id", 2.0: judge readings with the pose's drift relative to their
    #                                             #   landmark (drift.py) where the gate rejects them: "off",
    #                                             #   "rescue" or "consistent" (two landmarks at once); id_gate.py
    # -- resampling and storage ------------------------------------------------------------------------------
    resample_threshold: float = 0.5               # resample when ESS < threshold · n_particles
    weight_evidence: str = "all"                  # "id": "shared_creation" weighs a reading only between particles
    #                                             #   that made its landmark in one creation (shared_evidence.py);
    #                                             #   "unknown" association ignores it (ids are per particle)
    block_size: int = 64                          # landmarks per copy-on-write block
    descriptor_size: int = 64
    descriptor_slots: int = 1                     # descriptors a landmark keeps, each with the view (range, and
    #                                             #   direction: descriptor_slot_key) it was made from; an
    #                                             #   observation is compared with the one of the nearest view
    #                                             #   (appearance.py: U-SURF changes with distance); 1: the first only
    descriptor_slot_ratio: float = 1.25           # a matched sighting from a range more than this factor from every
    #                                             #   kept one is kept too (while a slot is free)
    descriptor_slot_key: str = "range"            # with descriptor_slots > 1, what a slot's view is: "range",
    #                                             #   "direction" (the line of sight's world bearing, best particle)
    #                                             #   or "range+direction" (a new view if either steps; appearance.py)
    descriptor_slot_angle: float = 0.3            # rad: a matched sighting from a direction more than this from
    #                                             #   every kept one is kept too ("direction" keys)
    descriptor_learn_gate: float = 0.0            # > 0: only a match of a confirmed landmark with d² below this,
    #                                             #   and the reading's only candidate in the best particle (no
    #                                             #   other landmark passes descriptor and gate), teaches a new look;
    #                                             #   0: every match of the best particle (session 6's rule)
    unknown_relative_drift: str = "off"           # "unknown", 2.0: "consistent" re-associates old landmarks the gate
    #                                             #   rejects where one drift correction explains two of them
    #                                             #   jointly, each with a unique candidate (unknown_rescue.py)
    self_check_false_alarm: float = 1e-5          # self_check.py: false flags "the map lost its place" per frame
    #                                             #   (CUSUM threshold ln(1/α)); the check never changes estimates
    id_drift_inherit: bool = False                # with id_relative_drift: landmarks re-measured in a frame anchored
    #                                             #   on an older one take D_a + P_local (id_gate.RelativeGate.inherit);
    #                                             #   off: landmarks within the NEES bound fell (docs, "Session 7")
    drift_lever: bool = True                      # the drift tracker carries a matched landmark's creation-pose
    #                                             #   covariance to the robot with the heading's lever arm
    #                                             #   (lever_drift.py); export and D_r only on the stereo path.
    #                                             #   False: the rule before session 8, which dropped the lever
    observation_correlation: float = 0.49         # lag-1 correlation of a landmark's successive observation
    #                                             #   errors (AR(1)); the export multiplies each landmark's EKF
    #                                             #   covariance by lever_drift.correlated_mean_factor; estimates
    #                                             #   unchanged. 0.49: measured on the stereo front end's rendered
    #                                             #   frames (0.47-0.49 on four runs; docs/fastslam-history.md "Session
    #                                             #   8: honest covariances"); 0: the EKF's independence taken as given
    drift_export: str = "plain"                   # "id" association without drift_lever only (drift_lever's
    #                                             #   tracker exports the lever itself; "unknown" keeps the
    #                                             #   plain tracker, whose C_l its merges read): "lever" exports
    #                                             #   the landmarks' drift term with the heading's lever;
    #                                             #   "lever+heading" also keeps the heading through frames that
    #                                             #   match one landmark; "lever+heading+relative" also the
    #                                             #   mean drift of the poses that re-sighted a landmark relative
    #                                             #   to the one that made it, the landmark's shape part (export_
    #                                             #   drift.py, docs "Session 14 ... (J)"); the gate, so every
    #                                             #   estimate, unchanged. range_bearing_config's choice since
    #                                             #   session 14 ("lever+heading+relative"): MRCLAM within the NEES
    #                                             #   bound 23-86 % (plain) -> 57-100 % -> 79-100 %
    #                                             #   (docs/fastslam-history.md "Session 13 ... (N)", "Session 14 ...
    #                                             #   (J)")
    drift_translation_per_m: float = 0.0          # with drift_lever: m² per axis per metre the robot's position
    #                                             #   walks from the pose that made the landmarks it is pinned to
    #                                             #   (lever_drift.py); export and D_r only on the stereo path
    drift_local_empirical: bool = True            # the drift's local pose covariance takes the position variance
    #                                             #   of the frame's matched residuals' mean, × f(n, ρ)/n of the
    #                                             #   landmarks' sightings, where larger than the proposal's
    #                                             #   (lever_drift.with_empirical_position): measured online,
    #                                             #   unlike drift_translation_per_m; export and D_r only.
    #                                             #   Default since session 9 (rendered seeds 0-3 x 2 robots: 93-95 %
    #                                             #   of landmarks within the NEES bound, was 72-94 %)
    unknown_association_rule: str = "nearest"     # "unknown": each reading takes the nearest gated landmark
    #                                             #   ("nearest", maximum likelihood); or per particle one drawn in
    #                                             #   proportion to its likelihood, a new landmark among them
    #                                             #   ("sampled"); or the nearest only if its posterior among the
    #                                             #   gated ones is ≥ 0.99, else unused ("unambiguous");
    #                                             #   association_rules.py, docs "Session 8"
    detection_in_weight: bool = False             # "unknown": a particle's weight also carries its map's detection
    #                                             #   likelihood, P_D per landmark detected and 1 − P_D per one
    #                                             #   missed well in view (negative information; detection_term.py,
    #                                             #   docs "Session 9")

    def __post_init__(self) -> None:
        if self.n_particles < 1:
            raise ValueError(f"n_particles must be ≥ 1, not {self.n_particles}")
        if self.version not in (1, 2):
            raise ValueError(f"version must be 1 or 2, not {self.version}")
        if self.block_size < 1 or self.descriptor_size < 0:
            raise ValueError("block_size must be ≥ 1 and descriptor_size ≥ 0")
        if self.observation_selection not in ("spread", "nearest"):
            raise ValueError(f"observation_selection must be 'spread' or 'nearest', not {self.observation_selection!r}")
        if not (math.isfinite(self.odom_theta_var_per_s) and self.odom_theta_var_per_s >= 0.0):
            raise ValueError(f"odom_theta_var_per_s must be finite and ≥ 0, not {self.odom_theta_var_per_s}")
        if not self.odom_turn_xy_inflation >= 1.0:
            raise ValueError(f"odom_turn_xy_inflation must be ≥ 1, not {self.odom_turn_xy_inflation}")
        drift_sigma, drift_tau = self.odom_heading_drift_sigma_per_m, self.odom_heading_drift_tau_s
        if not (math.isfinite(drift_sigma) and drift_sigma >= 0.0 and math.isfinite(drift_tau) and drift_tau >= 0.0):
            raise ValueError(f"odom_heading_drift_sigma_per_m and odom_heading_drift_tau_s must be finite and ≥ 0, "
                             f"not {drift_sigma} and {drift_tau}")
        if drift_sigma > 0.0 and not drift_tau > 0.0:
            raise ValueError(f"odom_heading_drift_tau_s must be > 0 when odom_heading_drift_sigma_per_m is > 0, "
                             f"not {drift_tau}")
        if not self.observation_cov_scale > 0.0:
            raise ValueError(f"observation_cov_scale must be > 0, not {self.observation_cov_scale}")
        if not self.merge_log_odds > 0.0:
            raise ValueError(f"merge_log_odds must be > 0, not {self.merge_log_odds}")
        if self.descriptor_slots < 1 or not self.descriptor_slot_ratio > 1.0:
            raise ValueError(f"descriptor_slots must be ≥ 1 and descriptor_slot_ratio > 1, not "
                             f"{self.descriptor_slots} and {self.descriptor_slot_ratio}")
        if self.descriptor_slot_key not in DESCRIPTOR_SLOT_KEYS:
            raise ValueError(f"descriptor_slot_key must be one of {', '.join(DESCRIPTOR_SLOT_KEYS)}, "
                             f"not {self.descriptor_slot_key!r}")
        if not 0.0 < self.descriptor_slot_angle <= math.pi:
            raise ValueError(f"descriptor_slot_angle must be in (0, π] rad, not {self.descriptor_slot_angle}")
        if not (math.isfinite(self.descriptor_learn_gate) and self.descriptor_learn_gate >= 0.0):
            raise ValueError(f"descriptor_learn_gate must be finite and ≥ 0, not {self.descriptor_learn_gate}")
        if self.merge_relative_drift and not self.merge_covisibility:
            raise ValueError("merge_relative_drift needs merge_covisibility (which pairs were detected in one frame)")
        if self.merge_every < 1:
            raise ValueError(f"merge_every must be ≥ 1, not {self.merge_every}")
        if self.id_relative_drift not in ID_RELATIVE_DRIFT_MODES:
            raise ValueError(f"id_relative_drift must be one of {', '.join(ID_RELATIVE_DRIFT_MODES)}, "
                             f"not {self.id_relative_drift!r}")
        if self.unknown_relative_drift not in UNKNOWN_RELATIVE_DRIFT_MODES:
            raise ValueError(f"unknown_relative_drift must be one of {', '.join(UNKNOWN_RELATIVE_DRIFT_MODES)}, "
                             f"not {self.unknown_relative_drift!r}")
        if self.unknown_association_rule not in UNKNOWN_ASSOCIATION_RULES:
            raise ValueError(f"unknown_association_rule must be one of {', '.join(UNKNOWN_ASSOCIATION_RULES)}, "
                             f"not {self.unknown_association_rule!r}")
        if self.association not in ("unknown", "id"):
            raise ValueError(f"association must be 'unknown' or 'id', not {self.association!r}")
        if not (self.existence_remove < self.existence_initial <= self.existence_max and self.existence_hit >= 0
                and self.existence_miss <= 0):
            raise ValueError("existence log-odds need existence_remove < existence_initial <= existence_max, "
                             "existence_hit >= 0 and existence_miss <= 0")
        object.__setattr__(self, "detection_probabilities", tuple(float(v) for v in self.detection_probabilities))
        object.__setattr__(self, "detection_range_edges", tuple(float(v) for v in self.detection_range_edges))
        if self.detection_probabilities:
            edges, p_d = self.detection_range_edges, self.detection_probabilities
            if len(edges) != len(p_d) - 1 or any(b <= a for a, b in zip(edges, edges[1:], strict=False)):
                raise ValueError("detection_range_edges must be ascending, one fewer than detection_probabilities")
            if not (all(0.0 < p < 1.0 for p in p_d) and 0.0 < self.false_alarm_probability < 1.0):
                raise ValueError("detection_probabilities and false_alarm_probability must lie in (0, 1)")
        if not 0.0 <= self.detection_correlation < 1.0:
            raise ValueError(f"detection_correlation must lie in [0, 1), not {self.detection_correlation}")
        if not 0.0 < self.self_check_false_alarm < 1.0:
            raise ValueError(f"self_check_false_alarm must lie in (0, 1), not {self.self_check_false_alarm}")
        if self.merge_estimate not in MERGE_ESTIMATES:
            raise ValueError(f"merge_estimate must be one of {', '.join(MERGE_ESTIMATES)}, not {self.merge_estimate!r}")
        if self.merge_look not in MERGE_LOOKS:
            raise ValueError(f"merge_look must be one of {', '.join(MERGE_LOOKS)}, not {self.merge_look!r}")
        if self.coincident_readings not in COINCIDENT_RULES:
            raise ValueError(f"coincident_readings must be one of {', '.join(COINCIDENT_RULES)}, "
                             f"not {self.coincident_readings!r}")
        if self.drift_export not in DRIFT_EXPORTS:
            raise ValueError(f"drift_export must be one of {', '.join(DRIFT_EXPORTS)}, not {self.drift_export!r}")
        if not self.drift_translation_per_m >= 0.0:
            raise ValueError(f"drift_translation_per_m must be ≥ 0, not {self.drift_translation_per_m}")
        if not 0.0 <= self.observation_correlation < 1.0:
            raise ValueError(f"observation_correlation must lie in [0, 1), not {self.observation_correlation}")
        if self.weight_evidence not in WEIGHT_EVIDENCE_RULES:
            raise ValueError(f"weight_evidence must be one of {', '.join(WEIGHT_EVIDENCE_RULES)}, "
                             f"not {self.weight_evidence!r}")
        if not 0.0 <= self.resample_threshold <= 1.0:
            raise ValueError(f"resample_threshold must be in [0, 1], not {self.resample_threshold}")
        object.__setattr__(self, "sensor_offset", tuple(float(v) for v in self.sensor_offset))

    def to_dict(self) -> dict:
        """Plain JSON-ready values (tuples as lists), e.g. for a map's metadata."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, values: dict) -> FastSLAMConfig:
        """Inverse of :meth:`to_dict`; unknown keys raise ``ValueError`` naming them."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"unknown FastSLAM setting(s): {', '.join(unknown)}")
        return cls(**values)


def range_bearing_config(**overrides) -> FastSLAMConfig:
    """A configuration for planar range-bearing sensors (all-round view, sensor at the robot's origin).

    Known-ID readings that the gate rejects in a particle are judged with the pose's drift since their landmark
    was made, and two such landmarks in one frame correct the pose (``id_relative_drift="consistent"``,
    id_gate.py; MRCLAM: docs/fastslam-history.md, "Session 6"). With known IDs the exported landmark covariances carry
    the heading's lever, keep the heading through one-landmark frames and count the re-sighting poses' drift relative to
    each landmark's creation (``drift_export="lever+heading+relative"``, export_drift.py; MRCLAM:
    docs/fastslam-history.md, "Session 14")."""
    values = dict(sensor_offset=(0.0, 0.0, 0.0), fov_horizontal=2 * math.pi, fov_vertical=math.pi,
                  min_range=0.0, max_range=30.0, descriptor_size=0, mahalanobis_gate=11.345,
                  merge_covisibility=True,   # such a sensor reports each object at most once a frame
                  id_relative_drift="consistent",
                  # the drift feeds the known-ID gate here, so the lever would change estimates, not only what the
                  # export claims (not measured on MRCLAM); the AR(1) factor was measured on stereo frames only,
                  # and so was the empirical drift (it too would feed the gate here)
                  drift_lever=False, observation_correlation=0.0, drift_local_empirical=False,
                  # known-ID only (export_drift.py): the plain tracker's reset drops the heading's lever and takes
                  # the heading from one-landmark frames, and no tracker counted the re-sighting poses' drift
                  # relative to the landmark's creation (its shape part); the export carries all three, estimates
                  # unchanged
                  drift_export="lever+heading+relative")
    values.update(overrides)
    return FastSLAMConfig(**values)
