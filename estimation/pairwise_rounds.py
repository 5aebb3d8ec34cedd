"""The unknown-association chain's last merges, on a tight map: :func:`pairwise_rounds` (every group of names that
can be one post and nothing else, :func:`estimation.constellation.pairwise_groups`, screened, guarded, merged and
bisected as the passes' pairings are in the rounds) and :func:`alone_checked` (``pairwise_alone``: each group's own
cost check before the batch's). Split out of :mod:`estimation.name_chain` in session 37 (B), unchanged."""
from __future__ import annotations

import numpy as np

from estimation.chain_observer import ChainObserver
from estimation.chain_run import ChainRun
from estimation.constellation import pairwise_groups, spanning_pairs
from estimation.merge_screens import flagged_names
from estimation.name_merging import NamedSmoother, merge_once
from estimation.named_smoothing import MergeRound
from estimation.pairwise_audit import refused_alone
from estimation.pass_matching import PassVerdict, merges_from, pairwise_inputs

__all__ = ["alone_checked", "pairwise_rounds"]


def pairwise_rounds(run: ChainRun, current: MergeRound) -> MergeRound:
    """The last merges on a tight map (:func:`estimation.constellation.pairwise_groups`): every group of names
    that can be one post and nothing else, merged (with ``guard``, the groups' leave-one-out shares tested
    first), checked by the cost rise and bisected as the passes are; repeated until nothing merges or
    ``pairwise`` rounds, numbered on from the pairwise rounds ``run`` already ran (its count goes on)."""
    s = run.settings
    done = run.pairwise_done
    for k in range(done, done + s.pairwise):
        number = k + 1
        run.pairwise_done = number
        run.observer.pairwise_begins(number, current)
        problem, solution = current.named.problem, current.solution
        covariance, covisible, seen = pairwise_inputs(current, name_floor_m=s.name_floor,
                                                      kept_covisible=s.kept_covisible)
        groups = pairwise_groups(solution.landmarks, covariance, seen, allowed=~covisible,
                                 split_ambiguous=s.split_ambiguous)
        run.observer.pairwise_grouped(number, current, groups)
        if s.honest_names is not None:      # helper B's screen (session 27): a member holding a run that bends
            flagged = flagged_names(problem, solution, s.honest_names, two_points=s.hold_two_points)
            held = [g for g in groups if g.status == "merge" and flagged[list(g.members)].any()]
            run.observer.pairwise_honest(number, current, flagged, held)
            groups = [g for g in groups if not any(g is h for h in held)]
        merging = [PassVerdict(-1 - i, "matched", spanning_pairs([(g.members[0], m) for m in g.members[1:]]),
                               (len(g.members), -g.d2 / g.dof), 0, True)
                   for i, g in enumerate(x for x in groups if x.status == "merge")]
        clusters, used = merges_from(merging, covisible)
        if used and s.pairwise_alone:       # each group's own cost check before the batch's (session 32, A)
            used = alone_checked(run.smoother, current, used, covisible, observer=run.observer, number=number)
        guarded = None
        if used:
            guarded = run.guard(f"pairwise {number}", current, covariance, used, covisible)
        run.observer.pairwise_proposed(number, current, used)
        if not used:
            break
        state = run.merge(current, used, guarded, f"pairwise {number}", kept_covisible=s.kept_covisible,
                          untestable=False)
        if state is current:
            break
        run.observer.state_kept(f"pairwise{number}", state, -number, run.smoother, current)
        current = state
    return current


def alone_checked(smoother: NamedSmoother, current: MergeRound, used: list[PassVerdict], covisible: np.ndarray, *,
                  observer: ChainObserver | None = None, number: int = 0) -> list[PassVerdict]:
    """``pairwise_alone`` (session 32, A): each pairwise group of ``used`` merged alone from ``current`` and kept for
    the batch only when its own rise is within χ² 99 % for 2 per absorbed name
    (:func:`estimation.pairwise_audit.refused_alone`): the batch's bound is the sum over its groups, and one wrong
    group hides in the others' slack (robot 2 seed 1's glimpse: 9.6 alone against 9.2, 14.2 against 23.2 in its
    batch of five). Each group's rise and verdict told to ``observer`` (as pairwise round ``number``)."""
    rises, absorbed = [], []
    for v in used:
        alone = merge_once(smoother, current, merges_from([v], covisible)[0])
        rises.append(alone.rise)
        absorbed.append(len(alone.merged))
    refused = refused_alone(rises, absorbed)
    if observer is not None:
        observer.alone_checked(number, current, used, rises, absorbed, refused)
    return [v for v, f in zip(used, refused, strict=True) if not f]
