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

from . import chi2


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
                        ratio: float = np.inf, max_nodes: int = 200_000,
                        fewer_rival: bool = False, distinct_points: bool = False) -> ConstellationMatch:
    """Which of ``map_points`` the ``pass_points`` are, tested jointly (module docstring).

    positions (n, 2), covariance (2n, 2n): every point's position and their joint covariance; pass_points,
    map_points: indices into them (disjoint). ``allowed`` (n, n) bool: pairings that may be made at all (e.g. not
    two points seen in one frame; default: all). ``probability``: the χ² gate of every test. ``ratio``: a rival
    within this likelihood ratio of the best refuses the match (∞: any compatible rival does). ``max_nodes``: a
    cap on the search (exceeding it raises: the caller's candidates are too many for an exhaustive search).

    ``fewer_rival`` (session 29): a match is also refused (``"ambiguous"``, the rival returned) when a hypothesis
    with one pairing fewer that shares no pairing with the best fits at least as well — its d² as likely under
    χ²_{2(k−1)} as the best's under χ²_{2k}. "Most pairings wins" assumes a wrong hypothesis cannot gather as many
    pairings as the truth; on a loose map (gates metres wide) a row of posts shifted by one post gathers one pairing
    more than the truth, which leaves the row's end post unpaired, and only the fit tells them apart. A match must
    then out-fit the best contradicting hypothesis of one pairing fewer, not only out-number it (searched again
    without the best's pairings, so the search cost at most doubles).

    ``distinct_points`` (session 29): the pairings that count towards ``min_pairs`` are the best's *distinct* pass
    points — two of its pass points within each other's χ²₂ gate (two names the chain left of one post: their
    difference is centimetres, known to centimetres) are one point of the constellation. Pairing such twins with an
    earlier pass's twins adds a pairing but no distance or angle: a row of two posts then looks like three, and
    any two neighbours of a row 1.5 m apart match (robot 4, session 29). Fewer distinct points: ``"too_few"``."""
    if min_pairs < 1:
        raise ValueError(f"a match needs at least one pairing, not min_pairs={min_pairs}")
    if not ratio > 1:
        raise ValueError(f"the likelihood ratio over a rival must be > 1, not {ratio}")
    positions = np.asarray(positions, float)
    pass_points = [int(p) for p in pass_points]
    map_points = [int(q) for q in map_points]
    if set(pass_points) & set(map_points):
        raise ValueError("a point cannot be both in the pass and in the map")
    gates = chi2.ppf(probability, 2 * np.arange(1, len(pass_points) + 2))
    found = _most_pairings(positions, covariance, pass_points, map_points, allowed, gates, max_nodes)
    if not found:
        return ConstellationMatch("incompatible", None, None, float("-inf"), 0)
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
    if distinct_points and distinct_count(positions, covariance, [p for p, _ in best.pairs], probability) < min_pairs:
        return ConstellationMatch("too_few", best, rival, log_ratio, compatible)
    if rival is not None and not log_ratio >= np.log(ratio):
        return ConstellationMatch("ambiguous", best, rival, log_ratio, compatible)
    if fewer_rival and top > 1:
        near = _best_fewer_rival(positions, covariance, pass_points, map_points, allowed, gates, max_nodes, best)
        if near is not None and chi2.logsf(near.d2, near.dof) >= chi2.logsf(best.d2, best.dof):
            return ConstellationMatch("ambiguous", best, near, best.log_likelihood - near.log_likelihood,
                                      compatible)
    return ConstellationMatch("matched", best, rival, log_ratio, compatible)


