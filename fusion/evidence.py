"""Whether an alignment can be trusted, on the alignment's own evidence (issue 13).

The supports beyond the two that define a hypothesis are compared with the number a wrong transform gathers by
chance on *these* maps: decoy transforms scored with the same gate (landmark density, clustering along walls, map
sizes), the best hypothesis distinct from the winner, and each map's repeat of itself (repeated structure: a
building symmetric under a half turn, a corridor of identical doors).  The result is a false-alarm probability,
Bonferroni-corrected for the hypotheses tried, and the number of supports these maps need.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
from scipy.optimize import brentq, minimize_scalar
from scipy.special import betainc, gammaincinv, ndtri, pdtrc

from estimation.geometry import transform_points, wrap_angle
from estimation.landmark_map import LandmarkMap

from .errors import IncompatibleMapsError
from .fingerprint import content_rng
from .matching import self_correspondences
from .ransac import (
    CorrespondenceProblem,
    RansacSearch,
    correspondence_problem,
    has_descriptors,
    polish,
    ransac,
    residual_inflation,
    rotations_2d,
)

if TYPE_CHECKING:
    from .alignment_config import AlignmentConfig

# Descriptor distances computed at most when a map is matched against itself (self_structure).
SELF_SEARCH_PAIRS = 20_000_000
SELF_REPEAT_GATES = ("own", "pair")      # AlignmentConfig.self_repeat_gate
# AlignmentConfig.chance_model: the law of a wrong hypothesis' chance supports.  "poisson" (the default): Poisson with
# the decoys' rate.  "negative_binomial": the decoys' counts are overdispersed (variance/mean 1.4-2.2 on the rendered
# demo's maps, 2.1-3.4 on their halves cut to share nothing; 1.00 on MRCLAM's; session 51), so their law is a negative
# binomial with that variance/mean ratio (an upper confidence bound of it, below), whose upper tail -- where a false
# alarm lives -- is heavier than Poisson's of the same mean (on the disjoint halves it matches the decoys' tail to 10+
# supports, where
# Poisson's falls short by orders of magnitude).  What makes it: walls of landmarks whose look repeats across the
# building -- a decoy that lays one on another gathers several supports at once (positions spread uniformly, or
# descriptors permuted: 1.1-1.2).
CHANCE_MODELS = ("poisson", "negative_binomial")
# Why the moment estimate of the dispersion scatters (session 52): its sampling error is the sample's fourth moment,
# made by the rare decoys that lay a wall on a look-alike and gather 6-15 supports at a mean of 0.1-0.3 (on demo seed
# 9's maps the top 0.1 % of 200,000 decoys carry 8-21 % of the squared deviations; over 50 draws of 1,000 decoys the
# moment phi rises and falls with the share of its top 1 % decoys, correlation +0.82..+0.96).  A draw of 1,000 holds
# a handful of them or none: phi 1.17-3.15 over 50 draws on seed 9's two robots' maps (200,000 decoys: 1.52), and a
# draw without them is low, so the sample's own standard error (delta method) is low with it and covers the truth
# 68-92 % of the time at a stated 95 %.  The remedy: the rare decoys are cheap (20,000 score in ~10 ms), so the
# negative binomial draws AlignmentConfig.dispersion_decoys, and the null takes an upper confidence bound of phi
# (dispersion_bound), and the tail's largest value for a dispersion up to that bound (chance_tail_within).
DISPERSION_LEVEL = 0.95
# largest dispersion a bound reports as finite (dispersion_bound's search; beyond it the decoys cannot bound it)
MAX_DISPERSION = 1e4


@dataclass(frozen=True)
class Evidence:
    """How much a hypothesis with ``supports`` one-to-one supports can be trusted on these maps.

    chance_decoys: mean supports beyond its anchor that a decoy transform gathers (the chance rate);
    second_best: supports of the best hypothesis distinct from the winner (0 if none);
    chance_rate: the Poisson rate λ of chance supports beyond the two that define a hypothesis;
    hypotheses: how many were tried (the Bonferroni factor); log10_p: log10 of the false-alarm
    probability N · P(Poisson(λ) ≥ supports − 2); required: the fewest supports with p below ``significance``.
    """

    supports: int
    chance_decoys: float
    second_best: int
    chance_rate: float
    hypotheses: int
    log10_p: float
    required: int
    ambiguous: bool                       # the second-best hypothesis, not the decoys, set the chance rate
    self_repeat: int = 0                  # supports of the best repeat of either map onto itself (self_structure)
    rival_pose: np.ndarray | None = None  # (3,) the second-best hypothesis' pose, None if there is none
    rival_mask: np.ndarray | None = None  # (K,) its supports among the correspondences
    outside: int = 0                      # with a start prior: supports of the best distinct hypothesis outside it
    impossible: int = 0                   # with a co-location test: supports of the best distinct hypothesis it removed
    # the median radius (m) of the gate the winner's converged fit calls for, when the decision was taken in it
    # (narrower than the gate its polishing left; the counts above are then that gate's); nan: not narrowed
    narrowed_gate: float = float("nan")
    # variance/mean of the decoys' chance counts the null uses (1: Poisson; AlignmentConfig.chance_model)
    dispersion: float = 1.0

    @property
    def narrowed(self) -> bool:
        return bool(np.isfinite(self.narrowed_gate))


def chance_tail(excess: int, rate: float, dispersion: float = 1.0) -> float:
    """P(X ≥ excess) for chance supports X of mean ``rate`` and variance ``dispersion`` · ``rate``: Poisson at
    dispersion 1 (or below: the decoys' counts never prove underdispersion), else the negative binomial with
    r = rate / (dispersion − 1) successes of probability 1 / dispersion (P(X ≥ k) = I_{1−1/φ}(k, r)); it tends to
    Poisson's as the dispersion tends to 1."""
    if excess <= 0 or not rate < np.inf:
        return 1.0
    rate = max(rate, 1e-12)
    if not dispersion > 1.0 + 1e-9:
        return float(pdtrc(excess - 1, rate))
    return float(betainc(excess, rate / (dispersion - 1.0), 1.0 - 1.0 / dispersion))


def chance_tail_within(excess: int, rate: float, dispersion: float = 1.0) -> float:
    """The largest P(X ≥ excess) over the dispersions φ in [1, ``dispersion``] (an upper confidence bound of it; may be
    inf) for chance supports X of mean ``rate`` (:func:`chance_tail`): Poisson's at ``dispersion`` 1.

    The largest, not the one at the bound: at a fixed mean the negative binomial's tail at ``excess`` first rises with
    φ, then falls (the mass gathers at 0; the turn is near φ ≈ 2 · excess, e.g. 9.4 at excess 5, mean 0.3), so the
    tail at the bound alone would let a wider bound -- less known about φ -- make "found" easier.  Taken over the
    interval it never falls as the bound rises."""
    if excess <= 0:
        return 1.0
    if not dispersion > 1.0 + 1e-9:
        return chance_tail(excess, rate, 1.0)
    top = min(float(dispersion), MAX_DISPERSION)
    ends = max(chance_tail(excess, rate, 1.0), chance_tail(excess, rate, top))
    # unimodal in log φ: its interior maximum, if it lies inside the interval
    res = minimize_scalar(lambda u: -chance_tail(excess, rate, float(np.exp(u))), bounds=(0.0, float(np.log(top))),
                          method="bounded", options={"xatol": 1e-6})
    return max(ends, float(-res.fun))


def log10_false_alarm(excess: int, rate: float, hypotheses: int, dispersion: float = 1.0) -> float:
    """log10 min(1, N · P(X ≥ excess)), X Poisson(rate) (``dispersion`` 1) or its overdispersed negative binomial
    with any dispersion up to ``dispersion`` (an upper confidence bound of it; :func:`chance_tail_within`)."""
    if excess <= 0:
        return 0.0
    tail = chance_tail_within(excess, rate, dispersion)
    return min(0.0, float(np.log10(max(tail, 1e-300)) + np.log10(max(hypotheses, 1))))


def _rate_for_maximum(excess: int, hypotheses: int) -> float:
    """The Poisson rate at which the best of N wrong hypotheses reaches ``excess`` supports half the time:
    a null calibrated on the maps' own repeated structure."""
    if excess <= 0:
        return 0.0
    lo, hi = -12.0, 3.0                         # log10 λ
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if hypotheses * pdtrc(excess - 1, 10.0 ** mid) < 0.5:
            lo = mid
        else:
            hi = mid
    return 10.0 ** hi


def _log10_null(excess: int, decoy_rate: float, structure_rate: float, hypotheses: int, dispersion: float) -> float:
    """log10 of the false-alarm probability under the stricter of the two nulls.  Poisson (``dispersion`` 1): one
    Poisson law whose rate is the larger of the decoys' and the structure's (as ever).  Otherwise each null with its
    own law: the decoys' counts as their negative binomial (the dispersion measured on them), the structure's rate
    as Poisson -- that rate is already calibrated on the tail itself (the best of N real hypotheses, or the map's
    repeat, made a typical maximum), where the decoys' dispersion, measured at a mean of ~0.2, says nothing of the
    law near a mean of 5-10 (extrapolated there it made 3 of 10 correct smoothed-demo alignments ambiguous)."""
    if dispersion == 1.0:
        return log10_false_alarm(excess, max(decoy_rate, structure_rate, 1e-9), hypotheses)
    return max(log10_false_alarm(excess, max(structure_rate, 1e-9), hypotheses),
               log10_false_alarm(excess, max(decoy_rate, 1e-9), hypotheses, dispersion))


def decoy_counts(problem: CorrespondenceProblem, map1: LandmarkMap, map2: LandmarkMap, decoys: int,
                 rng: np.random.Generator, exclude: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Chance supports each of ``decoys`` random transforms gathers beyond its anchor, scored with the same gates:
    ((D,) counts, (D,) the same without the correspondences ``exclude`` (K,) bool marks; the counts again without
    it); empty when there is nothing to score.

    Each decoy puts a random map-2 landmark on a random map-1 landmark at a random angle (so the maps
    overlap as a RANSAC hypothesis makes them), then counts the correspondences inside the gate — the
    maps' density, their clustering along walls and their sizes all enter.
    """
    k = len(problem.i)
    if decoys <= 0 or k == 0 or len(map1) == 0 or len(map2) == 0:
        return np.zeros(0), np.zeros(0)
    theta = rng.uniform(-np.pi, np.pi, decoys)
    a = rng.integers(len(map1), size=decoys)
    b = rng.integers(len(map2), size=decoys)
    R = rotations_2d(theta)
    t = map1.positions[a, :2] - np.einsum("hij,hj->hi", R, map2.positions[b, :2])
    poses = np.column_stack([t, theta])
    # the anchor itself supports a decoy only when (a, b) is a correspondence
    n2 = max(len(map2), int(problem.j.max()) + 1)
    keys = problem.i * n2 + problem.j
    order = np.argsort(keys)
    anchor = a * n2 + b
    pos = np.clip(np.searchsorted(keys[order], anchor), 0, k - 1)
    anchor_row = np.where(keys[order][pos] == anchor, order[pos], -1)
    out = np.empty(decoys)
    outside = out if exclude is None else np.empty(decoys)
    batch = max(1, 4_000_000 // max(k, 1))
    for start in range(0, decoys, batch):
        sl = slice(start, start + batch)
        masks = problem.masks(poses[sl])
        counts = problem.distinct_counts(masks).astype(float)
        rows = anchor_row[sl]
        has = rows >= 0
        counts[has] -= masks[np.flatnonzero(has), rows[has]]
        out[sl] = counts
        if exclude is not None:
            masks &= ~exclude
            counts = problem.distinct_counts(masks).astype(float)
            counts[has] -= masks[np.flatnonzero(has), rows[has]]
            outside[sl] = counts
    return out, outside


def decoy_chance_supports(problem: CorrespondenceProblem, map1: LandmarkMap, map2: LandmarkMap, decoys: int,
                          rng: np.random.Generator) -> float:
    """Chance supports a wrong transform gathers beyond its anchor, scored with the same gates: the 95 %
    upper bound of their mean over the decoys (:func:`decoy_counts`), as a Poisson rate."""
    counts, _ = decoy_counts(problem, map1, map2, decoys, rng)
    if len(counts) == 0:
        return 0.0
    # 95 % upper confidence bound of a Poisson rate from ``total`` events in ``decoys`` trials: a finite sample
    # of decoys that saw no chance support does not prove the rate is zero
    return float(gammaincinv(float(counts.sum()) + 1.0, 0.95)) / decoys


def dispersed_chance_supports(problem: CorrespondenceProblem, map1: LandmarkMap, map2: LandmarkMap, decoys: int,
                              rng: np.random.Generator, mask: np.ndarray | None = None,
                              dispersion_decoys: int = 0) -> tuple[float, float]:
    """The decoys' chance supports as an overdispersed law (``chance_model="negative_binomial"``): (the 95 % upper
    bound of their mean, the 95 % upper bound of their dispersion φ = variance / mean, ≥ 1; :func:`dispersed_rate`).

    The mean's bound is on the first ``decoys`` decoys, the very ones :func:`decoy_chance_supports` draws from the
    same ``rng``, and φ's on those and ``dispersion_decoys`` − ``decoys`` more drawn after them: the bound of the mean
    is then at least Poisson's on the same counts (quasi-Poisson at φ ≥ 1) and the tail at least Poisson's (the
    dispersions from 1 up), so this null never finds what the Poisson default does not; the more decoys only steady φ.

    φ over the decoys' counts *without the winner's supports* (``mask``; all of them without one): a decoy near the
    winner (anchored on one of its pairs, a little turned) gathers part of the winner's own supports, which measures
    the winner, not chance -- on maps that overlap these few decoys made the tail (MRCLAM's 15-landmark maps with
    identities: φ 1.5-9 with them, 1.00 without; on the rendered demo's maps a few in 20,000 gather 20-46 supports
    there)."""
    exclude = None if mask is None else np.asarray(mask, bool)
    counts, kept = decoy_counts(problem, map1, map2, decoys, rng, exclude)
    if len(counts) == 0:
        return 0.0, 1.0
    if dispersion_decoys > decoys:
        _, more = decoy_counts(problem, map1, map2, dispersion_decoys - decoys, rng, exclude)
        kept = np.concatenate([kept, more])
    return dispersed_rate(counts, kept)


def dispersion_bound(counts: np.ndarray, level: float = DISPERSION_LEVEL) -> float:
    """The ``level`` upper confidence bound of the dispersion φ = variance / mean of ``counts`` (D,), i.i.d.
    non-negative counts; at least 1 (counts never prove underdispersion), 1 when they are all 0, inf when they cannot
    bound it (a heavy tail seen in too few counts).

    The moment estimate φ̂ = s² / x̄ has the standard error σ(φ) of a negative binomial of dispersion φ and mean x̄,
    σ² = (φ (3φ − 1)(φ − 1) / x̄ + 2φ²) / D (the delta method on its moments; 2 / D at φ = 1, Pearson's χ²), or the
    sample's own by the delta method on its influence values where that is larger (the decoys' tail is heavier than a
    negative binomial's).  The bound is the smallest φ ≥ 1 with φ − z σ(φ) ≥ φ̂ (z the normal ``level`` quantile):
    the test inverted, σ taken *at the bound*, not at φ̂ -- a draw that misses the rare large counts has a low φ̂ and a
    low standard error of its own, and a bound φ̂ + z σ(φ̂) covered a negative binomial's φ 73-93 % of the time at a
    stated 95 % (1,000 counts of mean 0.1-1); inverted, 95-100 % at 20,000 counts (``tests/fusion/
    test_s52_dispersion_bound.py``).  With 1,000 counts of mean 0.1-0.3 and φ ≥ 1.5 there is often none (inf)."""
    counts = np.asarray(counts, float)
    if counts.ndim != 1:
        raise ValueError(f"dispersion_bound: counts must be one-dimensional, not of shape {counts.shape}")
    if not 0.0 < level < 1.0:
        raise ValueError(f"dispersion_bound: level must be between 0 and 1, not {level!r}")
    if len(counts) < 2:
        raise ValueError(f"dispersion_bound: needs at least 2 counts, not {len(counts)}")
    if not np.all(np.isfinite(counts)) or np.any(counts < 0):
        raise ValueError("dispersion_bound: counts must be finite and non-negative")
    n, mean = len(counts), float(counts.mean())
    if mean == 0.0:
        return 1.0
    var = float(counts.var(ddof=1))
    phi = var / mean
    dev = counts - mean
    influence = (dev ** 2 - var) / mean - var * dev / mean ** 2
    se_own = float(influence.std(ddof=1)) / np.sqrt(n)
    z = float(ndtri(level))

    def slack(u):                     # u − z σ(u) − φ̂: the bound is its first zero at or above 1
        u = np.asarray(u, float)
        sd_nb = np.sqrt((u * (3.0 * u - 1.0) * (u - 1.0) / mean + 2.0 * u * u) / n)
        return u - z * np.maximum(se_own, sd_nb) - phi

    if slack(1.0) >= 0.0:
        return 1.0
    grid = np.geomspace(1.0, MAX_DISPERSION, 4001)
    above = np.flatnonzero(slack(grid) >= 0.0)
    if len(above) == 0:
        return float("inf")
    i = int(above[0])
    return float(brentq(lambda u: float(slack(u)), grid[i - 1], grid[i], xtol=1e-12, rtol=1e-12))


def dispersed_rate(counts: np.ndarray, kept: np.ndarray | None = None, level: float = 0.95) -> tuple[float, float]:
    """(the ``level`` upper bound of the mean of ``counts`` (D,) i.i.d. chance counts, the ``level`` upper bound of
    their dispersion φ = variance / mean (:func:`dispersion_bound`) on ``kept`` (default: ``counts``; any length: the
    same decoys' counts without the winner's supports, and more of them)).  The mean's bound is
    quasi-Poisson at that φ: φ · Γ⁻¹(total / φ + 1, level) / D (the total of D counts of dispersion φ carries the
    information of total / φ Poisson events), Poisson's at φ = 1; inf with φ."""
    counts = np.asarray(counts, float)
    kept = counts if kept is None else np.asarray(kept, float)
    if len(counts) == 0:
        return 0.0, 1.0
    phi = dispersion_bound(kept, level) if len(kept) > 1 else 1.0
    if not np.isfinite(phi):
        return float("inf"), phi
    total = float(counts.sum())
    return phi * float(gammaincinv(total / phi + 1.0, level)) / len(counts), phi


def decoy_null(problem: CorrespondenceProblem, map1: LandmarkMap, map2: LandmarkMap, config: AlignmentConfig,
               rng: np.random.Generator, mask: np.ndarray | None = None) -> tuple[float, float]:
    """The decoys' chance rate and dispersion under ``config.chance_model``: ("poisson") :func:`decoy_chance_supports`
    on ``config.decoys`` decoys, and 1; ("negative_binomial") :func:`dispersed_chance_supports`: the rate's bound on
    the same ``config.decoys`` decoys, the dispersion's on ``config.dispersion_decoys`` (if more)."""
    if config.chance_model not in CHANCE_MODELS:
        raise IncompatibleMapsError(f"unknown chance_model {config.chance_model!r} (choose from "
                                    f"{', '.join(CHANCE_MODELS)})")
    if config.chance_model == "poisson":
        return decoy_chance_supports(problem, map1, map2, config.decoys, rng), 1.0
    return dispersed_chance_supports(problem, map1, map2, config.decoys, rng, mask, config.dispersion_decoys)


def rms_shift(poses: np.ndarray, points: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(H,) RMS distance (m) between ``points`` (S, 2|3) moved by each of ``poses`` (H, 3) and ``reference`` (S, 2).

    Each coordinate of R(θ) p + t is summed as ``np.einsum("hij,kj->hki", R, p) + t`` sums it (r_i0·x + r_i1·y,
    then + t), bit for bit (tests/fusion/test_fusion_exact_forms.py), without einsum's general loop (1.4 ms for 70
    hypotheses × 150 points, against 0.1 ms)."""
    R = rotations_2d(poses[:, 2])
    x, y = points[:, 0], points[:, 1]
    dx = (R[:, 0, 0, None] * x + R[:, 0, 1, None] * y + poses[:, 0, None]) - reference[:, 0]
    dy = (R[:, 1, 0, None] * x + R[:, 1, 1, None] * y + poses[:, 1, None]) - reference[:, 1]
    return np.sqrt(np.mean(dx ** 2 + dy ** 2, axis=1))


@dataclass(frozen=True)
class _Rival:
    """The best hypothesis distinct from the winner: its one-to-one supports (a repeated pair counted once when a
    map is matched against itself), pose (3,) and support mask (K,); None when there is none."""

    supports: int = 0
    pose: np.ndarray | None = None
    mask: np.ndarray | None = None


def _best_distinct(problem: CorrespondenceProblem, search: RansacSearch, pose: np.ndarray, mask: np.ndarray,
                   config: AlignmentConfig, unordered: bool = False, admissible=None,
                   distinct_gate: float | None = None) -> _Rival:
    """The best hypothesis clearly distinct from ``pose``: it moves the winner's supports (or, without any, every
    correspondence) by more than two gate radii on average.  The three strongest candidates are re-scored with the
    final gate and polished like the winner.  ``admissible(poses (H, 3)) -> (H,) bool`` (a start prior) keeps only
    the hypotheses it admits, before and after polishing.  ``distinct_gate``: the gate radius (m) that defines
    "distinct" (default: this problem's)."""
    if search.evaluated == 0:
        return _Rival()
    pts = problem.p2[mask] if mask.sum() >= 2 else problem.p2
    ref = transform_points(pose, pts)[:, :2]
    far = 2.0 * (problem.gate_radius if distinct_gate is None else distinct_gate)

    def distinct(poses: np.ndarray) -> np.ndarray:
        return rms_shift(poses, pts, ref) > far

    cand = np.flatnonzero(distinct(search.poses) & (True if admissible is None else admissible(search.poses)))
    if len(cand) == 0:
        return _Rival()
    best = _Rival()
    counts = np.zeros(len(cand), np.int64)
    for start in range(0, len(cand), 256):
        sl = cand[start:start + 256]
        counts[start:start + 256] = problem.distinct_counts(problem.masks(search.poses[sl]))
    # the rival is the null: with the residual rule it is also polished as the inflate rule polishes (the gate never
    # narrowed), and the stronger of the two counts (a rival polished in a narrowed gate can lose its own supports)
    polish_configs = [config] if config.gate_scale == "inflate" else [config, replace(config, gate_scale="inflate")]
    for c in cand[np.argsort(-counts, kind="stable")[:3]]:
        for polish_config in polish_configs:
            p = search.poses[c]
            m = problem.masks(p[None])[0]
            p, _, m, _ = polish(replace(problem), p, m, polish_config)
            m = problem.one_to_one(problem.masks(p[None])[0], p)     # scored with the winner's gate
            if distinct(p[None])[0] and (admissible is None or admissible(p[None])[0]):
                # a map matched against itself: (i, j) and (j, i) are one repeated pair (a half turn maps both ways)
                n = (len({frozenset(e) for e in zip(problem.i[m], problem.j[m], strict=True)}) if unordered
                     else int(m.sum()))
                if n > best.supports:
                    best = _Rival(n, p, m)
    return best


def _second_best(problem: CorrespondenceProblem, search: RansacSearch, pose: np.ndarray, mask: np.ndarray,
                 config: AlignmentConfig, unordered: bool = False) -> int:
    """Supports of the best hypothesis clearly distinct from ``pose`` (see :func:`_best_distinct`)."""
    return _best_distinct(problem, search, pose, mask, config, unordered).supports


def rival_offset(pose: np.ndarray, rival_pose: np.ndarray, points: np.ndarray) -> tuple[float, float]:
    """How far a rival hypothesis is from the winner: (RMS distance (m) by which it moves ``points`` (S, 2|3), map-2
    positions, against the winner; |Δθ| (rad)).  Frame-independent, unlike the difference of the poses' xy."""
    a = transform_points(pose, points)[:, :2]
    b = transform_points(rival_pose, points)[:, :2]
    shift = float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1)))) if len(points) else float("nan")
    return shift, float(abs(wrap_angle(rival_pose[2] - pose[2])))


