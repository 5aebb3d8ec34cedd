"""Map alignment: the transformation between two landmark maps by RANSAC (Section 3.1 of the ISR 2009 paper).

Convention.  The result ``pose = (tx, ty, θ)`` is the pose of map 2's frame (robot 2's start) in map 1's
frame, REP-103, θ counter-clockwise: a map-2 point p' lies at ``p = R(θ) p' + t`` in map 1 (z unchanged),
so ``pose`` composes with :mod:`estimation.geometry` and equals ``between(start1, start2)`` for true start
poses in a common world frame.  ``Alignment.matrix`` is the 4×4 homogeneous transform of eq. 5 in the
column-vector convention (``p_h = T @ p'_h``; rotation block ``[[c, -s], [s, c]]``, translation in the
last column).

Where the code departs from the text, and why:

* Eq. 1 compares the wrong sums ((A² + C²) vs (B² + D²) mixes the two maps' x and y differences).  The
  intended rigid-motion check is that the distance between the two landmarks is preserved:
  ``|d'² − d²| < th1`` with ``d'² = A² + B²`` (map 2) and ``d² = C² + D²`` (map 1).  Note that th1 = 2 "m"
  in the text is then a tolerance on squared distances (m²); the paper preset keeps the number.
* Eqs. 2–4 are consistent with each other only for θ measured the other way round (the text's matrix of
  eq. 5, written for row vectors, rotates by −θ).  We report θ = −θ_text so that (tx, ty, θ) is a pose;
  tx, ty are unchanged.  Eq. 4 uses the quadrant-safe ``atan2(AD − BC, AC + BD)`` — a plain arctangent
  of the ratio loses half the circle.
* Step 1 with th0 = 2: descriptors are unit vectors, so descriptor distances lie in [0, 2] and th0 = 2
  accepts every nearest neighbour; the paper preset keeps it (the text's behaviour) and the robust preset
  replaces it with a ratio test, mutual best matches and a real distance gate.
* Maps whose landmarks carry external identities (``metadata["external_ids"]``: barcodes, fiducials, as
  known-ID FastSLAM writes them) pair equal identities in step 1; a duplicated identity gives several
  candidate pairs, and supports count one-to-one.
* Maps without descriptors (range-bearing landmark maps built without IDs): step 1 has nothing to compare,
  so every landmark of map 1 is a candidate for every landmark of map 2 (n1·n2 candidate pairs), and a
  support counts once per landmark (one-to-one), whatever the preset.

The ``robust`` preset further adapts the iteration count to the inlier ratio, refines the winning
hypothesis by weighted least squares (Gauss–Newton) on all supports, re-gates them, and reports the
alignment's 3×3 covariance.  Its support gate is the two landmarks' combined covariance, floored at
``min_gate`` and inflated by the supports' own residual scale (``gate_inflation``: the median normalised
squared residual over its χ²₂ median), because FastSLAM's per-particle landmark covariances leave the
robot's pose error out and can be ten times too small; with honest start-frame covariances, whose shared drift the
transform removes, the same scale narrows it (``gate_scale="residual"``, :mod:`fusion.gate_scale`).  It decides
that the maps overlap only on the alignment's own evidence (:mod:`fusion.evidence`): the supports beyond the two that
define a hypothesis are compared with the number a wrong transform gathers by chance on *these* maps — measured
by scoring decoy transforms with the same gate (landmark density, clustering along walls, map sizes) and by the best
hypothesis distinct from the winner (repeated structure: a corridor of identical doors) — giving a
false-alarm probability, Bonferroni-corrected for the hypotheses tried; the supports must also be spread
out (a bunch in one spot fixes no angle).  The number of supports needed therefore adapts to the maps.

A found alignment with a start prior also says whether the maps alone would find it: the winner's evidence
measured again without the prior (:mod:`fusion.prior_backing`).

This module holds the configuration, the results and the entry points (:func:`align`, :func:`align_at`); steps 1–3
(correspondences, hypotheses, the search and the refinement) are in :mod:`fusion.ransac`, the evidence in
:mod:`fusion.evidence`, the evidence without the start prior in :mod:`fusion.prior_backing`.
"""
from __future__ import annotations

import copy
from dataclasses import asdict, dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from estimation.geometry import between, inverse, pose_to_matrix, transform_points, wrap_angle
from estimation.landmark_map import LandmarkMap