def distinct_count(positions: np.ndarray, covariance: np.ndarray, points, probability: float = 0.99) -> int:
    """How many distinct places ``points`` are: the connected sets of points within each other's χ²₂ gate at
    ``probability`` (:func:`pairwise_d2`, the joint covariance's cross terms included)."""
    points = [int(p) for p in points]
    if len(points) < 2:
        return len(points)
    linked = pairwise_d2(positions, covariance, points) < chi2.ppf(probability, 2)
    label = list(range(len(points)))

    def find(i: int) -> int:
        while label[i] != i:
            i = label[i]
        return i

    for i, j in zip(*np.nonzero(np.triu(linked, 1)), strict=True):
        label[find(int(i))] = find(int(j))
    return len({find(i) for i in range(len(points))})


def _most_pairings(positions, covariance, pass_points, map_points, allowed, gates, max_nodes) -> list[Hypothesis]:
    """The depth-first search of :func:`match_constellation`: every jointly compatible hypothesis it meets with at
    least as many pairings as the most found so far (so those with the most pairings are all among them); [] when
    no pairing is individually compatible."""
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
        return []
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
    return found


def _best_fewer_rival(positions, covariance, pass_points, map_points, allowed, gates, max_nodes,
                      best: Hypothesis) -> Hypothesis | None:
    """The best-fitting (least d²) compatible hypothesis with one pairing fewer than ``best`` that makes none of its
    pairings; None when the most such a hypothesis reaches is fewer (or as many: that is a rival of equal size,
    already judged by the ratio)."""
    n = len(positions)
    without = np.ones((n, n), bool) if allowed is None else np.array(allowed, bool, copy=True)
    for p, q in best.pairs:
        without[p, q] = without[q, p] = False
    found = _most_pairings(positions, covariance, pass_points, map_points, without, gates, max_nodes)
    fewer = [h for h in found if len(h.pairs) == len(best.pairs) - 1]
    if not fewer or max(len(h.pairs) for h in found) != len(best.pairs) - 1:
        return None
    return min(fewer, key=lambda h: h.d2)


# ---- a tight map's last merges, pair by pair; a batch's merges tested one group at a time --------------------------

@dataclass(frozen=True)
class PairwiseGroup:
    """Points that :func:`pairwise_groups` finds within each other's gate: ``members`` (indices, ascending), d² of
    their differences from the first under the joint covariance and its degrees of freedom, and the verdict:
    ``"merge"`` (every two members within the gate, never sighted together, jointly compatible, no point outside
    the group within any member's gate) or why not: ``"covisible"`` (two members may not be one point),
    ``"not_joint"`` (a member outside another's gate, or the members' differences jointly out of the gate)."""

    members: tuple[int, ...]
    d2: float
    dof: int
    status: str


def pairwise_d2(positions: np.ndarray, covariance: np.ndarray, points) -> np.ndarray:
    """(k, k) d² of every two of ``points``' difference under their joint covariance (the 2 × 2 blocks of the
    covariance, cross terms included: two points' shared pose error cancels in their difference); inf on the
    diagonal and where the covariance is not finite or not positive definite."""
    points = np.asarray(points, int)
    k = len(points)
    idx = np.stack([2 * points, 2 * points + 1], 1).reshape(-1)
    blocks = np.asarray(covariance, float)[np.ix_(idx, idx)].reshape(k, 2, k, 2).transpose(0, 2, 1, 3)
    own = blocks[np.arange(k), np.arange(k)]
    with np.errstate(invalid="ignore"):
        s = own[:, None] + own[None, :] - blocks - blocks.transpose(1, 0, 2, 3)
    ok = np.all(np.isfinite(s.reshape(k, k, 4)), axis=2) & ~np.eye(k, dtype=bool)
    s = np.where(ok[..., None, None], s, np.eye(2))
    det = s[..., 0, 0] * s[..., 1, 1] - s[..., 0, 1] * s[..., 1, 0]
    ok &= (det > 0) & (s[..., 0, 0] > 0)
    det = np.where(ok, det, 1.0)
    d = np.asarray(positions, float)[points][:, None] - np.asarray(positions, float)[points][None]
    d2 = (s[..., 1, 1] * d[..., 0] ** 2 - (s[..., 0, 1] + s[..., 1, 0]) * d[..., 0] * d[..., 1]
          + s[..., 0, 0] * d[..., 1] ** 2) / det
    return np.where(ok, d2, np.inf)


