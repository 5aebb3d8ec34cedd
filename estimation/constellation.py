"""Joint compatibility of a constellation: which of a map's points a group of co-visible points is, tested together.

A pass of a robot past a few posts sees them close in time, so their relative geometry is known far better than
the pass's place in the map: over hundreds of seconds of odometry the pass may be off by metres and degrees, while
the posts of one pass stay centimetres apart from each other. A test of one pair of names (is point p point q?)
sees only the metres; a test of all of a pass's pairings together sees the centimetres too, because the pass's
points move together. That is joint compatibility (Neira & Tardós 2001, JCBB): a hypothesis pairs some of the
pass's points with distinct map points, and is compatible when the stacked differences d = [x_p − x_q] of all its
pairings lie within χ²_{2m} of zero under their joint covariance S = A C Aᵀ (C the points' joint covariance, A the
differencing). The unknown rigid offset of the pass is not a separate unknown here: it is in C, as the cross
covariance the smoother (or any estimator) gives points seen at different times — with an honest odometry model,
heading drift included, its long-range part is metres wide while the pass's internal part stays tight.

:func:`match_constellation` searches every jointly compatible hypothesis (depth first over the pass's points, each
paired with an allowed map point or with none, a branch cut as soon as its pairings are not jointly compatible),
keeps those with the most pairings, and decides:

- ``"matched"``: the best has ≥ ``min_pairs`` pairings and no rival — another compatible hypothesis with as many
  pairings that pairs some point differently — is within the likelihood ratio ``ratio`` of it (the default, ∞:
  any compatible rival refuses the match);
- ``"ambiguous"``: a rival is (the layout repeats within the pass's uncertainty);
- ``"too_few"``: no compatible hypothesis reaches ``min_pairs`` pairings, though one pairing was compatible;
- ``"incompatible"``: no pairing at all is individually compatible.

Why three pairings by default: two points fix a distance and a direction; within a layout of 15 posts 0.7–5 m
apart many pairs share a distance to centimetres, and the direction is what the pass's heading uncertainty
blurs. A third point adds a second distance and an angle, which a random layout rarely repeats.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.stats


@dataclass(frozen=True)
class Hypothesis:
    """Pairings (pass point, map point) as indices into the positions; d² of their stacked differences and its
    χ² degrees of freedom (2 per pairing); the Gaussian log likelihood of the differences at zero."""

    pairs: tuple[tuple[int, int], ...]
    d2: float
    log_likelihood: float

    @property
    def dof(self) -> int:
        return 2 * len(self.pairs)


@dataclass
class ConstellationMatch:
    """:func:`match_constellation`'s verdict (``status``: matched / ambiguous / too_few / incompatible), the best
    hypothesis (None when no pairing is compatible), the strongest rival with as many pairings (None: none), the
    log likelihood ratio of the best over it (∞ without a rival), and how many compatible hypotheses the search
    met (search nodes that passed the gate)."""

    status: str
    best: Hypothesis | None
    rival: Hypothesis | None
    log_ratio: float
    compatible: int


def joint_d2(positions: np.ndarray, covariance: np.ndarray, pairs) -> tuple[float, float]:
    """d² of the stacked differences x_p − x_q of ``pairs`` under their joint covariance, and log det of it.

    positions (n, 2); covariance (2n, 2n) the positions' joint covariance (rows of point i: 2i, 2i + 1)."""
    pairs = np.asarray(pairs, int).reshape(-1, 2)
    if len(pairs) == 0:
        return 0.0, 0.0
    p, q = pairs[:, 0], pairs[:, 1]
    d = (positions[p] - positions[q]).reshape(-1)
    ip = np.stack([2 * p, 2 * p + 1], 1).reshape(-1)
    iq = np.stack([2 * q, 2 * q + 1], 1).reshape(-1)
    s = covariance[np.ix_(ip, ip)] + covariance[np.ix_(iq, iq)] - covariance[np.ix_(ip, iq)] \
        - covariance[np.ix_(iq, ip)]
    if not np.all(np.isfinite(s)):
        return float("inf"), 0.0
    try:
        chol = np.linalg.cholesky(0.5 * (s + s.T))
    except np.linalg.LinAlgError:
        return float("inf"), 0.0
    z = np.linalg.solve(chol, d)
    return float(z @ z), float(2 * np.sum(np.log(np.diag(chol))))