def self_structure(landmark_map: LandmarkMap, config: AlignmentConfig, rng: np.random.Generator | None = None,
                   inflation: float | None = None) -> int:
    """Supports of the best transform, other than the identity, that maps a map onto *itself* by its descriptors:
    the repeated structure inside one map (a building symmetric under a half turn whose corners look alike, a
    row of identical doors).  If one map repeats itself under T_s, a wrong cross-map alignment T_s ∘ T can
    gather about as many supports as the repeat holds, even when the true overlap T gathers few (a damaged
    map).  0 without descriptors.

    ``inflation`` (a pair's final gate scale, with ``config.self_repeat_gate == "pair"``): the repeat's supports are
    counted in the gate that scale gives, the gate every other count of the decision uses.  Without it they are
    counted in the map's own claimed covariances, which with honest start-frame covariances reach the 1 m cap
    (rendered demo seed 8, robot 2: 23 supports of a 1 m shift, 12 of them 0.44-0.96 m off it; 14 in the pair's
    gate).

    ``rng`` None: the generator seeded by the map's content (:func:`fusion.fingerprint.content_rng`), made only when a
    draw is needed -- most maps have fewer than four self-matches and draw nothing, so they skip hashing the map
    (0.15 ms for 364 landmarks); the draws are the same either way."""
    n = len(landmark_map)
    if not has_descriptors(landmark_map) or n < 4:
        return 0
    # very large maps: a random subset of queries (a repeat shows in any sizeable sample of the map)
    rows = None
    if n * n > SELF_SEARCH_PAIRS:
        rng = content_rng(landmark_map) if rng is None else rng
        rows = np.sort(rng.choice(n, max(64, SELF_SEARCH_PAIRS // n), replace=False))
    pairs = self_correspondences(landmark_map.descriptors, config.descriptor_threshold, config.ratio or 1.0, rows)
    if len(pairs) < 4:
        return 0
    rng = content_rng(landmark_map) if rng is None else rng
    problem = correspondence_problem(landmark_map, landmark_map, pairs, config, distinct_scoring=True)
    # a fixed number of hypotheses: the near-identity ones (duplicates side by side) must not stop the search
    search = ransac(problem, replace(config, adaptive=False, iterations=min(config.iterations, 500)), rng)
    scored = problem if inflation is None else problem.inflated(inflation)
    return _second_best(scored, search, np.zeros(3), np.zeros(len(pairs), bool), config, unordered=True)


def evidence(problem: CorrespondenceProblem, search: RansacSearch, pose: np.ndarray, mask: np.ndarray,
             map1: LandmarkMap, map2: LandmarkMap, config: AlignmentConfig, rng: np.random.Generator,
             repeats: bool = False, self_repeat=None, admissible=None, possible=None,
             distinct_gate: float | None = None) -> Evidence:
    """The alignment's own evidence (see the module docstring): supports beyond the two that define a
    hypothesis against a Poisson null whose rate is the largest of the decoys', the one that makes the
    second-best distinct hypothesis a typical maximum and (``repeats``: maps matched by descriptors) the one
    that makes either map's repeat of itself (:func:`self_structure`) a typical maximum; Bonferroni over the
    hypotheses tried.  ``self_repeat(map) -> int`` gives a map's self-repeat count (default: :func:`self_structure`
    with a generator seeded by the map's content, so that the count is a property of the map alone); with
    ``config.self_repeat_gate == "pair"`` it is called as ``self_repeat(map, inflation)``, the pair's gate scale.

    ``admissible(poses) -> bool`` (a start prior, :mod:`fusion.prior`): only the hypotheses it admits are rivals and
    count in the Bonferroni factor (a false alarm needs the best hypothesis inside it); the best one outside it is
    reported (``outside``).  Each map's repeat of itself stays in the null whatever the prior: a wrong prior that
    agrees with a wrong winner (the truth damaged, its repeat winning) must not make it "found".

    ``possible(poses) -> bool`` (the co-location test, :mod:`fusion.colocation`) removes hypotheses as the prior does,
    from the rivals and the Bonferroni factor; the best one it removed is reported (``impossible``), not as outside the
    prior.

    The re-test in a narrower gate (the residual gate scale; ``distinct_gate`` None): polishing only widens the gate
    after its first round (``settled_scale``), so a hypothesis whose first fit was crude keeps the wide gate that fit
    called for after its pose has converged, and gathers loose supports in it that the rival, scored in the same gate,
    cannot match (rendered demo seed 4, robot 2 against robot 1's part before its gap: the building's half turn,
    polished from a hypothesis 0.2 rad off, keeps κ 1.8 and the 1 m cap where its converged fit calls for κ 0.28;
    32 supports against the truth's 20 in the 1 m gate, 19 against 15 in the narrower one).  When the winner's
    converged supports call for a gate whose median radius is smaller, the winner is polished again from its pose in
    that gate and the whole evidence (decoys, the same ones; rival; self-repeat) is measured again there, "distinct"
    still meaning what it meant in the first gate (``distinct_gate``: a narrower gate must not make the winner's own
    near neighbours its rivals); the stricter of the two decisions is returned (``narrowed_gate``: the second
    one's)."""
    s = int(problem.distinct_counts(mask[None])[0])
    narrow = distinct_gate is None                       # (the re-test in a narrower gate does not narrow again)
    same_decoys = copy.deepcopy(rng) if narrow else rng    # the narrower gate scores the same decoys, drawing nothing
    n_all = max(search.evaluated, 1)
    allowed = admissible
    if possible is not None:
        def allowed(poses: np.ndarray) -> np.ndarray:
            return possible(poses) & (True if admissible is None else admissible(poses))
    n = n_all if allowed is None else max(int(allowed(search.poses).sum()), 1)
    decoy_rate, phi = decoy_null(problem, map1, map2, config, rng, mask)
    rival = _best_distinct(problem, search, pose, mask, config, admissible=allowed, distinct_gate=distinct_gate)
    outside = 0 if admissible is None else _best_distinct(
        problem, search, pose, mask, config,
        admissible=lambda poses: ~admissible(poses) & (True if possible is None else possible(poses)),
        distinct_gate=distinct_gate).supports
    impossible = 0 if possible is None else _best_distinct(
        problem, search, pose, mask, config, admissible=lambda poses: ~possible(poses),
        distinct_gate=distinct_gate).supports
    second = rival.supports
    if config.self_repeat_gate not in SELF_REPEAT_GATES:
        raise IncompatibleMapsError(f"unknown self_repeat_gate {config.self_repeat_gate!r} (choose from "
                                    f"{', '.join(SELF_REPEAT_GATES)})")
    pair_gate = config.self_repeat_gate == "pair"
    if self_repeat is None:
        def self_repeat(m: LandmarkMap, inflation: float | None = None) -> int:
            return self_structure(m, config, None, inflation)      # seeded by the map's content when it draws
    repeat = 0
    if repeats:
        counts = [self_repeat(m, problem.inflation) if pair_gate else self_repeat(m) for m in (map1, map2)]
        repeat = max(counts)
    # the rival is the best of the n hypotheses inside the prior; the self-repeat was found without one, so its rate is
    # calibrated on all of them (a prior must not make the repeat's null stricter than it is without a prior)
    structure_rate = max(_rate_for_maximum(second - 2, n), _rate_for_maximum(repeat - 2, n_all))
    rate = max(decoy_rate, structure_rate, 1e-9)
    log10_p = _log10_null(s - 2, decoy_rate, structure_rate, n, phi)
    level = np.log10(config.significance) if config.significance is not None else -6.0
    required = max(config.min_supports, 3) if np.isfinite(decoy_rate) else 100_000   # (inf: no bound of φ)
    while _log10_null(required - 2, decoy_rate, structure_rate, n, phi) > level and required < 100_000:
        required += 1
    ambiguous = (structure_rate > decoy_rate if phi == 1.0 else
                 log10_false_alarm(s - 2, max(structure_rate, 1e-9), n)
                 >= log10_false_alarm(s - 2, max(decoy_rate, 1e-9), n, phi))
    wide = Evidence(s, decoy_rate, second, rate, n, log10_p, required, ambiguous, repeat,
                    rival.pose, rival.mask, outside, impossible, dispersion=phi)
    if not (narrow and config.gate_scale == "residual" and config.refine and config.inflate_gate) or s < 3:
        return wide
    kappa = residual_inflation(problem, mask, pose, config.gate_scale)
    if not (np.isfinite(kappa) and kappa < problem.inflation):
        return wide
    narrower = problem.inflated(kappa)
    if not narrower.gate_radius < problem.gate_radius:               # the gate the alignment reports would not narrow
        return wide
    n_pose, _, n_mask, narrower = polish(narrower, pose, narrower.masks(pose[None])[0], config)
    if not narrower.gate_radius < problem.gate_radius or n_mask.sum() < 2:
        return wide
    tight = evidence(narrower, search, n_pose, n_mask, map1, map2, config, same_decoys, repeats, self_repeat,
                     admissible, possible, distinct_gate=problem.gate_radius)
    # the stricter one: it never makes a "found" (nor lifts a start prior's contradiction, outside > supports)
    stricter = tight.log10_p > log10_p and (outside <= s or tight.outside > tight.supports)
    return replace(tight, narrowed_gate=narrower.gate_radius) if stricter else wide

