"""Live fusion: an alignment of maps that are still growing is a candidate until a later fusion agrees.

Why. The decision (``fusion.align``) counts supports against what maps of these sizes give by chance, and a map's
own repeated structure (its self-repeat) raises the count it needs.  Early in a mission the maps are small: each
robot has seen one part of the building, and a building that repeats itself (the rendered demo's is symmetric
under a half turn, in layout and appearance) can show one copy of its repetition in one robot's map and the other
copy in the other's.  Neither map then holds both copies, so neither self-repeat can warn, and the half turn wins
with supports the chance model calls overwhelming: demo seed 1 at t = 20 s, 26 supports of 24 needed,
P(chance) 3e-8, 4.85 m / π from the truth (session 9 measured 7 such "found" on 6 of 10 seeds, while every final
fusion was right).

What. A mission or a live fusion node knows more than one fusion: it fuses the same robots again as their maps
grow.  Loop closures in visual SLAM are treated the same way: a place-recognition match is accepted only when
later keyframes agree with it (ORB-SLAM's loop detection asks three consecutive consistent candidates).  So here a
found alignment of a pair is reported *found* only when a fusion at least ``min_gap`` seconds later, on maps that
changed, finds a transform that agrees with it; until then it is a *candidate* and not found (its reason says
so, with its supports and pose).  Agreement: the two transforms' difference within χ²₃ (``level``) of the sum of
their start covariances (each already counts its maps' frame errors, which move between two fusions); for the
paper preset, which has no covariances, the two transforms must place every support of the later alignment
within the paper's support distance th2 of each other.

Against which earlier found.  Each pair keeps the *first* found of its current run of agreeing founds (its
anchor), and every later found is judged against it: one that agrees continues the run, and is confirmed once it
is ``min_gap`` or more after the anchor; one that disagrees is a candidate and starts a new run (the clock
restarts).  A fusion that found nothing (ambiguous, too few supports) neither continues nor ends a run.  So a
live node that fuses every second confirms ``min_gap`` seconds after the run began (judged against the latest
found only, each found was always less than ``min_gap`` after the one before, and nothing was confirmed until the
final fusion: session 48), and a mission that fuses every ``min_gap`` seconds decides as before.  If the maps
have not changed since the anchor's fusion, the anchor is taken as that later fusion's: the clock counts the maps'
growth, not the fusions.  Once confirmed, a pair stays found while each found agrees with its anchor.

What it does not do. It adds no evidence: two fusions of overlapping data can agree on a wrong alignment if the
maps keep showing one copy each of a repetition for longer than ``min_gap``.  It only asks the wrong alignment to
survive the maps' growth, which every one measured on the demo did not.  A final fusion on complete maps (a mission
whose robots all finished their routes; the fleet node's last) is the caller's to decide on the maps alone, through
``inner``, as ``p3at fuse`` does on saved maps.
"""
from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from estimation import chi2
from estimation.geometry import transform_points, wrap_angle

from .cache import AlignmentCache
from .fingerprint import map_fingerprint

if TYPE_CHECKING:
    from .alignment import Alignment

CANDIDATE = "candidate"   # the first word of a demoted alignment's reason


def transforms_agree(earlier: Alignment, later: Alignment, later_points: np.ndarray | None = None,
                     support_distance: float = 0.0, level: float = 0.999) -> tuple[bool, str]:
    """Whether two found alignments of one pair of robots are the same transform; (agree, how far apart in words).

    With both start covariances (else the alignments' own): the difference (Δx, Δy, Δθ) within χ²₃ at ``level`` of
    their sum.  Without covariances (paper preset): ``later_points`` (P, 3), the later alignment's supports in the
    other map's frame, must land within ``support_distance`` under both transforms.
    """
    a, b = np.asarray(earlier.pose, float), np.asarray(later.pose, float)
    delta = np.array([b[0] - a[0], b[1] - a[1], wrap_angle(b[2] - a[2])])
    apart = f"{np.hypot(delta[0], delta[1]):.2f} m / {abs(delta[2]):.3f} rad apart"
    covs = [x.start_covariance if x.start_covariance is not None else x.covariance for x in (earlier, later)]
    if all(c is not None for c in covs):
        total = np.asarray(covs[0], float) + np.asarray(covs[1], float)
        try:
            d2 = float(delta @ np.linalg.solve(total, delta))
        except np.linalg.LinAlgError:
            return False, apart + " (singular covariance)"
        return bool(d2 <= chi2.ppf(level, 3)), apart
    if later_points is None or len(later_points) == 0:
        return False, apart + " (no covariance and no supports to compare)"
    moved = transform_points(b, later_points) - transform_points(a, later_points)
    return bool(np.max(np.hypot(moved[:, 0], moved[:, 1])) <= support_distance), apart