def pairwise_groups(positions: np.ndarray, covariance: np.ndarray, points, *, allowed: np.ndarray | None = None,
                    probability: float = 0.99, split_ambiguous: bool = False) -> list[PairwiseGroup]:
    """The last merges of a tight map: which of ``points`` are one point, judged pair by pair but never alone.

    Two points are linked when the d² of their difference under their joint covariance (:func:`pairwise_d2`) is
    within χ²₂ at ``probability``. Each connected set of linked points (two or more) is one group, merged only when
    it can be one point and nothing else can be: every two members linked and allowed (``allowed`` (n, n) bool,
    e.g. not sighted in one frame; default all), and the members' stacked differences from the first jointly
    within χ²_{2(m−1)}. A point inside a member's gate is in the group by construction, so a rival — a second point
    the member could be, which cannot be the same point as the first — leaves the group not all linked, or not
    allowed, or jointly out of the gate, and refuses the whole group (ambiguous: nothing merges).

    ``split_ambiguous`` (session 27): a refused group is not refused whole. Its *ambiguous* members — those whose
    gate holds two members that cannot be one point (not linked to each other, or not allowed) — are left out (they
    stay as they are, status ``ambiguous``, one group each), and the rest is grouped and judged again by the same
    rules, until nothing is left out: a glimpse that could be either of two posts no longer keeps the names of
    each post apart. The names it could be are unaffected by where it goes."""
    points = [int(p) for p in points]
    if not points:
        return []
    d2 = pairwise_d2(positions, covariance, points)
    gate = float(chi2.ppf(probability, 2))
    linked = d2 < gate
    if split_ambiguous:
        return _split_groups(positions, covariance, points, linked, allowed, probability)
    label = list(range(len(points)))

    def find(i: int) -> int:
        while label[i] != i:
            label[i] = label[label[i]]
            i = label[i]
        return i

    for i, j in zip(*np.nonzero(np.triu(linked, 1)), strict=True):
        label[find(int(i))] = find(int(j))
    components: dict[int, list[int]] = {}
    for i in range(len(points)):
        components.setdefault(find(i), []).append(i)
    out = []
    for local in components.values():
        if len(local) < 2:
            continue
        members = [points[i] for i in local]
        order = np.argsort(members)
        local = [local[i] for i in order]
        members = [points[i] for i in local]
        pairs = [(members[0], m) for m in members[1:]]
        joint, _ = joint_d2(positions, covariance, pairs)
        dof = 2 * len(pairs)
        sub = np.ix_(local, local)
        if allowed is not None and not np.all(np.asarray(allowed)[np.ix_(members, members)]
                                              | np.eye(len(members), dtype=bool)):
            status = "covisible"
        elif not np.all(linked[sub] | np.eye(len(local), dtype=bool)) \
                or not joint < chi2.ppf(probability, dof):
            status = "not_joint"
        else:
            status = "merge"
        out.append(PairwiseGroup(tuple(members), float(joint), dof, status))
    return sorted(out, key=lambda g: g.d2 / g.dof)


def _split_groups(positions, covariance, points, linked, allowed, probability) -> list[PairwiseGroup]:
    """:func:`pairwise_groups` with ``split_ambiguous``: each refused group judged again without its ambiguous
    members, until every group merges or has no ambiguous member."""
    index = {p: i for i, p in enumerate(points)}
    can = np.ones((len(points), len(points)), bool) if allowed is None else \
        np.asarray(allowed)[np.ix_(points, points)] | np.eye(len(points), dtype=bool)
    compatible = (linked | np.eye(len(points), dtype=bool)) & can       # two members that may be one point
    out, todo = [], [points]
    while todo:
        subset = todo.pop()
        groups = pairwise_groups(positions, covariance, subset, allowed=allowed, probability=probability)
        for g in groups:
            if g.status == "merge":
                out.append(g)
                continue
            local = [index[m] for m in g.members]
            ambiguous = [m for m, i in zip(g.members, local, strict=True)
                         if _holds_two_apart(i, local, linked, compatible)]
            if not ambiguous:
                out.append(g)
                continue
            out.extend(PairwiseGroup((m,), 0.0, 0, "ambiguous") for m in ambiguous)
            rest = [m for m in g.members if m not in ambiguous]
            if len(rest) >= 2:
                todo.append(rest)
    return sorted(out, key=lambda g: g.d2 / g.dof if g.dof else np.inf)