from .alignment_config import AlignmentConfig, resolve_preset
from .colocation import colocation_test
from .errors import IncompatibleMapsError, NoOverlapError
from .evidence import (
    Evidence,
    decoy_null,
    evidence,
    log10_false_alarm,
    rival_offset,
)
from .frame_covariance import start_frame_covariance
from .matching import query_subset, search_workspace
from .pose_covariance import inverse_with_covariance
from .prior_backing import prior_backing_text, self_repeat_counted_once, without_prior_statistics
from .ransac import (
    CHI2_999,
    MAX_GEOMETRIC_PAIRS,
    CorrespondenceProblem,
    correspondence_problem,
    has_descriptors,
    landmark_identities,
    polish,
    putative_correspondences,
    ransac,
    refine_pose,
)

if TYPE_CHECKING:
    from .cache import AlignmentCache
    from .prior import StartPrior


@dataclass(frozen=True)
class AlignmentStatistics:
    """How the alignment was reached and how much it can be trusted (counts refer to the putative
    correspondences; supports are one-to-one)."""

    correspondences: int = 0             # putative correspondences (n1·n2 without descriptors)
    iterations: int = 0                  # hypotheses evaluated
    supports: int = 0
    inlier_ratio: float = 0.0            # supports / correspondences
    residual_rms: float = float("nan")   # metres, 3-D, over the supports
    expected_chance_supports: float = float("nan")  # supports a wrong hypothesis gathers (its 2 included)
    log10_chance_probability: float = float("nan")  # log10 false-alarm probability (Bonferroni-corrected)
    support_spread: float = 0.0          # metres, principal std of the supports in map 1 (xy), major axis
    support_spread_minor: float = 0.0    # metres, minor axis (≈ 0: the supports lie on a line)
    second_best_supports: int = 0        # best hypothesis distinct from the winner (repeated structure)
    self_repeat_supports: int = 0        # best non-identity transform of either map onto itself (self_structure)
    required_supports: int = 0           # fewest supports that would have been accepted on these maps
    # the second-best hypothesis against the winner: |Δθ| (rad), the RMS distance (m) by which it moves the winner's
    # supports, and the median descriptor distance of each one's supports (nan: none, or maps not matched by
    # descriptors) -- what a user needs to see why a pair is ambiguous
    second_best_turn: float = float("nan")
    second_best_shift: float = float("nan")
    support_descriptor_distance: float = float("nan")
    second_best_descriptor_distance: float = float("nan")
    gate_inflation: float = 1.0          # covariance scale the supports' residuals called for
    gate_radius: float = float("nan")    # metres, median support-gate radius in the plane
    descriptors: bool = True             # False: maps without descriptors, geometry alone
    second_best_pose: tuple = ()         # (tx, ty, θ) of the second-best hypothesis (empty: none)
    # with a start prior (fusion.prior): the winner's χ² against it, the hypotheses tried inside it (the Bonferroni
    # factor), and the supports of the best hypothesis outside it (not a rival; nan / 0 without a prior)
    prior_chi2: float = float("nan")
    prior_hypotheses: int = 0
    outside_prior_supports: int = 0
    # with AlignmentConfig.colocation (fusion.colocation): what the test did or why there was none ('' when off), and
    # the supports of the best distinct hypothesis it removed (0: none)
    colocation: str = ""
    colocation_removed_supports: int = 0
    # a found alignment with a start prior: what the maps alone decide (the evidence measured again without the prior,
    # as align(prior=None) measures it; fusion.prior_backing). prior_decides: "" (no prior, not found, or the maps
    # alone find it too), "ambiguous" (a distinct transform the prior excluded or discounted is a rival), "repeat" (a
    # map's repeat of itself), "chance" (too few supports for the hypotheses tried without the prior). The rival:
    # supports, pose (map 1's frame), the RMS distance (m) by which it moves the winner's supports and its turn (rad)
    # from the winner, and whether the prior excludes it. nan / 0 / () / False: not measured
    prior_decides: str = ""
    without_prior_log10_chance_probability: float = float("nan")
    without_prior_required_supports: int = 0
    without_prior_hypotheses: int = 0
    without_prior_rival_supports: int = 0
    without_prior_rival_pose: tuple = ()
    without_prior_rival_shift: float = float("nan")
    without_prior_rival_turn: float = float("nan")
    without_prior_rival_outside: bool = False

    @property
    def prior_backed(self) -> bool:
        """Found only because of the start prior: the maps alone would not find it (``prior_decides``)."""
        return bool(self.prior_decides)

    @property
    def false_alarm_probability(self) -> float:
        """Probability that maps which do not overlap give this much support (nan if not evaluated)."""
        return float(10.0 ** self.log10_chance_probability) if np.isfinite(self.log10_chance_probability) \
            else float("nan")

    def to_dict(self) -> dict:
        out = {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in asdict(self).items()}
        p = self.false_alarm_probability
        out["false_alarm_probability"] = None if not np.isfinite(p) else p
        out["prior_backed"] = self.prior_backed
        return out


