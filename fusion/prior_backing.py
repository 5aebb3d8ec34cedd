"""Whether a found alignment rests on its start prior: the winner's evidence measured again without the prior.

A start prior (``align(prior=)``, :mod:`fusion.prior`) removes the hypotheses outside it from the rivals and the
Bonferroni factor, so a pair whose maps alone are ambiguous (a building's half turn nearly as supported as the truth)
or too weak can be found with it.  Such a result stays "found": the prior is the user's stated knowledge of where the
robots started, and a right one is how a symmetric building is settled (the maps cannot do it; refusing would make
the prior useless exactly where it is needed).  But it is then only as right as the prior -- on rendered demo seed 19
(robot 2 first) a prior centred on the half turn gives "found", 19.6 m / 3.13 rad off, where the maps alone say
"ambiguous" (48 supports against 43) -- so the user must be able to tell it from a found the maps' evidence carries
alone: the winner's evidence is measured again without the prior (the search is not repeated: the prior never enters
RANSAC; the same decoys, each map's self-repeat counted once), and when that is not found the statistics say so
(``AlignmentStatistics.prior_decides``, the ``without_prior_*`` figures: the rival's supports, how far it is, whether
the prior excluded it) and ``Alignment.prior_backing`` gives the sentence ('found with the prior: the maps alone are
ambiguous (rival 43 supports against the best one's 48, turned 3.13 rad from it and moving its supports 8.0 m,
outside the prior; ...)') that ``p3at fuse``, the demo's summary and the recording report, with a warning.

:func:`fusion.align` calls :func:`self_repeat_counted_once` before its evidence and :func:`without_prior_statistics`
for a winner it finds with a prior; :func:`prior_backing_text` words the result.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .evidence import evidence, rival_offset, self_structure

if TYPE_CHECKING:
    from estimation.landmark_map import LandmarkMap

    from .alignment import AlignmentStatistics
    from .alignment_config import AlignmentConfig
    from .prior import StartPrior
    from .ransac import CorrespondenceProblem

PRIOR_BACKED = "found with the prior"


def prior_backing_text(stats: AlignmentStatistics) -> str:
    """Why a found alignment rests on its start prior, in one clause beginning 'found with the prior: the maps alone
    are ambiguous (rival 43 supports against the best one's 48, turned 3.13 rad from it and moving its supports
    8.0 m, outside the prior; ...)' (rendered demo seed 19, robot 2 first, a prior on the half turn); '' when the maps
    alone find it too (or no prior was given).  How far the rival is: its turn from the winner and the RMS distance
    by which it moves the winner's supports, as an ambiguous pair's reason says it (frame-independent, unlike the
    difference of the poses' translations: 19.6 m there)."""
    kind = stats.prior_decides
    if not kind:
        return ""
    alone = (f"false-alarm probability without the prior 10^{stats.without_prior_log10_chance_probability:.1f} over "
             f"{stats.without_prior_hypotheses} hypotheses, {stats.without_prior_required_supports} supports needed; "
             f"with it 10^{stats.log10_chance_probability:.1f} over {stats.prior_hypotheses}")
    if kind == "chance":
        return (f"{PRIOR_BACKED}: the maps alone are too weak ({stats.supports} supports are explainable by chance "
                f"without the prior; {alone})")
    if kind == "repeat":
        return (f"{PRIOR_BACKED}: the maps alone are ambiguous (one map repeats itself under a distinct transform "
                f"with {stats.self_repeat_supports} supports; {alone})")
    where = ("outside the prior" if stats.without_prior_rival_outside else
             "inside the prior, which discounts it by trying fewer hypotheses")
    away = (f", turned {stats.without_prior_rival_turn:.2f} rad from it and moving its supports "
            f"{stats.without_prior_rival_shift:.1f} m" if np.isfinite(stats.without_prior_rival_shift) else "")
    return (f"{PRIOR_BACKED}: the maps alone are ambiguous (rival {stats.without_prior_rival_supports} supports "
            f"against the best one's {stats.supports}{away}, {where}; {alone})")


def without_prior_statistics(problem: CorrespondenceProblem, search, pose: np.ndarray, mask: np.ndarray,
                             final_pose: np.ndarray, map1: LandmarkMap, map2: LandmarkMap, config: AlignmentConfig,
                             rng: np.random.Generator, repeats: bool, self_repeat, possible, prior: StartPrior,
                             start_cov: np.ndarray | None) -> dict:
    """The AlignmentStatistics fields that say what the maps alone decide about a winner found with a start prior:
    its evidence measured again without the prior (``rng`` in the state the first measurement found it, so the
    decoys are the same ones and the figures are align(prior=None)'s), and, when that is not found, why
    (``prior_decides``).  The search is not repeated: the prior enters only the evidence, never RANSAC."""
    alone = evidence(problem, search, pose, mask, map1, map2, config, rng, repeats=repeats, self_repeat=self_repeat,
                     admissible=None, possible=possible)
    out = {"without_prior_log10_chance_probability": alone.log10_p, "without_prior_required_supports": alone.required,
           "without_prior_hypotheses": alone.hypotheses, "without_prior_rival_supports": alone.second_best}
    if alone.rival_pose is not None:
        out["without_prior_rival_pose"] = tuple(float(v) for v in alone.rival_pose)
        out["without_prior_rival_outside"] = not bool(prior.admits(alone.rival_pose, start_cov))
        if mask.any():
            out["without_prior_rival_shift"], out["without_prior_rival_turn"] = rival_offset(
                final_pose, alone.rival_pose, problem.p2[mask])
    if alone.log10_p > np.log10(config.significance):
        out["prior_decides"] = ("chance" if not alone.ambiguous else
                                "repeat" if alone.self_repeat > alone.second_best else "ambiguous")
    return out


def self_repeat_counted_once(self_repeat, config: AlignmentConfig):
    """``self_repeat(map, *scale)`` as :func:`fusion.evidence.evidence` calls it (None: its default,
    :func:`fusion.evidence.self_structure` seeded by the map's content), each count computed once: the evidence
    measured again without a prior asks for the same maps' counts."""
    counts: dict = {}

    def remembered(m: LandmarkMap, *scale) -> int:
        key = (id(m), scale)
        if key not in counts:
            counts[key] = (self_structure(m, config, None, *scale) if self_repeat is None else self_repeat(m, *scale))
        return counts[key]
    return remembered