def _holds_two_apart(i: int, local: list[int], linked: np.ndarray, compatible: np.ndarray) -> bool:
    """Whether member ``i``'s gate holds two members of ``local`` that cannot be one point."""
    near = [j for j in local if j != i and linked[i, j]]
    return any(not compatible[a, b] for k, a in enumerate(near) for b in near[k + 1:])


def spanning_pairs(pairs) -> list[tuple[int, int]]:
    """The pairings that join the same points into the same groups without a redundant one (a spanning forest:
    (root, member) for every point a group absorbs), so that their stacked differences have a regular covariance."""
    parent: dict[int, int] = {}

    def find(x: int) -> int:
        while parent.get(x, x) != x:
            x = parent[x]
        return x

    out = []
    for a, b in pairs:
        ra, rb = find(int(a)), find(int(b))
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
            out.append((int(a), int(b)))
    return out


def leave_one_out(positions: np.ndarray, covariance: np.ndarray, batches) -> list[tuple[float, int]]:
    """Each batch's share of a set of merges, tested given all the others: (d², degrees of freedom) of batch b's
    pairings conditioned on every other batch's — d²(all) − d²(all but b), each of the stacked differences of a
    spanning set of the pairings under their joint covariance, dof 2 per point b's pairings absorb beyond the
    others'. To first order the d² of all pairings is the cost a smoother pays to merge them, so this is the rise
    the batch adds on top of the others; a wrong batch hidden in many right ones stands out in its own share where
    the sum's rise cannot show it."""
    batches = [[(int(a), int(b)) for a, b in batch] for batch in batches]
    every = [pair for batch in batches for pair in batch]
    span = spanning_pairs(every)
    total, _ = joint_d2(positions, covariance, span)
    out = []
    for k in range(len(batches)):
        rest = spanning_pairs([pair for j, batch in enumerate(batches) if j != k for pair in batch])
        d2, _ = joint_d2(positions, covariance, rest)
        out.append((float(total - d2), 2 * (len(span) - len(rest))))
    return out


def guard_batches(positions: np.ndarray, covariance: np.ndarray, batches, *, probability: float = 0.99
                  ) -> tuple[list[int], list[tuple[int, float, int]]]:
    """The batches that may be merged together: while some batch's :func:`leave_one_out` share is beyond χ² at
    ``probability`` for its degrees of freedom, the one furthest beyond (by the χ² survival probability) is set aside
    and the shares taken again without it. Returns the kept batches' indices and the set-aside ones as (index, d²,
    dof) in the order they went. The batches should be disjoint groups of points: a pairing two batches both hold
    leaves each of them a share of 0 degrees of freedom (it is tested in neither). The shares are linearised at the
    current map: on a map far from linear (headings uncertain by tenths of a radian) they overstate the rise."""
    keep = list(range(len(batches)))
    dropped = []
    while keep:
        shares = leave_one_out(positions, covariance, [batches[k] for k in keep])
        worst, worst_log = None, float(np.log1p(-probability))
        for k, (d2, dof) in zip(keep, shares, strict=True):
            if dof == 0:
                continue
            log_sf = float(chi2.logsf(d2, dof))
            if log_sf < worst_log:
                worst, worst_log = (k, d2, dof), log_sf
        if worst is None:
            break
        keep.remove(worst[0])
        dropped.append(worst)
    return keep, dropped