@dataclass(frozen=True)
class Alignment:
    """Result of aligning map 2 to map 1.

    found: whether the maps overlap (if False, ``pose`` and ``covariance`` are None, ``reason`` says why and
    ``supports`` holds the best rejected hypothesis' supports, for diagnostics);
    pose (3,) (tx, ty, θ) of map 2's frame in map 1's frame; covariance (3, 3) or None (paper preset): the
    alignment's own precision (placing one map on the other; what merging adds to map 2's landmarks);
    start_covariance (3, 3) or None: its uncertainty against the true relative pose of the two start frames,
    each map's landmark errors taken as possibly moving together at the overlap (``frame_covariance``);
    supports (S, 2) int64 rows (landmark index in map 1, landmark index in map 2).
    """

    found: bool
    preset: str
    pose: np.ndarray | None
    covariance: np.ndarray | None
    supports: np.ndarray
    statistics: AlignmentStatistics = field(default_factory=AlignmentStatistics)
    reason: str = ""
    start_covariance: np.ndarray | None = None
    prior: StartPrior | None = None      # the start prior the decision used (fusion.prior), or None

    @classmethod
    def from_pose(cls, pose, covariance=None, supports=None, preset: str = "given") -> Alignment:
        """An alignment known from elsewhere (e.g. calibrated start poses); supports (S, 2) optional."""
        sup = np.zeros((0, 2), np.int64) if supports is None else np.asarray(supports, np.int64).reshape(-1, 2)
        cov = None if covariance is None else np.asarray(covariance, float).reshape(3, 3)
        return cls(True, preset, np.asarray(pose, float).reshape(3), cov, sup,
                   AlignmentStatistics(supports=len(sup)), start_covariance=cov)

    @property
    def prior_backing(self) -> str:
        """'' for an alignment the maps' own evidence finds (or not found); for one found only because of its start
        prior, why the maps alone do not decide it, beginning 'found with the prior: '
        (:func:`fusion.prior_backing.prior_backing_text`)."""
        return prior_backing_text(self.statistics) if self.found else ""

    @property
    def matrix(self) -> np.ndarray:
        """The 4×4 transform of eq. 5 in column-vector form: map-1 point = T @ map-2 point (homogeneous)."""
        return pose_to_matrix(self.require().pose)

    @property
    def tx(self) -> float:
        return float(self.require().pose[0])

    @property
    def ty(self) -> float:
        return float(self.require().pose[1])

    @property
    def theta(self) -> float:
        return float(self.require().pose[2])

    def require(self) -> Alignment:
        """This alignment, or :class:`NoOverlapError` if none was found."""
        if not self.found:
            raise NoOverlapError(f"the maps do not overlap: {self.reason}")
        return self

    def inverse(self) -> Alignment:
        """The alignment of map 1 to map 2 (pose inverted, covariance propagated, support columns swapped)."""
        if not self.found:
            return replace(self, supports=self.supports[:, ::-1].copy(),
                           prior=None if self.prior is None else self.prior.inverse())
        cov, start_cov = self.covariance, self.start_covariance
        pose = inverse(self.pose)
        if cov is not None:
            cov = inverse_with_covariance(self.pose, cov)[1]
        if start_cov is not None:
            start_cov = inverse_with_covariance(self.pose, start_cov)[1]
        return replace(self, pose=pose, covariance=cov, start_covariance=start_cov,
                       supports=self.supports[:, ::-1].copy(),
                       prior=None if self.prior is None else self.prior.inverse())

    def to_dict(self) -> dict:
        """JSON-friendly summary (supports as a list of index pairs)."""
        return {
            "found": self.found, "preset": self.preset, "reason": self.reason,
            "pose": None if self.pose is None else [float(v) for v in self.pose],
            "covariance": None if self.covariance is None else self.covariance.tolist(),
            "start_covariance": None if self.start_covariance is None else self.start_covariance.tolist(),
            "supports": self.supports.tolist(), "statistics": self.statistics.to_dict(),
            "prior": None if self.prior is None else self.prior.to_dict(),
            "rests_on_prior": self.prior_backing or None,
        }