@dataclasses.dataclass
class _PairState:
    """A found alignment of one pair of robots, what it rested on, and how it was judged."""

    alignment: Alignment
    content: tuple            # the maps' fingerprints it was computed from
    t: float
    confirmed: bool
    continues: bool           # it agrees with the pair's anchor (or is the anchor's maps again): the run goes on


class ConfirmingCache:
    """An :class:`~fusion.cache.AlignmentCache` for a caller that fuses the same robots again and again: a found
    alignment becomes found only when a fusion ``min_gap`` s or more after the first found of its agreeing run, on
    changed maps, agrees with that first one (module doc).

    Call :meth:`start_round` with the fusion's time before each fusion; every ``align`` of that fusion is judged
    against the founds of earlier rounds only (a flagged map's parts and the whole map are aligned in one round and
    never confirm each other).  ``inner`` computes and caches the alignments; a final fusion that should be decided
    on the maps alone uses ``inner`` directly.
    """

    def __init__(self, min_gap: float, inner: AlignmentCache | None = None, level: float = 0.999) -> None:
        if not (np.isfinite(min_gap) and min_gap >= 0):
            raise ValueError(f"min_gap must be a finite number of seconds >= 0, not {min_gap!r}")
        self.min_gap, self.level = float(min_gap), float(level)
        self.inner = inner if inner is not None else AlignmentCache()
        self._anchor: dict[tuple, _PairState] = {}     # by pair of robots: the first found of the agreeing run
        self._latest: dict[tuple, _PairState] = {}     # by pair of robots: the latest round's found
        self._this_round: dict[tuple, _PairState] = {}
        self.t = 0.0

    def start_round(self, t: float) -> None:
        """A new fusion at time ``t`` (s): the previous round's founds become what later ones are judged against."""
        for key, state in self._this_round.items():
            anchor = self._anchor.get(key)
            if anchor is None or not state.continues or anchor.content == state.content:
                self._anchor[key] = state      # a new run; or the anchor's maps, still unchanged at this later fusion
            self._latest[key] = state
        self._this_round = {}
        self.t = float(t)

    def self_structure(self, *args, **kwargs) -> int:
        return self.inner.self_structure(*args, **kwargs)

    def align(self, map1, map2, preset="robust", rng: np.random.Generator | None = None, prior=None) -> Alignment:
        """``inner.align``, then found only if it agrees with its run's first found, ``min_gap`` s or more earlier
        (else a candidate, not found)."""
        result = self.inner.align(map1, map2, preset, rng, prior=prior)
        if not result.found:
            return result
        key = (tuple(map1.robots), tuple(map2.robots))
        content = (map_fingerprint(map1), map_fingerprint(map2))
        latest, anchor = self._latest.get(key), self._anchor.get(key)
        if latest is not None and latest.content == content:    # the same maps: no new evidence either way
            confirmed, continues, why = latest.confirmed, True, "the maps have not changed since"
        elif anchor is None:
            confirmed, continues, why = False, False, "no earlier fusion of these maps found it"
        else:
            from .alignment_config import resolve_preset

            config = resolve_preset(preset)
            points = map2.positions[result.supports[:, 1]] if len(result.supports) else None
            continues, apart = transforms_agree(anchor.alignment, result, points, config.support_threshold,
                                                self.level)
            if not continues:
                confirmed, why = False, f"disagrees with the fusion at t={anchor.t:.0f}s ({apart})"
            elif self.t - anchor.t < self.min_gap:
                confirmed, why = False, (f"agrees with the fusion at t={anchor.t:.0f}s, which is less than "
                                         f"{self.min_gap:g} s before")
            else:
                confirmed, why = True, f"agrees with the fusion at t={anchor.t:.0f}s"
        best = self._this_round.get(key)
        if best is None or len(result.supports) > len(best.alignment.supports):
            self._this_round[key] = _PairState(result, content, self.t, confirmed, continues)
        return result if confirmed else demoted(result, why, self.min_gap)


def demoted(alignment: Alignment, why: str, min_gap: float) -> Alignment:
    """The candidate that ``alignment`` is until confirmed: not found, its statistics and supports kept."""
    x, y, th = (float(v) for v in alignment.pose)
    reason = (f"{CANDIDATE}: {len(alignment.supports)} supports at ({x:.2f} m, {y:.2f} m, {th:.3f} rad); {why}; "
              f"the maps are still growing, so a fusion at least {min_gap:g} s later must agree")
    return dataclasses.replace(alignment, found=False, pose=None, covariance=None, start_covariance=None,
                               reason=reason)


def candidate_clause(reason: str) -> str | None:
    """For a demoted alignment's reason: '26 supports at (…); why it is not confirmed' (None for any other reason)."""
    prefix = f"{CANDIDATE}: "
    if not reason.startswith(prefix):
        return None
    return reason[len(prefix):].split("; the maps are still growing", 1)[0]