def match_constellation(positions: np.ndarray, covariance: np.ndarray, pass_points, map_points, *,
                        allowed: np.ndarray | None = None, min_pairs: int = 3, probability: float = 0.99,
                        ratio: float = np.inf, max_nodes: int = 200_000) -> ConstellationMatch:
    """Which of ``map_points`` the ``pass_points`` are, tested jointly (module docstring).

    positions (n, 2), covariance (2n, 2n): every point's position and their joint covariance; pass_points,
    map_points: indices into them (disjoint). ``allowed`` (n, n) bool: pairings that may be made at all (e.g. not
    two points seen in one frame; default: all). ``probability``: the χ² gate of every test. ``ratio``: a rival
    within this likelihood ratio of the best refuses the match (∞: any compatible rival does). ``max_nodes``: a
    cap on the search (exceeding it raises: the caller's candidates are too many for an exhaustive search)."""
    if min_pairs < 1:
        raise ValueError(f"a match needs at least one pairing, not min_pairs={min_pairs}")
    if not ratio > 1:
        raise ValueError(f"the likelihood ratio over a rival must be > 1, not {ratio}")
    positions = np.asarray(positions, float)
    pass_points = [int(p) for p in pass_points]
    map_points = [int(q) for q in map_points]
    if set(pass_points) & set(map_points):
        raise ValueError("a point cannot be both in the pass and in the map")
    gates = scipy.stats.chi2.ppf(probability, 2 * np.arange(1, len(pass_points) + 2))
    # individually compatible pairings first (the tree's branches)
    options: list[list[int]] = []
    for p in pass_points:
        row = []
        for q in map_points:
            if allowed is not None and not allowed[p, q]:
                continue
            d2, _ = joint_d2(positions, covariance, [(p, q)])
            if d2 < gates[0]:
                row.append(q)
        options.append(row)
    if not any(options):
        return ConstellationMatch("incompatible", None, None, float("-inf"), 0)
    found: list[Hypothesis] = []
    nodes = 0
    most = 0

    def search(i: int, pairs: list[tuple[int, int]], used: set[int]) -> None:
        nonlocal nodes, most
        if i == len(pass_points):
            if pairs and len(pairs) >= most:
                d2, logdet = joint_d2(positions, covariance, pairs)
                most = len(pairs)
                found.append(Hypothesis(tuple(pairs), d2, -0.5 * d2 - 0.5 * logdet
                                        - len(pairs) * np.log(2 * np.pi)))
            return
        remaining = len(pass_points) - i
        for q in options[i]:
            if q in used:
                continue
            trial = pairs + [(pass_points[i], q)]
            nodes += 1
            if nodes > max_nodes:
                raise RuntimeError(f"constellation search over {max_nodes} nodes: too many candidate pairings")
            d2, _ = joint_d2(positions, covariance, trial)
            if d2 < gates[len(trial) - 1]:
                search(i + 1, trial, used | {q})
        if len(pairs) + remaining - 1 >= max(most, 1):      # the point left unpaired can still reach the best
            search(i + 1, pairs, used)

    search(0, [], set())
    compatible = len(found)
    top = max(len(h.pairs) for h in found)
    peers = sorted((h for h in found if len(h.pairs) == top), key=lambda h: -h.log_likelihood)
    best = peers[0]
    # every other hypothesis with as many pairings pairs some point differently: both cannot hold, or their union
    # (more pairings) would have been compatible and the best
    rival = peers[1] if len(peers) > 1 else None
    log_ratio = best.log_likelihood - rival.log_likelihood if rival is not None else float("inf")
    if top < min_pairs:
        return ConstellationMatch("too_few", best, rival, log_ratio, compatible)
    if rival is not None and not log_ratio >= np.log(ratio):
        return ConstellationMatch("ambiguous", best, rival, log_ratio, compatible)
    return ConstellationMatch("matched", best, rival, log_ratio, compatible)