# -- ground truth ----------------------------------------------------------------------------------------
def true_relative_pose(map1: LandmarkMap, map2: LandmarkMap) -> np.ndarray | None:
    """between(true start 1, true start 2) from ``metadata["true_start_pose"]``, or None if either lacks it, or if
    the two starts' headings come from different truths (:func:`truth_heading`: a motion capture's markers against
    the direction of travel differ by up to 0.017 rad on MRCLAM, which would be scored as the alignment's error)."""
    if truth_heading(map1) != truth_heading(map2):
        return None
    try:
        start1 = np.asarray(map1.metadata["true_start_pose"], float).reshape(3)
        start2 = np.asarray(map2.metadata["true_start_pose"], float).reshape(3)
    except (KeyError, TypeError, ValueError):
        return None
    return between(start1, start2)


def truth_heading(landmark_map: LandmarkMap) -> str:
    """Which heading the map's ``true_start_pose`` holds: ``metadata["truth_heading"]`` (``p3at slam dataset
    --truth-heading``), "mocap" (as the truth wrote it) for maps that do not say."""
    value = landmark_map.metadata.get("truth_heading", "mocap")
    return value if isinstance(value, str) else repr(value)


def alignment_error(pose, true_pose) -> np.ndarray:
    """|Δtx|, |Δty|, |Δθ| (θ wrapped) of an estimated (tx, ty, θ) against the truth -> (3,)."""
    d = np.asarray(pose, float) - np.asarray(true_pose, float)
    return np.abs(np.array([d[0], d[1], wrap_angle(d[2])]))


def alignment_error_xy_theta(pose, true_pose) -> tuple[float, float]:
    """(error xy (m), error θ (rad)): the translation error's length and |Δθ| wrapped, the demo's columns."""
    e = alignment_error(pose, true_pose)
    return float(np.hypot(e[0], e[1])), float(e[2])



# -- what an ambiguous pair reports ----------------------------------------------------------------------------
# A rival turned by more than this is reported as a half turn (a building symmetric under a half turn).
HALF_TURN = 2.8
DISAMBIGUATION = ("to tell them apart: more common landmarks outside the repeated part (a longer shared route), "
                  "landmarks with identities (fiducials), or a rough relative start of the robots")


def _median_descriptor_distance(map1: LandmarkMap, map2: LandmarkMap, pairs: np.ndarray) -> float:
    if len(pairs) == 0:
        return float("nan")
    d = map1.descriptors[pairs[:, 0]].astype(np.float32) - map2.descriptors[pairs[:, 1]]
    return float(np.median(np.linalg.norm(d, axis=1)))


def _rival_figures(map1: LandmarkMap, map2: LandmarkMap, pairs: np.ndarray, pose: np.ndarray, mask: np.ndarray,
                   problem: CorrespondenceProblem, ev: Evidence, compare_descriptors: bool) -> dict:
    """The AlignmentStatistics fields that describe the second-best hypothesis against the winner."""
    out = {}
    if ev.rival_pose is not None:
        out["second_best_pose"] = tuple(float(v) for v in ev.rival_pose)
    if ev.rival_pose is not None and mask.any():
        out["second_best_shift"], out["second_best_turn"] = rival_offset(pose, ev.rival_pose, problem.p2[mask])
    if compare_descriptors and map1.descriptor_size:
        out["support_descriptor_distance"] = _median_descriptor_distance(map1, map2, pairs[mask])
        if ev.rival_mask is not None:
            out["second_best_descriptor_distance"] = _median_descriptor_distance(map1, map2, pairs[ev.rival_mask])
    return out


def rival_text(stats: AlignmentStatistics) -> str:
    """The second-best hypothesis in words ('' if none was measured): how far it turns and moves the winner's
    supports, and how closely each one's supports match in appearance."""
    parts = []
    if np.isfinite(stats.second_best_turn):
        half = " (a half turn)" if stats.second_best_turn > HALF_TURN else ""
        parts.append(f"turned {stats.second_best_turn:.2f} rad from the best one{half}, moving its supports "
                     f"{stats.second_best_shift:.1f} m")
    if np.isfinite(stats.second_best_descriptor_distance) and np.isfinite(stats.support_descriptor_distance):
        parts.append(f"median descriptor distance of its supports {stats.second_best_descriptor_distance:.3f}, "
                     f"the best one's {stats.support_descriptor_distance:.3f}")
    return "; ".join(parts)


# -- the entry point -----------------------------------------------------------------------------------------
def guided_supports(map1: LandmarkMap, map2: LandmarkMap, pose: np.ndarray, config: AlignmentConfig,
                    candidates: int = 4) -> np.ndarray:
    """All supports of a known transform: pairs (K, 2) near in position *and* in descriptor, one-to-one.

    Every map-1 landmark takes, among its ``candidates`` nearest transformed map-2 landmarks within th2
    (a k-d tree on positions) that pass the Mahalanobis gate, the one nearest in descriptor (below th0);
    a map-2 landmark claimed twice goes to the nearer descriptor.
    """
    from scipy.spatial import cKDTree

    from estimation.geometry import rot_z

    R3 = rot_z(pose[2])
    x2 = transform_points(pose, map2.positions)
    k = min(candidates, len(map2))
    if k == 0 or len(map1) == 0:
        return np.zeros((0, 2), np.int64)
    dist, j = cKDTree(x2).query(map1.positions, k=k, distance_upper_bound=config.support_threshold)
    i, slot = np.nonzero(np.isfinite(dist.reshape(len(map1), k)))
    j = j.reshape(len(map1), k)[i, slot]
    r = map1.positions[i] - x2[j]
    S = map1.covariances[i] + R3 @ map2.covariances[j] @ R3.T + config.position_floor ** 2 * np.eye(3)
    gate = np.einsum("ki,ki->k", r, np.linalg.solve(S, r[..., None])[..., 0]) < CHI2_999[3]
    d_desc = np.linalg.norm(map1.descriptors[i].astype(np.float32) - map2.descriptors[j], axis=1)
    keep = gate & (d_desc < config.descriptor_threshold)
    i, j, d_desc = i[keep], j[keep], d_desc[keep]
    order = np.argsort(d_desc, kind="stable")
    i, j = i[order], j[order]
    _, first_i = np.unique(i, return_index=True)           # each map-1 landmark: its best candidate
    i, j = i[first_i], j[first_i]
    d_best = d_desc[order][first_i]
    order = np.argsort(d_best, kind="stable")
    _, first_j = np.unique(j[order], return_index=True)    # each map-2 landmark: its best claimant
    pick = np.sort(order[first_j])
    return np.column_stack([i[pick], j[pick]]).astype(np.int64)


def support_spread(xy: np.ndarray) -> tuple[float, float]:
    """Principal standard deviations (m) of points xy (S, 2): major, minor axis."""
    if len(xy) < 2:
        return 0.0, 0.0
    ev = np.linalg.eigvalsh(np.cov(xy.T))
    return float(np.sqrt(max(ev[-1], 0.0))), float(np.sqrt(max(ev[0], 0.0)))



def align(map1: LandmarkMap, map2: LandmarkMap, preset: str | AlignmentConfig = "robust",
          rng: np.random.Generator | None = None, cache: AlignmentCache | None = None,
          prior: StartPrior | None = None) -> Alignment:
    """Align map 2 to map 1 (RANSAC, see the module docstring); never raises for non-overlapping maps.

    Returns an :class:`Alignment` whose ``found`` says whether the maps overlap and whose ``statistics``
    carry the evidence (false-alarm probability, chance supports, second-best hypothesis, supports
    required on these maps).  Deterministic given the ``rng`` (None -> ``np.random.default_rng(0)``).
    Raises :class:`IncompatibleMapsError` when the descriptor sizes differ or the preset is unknown.
    ``cache`` (:class:`fusion.cache.AlignmentCache`) supplies each map's self-repeat count computed once per map
    content (use ``cache.align`` to reuse whole alignments of unchanged maps).
    ``prior`` (:class:`fusion.prior.StartPrior`): a rough relative start of the robots; hypotheses outside it are no
    rivals, and a best alignment outside it is "not found: ... contradicts the prior" (the prior removes hypotheses,
    it never adds support; see :mod:`fusion.prior`).  A found alignment with a prior says whether the maps alone would
    find it (``statistics.prior_decides``, ``prior_backing``; :mod:`fusion.prior_backing`).
    """
    with search_workspace():       # its three descriptor searches share their distance buffers
        return _align(map1, map2, preset, rng, cache, prior)


def _align(map1: LandmarkMap, map2: LandmarkMap, preset: str | AlignmentConfig, rng: np.random.Generator | None,
           cache: AlignmentCache | None, prior: StartPrior | None) -> Alignment:
    config = resolve_preset(preset)
    rng = np.random.default_rng(0) if rng is None else rng
    if map1.descriptor_size != map2.descriptor_size and len(map1) and len(map2):
        raise IncompatibleMapsError(f"descriptor sizes differ: {map1.descriptor_size} (map 1 of {map1.robot}) "
                                    f"vs {map2.descriptor_size} (map 2 of {map2.robot})")
    empty = np.zeros((0, 2), np.int64)

    def not_found(reason: str, stats: AlignmentStatistics, supports=empty) -> Alignment:
        return Alignment(False, config.name, None, None, supports, stats, reason, prior=prior)

    identities = landmark_identities(map1) is not None and landmark_identities(map2) is not None
    with_descriptors = identities or (has_descriptors(map1) and has_descriptors(map2))
    no_desc = "" if with_descriptors else (f"the maps carry no descriptors, so every landmark of one is a candidate "
                                           f"for every landmark of the other ({len(map1)} × {len(map2)} pairs); ")
    if not with_descriptors and len(map1) * len(map2) > MAX_GEOMETRIC_PAIRS:
        return not_found(f"{no_desc}more than {MAX_GEOMETRIC_PAIRS} candidate pairs are too many for a search by "
                         f"geometry alone", AlignmentStatistics(descriptors=False))
    if not with_descriptors and min(len(map1), len(map2)) < config.min_supports:
        return not_found(f"{no_desc}at most {min(len(map1), len(map2))} supports are possible, fewer than the "
                         f"{config.min_supports} this preset needs", AlignmentStatistics(descriptors=False))

    # step 1: putative correspondences (from descriptors, or every pair without them)
    pairs, _ = putative_correspondences(map1, map2, config, rng)
    subset_search = (not identities and with_descriptors
                     and query_subset(len(map1), len(map2), np.random.default_rng(0)) is not None)
    k = len(pairs)
    needed = max(2, config.min_supports)
    if k < needed:
        what = "identity" if identities else "descriptor"
        return not_found(f"only {k} {what} correspondences (at least {needed} needed)",
                         AlignmentStatistics(correspondences=k, descriptors=with_descriptors))
    problem = correspondence_problem(map1, map2, pairs, config, distinct_scoring=not with_descriptors or identities)

    # steps 2–3, repeated: hypotheses from pairs of correspondences, scored by their supports
    search = ransac(problem, config, rng)
    if search.pose is None:
        return not_found(f"{no_desc}no pair of correspondences keeps its distance between the maps",
                         AlignmentStatistics(correspondences=k, iterations=search.evaluated,
                                             descriptors=with_descriptors))
    raw_count = int(search.mask.sum())
    pose, covariance, mask, problem = polish(problem, search.pose, search.mask, config)
    inside, prior_chi2 = None, float("nan")
    # the prior and the co-location test are about the true starts: the winner's uncertainty against them widens them
    # (for every hypothesis)
    winner_start = (start_frame_covariance(problem.p1[mask], problem.P1[mask], problem.p2[mask], problem.P2[mask],
                                           pose, config.position_floor)
                    if (prior is not None or config.colocation) and covariance is not None and mask.sum() >= 2
                    else None)
    possible, colocation_note, colocation_failure = None, "", ""
    if config.colocation:
        test, why = colocation_test(map1, map2)
        if test is not None and winner_start is None:
            test, why = None, "the alignment has no covariance to carry to the robots"
        if test is None:
            colocation_note = f"no co-location test: {why}"
        else:
            colocation_note = test.text()
            colocation_failure = test.reason(pose, winner_start)

            def possible(poses: np.ndarray) -> np.ndarray:
                return test.admits(poses, winner_start)
    if prior is not None:
        prior_chi2 = float(prior.chi2(pose, winner_start))
        if prior_chi2 <= prior.bound:

            def inside(poses: np.ndarray) -> np.ndarray:
                return prior.admits(poses, winner_start)
    repeats = config.refine and with_descriptors and not identities
    self_repeat = None if cache is None else (lambda m, *scale: cache.self_structure(m, config, *scale))
    alone_rng = None
    if prior is not None and config.significance is not None:
        # a winner found with the prior is measured again without it (without_prior_statistics): the same decoys, and
        # each map's self-repeat counted once
        alone_rng = copy.deepcopy(rng)
        self_repeat = self_repeat_counted_once(self_repeat, config)
    ev = evidence(problem, search, pose, mask, map1, map2, config, rng, repeats=repeats, self_repeat=self_repeat,
                  admissible=inside, possible=possible)
    evidence_pose, evidence_mask = pose, mask
    supports = pairs[mask] if (config.refine or not with_descriptors) else pairs[search.mask]
    s = ev.supports
    residual = problem.p1[mask] - transform_points(pose, problem.p2[mask])
    rms = float(np.sqrt(np.mean(np.sum(residual ** 2, axis=1)))) if s else float("nan")
    fit = (problem.p1[mask], problem.P1[mask], problem.p2[mask], problem.P2[mask])
    if subset_search and config.refine and s >= 2:
        # the subset fixed the transform; now every landmark's support, by guided matching
        guided = guided_supports(map1, map2, pose, config)
        if len(guided) >= max(s, 3):
            g_problem = correspondence_problem(map1, map2, guided, config, distinct_scoring=False)
            pose, covariance, _ = refine_pose(g_problem.p1, g_problem.P1, g_problem.p2, g_problem.P2, pose,
                                              config.position_floor)
            supports = guided
            residual = g_problem.p1 - transform_points(pose, g_problem.p2)
            rms = float(np.sqrt(np.mean(np.sum(residual ** 2, axis=1))))
            fit = (g_problem.p1, g_problem.P1, g_problem.p2, g_problem.P2)
            winner_start = None                    # computed on the supports before guided matching: not this fit's
    major, minor = support_spread(problem.p1[mask, :2])
    rival = _rival_figures(map1, map2, pairs, pose, mask, problem, ev, compare_descriptors=with_descriptors
                           and not identities)
    stats = AlignmentStatistics(
        correspondences=k, iterations=search.evaluated, supports=len(supports), inlier_ratio=s / k,
        residual_rms=rms, expected_chance_supports=2.0 + ev.chance_rate, log10_chance_probability=ev.log10_p,
        support_spread=major, support_spread_minor=minor, second_best_supports=ev.second_best,
        self_repeat_supports=ev.self_repeat,
        required_supports=ev.required, gate_inflation=problem.inflation, gate_radius=problem.gate_radius,
        descriptors=with_descriptors, prior_chi2=prior_chi2,
        prior_hypotheses=ev.hypotheses if inside is not None else 0, outside_prior_supports=ev.outside,
        colocation=colocation_note, colocation_removed_supports=ev.impossible, **rival)

    # the evidence counted in the gate the winner's converged fit calls for (fusion.evidence.evidence): say so
    narrowed = (f" (counted in the gate of the best one's converged fit, median radius {ev.narrowed_gate:.2f} m, not "
                f"the {problem.gate_radius:.2f} m its polishing left)" if ev.narrowed else "")
    counted = raw_count if not config.refine and with_descriptors else len(supports)
    if counted < config.min_supports:
        return not_found(f"{no_desc}only {counted} supports (at least {config.min_supports} needed)", stats, supports)
    if prior is not None and (inside is None or ev.outside > s):
        return not_found(_contradiction(prior, pose, s, prior_chi2, ev, config, major, inside is None), stats,
                         supports)
    if colocation_failure:
        return not_found(f"the maps' best alignment ({s} supports) contradicts co-location: {colocation_failure}",
                         stats, supports)
    if config.significance is not None and ev.log10_p > np.log10(config.significance):
        if ev.ambiguous and ev.self_repeat > ev.second_best:
            return not_found(
                f"ambiguous: one map repeats itself under a distinct transform with {ev.self_repeat} supports "
                f"(repeated structure), so a wrong alignment could gather as many as the best one's {s}; on these "
                f"maps {ev.required} would be needed (false-alarm probability 10^{ev.log10_p:.1f}){narrowed}; "
                f"{DISAMBIGUATION}", stats, supports)
        if ev.ambiguous:
            what = rival_text(stats)
            return not_found(
                f"ambiguous: a distinct transform gathers {ev.second_best} supports against the best one's {s} "
                f"(repeated structure{': ' + what if what else ''}); on these maps {ev.required} would be needed "
                f"(false-alarm probability 10^{ev.log10_p:.1f}){narrowed}; {DISAMBIGUATION}", stats, supports)
        return not_found(
            f"{no_desc}{s} supports are explainable by chance: a wrong transform gathers "
            f"{stats.expected_chance_supports:.1f} on these maps and the best of {ev.hypotheses} hypotheses more; "
            f"{ev.required} would be needed (false-alarm probability 10^{ev.log10_p:.1f}){narrowed}", stats, supports)
    if major < config.min_spread:
        return not_found(f"the {s} supports are bunched within {major:.2f} m (at least {config.min_spread} m "
                         f"spread needed to fix the angle)", stats, supports)
    start_cov = winner_start                       # (with a prior or the co-location test: this fit's, computed once)
    if start_cov is None and covariance is not None and len(fit[0]) >= 2:
        start_cov = start_frame_covariance(*fit, pose, config.position_floor)
    if alone_rng is not None:                      # found with a prior: would the maps alone find it?
        stats = replace(stats, **without_prior_statistics(problem, search, evidence_pose, evidence_mask, pose, map1,
                                                          map2, config, alone_rng, repeats, self_repeat, possible,
                                                          prior, winner_start))
    return Alignment(True, config.name, pose, covariance, supports, stats, "", start_cov, prior)


def _contradiction(prior: StartPrior, pose: np.ndarray, s: int, chi2: float, ev: Evidence, config: AlignmentConfig,
                   spread: float, winner_outside: bool) -> str:
    """Why a best alignment that contradicts the start prior is not found: how far, and what the evidence says."""
    if not winner_outside:
        return (f"the maps' best alignment contradicts the prior: a hypothesis outside it gathers {ev.outside} "
                f"supports against the best one inside's {s} ({prior.text()})")
    dxy, dth = prior.offset(pose)
    level = np.log10(config.significance) if config.significance is not None else -6.0
    alone = ("the evidence alone would find it" if ev.log10_p <= level and spread >= config.min_spread
             else f"the evidence alone would not find it either (false-alarm probability 10^{ev.log10_p:.1f}, "
                  f"{ev.required} supports needed)")
    return (f"the maps' best alignment contradicts the prior: {s} supports at tx={pose[0]:+.2f} m ty={pose[1]:+.2f} m "
            f"θ={pose[2]:+.3f} rad, {dxy:.2f} m / {dth:.3f} rad from the prior's mean (χ² {chi2:.1f} > "
            f"{prior.bound:.1f}); {alone}; {prior.text()}")


def align_at(map1: LandmarkMap, map2: LandmarkMap, pose, preset: str | AlignmentConfig = "robust",
             rng: np.random.Generator | None = None) -> Alignment:
    """Map 2 tested at one given transform ``pose`` (3,) (another part's alignment): the correspondences and gates
    of :func:`fusion.align`, the supports of ``pose`` polished as align polishes its winner, and its evidence
    without a search: one hypothesis given from outside, so no Bonferroni factor for hypotheses tried and no rival
    (the other part's alignment already chose among them). Found iff P(Poisson(λ_decoy) ≥ s − 2) is below the
    preset's significance, s ≥ its minimum and the supports spread out, as for align."""
    config = resolve_preset(preset)
    rng = np.random.default_rng(0) if rng is None else rng
    empty = np.zeros((0, 2), np.int64)
    identities = landmark_identities(map1) is not None and landmark_identities(map2) is not None
    with_descriptors = identities or (has_descriptors(map1) and has_descriptors(map2))
    if not with_descriptors and len(map1) * len(map2) > MAX_GEOMETRIC_PAIRS:
        return Alignment(False, config.name, None, None, empty, AlignmentStatistics(descriptors=False),
                         f"more than {MAX_GEOMETRIC_PAIRS} candidate pairs without descriptors")
    pairs, _ = putative_correspondences(map1, map2, config, rng)
    if len(pairs) < max(2, config.min_supports):
        return Alignment(False, config.name, None, None, empty, AlignmentStatistics(correspondences=len(pairs)),
                         f"only {len(pairs)} correspondences at the other part's transform")
    problem = correspondence_problem(map1, map2, pairs, config, distinct_scoring=not with_descriptors or identities)
    pose = np.asarray(pose, float).copy()
    pose, covariance, mask, problem = polish(problem, pose, problem.masks(pose[None])[0], config)
    s = int(problem.distinct_counts(mask[None])[0])
    rate, phi = decoy_null(problem, map1, map2, config, rng, mask)   # the dispersion 1 under "poisson"
    rate = max(rate, 1e-9)
    log10_p = log10_false_alarm(s - 2, rate, 1, phi)
    major, minor = support_spread(problem.p1[mask, :2])
    residual = problem.p1[mask] - transform_points(pose, problem.p2[mask])
    stats = AlignmentStatistics(
        correspondences=len(pairs), iterations=1, supports=s, inlier_ratio=s / len(pairs),
        residual_rms=float(np.sqrt(np.mean(np.sum(residual ** 2, axis=1)))) if s else float("nan"),
        expected_chance_supports=2.0 + rate, log10_chance_probability=log10_p, support_spread=major,
        support_spread_minor=minor, gate_inflation=problem.inflation, gate_radius=problem.gate_radius,
        descriptors=with_descriptors)
    supports = pairs[mask]
    level = np.log10(config.significance) if config.significance is not None else -6.0
    if s < config.min_supports or log10_p > level or major < config.min_spread or covariance is None:
        return Alignment(False, config.name, None, None, supports, stats,
                         f"at the other part's transform {s} supports, where chance gives {rate:.1f} beyond 2 "
                         f"(false-alarm probability 10^{log10_p:.1f}), spread {major:.2f} m")
    start = start_frame_covariance(problem.p1[mask], problem.P1[mask], problem.p2[mask], problem.P2[mask], pose,
                                   config.position_floor)
    return Alignment(True, config.name, pose, covariance, supports, stats, "", start)
