"""MRCLAM without barcodes: a pass's co-visible names matched to an earlier pass's jointly (a constellation test).

Run from the repository root:

    .venv/bin/python -m benchmarks.mrclam_constellation [--robots 1,2,3,4,5] [--seed 0] [--names-cache DIR]
        [--drift 0.16 10] [--path-step 0.25] [--split-bends] [--pass-seconds 20] [--min-pairs 3] [--ratio R]
        [--max-rounds 3] [--bisect 2] [--reguess] [--layout] [--ceiling] [--progress] [--json]
        [--state-dir DIR] [--from-round K] [--pairwise ROUNDS] [--kept-covisible] [--name-floor M] [--guard]
        [--sighting-offset M] [--offsets-once-tight] [--split-ambiguous] [--honest-names ALPHA]
        [--leave-out-ambiguous] [--leave-out-unconfirmed] [--name-unnamed] [--runs-out] [--slip 0.3]
        [--fewer-rival] [--distinct-points] [--rival-rounds K] [--hold-two-points] [--mutual-rounds] [--fresh-start]
        [--audit-parts FLOOR_M] [--pairwise-alone] [--out-maps DIR] [--heading-loss student-t] [--heading-dof NU]
        [--noise FILE]

Measured (session 24, A; docs: "Session 24: joint (constellation) tests of a pass's co-visible names (A)"):
**negative** against the target, nothing wired. Robots 1-5, seed 0, 3-4 rounds: 0 wrong merges kept (every batch
that held one was undone by the cost rise); ATE 4.03 / 0.92 / 2.21 / 2.96 / 1.42 -> 2.62 / 0.127 / 0.100 / 2.77 /
0.139 m (known-ID 0.286 / 0.030 / 0.095 / 0.044 / 0.030 m), but duplicates 83 / 75 / 46 / 85 / 89 % and the partly
merged maps overconfident (start-frame NEES within 28 / 52 / 70 / 73 / 94 %). ``--ceiling`` (the names merged by
their barcodes): ATE 0.075 / 0.029 / 0.095 / 0.044 / 0.028 m, NEES within 100 %: the names would do.

Session 25 (A; docs: "Session 25: why partly merged maps are overconfident ... (A)"): the overconfidence had two
causes on robot 2, each measured: increments across sighting gaps took the random walk's variance of their chord
(now ``--path-step 0.25``: along the path), and a chained name's run of another post's sightings pinned its stretch
once the name was merged (``--split-bends`` finds it: cost drop 33.2 against 0.0-3.6). With both, robot 2's round 1
keeps NEES within 90 % (69 % before) and round 2 reaches ATE 0.048 m, 2.7 names per post, with one wrong merge in a
batch of 75. ``--bisect`` keeps more right merges but let a wrong one through twice (robot 2: a piece of 7, rise 6.3
over 29.1; robot 5 seed 2: a half of 71, 183.1 over 184.1). Seed 0 with path variances and bisection, 0 wrong merges:
robots 1 / 3 / 4 / 5 at 1.5 / 1.9 / 2.5 / 2.0 names per post, ATE 0.086 / 0.101 / 0.122 / 0.030 m (known-ID 0.286 /
0.095 / 0.044 / 0.030 m). Duplicates < 5 % not reached: the passes left are incompatible with the map.

Session 26 (A; docs: "Session 26: the last merges of a tight map pair by pair, ... (A)"): ``--pairwise`` on robot
5 seed 0 after six rounds (``--kept-covisible``): 8 merges, 0 wrong, 33 -> 25 names (1.6 per post, duplicates 38 %),
ATE 0.029 m; on robot 3 it makes one wrong merge (its map is 0.6 m wrong at σ 0.1 m over a 22 s stretch). The last
passes are incompatible because 55 of 90 are never offered their twin (a name the pass itself holds) and 35 find it
3-13 cm off at σ ~1 cm. ``--guard`` on robot 5 seed 2 sets aside exactly session 25's three wrong groups (0 wrong, ATE
0.074 m, 2.9 names per post); it does not see robot 2's (posts 19 and 20, 0.73 m apart, are not told apart there).

Session 27 (A; docs: "Session 27: a sighting offset per name in the smoother's model ... (A)"): ``--sighting-offset
0.03`` gives every smoothing a 2-D offset per chained name (the round-0 names) with prior σ 0.03 m per axis
(:class:`estimation.landmark_smoother.SightingOffset`; σ measured against the truth by
``benchmarks.mrclam_sighting_offset``: a visit's or a name's sightings share ≈ 3 cm, a post's all visits ≈ 1 cm), so
merged names of one post may differ by ≈ σ√2 at the prior's cost. ``--split-ambiguous``: a refused pairwise group is
judged again without the glimpses whose gate holds two posts. From session 26's states, 0 wrong merges: robot 5
seed 0 25 → 20 names (duplicates 38 → 25 %), robot 1 seed 0 20 → 17 names, robot 2 seed 2 20 → 16 names (duplicates
6 %, one 5-sighting glimpse left), ATE within 1.1× known-ID (robot 1 0.067 m against 0.286 m); robot 3 seed 0 still
makes session 26's wrong pairwise merge (its map, not the offsets).

Session 28 (lead; docs: "Session 28: the whole chain as one command ... (lead)"): ``--max-rounds 9 --guard
--sighting-offset 0.03 --offsets-once-tight --pairwise 6 --kept-covisible --split-ambiguous --honest-names 0.01
--leave-out-ambiguous --leave-out-unconfirmed``: robots 1, 3, 5 seed 0 and 2 seed 2 at 15 names for 15 posts
(duplicates 0 %), ATE 0.064 / 0.137 / 0.033 / 0.033 m, landmark NEES within 100 %, 0 wrong merges, no post lost;
robot 5 seed 2 the same but ATE 0.070 m (2.3x known-ID); robots 2 s0, 3 s2, 1 s2, 4 s0, 4 s2 keep the wrong merges of
their first rounds (``--min-pairs 4`` removes robot 4's and adds 3 on robots 1 and 2 seed 0). With ``--honest-rounds``
also robot 3 seed 2 (15 names, 0.129 m, 0 wrong): five robot-seeds; robot 2 seed 0 then makes 2 wrong pairwise
merges on its overconfident wiggle stretch, robot 4 seed 0 keeps its 15.

Session 29 (lead, A, C; docs: "Session 29: sightings the chain left unnamed ... (lead)"): ``--name-unnamed`` (step
9), ``--slip`` (the smoother's heading slip per radian turned on the spot, C), ``--fewer-rival`` and
``--distinct-points`` (step 3, A). With ``--slip 0.3 --name-unnamed`` robots 3, 5 seed 0 and 2, 3, 5 seed 2 meet every
figure (15 names, ATE ≤ 1.1x known-ID, NEES within 100 %, 0 wrong); robot 1 seed 0's ATE is 0.340 m (its first
second, named now, moves the frame: known-ID 0.288 m) with NEES within 87 %; A's options give robot 4 both seeds
0 wrong merges and 16 names but robot 2 seed 0 three wrong merges. (Robot 2 seed 2's row there was a scratch run:
with the committed code its round 2 keeps one wrong merge; session 30, B.)

Session 30 (lead, B, C; docs: "Session 30: the remedies in one command ... (lead)"): ``--runs-out`` (step 10, B),
``--hold-two-points`` (C), ``--rival-rounds`` (not adopted), ``map_consistency`` in the final record (C). Session
29's command with ``--fewer-rival --distinct-points --hold-two-points --runs-out``: all five robots of seed 0 at 15
names, ATE 1.02-1.17x known-ID, NEES within 93-100 %, 0 wrong merges on robots 1-4 and one on robot 5 (round 5);
robot 4 seed 2 the same with 0 wrong; seed 2 does not meet (robot 5's rounds go 1 m off with A's options, robot 1
keeps wrong merges, robot 2 one round-2 wrong merge).

Session 31 (lead, A, B, C; docs: "Session 31 ..."): ``--out-maps`` writes each final map without descriptors or
identities for ``p3at fuse`` (geometry alone); three options for the remaining wrong merges, each measured by its
helper on the robot-seeds it was designed on: ``--mutual-rounds`` (B: a round's cluster merges only if its members
are all within each other's gate; robot 1 seed 2), ``--fresh-start`` (A: a refused whole batch judged again from the
filter's guess on the merged names; robot 5 seed 2's local minimum), ``--audit-parts 0.042`` (C: each part of a merged
name tested on the merged map, floor √2 × the 3 cm per-name offset; robots 5 seed 0 and 2 seed 2).

Session 32 (lead, A, B; docs: "Session 32 ..."): ``--pairwise-alone`` (A: each pairwise group merged alone
first and left out of the batch when its own rise is beyond χ² 99 % for 2 per absorbed name; robot 2 seed 1's glimpse,
9.6 alone against 9.21, hid in its batch's 14.2 against 23.2).

Session 23 (E) left the chain of names (``benchmarks.mrclam_chained_names``) honest with the smoother's heading-bias
states, and its loops unclosed: over hundreds of seconds the difference of two names of one post has σ 1.7–3.7 m,
the posts are 0.7–1.9 m apart, and 33–60 % of other-post pairs fall in a pairwise gate. A pass past the posts sees
3–6 of them within seconds, and their relative geometry is known to centimetres; this benchmark tests a pass's
names against an earlier pass's *together* (:mod:`estimation.constellation`).

The method (the barcodes never decide; they only score). Since session 36 (A) the whole of it, steps 1 to 10, is
:func:`estimation.name_chain.run_chain` with :class:`estimation.name_chain.ChainSettings` (:func:`settings_of` the
options below; its defaults are session 30's command); this benchmark gives it the cached chained names and guess,
or a kept state (``--from-round``), and records and scores every decision through its observer (:class:`_Recorder`):

1. **Names**: session 21's chained names (``mrclam_chained_names._chained``, the same ``--names-cache``; the method
   is :mod:`estimation.chained_names`, the smoothing :mod:`estimation.named_smoothing`), smoothed
   with the heading drift (``--drift``, default σ_b 0.16 rad/m, τ 10 s, E's) from the known-ID filter's guess; the
   odometry increments between sighting frames with their variance along the path driven (``--path-step``, 0.25 s
   steps; session 25: the chord's variance made a gap of sightings in which the robot turned back and forth as
   certain as no turn). 1b. With ``--split-bends``: names split where the odometry bends and the cost says so
   (:func:`split_at_bends`; session 25: a chained name holding a run of another post's sightings).
2. **Passes** (steps 2 to 4's passes, joint tests and merge clusters are :mod:`estimation.pass_matching`'s): the
   log cut into disjoint spans of ``--pass-seconds``; a pass holds the names with at least ``--min-sightings`` kept
   sightings in its span.
3. **Joint test**: each pass P against each earlier pass Q
   (:func:`estimation.constellation.match_constellation`; names both hold are pairings already made, counted
   towards ``--min-pairs``, the others are tested): positions and joint covariance from the smoother
   (``joint_landmark_covariance``: the pass's unknown offset is in the cross covariance, drift included), pairings
   only between names never sighted in one frame; matched when ≥ ``--min-pairs`` pairings are jointly compatible
   (χ²_{2m} 99 %) and no rival with as many pairings is (or, with ``--ratio``, none is within that likelihood
   ratio). Then across the earlier passes P matched: all their pairings together must be jointly compatible
   (two different places for one pass's constellation: ambiguous, refused). ``--fewer-rival``: a match is refused
   when a hypothesis of one pairing fewer, sharing none of its pairings, fits as well by χ² survival (a row of posts
   shifted by one pairs one name more than the truth); ``--distinct-points``: pairings counted by distinct pass
   points; ``--rival-rounds K``: both in rounds 1..K only (the loose map's, where a shifted row fits).
4. **Merges**: the matched passes' pairings, most pairings first then largest ratio, joined name by name unless the
   join puts two names sighted in one frame together; re-smoothed, the batch kept when the truncated cost's rise
   is within χ² 99 % for 2 per absorbed name; a refused batch is cut in halves, each tried in turn, down to
   ``--bisect`` levels, the last level's refused halves retried as their strongest pass alone (``--bisect 0``:
   session 24's rule, the strongest pass alone at once); up to ``--max-rounds`` rounds. Before the merge, the
   guard (:func:`estimation.constellation.guard_batches`) tests each merge group's share of the batch given the
   others' (leave one out, linearised on the current map); its verdict is printed on every round and, with
   ``--guard``, a batch the cost check refuses is retried without the groups it set aside before it is bisected
   (session 26: on loose maps the linear shares are far above the smoother's rise, so the guard never overrules an
   accepted batch).
5. **Pairwise** (``--pairwise ROUNDS``, after the rounds): every group of names within each other's χ²₂ 99 % gate
   under the joint covariance, never sighted in one frame, jointly compatible and with no rival in any member's gate
   (:func:`estimation.constellation.pairwise_groups`), merged and checked as a batch is (session 26: the pass
   structure never pairs two names one pass holds). ``--kept-covisible``: "sighted in one frame" by kept sightings
   only. ``--name-floor``: a per-name offset σ added in the pairwise gate. ``--split-ambiguous``: a refused group
   is judged again without its ambiguous members (``pairwise_groups(split_ambiguous=True)``).
   ``--pairwise-alone``: each group merged alone first, and left out when its own rise is beyond the bound for its
   absorbed names (:func:`estimation.pairwise_audit.refused_alone`).
6. ``--sighting-offset M`` (session 27): every smoothing (and so every joint covariance, gate and cost check) carries
   an offset per round-0 name of prior σ M per axis; from a saved state, the state is re-smoothed with it first.
   ``--offsets-once-tight`` (session 28): the rounds run without the offsets until one keeps nothing (or the last
   round), then the state is re-smoothed with them and that round judged again (session 27: on a loose map the
   offsets let batches holding wrong pairings pass the cost check; they belong to the tight map's last merges).
7. ``--leave-out-ambiguous`` (session 28): after the merges, each name whose pairwise gate holds two names that
   cannot be one post (:func:`ambiguous_names`, the least certain first, judged again after each) is left out of
   the map — its sightings unnamed, the rest re-smoothed — instead of standing as a second name of one post; then
   the pairwise rounds again (a name the glimpse kept apart from its twin may merge). Scored by the barcodes (was it
   a duplicate, did a post lose its only name).
8. ``--leave-out-unconfirmed`` (session 28), last: the filter's own two rules on the smoothed map
   (:func:`unconfirmed_names`): a name whose existence log-odds (detections and in-view misses at the calibrated
   detection rates) are below the removal threshold, and which a neighbour within ``merge_radius``, never detected
   with it, explains by the co-visibility test, is left out: a few sightings placed off their post by a bent stretch
   (robot 5: 3-6 sightings 0.2-0.56 m off, in view in ~1,600 frames), not a landmark of its own.

9. ``--name-unnamed`` (session 29), last: every sighting no name holds that exactly one name explains at the
   smoothed pose by the smoother's own outlier bound (:func:`unnamed_names`) is named, and the map re-smoothed
   (:func:`name_unnamed`): the first seconds' sightings tie the map's frame.

10. ``--runs-out`` (session 30, B and the lead): the runs of sightings the honest-names screen flags
   (:func:`estimation.map_honesty.flagged_runs`, a name's largest run never) are taken out of their names
   (:func:`leave_out_flagged_runs`) on the tight map before the pairwise rounds, so that the last merges do not judge
   a stretch the runs bend (robot 2 seed 0 with ``--fewer-rival``: 3 wrong pairwise merges -> 0), and again after the
   naming, then the pairwise rounds and the naming run again: a flagged run no longer keeps its name from its twin
   (robot 4), and a stray run no longer bends the stretch that holds a post's second name (robot 2 seed 0).

``--state-dir DIR`` keeps each robot's state (names and the smoother's solution, ``.npz``) after the chain
(``round0``), every kept round (``round<k>``) and pairwise round (``pairwise<k>``); ``--from-round K`` starts there.

``--reguess`` re-smooths each merge from the known-ID filter on the merged names instead of the last solution (the
same solution on robot 2). ``--layout`` and ``--ceiling`` are diagnostics in which the barcodes decide: how often the
passes' true constellations are unique in the true layout, and the names merged by their barcodes.

Printed per robot and round: passes (matched / ambiguous / too few / incompatible / no earlier pass), unique
constellations, pairings proposed and wrong (two barcodes), merges made and wrong, names per post, duplicates,
ATE, start-frame landmark NEES within χ²₂ 95 %.
"""
from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

from benchmarks.eval_mrclam import DATA  # noqa: E402
from benchmarks.mrclam_chained_names import (  # noqa: E402
    _chained,
    array_digest,
    cache_digest,
    majority,
    read_cache,
    round_scores,
    write_cache,
)
from benchmarks.mrclam_frame_nees import map_figures, truth_in_frame  # noqa: E402
from estimation import (  # noqa: E402
    chi2,  # noqa: E402
    name_leave_out,
    unnamed_sightings,
)
from estimation.chain_map import chain_landmark_map  # noqa: E402
from estimation.constellation import (  # noqa: E402
    joint_d2,
    leave_one_out,
    match_constellation,
    pairwise_d2,
)
from estimation.datasets import RangeBearingLog, read_mrclam  # noqa: E402
from estimation.fastslam import range_bearing_config  # noqa: E402
from estimation.fresh_start import names_guess  # noqa: E402
from estimation.landmark_map import LandmarkMap  # noqa: E402
from estimation.landmark_smoother import (  # noqa: E402
    HeadingDrift,
    HeadingLoss,
    Smoothed,
)
from estimation.name_chain import (  # noqa: E402
    ChainObserver,
    ChainResult,
    ChainSettings,
    Guard,
    Resume,
    flagged_names,  # noqa: F401  (the honest-names screen, imported from here by tests and tools)
    guard_groups,
    run_chain,
    without_flagged,
)
from estimation.name_merging import NamedSmoother  # noqa: E402
from estimation.named_smoothing import (  # noqa: E402
    MergeRound,
    NamedProblem,
    named_problem,
)
from estimation.noise_estimation import DATASET_CALIBRATIONS, estimate_noise  # noqa: E402
from estimation.noise_model import NoiseModel, NoiseModelError  # noqa: E402
from estimation.pass_matching import (  # noqa: E402
    STATUSES,
    Pass,
    PassVerdict,
    passes_of,
)
from runtime.commands.options import non_negative_float, non_negative_int, positive_float, positive_int  # noqa: E402

# what a saved final state records of the command that made it (benchmarks.mrclam_seed_vote votes only runs of one
# command): every option but where the run read and wrote and what it printed
_NOT_THE_METHOD = {"data", "robots", "seed", "names_cache", "state_dir", "from_round", "out_maps", "progress", "json"}
# recorded only when --noise is given (an in-sample run's command is as before the option): the file and its content's
# SHA-256 (two files at one path are told apart)
_NOISE_KEYS = ("noise", "noise_sha256")


def _smoother(log, noise, config, drift, path_step_s) -> NamedSmoother:
    """The :class:`estimation.name_merging.NamedSmoother` of the benchmark's wrappers of estimation functions
    (:func:`leave_out`, :func:`leave_out_flagged_runs`, :func:`name_unnamed`) when they are given none: no sighting
    offsets, Gaussian heading loss. The chain itself (:func:`run_robot`) runs
    :func:`estimation.name_chain.run_chain`, which carries its own."""
    return NamedSmoother(log, noise, config, drift, path_step_s)


def score_verdicts(verdicts: list[PassVerdict], named: NamedProblem, owner: dict[int, int]) -> dict:
    counts = {s: sum(v.status == s for v in verdicts) for s in STATUSES}
    code = np.array([owner.get(int(x), -1) for x in named.names])
    pairs = [pair for v in verdicts if v.status == "matched" for pair in v.pairs]
    wrong = sum(code[a] != code[b] for a, b in pairs)
    wrong_passes = sum(any(code[a] != code[b] for a, b in v.pairs) for v in verdicts if v.status == "matched")
    decided = counts["matched"] + counts["ambiguous"]
    return {"passes": len(verdicts), **counts, "pairings": len(pairs), "wrong_pairings": int(wrong),
            "wrong_passes": int(wrong_passes),
            "unique_fraction": counts["matched"] / decided if decided else float("nan")}


def ceiling(log: RangeBearingLog, names: np.ndarray, smoother: NamedSmoother, args) -> dict:
    """A diagnostic, the barcodes deciding: every name merged into its majority barcode, smoothed by the run's
    ``smoother`` (from the known-ID filter on those names): what the loops would give if every pass were matched
    right."""
    owner = majority(names, log.landmark_ids)
    merged = np.array([owner[int(x)] if x >= 0 else -1 for x in names], np.int64)
    poses, initial = _guess(log, merged, smoother.noise, smoother.config, args, cache=False)
    named, solution = smoother.smooth(merged, initial_poses=poses, initial=initial)
    final = MergeRound([], 0.0, 0.0, True, merged, named, solution)
    return round_scores(log, final, majority(merged, log.landmark_ids))


def layout_uniqueness(log: RangeBearingLog, named: NamedProblem, passes: list[Pass], *, turn_sigma: float,
                      shift_sigma: float, post_sigma: float = 0.05) -> dict:
    """How often a pass's set of posts is unique in the layout (the barcodes and the true positions, a diagnostic):
    each pass's true posts at their true positions, σ ``post_sigma`` each and a rigid offset prior (σ translation,
    σ rotation about the pass's centroid), matched against all the true posts by ``match_constellation``."""
    owner = majority(named.names[named.problem.landmark_index], np.asarray(log.landmark_ids)[named.sightings])
    code = np.array([owner[int(x)] for x in named.names])
    ids = sorted(int(i) for i in log.truth_ids)
    truth = dict(zip((int(i) for i in log.truth_ids), np.asarray(log.truth_positions)[:, :2], strict=True))
    layout = np.array([truth[i] for i in ids])
    out = {"passes": len(passes), "fewer_than_3": 0, "matched_right": 0, "matched_wrong": 0, "ambiguous": 0,
           "other": 0}
    for p in passes:
        posts = sorted({int(code[k]) for k in p.landmarks} & set(ids))
        if len(posts) < 3:
            out["fewer_than_3"] += 1
            continue
        seen = np.array([truth[i] for i in posts])
        positions = np.vstack([layout, seen])
        m, n = len(layout), len(layout) + len(posts)
        covariance = np.eye(2 * n) * post_sigma ** 2
        jac = np.zeros((2 * n, 3))
        centre = seen.mean(axis=0)
        for j, xy in enumerate(seen - centre):
            jac[2 * (m + j):2 * (m + j) + 2] = [[1, 0, -xy[1]], [0, 1, xy[0]]]
        covariance += jac @ np.diag([shift_sigma ** 2, shift_sigma ** 2, turn_sigma ** 2]) @ jac.T
        result = match_constellation(positions, covariance, range(m, n), range(m))
        if result.status == "matched":
            right = all(ids[q] == posts[k - m] for k, q in result.best.pairs)
            out["matched_right" if right else "matched_wrong"] += 1
        else:
            out["ambiguous" if result.status == "ambiguous" else "other"] += 1
    return out


def settings_of(args) -> ChainSettings:
    """The chain's settings (:class:`estimation.name_chain.ChainSettings`) as the command line gives them."""
    return ChainSettings(
        window_s=args.window, step_s=args.step, seed=args.seed, drift=tuple(args.drift), slip=args.slip,
        path_step_s=args.path_step, heading_loss=args.heading_loss, heading_dof=args.heading_dof,
        split_bends=args.split_bends, pass_seconds=args.pass_seconds, min_sightings=args.min_sightings,
        min_pairs=args.min_pairs, ratio=args.ratio, fewer_rival=args.fewer_rival, distinct_points=args.distinct_points,
        rival_rounds=args.rival_rounds, max_rounds=args.max_rounds, bisect=args.bisect, guard=args.guard,
        honest_names=args.honest_names, honest_rounds=args.honest_rounds, hold_two_points=args.hold_two_points,
        mutual_rounds=args.mutual_rounds, fresh_start=args.fresh_start, audit_parts=args.audit_parts,
        reguess=args.reguess, sighting_offset=args.sighting_offset, offsets_once_tight=args.offsets_once_tight,
        pairwise=args.pairwise, kept_covisible=args.kept_covisible, name_floor=args.name_floor,
        split_ambiguous=args.split_ambiguous, pairwise_alone=args.pairwise_alone,
        leave_out_ambiguous=args.leave_out_ambiguous, leave_out_unconfirmed=args.leave_out_unconfirmed,
        name_unnamed=args.name_unnamed, runs_out=args.runs_out)


def noise_file(path) -> NoiseModel:
    """``--noise FILE``'s model; a file that cannot be read as one, or whose model has no sensor part (the chain
    needs it), is refused (:class:`estimation.noise_model.NoiseModelError`, one line naming the file)."""
    noise = NoiseModel.load(path)
    if noise.range_bearing is None:
        raise NoiseModelError(f"{path}: no [range_bearing] section (the chain needs the sensor's noise)")
    return noise


def file_sha256(path) -> str:
    """SHA-256 (hex) of a file's bytes: what a kept state records of ``--noise FILE``'s content beside its path."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def run_noise(log: RangeBearingLog, path, sha256: str | None = None) -> NoiseModel:
    """The noise model a chain run on ``log`` is given: with ``path`` (``--noise FILE``) the file's, calibrated
    elsewhere (e.g. on the other robots' logs; :func:`noise_file`); without, fitted in sample, from this log against
    its ground truth (the sensor part by each sighting's barcode's post). ``sha256``: the content the file must hold
    (:func:`file_sha256`, as a run records it); a file that holds other content now is refused
    (:class:`estimation.noise_model.NoiseModelError`, one line). A run's states record the file and its digest (an
    in-sample run's have neither): :func:`saved_run_noise` gives a saved run's model back."""
    if path is None:
        return estimate_noise([log], **DATASET_CALIBRATIONS).model
    noise = noise_file(path)
    if sha256 is not None:
        now = file_sha256(path)
        if now != sha256:
            raise NoiseModelError(f"{path}: the file now holds other content (sha256 {now[:12]}...) than the run "
                                  f"was given (sha256 {sha256[:12]}...)")
    return noise


def saved_noise_file(meta: dict) -> str | None:
    """The ``--noise`` file a saved state's ``meta`` (:func:`saved_meta`) records, in the state's own meta or its final
    state's command (None: an in-sample run)."""
    return meta.get("noise") or (meta.get("command") or {}).get("noise")


def saved_noise_sha256(meta: dict) -> str | None:
    """The SHA-256 (hex) of the ``--noise`` file's content that a saved state's ``meta`` records beside the file
    (:func:`saved_noise_file`); None for an in-sample run and for a state made before states recorded it."""
    if saved_noise_file(meta) is None:
        return None
    return meta.get("noise_sha256") or (meta.get("command") or {}).get("noise_sha256")


def saved_run_noise(log: RangeBearingLog, meta: dict) -> NoiseModel:
    """The noise model the run whose state records ``meta`` (:func:`saved_meta`) was given (:func:`run_noise` of the
    ``noise`` file its state or its final state's command records, :func:`saved_noise_file`, refused if the file's
    content is no longer the one recorded beside it, :func:`saved_noise_sha256`): what a tool that smooths a saved
    run again (a vote, a re-smoothing, a re-examination) must smooth with."""
    return run_noise(log, saved_noise_file(meta), saved_noise_sha256(meta))


def saved_state_inputs(data, robot: int, path, logs: dict, noises: dict) -> tuple[RangeBearingLog, NoiseModel]:
    """The log of the saved state at ``path`` (robot ``robot`` of the data set at ``data``) and the noise model its
    run was given (:func:`saved_run_noise`), each read or fitted once across the states of one tool's run (cached in
    ``logs`` by robot, ``noises`` by robot and noise file); a model that cannot be had raises
    :class:`~estimation.noise_model.NoiseModelError`."""
    if robot not in logs:
        logs[robot] = read_mrclam(data, robot)
    log, meta = logs[robot], saved_meta(path)
    key = (robot, saved_noise_file(meta), saved_noise_sha256(meta))
    if key not in noises:
        noises[key] = saved_run_noise(log, meta)
    return log, noises[key]


def run_robot(log: RangeBearingLog, args) -> dict:
    """One robot's chain (:func:`estimation.name_chain.run_chain` with :func:`settings_of` ``args``), from the
    chained names and guess of ``--names-cache`` or from ``--from-round``'s saved state, every decision recorded and
    scored by the barcodes (:class:`_Recorder`); the row of figures."""
    noise = run_noise(log, args.noise or None, args.noise_sha256 if args.noise else None)
    config = range_bearing_config(n_particles=args.particles)
    settings = settings_of(args)
    chained, row = _chained(log, args, noise, config)
    names = chained.names
    recorder = _Recorder(log, args, row)
    if args.from_round is not None:
        path = state_path(args.state_dir, log, args.seed, f"round{args.from_round}")
        current, meta = load_state(path, log, noise, config, settings.heading_drift, settings.path_step,
                                   _loss_meta(settings.loss))
        if meta.get("noise") != (args.noise or None):     # the model the state was made with (absent: in sample)
            raise ValueError(f"{path}: a state made with noise {meta.get('noise')!r}, not {args.noise or None!r}")
        if meta.get("noise_sha256") and meta["noise_sha256"] != args.noise_sha256:   # (absent: made before it)
            raise ValueError(f"{path}: a state made with {args.noise} holding other content (sha256 "
                             f"{meta['noise_sha256'][:12]}...) than it holds now ({args.noise_sha256[:12]}...)")
        offset_names = None
        if args.sighting_offset > 0:     # the groups: the names after the chain (round 0)
            first = state_path(args.state_dir, log, args.seed, "round0")
            if not first.exists():
                raise SystemExit(f"--sighting-offset from round {args.from_round} needs {first} (its names are the "
                                 f"offsets' groups)")
            with np.load(first, allow_pickle=False) as data:
                offset_names = data["names"]
        run = run_chain(log, noise, config, settings, resume=Resume(current, int(meta["round"]), offset_names),
                        observer=recorder)
    else:
        guess = _guess(log, names, noise, config, args)
        recorder.started = time.process_time()
        run = run_chain(log, noise, config, settings, names=names, guess=guess, observer=recorder)
    return _finish(log, row, names, run, args)


def _finish(log: RangeBearingLog, row: dict, names: np.ndarray, run: ChainResult, args) -> dict:
    """The final scores in ``row`` (merges counted from the recorded attempts, scored against the chained names'
    barcodes), the final state kept (``--state-dir``) and the map written (``--out-maps``)."""
    current = run.state
    final = final_scores(log, current, majority(names, log.landmark_ids))
    kept = [a for r in row["rounds"] + row.get("pairwise", []) for a in [r.get("batch")] + r.get("tries", [])
            if a and a["accepted"]]
    final["merges"] = sum(a["merged"] for a in kept)
    final["wrong_merges"] = sum(a["wrong_merges"] for a in kept)
    row["final"] = final
    if args.state_dir:      # the final names: what a vote across seeds reads (benchmarks.mrclam_seed_vote)
        meta = _state_meta(log, args, run.smoother, run.rounds_done,
                           {key: float(v) for key, v in final.items() if isinstance(v, (int, float, np.number))})
        # the noise model's file as given (an in-sample run's command is recorded as before --noise existed)
        meta["command"] = {key: value for key, value in vars(args).items()
                           if key not in _NOT_THE_METHOD and not (key in _NOISE_KEYS and value is None)}
        save_state(state_path(args.state_dir, log, args.seed, "final"), current, meta)
    if args.out_maps:
        path = Path(args.out_maps) / f"robot{_robot_number(log)}.npz"
        chain_map(log, current).save(path)
        row["map"] = str(path)
    return row


class _Recorder(ChainObserver):
    """The chain's decisions as the benchmark records them: each round's and pairwise round's record in ``row``
    (scored by the barcodes), the steps after them, the states kept in ``--state-dir`` and, with ``--progress``,
    each step on stderr as it ends."""

    def __init__(self, log: RangeBearingLog, args, row: dict):
        self.log, self.args, self.row = log, args, row
        self.barcodes = log.landmark_ids
        self.started = time.process_time()
        self.record: dict = {}          # the round's or pairwise round's record
        self.owner: dict[int, int] = {}
        self.code = np.zeros(0, np.int64)
        self.audits: list[dict] = []

    def _say(self, text: str) -> None:
        if self.args.progress:
            print(text, file=sys.stderr, flush=True)

    def _scores(self, label: str, scores: dict) -> None:
        if self.args.progress:
            _print_scores(label, scores, file=sys.stderr)

    def chain_smoothed(self, state, smoother):
        log, args, row = self.log, self.args, self.row
        first = round_scores(log, state, majority(state.names, self.barcodes))
        row.update(first_smoothing=first, smooth_cpu_s=time.process_time() - self.started, rounds=[])
        if args.layout:
            first_passes = passes_of(state.named, state.solution, args.pass_seconds, args.min_sightings)
            row["layout"] = {f"turn {turn:g} rad, shift {shift:g} m": layout_uniqueness(
                log, state.named, first_passes, turn_sigma=turn, shift_sigma=shift) for turn in (0.05, 0.2, 0.5)
                for shift in (0.5, 2.0)}
        if args.ceiling:
            row["ceiling"] = ceiling(log, state.names, smoother, args)
        self._scores(f"{log.name} chain", first)

    def split_tried(self, split):
        self._say(f"  split name {split['name']} at {split['t']:.1f} s: cost drop {split['cost_drop']:.1f}")

    def splits_done(self, before, after, tried):
        log, row = self.log, self.row
        code = np.asarray(self.barcodes)
        for t in tried:       # scored: the barcodes of the name's sightings before and after the split
            mine = before.names == t["name"]
            t["before"] = sorted({int(c) for c in code[mine & (log.sighting_times < t["t"])]})
            t["after"] = sorted({int(c) for c in code[mine & (log.sighting_times >= t["t"])]})
        row["splits"] = tried
        row["after_splits"] = round_scores(log, after, majority(after.names, self.barcodes))
        row["after_splits"]["wrong_sightings_kept"] = wrong_sightings_kept(log, after)
        for t in tried:
            self._say(f"  split name {t['name']} at {t['t']:.1f} s (barcodes {t['before']} | {t['after']}): cost "
                      f"drop {t['cost_drop']:.1f} {'kept' if t['kept'] else 'not kept'}")
        self._scores(f"{log.name} after the splits", row["after_splits"])

    def resumed(self, state, round_done, offsets):
        log, row = self.log, self.row
        if offsets and self.args.progress:
            self._scores(f"{log.name} round {self.args.from_round} re-smoothed with sighting offsets "
                         f"σ {self.args.sighting_offset:g} m", round_scores(log, state, majority(state.names,
                                                                                                 self.barcodes)))
        row.setdefault("rounds", [])
        row["from_round"] = round_done
        row["first_smoothing"] = round_scores(log, state, majority(state.names, self.barcodes))
        self._scores(f"{log.name} state after round {round_done}", row["first_smoothing"])

    def state_kept(self, tag, state, round_done, smoother, before):
        if not self.args.state_dir:
            return
        if before is None:            # the chain's state (round 0)
            scores = None
        elif tag.startswith("out-"):
            scores = _round(self.log, state, majority(state.names, self.barcodes))
        else:
            scores = _round(self.log, state, majority(before.names, self.barcodes))
        save_state(state_path(self.args.state_dir, self.log, self.args.seed, tag), state,
                   _state_meta(self.log, self.args, smoother, round_done, scores))

    def round_begins(self, number, state, smoother):
        self.started = time.process_time()
        self.owner = majority(state.names, self.barcodes)
        self.record = {"round": number, "sighting_offsets": smoother.sighting_offset is not None}

    def round_judged(self, number, state, verdicts):
        judged = score_verdicts(verdicts, state.named, self.owner)
        judged["judge_cpu_s"] = time.process_time() - self.started
        self.record["judged"] = judged

    def honest_screened(self, number, state, verdicts, flagged):
        self.record["honest_names"] = _honest_record(state, verdicts, flagged, self.owner)
        self._say(f"  round {number}: honest names: {self.record['honest_names']}")

    def mutual_aside(self, number, state, aside):
        names, owner = state.named.names, self.owner
        self.record["mutual_aside"] = [{"names": [int(names[x]) for x in m],
                                        "wrong": len({owner.get(int(names[x]), -1) for x in m}) > 1} for m in aside]
        if aside:
            self._say(f"  round {number}: set aside, not all within each other's gate: {self.record['mutual_aside']}")

    def round_proposed(self, number, state, used):
        self.record["passes_used"] = len(used)
        self.row["rounds"].append(self.record)
        if self.args.progress:
            _print_judged(number, self.record["judged"], file=sys.stderr)

    def guard_judged(self, label, state, covariance, used, covisible, guard):
        self.record["guard"] = _guard_scores(state, covariance, used, self.owner, covisible, guard)
        if self.args.progress and label.startswith("round"):     # a pairwise round's is printed with its groups
            _print_guard(f"  {label}", self.record["guard"], file=sys.stderr)

    def audited(self, before, attempt, audit):
        named = attempt.named
        owner_before, owner_after = majority(before.names, self.barcodes), majority(attempt.names, self.barcodes)
        wrong = [owner_before[e] != owner_after[int(named.names[p.landmark])]
                 for e, p in zip(audit.earlier, audit.parts, strict=True)]
        verdict = audit.verdict
        self.audits.append({
            "parts": len(audit.parts), "wrong_parts": int(sum(wrong)), "spacing_m": audit.spacing_m,
            "held": [{"name": e, "sightings": len(p.sightings), "refused": bool(r), "untestable": bool(u), "wrong": w}
                     for e, p, r, u, h, w in zip(audit.earlier, audit.parts, verdict["refused"],
                                                 verdict["untestable"], audit.hold, wrong, strict=True) if h]})

    def merged(self, label, before, attempts, state):
        record = self.record
        record["batch"] = _round(self.log, attempts[0], self.owner)
        record["tries"] = [_round(self.log, a, self.owner) for a in attempts[1:]]
        record["cpu_s"] = time.process_time() - self.started
        if self.args.audit_parts is not None:
            record["audit"] = self.audits
        self.audits = []
        for audit in record.get("audit", []):
            self._say(f"  {label} audit: {audit['parts']} parts ({audit['wrong_parts']} wrong), spacing "
                      f"{audit['spacing_m']:.2f} m, held {audit['held'] or 'none'}")
        for key, scores in [("batch", record["batch"])] + [("try", t) for t in record["tries"]]:
            self._scores(f"  {label} {key}", scores)

    def offsets_entered(self, after_round, state):
        scores = round_scores(self.log, state, majority(state.names, self.barcodes))
        self.row["offsets_entered"] = {"after_round": after_round, "scores": scores}
        self._scores(f"{self.log.name} after round {after_round}, re-smoothed with sighting offsets σ "
                     f"{self.args.sighting_offset:g} m", scores)

    def pairwise_begins(self, number, state):
        self.started = time.process_time()
        self.owner = majority(state.names, self.barcodes)
        self.code = np.array([self.owner.get(int(x), -1) for x in state.named.names])
        self.row.setdefault("pairwise", [])

    def pairwise_grouped(self, number, state, groups):
        code = self.code
        self.record = {"round": number, "groups": {s: sum(g.status == s for g in groups)
                                                   for s in ("merge", "covisible", "not_joint")},
                       "groups_wrong": {s: sum(g.status == s and len({code[m] for m in g.members}) > 1
                                               for g in groups) for s in ("merge", "covisible", "not_joint")}}
        if self.args.split_ambiguous:
            self.record["groups"]["ambiguous"] = sum(g.status == "ambiguous" for g in groups)

    def pairwise_honest(self, number, state, flagged, held):
        self.record["honest_names"] = {"flagged": int(flagged.sum()), "groups_refused": len(held),
                                       "wrong_refused": sum(len({self.code[m] for m in g.members}) > 1 for g in held)}
        self._say(f"  pairwise {number}: honest names: {self.record['honest_names']}")

    def alone_checked(self, number, state, used, rises, absorbed, refused):
        self.record["alone"] = _alone_record(state, used, rises, absorbed, refused, self.code)
        self._say(f"  alone: {sum(refused)} of {len(used)} groups refused "
                  f"{[g for g in self.record['alone'] if g['refused']] or ''}")

    def pairwise_proposed(self, number, state, used):
        record = self.record
        record["judge_cpu_s"] = time.process_time() - self.started
        self._say(f"  pairwise {number}: groups {record['groups']} (wrong {record['groups_wrong']}), "
                  f"{record['judge_cpu_s']:.0f} s CPU")
        if self.args.progress and "guard" in record:
            _print_guard(f"  pairwise {number}", record["guard"], file=sys.stderr)
        self.row["pairwise"].append(record)

    def runs_flagged(self, key, before, flagged):
        self.row[key] = _runs_record(self.log, before, flagged)
        self._say(f"  runs taken out of their names ({key}): {self.row[key]['runs'] or 'none'}")

    def left_out(self, why, before, left, after):
        key = "left_out" if why == "ambiguous" else "unconfirmed_out"
        self.row[key] = _left_out_record(self.log, before, left)
        self._say(f"  left out as {why}: {self.row[key]['names'] or 'none'}; posts lost {self.row[key]['posts_lost']}")

    def named_again(self, key, before, after, proposed):
        self.row[key] = named_again_record(self.log, before, after, proposed)
        again = " again" if key == "named_after_runs_out" else ""
        self._say(f"  unnamed sightings named{again}: {self.row[key]}")


def final_scores(log: RangeBearingLog, current: MergeRound, owner_before: dict[int, int]) -> dict:
    """A final map's figures (scoring): :func:`round_scores`, the wrong sightings kept, when the map's frame starts
    and :func:`map_consistency`."""
    final = round_scores(log, current, owner_before)
    final["wrong_sightings_kept"] = wrong_sightings_kept(log, current)
    # s after the log's start: the map's frame is the pose at its first named sighting, the ATE's start pose
    # (session 29: robot 1 seed 0's two sightings of its first second move its ATE from 0.058 to 0.336 m)
    final["first_frame_s"] = float(current.named.frame_times[0] - log.start_time)
    final.update(map_consistency(log, current))
    return final


def _robot_number(log: RangeBearingLog) -> int:
    return int(log.name.rstrip("/").rsplit("Robot", 1)[-1])


def chain_map(log: RangeBearingLog, current: MergeRound) -> LandmarkMap:
    """The chain's final state as a landmark map that ``p3at fuse`` reads
    (:func:`estimation.chain_map.chain_landmark_map`: what ``p3at slam dataset --chain`` writes too): each name's
    smoothed position and covariance, the smoothed trajectory, the true start pose for scoring; no descriptors, no
    identities and no barcodes."""
    return chain_landmark_map(log, current, f"robot{_robot_number(log)}")


def map_consistency(log: RangeBearingLog, current: MergeRound, draws: int = 20_000) -> dict:
    """Scoring (session 30, C): the landmark NEES figure counts landmarks that all share the map frame's error, so it
    is one noisy draw; beside it, the joint NEES of the landmarks with a post (χ²_{2L}: is the map consistent as one
    estimate), the frame's rigid error (dx, dy, dθ) with its NEES₃, and how often a map exactly as uncertain as its
    joint covariance says fails "≥ 90 % within" (``benchmarks.mrclam_frame_nees``)."""
    owner = majority(current.names, log.landmark_ids)
    posts = np.array([owner.get(int(x), -1) for x in current.named.names])
    truth = truth_in_frame(log, posts, log.true_pose(current.named.frame_times[:1])[0])
    figures, _ = map_figures(current.named.problem, current.solution, truth, draws, np.random.default_rng(1))
    return {"landmark_joint_nees": figures["joint_nees"], "landmark_joint_dof": figures["joint_dof"],
            "landmark_joint_p": figures["joint_p"], "frame_error": figures["frame"],
            "nees_figure_p_fail": figures["figure_under_model"]["p_fail"]}


def rival_options(args, round_number: int) -> dict:
    """A's ``--fewer-rival``/``--distinct-points`` for round ``round_number``: off after ``--rival-rounds``
    (:meth:`estimation.name_chain.ChainSettings.rival_options`)."""
    return ChainSettings(fewer_rival=args.fewer_rival, distinct_points=args.distinct_points,
                         rival_rounds=args.rival_rounds).rival_options(round_number)


def _without_flagged(current: MergeRound, verdicts: list[PassVerdict], owner: dict[int, int], alpha: float,
                     two_points: bool = False) -> tuple[list[PassVerdict], dict]:
    """``--honest-rounds`` (:func:`estimation.name_chain.without_flagged`): the round's matched passes without their
    pairings of a name the split-score screen flags, and what it held back (scored by the barcodes)."""
    kept, flagged = without_flagged(current, verdicts, alpha, two_points)
    return kept, _honest_record(current, verdicts, flagged, owner)


def _honest_record(current: MergeRound, verdicts: list[PassVerdict], flagged: np.ndarray, owner: dict[int, int]
                   ) -> dict:
    """The honest rounds' screen scored by the barcodes: names flagged, pairings held back and how many were wrong."""
    code = np.array([owner.get(int(x), -1) for x in current.named.names])
    held = [(a, b) for v in verdicts if v.status == "matched" for a, b in v.pairs if flagged[a] or flagged[b]]
    return {"flagged": int(flagged.sum()), "pairings_held": len(held),
            "wrong_held": int(sum(code[a] != code[b] for a, b in held))}


def leave_out(log: RangeBearingLog, current: MergeRound, left: list[int], noise, config, drift, args
              ) -> tuple[MergeRound, dict]:
    """``current`` without the names ``left`` (:func:`estimation.name_leave_out.leave_out`; ``--leave-out-ambiguous``:
    ``ambiguous_names``; ``--leave-out-unconfirmed``: ``unconfirmed_names``) and what was left out, scored by the
    barcodes (:func:`_left_out_record`)."""
    record = _left_out_record(log, current, left)
    return name_leave_out.leave_out(_smoother(log, noise, config, drift, _path_step(args)), current, left), record


def _left_out_record(log: RangeBearingLog, current: MergeRound, left: list[int]) -> dict:
    """Names left out of ``current``, scored by the barcodes: each name's sightings and post, whether it was a
    duplicate (its post has another name), and the posts that lost their only name."""
    owner = majority(current.names, log.landmark_ids)
    return {"names": [{"name": x, "sightings": int(np.sum(current.names == x)), "post": owner[x],
                       "duplicate": any(owner[y] == owner[x] for y in owner if y != x)} for x in left],
            "posts_lost": sorted({owner[x] for x in left} - {owner[x] for x in owner if x not in left})}


def leave_out_flagged_runs(log: RangeBearingLog, current: MergeRound, noise, config, drift, args
                           ) -> tuple[MergeRound, dict]:
    """``--runs-out`` (session 30, B), after ``--name-unnamed``: the runs of sightings the honest-names screen flags
    (:func:`estimation.name_leave_out.flagged_runs_of`) are taken out of their names
    (:func:`estimation.name_leave_out.leave_out_runs`) instead of standing in the map and keeping their names from
    every merge; the pairwise rounds and the naming then run again. Returns the new state (``current`` when no run is
    flagged) and the runs taken out, scored by the barcodes (:func:`_runs_record`)."""
    flagged = name_leave_out.flagged_runs_of(current, args.honest_names)
    smoother = _smoother(log, noise, config, drift, _path_step(args))
    record = _runs_record(log, current, flagged)
    return name_leave_out.leave_out_runs(smoother, current, [run for run, _, _ in flagged]), record


def _runs_record(log: RangeBearingLog, current: MergeRound, flagged) -> dict:
    """Flagged runs scored by the barcodes: each run's name, post, span, sightings, score and wrong sightings."""
    named = current.named
    owner = majority(current.names, log.landmark_ids)
    times = named.frame_times[named.problem.pose_index - 1] - log.start_time
    barcodes = np.asarray(log.landmark_ids)
    record = {"runs": []}
    for run, score, threshold in flagged:
        rows = named.sightings[run.sightings]
        name = int(named.names[run.landmark])
        record["runs"].append({"name": name, "post": owner[name], "from_s": float(times[run.sightings[0]]),
                               "to_s": float(times[run.sightings[-1]]), "sightings": len(rows), "score": score,
                               "threshold": threshold, "wrong": int(np.sum(barcodes[rows] != owner[name]))})
    return record


def name_unnamed(log: RangeBearingLog, current: MergeRound, noise, config, drift, args, *,
                 smoother: NamedSmoother | None = None) -> tuple[MergeRound, dict]:
    """``--name-unnamed``, last (:func:`estimation.unnamed_sightings.name_unnamed`): the sightings the final map names
    unambiguously given their names, the map re-smoothed (by ``smoother``, e.g. one with the run's sighting offsets,
    whose groups the naming extends by their visits; None: :func:`_smoother`). Session 29, robot 5 seed 2: the chain
    leaves 18 sightings of the first 10 s unlinked, and without them the map's frame (pose 0 is the first named
    sighting's) turns 0.025 rad from the start pose: ATE 0.076 m with the barcodes naming the same sightings, 0.029 m
    with them too. Returns the new state and the naming scored by the barcodes."""
    smoother = smoother or _smoother(log, noise, config, drift, _path_step(args))
    state, proposed, _ = unnamed_sightings.name_unnamed(smoother, current)
    return state, named_again_record(log, current, state, proposed)


def named_again_record(log: RangeBearingLog, before: MergeRound, after: MergeRound, proposed: dict[int, int]) -> dict:
    """A naming of unnamed sightings scored by the barcodes: how many were named and kept by the smoother's outlier
    test, and how many of each went to a name whose post is not theirs."""
    owner = majority(before.names, log.landmark_ids)
    record = {"proposed": len(proposed),
              "wrong_proposed": sum(owner.get(x) != int(log.landmark_ids[r]) for r, x in proposed.items())}
    if not proposed:
        record.update(kept=0, wrong_kept=0)
        return record
    rows = np.array(sorted(proposed))
    kept_rows = np.setdiff1d(rows, after.named.sightings[~after.solution.inliers])     # the rest the smoother dropped
    record.update(kept=int(len(kept_rows)),
                  wrong_kept=sum(owner.get(int(after.names[r])) != int(log.landmark_ids[r]) for r in kept_rows))
    return record


STATE_ARRAYS = ("poses", "landmarks", "landmark_covariances", "covariance_poses", "pose_covariances", "inliers")


def state_path(directory, log: RangeBearingLog, seed: int, tag: str) -> Path:
    """Where ``--state-dir`` keeps one state of a robot's run: DIR/<robot>-seed<S>-<tag>.npz (tag: round<k>)."""
    return Path(directory) / f"{Path(log.name).name}-seed{seed}-{tag}.npz"


def save_state(path, state: MergeRound, meta: dict) -> None:
    """The names (N,) and the smoother's solution of ``state`` in an .npz (no pickle: arrays and a JSON string),
    written atomically; ``meta``: what the state was made with (robot, seed, drift, path step, round, scores), read
    back by :func:`load_state` to refuse a state made with other settings. The landmarks' joint covariance is not
    kept: :func:`load_state` gives back the problem and solution it is computed from."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    sol = state.solution
    arrays = {k: np.asarray(getattr(sol, k)) for k in STATE_ARRAYS}
    for k in ("heading_weights", "heading_biases", "turn_biases"):
        if getattr(sol, k) is not None:
            arrays[k] = np.asarray(getattr(sol, k))
    fit = {"chi2": float(sol.chi2), "dof": int(sol.dof), "iterations": int(sol.iterations),
           "converged": bool(sol.converged)}
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, names=state.names, meta=np.array(json.dumps({**meta, "fit": fit})), **arrays)
    os.replace(tmp, path)


def load_state(path, log: RangeBearingLog, noise, config, drift, path_step_s: float | None,
               heading_loss: list | None = None) -> tuple[MergeRound, dict]:
    """:func:`save_state`'s state of ``log`` as a MergeRound (the named problem rebuilt from the names, the solution
    as saved: no smoothing) and its meta; a state made with another drift, path step or heading loss (as
    :func:`_loss_meta` records it; None: Gaussian) is refused (ValueError)."""
    with np.load(path, allow_pickle=False) as data:
        meta = json.loads(str(data["meta"]))
        arrays = {k: data[k] for k in data.files if k not in ("names", "meta")}
        names = data["names"]
    want = {"robot": log.name, "drift": _drift_meta(drift),
            "path_step_s": path_step_s, "heading_loss": heading_loss}
    for key, value in want.items():
        if meta.get(key) != value:
            raise ValueError(f"{path}: a state made with {key} {meta.get(key)!r}, not {value!r}")
    named = named_problem(log, names, noise, config, path_step_s=path_step_s)
    fit = meta["fit"]
    solution = Smoothed(*(arrays[k] for k in STATE_ARRAYS), fit["chi2"], fit["dof"], fit["iterations"],
                        fit["converged"], arrays.get("heading_weights"), drift, arrays.get("heading_biases"),
                        turn_biases=arrays.get("turn_biases"))
    return MergeRound([], 0.0, 0.0, True, names, named, solution), meta


def saved_meta(path) -> dict:
    """What a state :func:`save_state` kept was made with (its meta), without the state."""
    with np.load(path, allow_pickle=False) as data:
        return json.loads(str(data["meta"]))


def load_saved_state(path, log: RangeBearingLog, noise, config) -> tuple[MergeRound, dict]:
    """:func:`load_state` with the drift, path step and heading loss the state was made with (read from its own
    meta): for tools that examine saved states rather than continue a run."""
    meta = saved_meta(path)
    return load_state(path, log, noise, config, saved_drift(meta), meta.get("path_step_s"), meta.get("heading_loss"))


def _drift_meta(drift: HeadingDrift | None) -> list | None:
    """The drift as a state's meta records it: [σ_b, τ], and the slip's σ per radian after them when it has one (so
    the states saved before the slip existed still load)."""
    if drift is None:
        return None
    return [drift.sigma_per_m, drift.tau_s] + ([drift.sigma_per_rad] if drift.sigma_per_rad > 0 else [])


def _state_meta(log: RangeBearingLog, args, smoother: NamedSmoother, round_done: int, scores: dict | None = None
                ) -> dict:
    """What a kept state was made with: the robot, seed, the run's smoother (drift, path step, sighting offset,
    heading loss as it stood), the rounds done, the scores and ``--noise``'s file (absent: fitted in sample, as every
    state before the option)."""
    offset, loss = smoother.sighting_offset, smoother.heading_loss
    return {"robot": log.name, "seed": args.seed, "drift": _drift_meta(smoother.heading_drift),
            "path_step_s": smoother.path_step_s, "round": round_done, "scores": scores or {},
            "sighting_offset_m": offset.sigma_m if offset is not None else 0.0,
            **({"heading_loss": _loss_meta(loss)} if loss is not None else {}),
            **({"noise": args.noise, "noise_sha256": args.noise_sha256} if args.noise else {})}


def _loss_meta(loss: HeadingLoss | None) -> list | None:
    """A state's heading loss ([kind, ν]; None, and absent from the meta: Gaussian, as every state before it)."""
    return None if loss is None else [loss.kind, float(loss.dof)]


def saved_drift(meta: dict) -> HeadingDrift | None:
    """The heading drift a state's ``meta`` records (:func:`_drift_meta`'s inverse; None: none)."""
    return HeadingDrift(*meta["drift"]) if meta.get("drift") else None


def saved_heading_loss(meta: dict) -> HeadingLoss | None:
    """The heading loss a state's ``meta`` records (:func:`_loss_meta`'s inverse; None or absent: Gaussian)."""
    return HeadingLoss(*meta["heading_loss"]) if meta.get("heading_loss") else None


def guard_record(current: MergeRound, covariance: np.ndarray, used: list[PassVerdict], owner: dict[int, int],
                 covisible: np.ndarray) -> tuple[dict, list[PassVerdict]]:
    """:func:`estimation.name_chain.guard_groups` on the groups of names a round would merge, scored
    (:func:`_guard_scores`), and the groups it keeps, each as a verdict of pairings (root, member), largest first."""
    guard = guard_groups(current, covariance, used, covisible)
    return _guard_scores(current, covariance, used, owner, covisible, guard), guard.kept


def _guard_scores(current: MergeRound, covariance: np.ndarray, used: list[PassVerdict], owner: dict[int, int],
                  covisible: np.ndarray, guard: Guard) -> dict:
    """The guard's verdict scored by the barcodes (a group of two barcodes is wrong), with the linear d² of all its
    pairings, each group's leave-one-out share and the groups with a rival (:func:`group_rivals`)."""
    positions = current.solution.landmarks
    code = np.array([owner.get(int(x), -1) for x in current.named.names])
    groups = guard.groups

    def wrong(g) -> bool:
        return len({code[a] for pair in g for a in pair}) > 1

    linear, _ = joint_d2(positions, covariance, [p for g in groups for p in g])
    rivals = group_rivals(positions, covariance, groups, covisible)
    shares = leave_one_out(positions, covariance, groups)
    return {"passes": len(used), "groups": len(groups), "linear_d2": float(linear),
            "wrong_groups": sum(wrong(g) for g in groups),
            "shares": [{"group": [int(current.named.names[x]) for x in (g[0][0], *(m for _, m in g))], "d2": d2,
                        "dof": dof, "wrong": wrong(g)} for g, (d2, dof) in zip(groups, shares, strict=True)],
            "set_aside": [{"group": [int(current.named.names[x]) for x in (groups[i][0][0],
                                                                          *(m for _, m in groups[i]))],
                           "d2": d2, "dof": dof, "wrong": wrong(groups[i])} for i, d2, dof in guard.dropped],
            "kept_wrong_groups": sum(wrong(groups[i]) for i in guard.keep),
            "with_rivals": sum(r > 0 for r in rivals),
            "wrong_with_rivals": sum(r > 0 and wrong(g) for g, r in zip(groups, rivals, strict=True))}


def group_rivals(positions: np.ndarray, covariance: np.ndarray, groups: list[list[tuple[int, int]]],
                 covisible: np.ndarray, probability: float = 0.99) -> list[int]:
    """A diagnostic beside the guard: for each group of names to be merged (pairings (root, member)), how many names
    outside it lie within some member's χ²₂ gate (:func:`pairwise_d2`) yet cannot be the group's post (sighted in
    one frame with a member, or the group with it jointly out of χ²_{2m}): rivals the passes' search never met."""
    n = len(positions)
    seen = np.flatnonzero(np.isfinite(np.diagonal(covariance)).reshape(n, 2).all(axis=1))
    d2 = np.full((n, n), np.inf)
    d2[np.ix_(seen, seen)] = pairwise_d2(positions, covariance, seen)
    gate = float(chi2.ppf(probability, 2))
    out = []
    for g in groups:
        members = [g[0][0]] + [m for _, m in g]
        near = set(np.flatnonzero((d2[members] < gate).any(axis=0)).tolist()) - set(members)
        count = 0
        for x in near:
            if covisible[x, members].any():
                count += 1
                continue
            pairs = g + [(members[0], x)]
            joint, _ = joint_d2(positions, covariance, pairs)
            count += not joint < chi2.ppf(probability, 2 * len(pairs))
        out.append(count)
    return out


def _print_guard(label: str, g: dict, file=None) -> None:
    aside = ", ".join(f"{len(a['group'])} names d² {a['d2']:.1f}/{a['dof']}{' WRONG' if a['wrong'] else ''}"
                      for a in g["set_aside"])
    print(f"{label} guard: {g['passes']} passes, {g['groups']} groups ({g['wrong_groups']} of two posts), linear d² "
          f"{g['linear_d2']:.1f}; set aside {len(g['set_aside'])} ({aside or '-'}); kept of two posts "
          f"{g['kept_wrong_groups']}; groups with a rival {g['with_rivals']} ({g['wrong_with_rivals']} of two posts)",
          file=file, flush=True)


def _alone_record(current: MergeRound, used: list[PassVerdict], rises, absorbed, refused, code: np.ndarray
                  ) -> list[dict]:
    """``--pairwise-alone`` (:func:`estimation.name_chain.alone_checked`): each group's own rise and verdict, scored
    by the barcodes (a group of two posts is wrong)."""
    return [{"group": sorted(int(current.named.names[a]) for a in {x for p in v.pairs for x in p}),
             "rise": r, "absorbed": a, "refused": bool(f), "wrong": len({code[x] for p in v.pairs for x in p}) > 1}
            for v, r, a, f in zip(used, rises, absorbed, refused, strict=True)]


def wrong_sightings_kept(log: RangeBearingLog, r: MergeRound) -> int:
    """Sightings kept by the smoother under a name whose barcode (its sightings' majority) is not theirs (scoring)."""
    owner = majority(r.names, log.landmark_ids)
    problem = r.named.problem
    mine = np.array([owner[int(r.named.names[k])] for k in problem.landmark_index])
    return int(np.sum((np.asarray(log.landmark_ids)[r.named.sightings] != mine) & r.solution.inliers))


def _path_step(args) -> float | None:
    return args.path_step if args.path_step > 0 else None


def _round(log, attempt: MergeRound, owner) -> dict:
    scores = round_scores(log, attempt, owner)
    scores["converged"], scores["iterations"] = bool(attempt.solution.converged), int(attempt.solution.iterations)
    if not attempt.accepted:       # round_scores counts the merges of the attempt, scored on the kept solution
        scores["merged"] = len(attempt.merged)
    return scores


def _guess(log, names, noise, config, args, cache: bool = True):
    """The known-ID filter and smoother with the chained names as identities (U's starting guess), kept beside the
    names' cache when one is given, with the digest of the log, names, noise model, filter and seed it was made from
    (:func:`benchmarks.mrclam_chained_names.cache_digest`): an entry made from anything else is computed again."""
    path = digest = None
    if args.names_cache and cache:
        step = args.step or args.window / 2
        path = Path(args.names_cache) / (f"{log.name}-w{args.window:g}-s{step:g}-seed{args.seed}"
                                         f"-p{args.particles}-guess.npz")
        digest = cache_digest(log, noise, config, what="guess", names=array_digest(names), seed=args.seed)
        data = read_cache(path, digest, "mrclam_constellation")
        if data is not None:
            return data["poses"], dict(zip(data["ids"].tolist(), data["positions"], strict=True))
    poses, guess = names_guess(log, names, noise, config, np.random.default_rng(args.seed))
    if path is not None:
        write_cache(path, digest, poses=poses, ids=np.array(list(guess), np.int64),
                    positions=np.array(list(guess.values())))
    return poses, guess


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", default=str(DATA))
    parser.add_argument("--robots", default="1,2,3,4,5")
    parser.add_argument("--window", type=positive_float, default=40.0, help="the chain's windows, s")
    parser.add_argument("--step", type=positive_float, default=None, help="the chain's window step, s (default: half)")
    parser.add_argument("--seed", type=non_negative_int, default=0)
    parser.add_argument("--particles", type=positive_int, default=100)
    parser.add_argument("--names-cache", metavar="DIR", default=None,
                        help="mrclam_chained_names' cache of chained names (and the smoother's guess here)")
    parser.add_argument("--drift", type=positive_float, nargs=2, default=(0.16, 10.0), metavar=("RAD_PER_M", "S"),
                        help="the smoother's heading drift σ (rad/m) and correlation time (s)")
    parser.add_argument("--slip", type=non_negative_float, default=0.0, metavar="RAD_PER_RAD",
                        help="the smoother's heading slip per radian turned on the spot (HeadingDrift.sigma_per_rad, "
                             "τ the drift's; 0: none; 0.3 measured by benchmarks.mrclam_heading_slip)")
    parser.add_argument("--heading-loss", choices=("gaussian", "student-t"), default="gaussian",
                        help="the loss on the odometry's heading residuals in every smoothing and merge cost "
                             "(estimation.landmark_smoother.HeadingLoss; gaussian: none)")
    parser.add_argument("--heading-dof", type=positive_float, default=3.0, metavar="NU",
                        help="--heading-loss student-t's degrees of freedom ν")
    parser.add_argument("--pass-seconds", type=positive_float, default=20.0, help="a pass's span, s")
    parser.add_argument("--min-sightings", type=positive_int, default=2,
                        help="kept sightings of a name within a pass's span for it to be the pass's")
    parser.add_argument("--min-pairs", type=positive_int, default=3, help="pairings a match needs")
    parser.add_argument("--ratio", type=positive_float, default=None,
                        help="likelihood ratio of the best hypothesis over a rival (default: no rival allowed)")
    parser.add_argument("--fewer-rival", action="store_true",
                        help="a match is refused when a hypothesis of one pairing fewer, sharing none of its "
                             "pairings, fits as well (χ² survival; session 29: a row of posts shifted by one)")
    parser.add_argument("--distinct-points", action="store_true",
                        help="a match's pairings counted by its distinct pass points (two names within each "
                             "other's χ²₂ gate are one; session 29)")
    parser.add_argument("--rival-rounds", type=positive_int, default=None, metavar="K",
                        help="--fewer-rival and --distinct-points in rounds 1..K only (the loose map's; default: "
                             "every round; session 30)")
    parser.add_argument("--max-rounds", type=non_negative_int, default=3,
                        help="the last round to run (counted from the chain, also after --from-round)")
    parser.add_argument("--state-dir", metavar="DIR", default=None,
                        help="keep each robot's state (names and solution) after the chain and every kept round "
                             "here, as <robot>-seed<S>-round<k>.npz")
    parser.add_argument("--from-round", type=non_negative_int, default=None, metavar="K",
                        help="start from the state --state-dir kept after round K instead of the chain")
    parser.add_argument("--path-step", type=non_negative_float, default=0.25, metavar="S",
                        help="the odometry increments' variances propagated along the path in steps of S s (0: the "
                             "random walk's variance of the chord between sighting frames, session 24's)")
    parser.add_argument("--bisect", type=non_negative_int, default=2, metavar="DEPTH",
                        help="a refused batch of merges is cut in halves down to DEPTH levels (0: retried as its "
                             "strongest pass alone, session 24's)")
    parser.add_argument("--fresh-start", action="store_true",
                        help="a round's or pairwise round's whole batch refused by the cost check is smoothed again "
                             "from the filter's guess on the merged names and judged at the lower cost (session 31)")
    parser.add_argument("--guard", action="store_true",
                        help="when the cost check refuses a round's batch, leave out the groups of names whose share "
                             "of it, tested given the others' (leave one out), is beyond χ² 99 %%, before bisecting "
                             "(without it the guard's verdict is only printed)")
    parser.add_argument("--pairwise", type=non_negative_int, default=0, metavar="ROUNDS",
                        help="after the rounds, up to ROUNDS rounds of pairwise merges of the names left (groups "
                             "of names within each other's χ²₂ 99 %% gate and no rival's; 0: none)")
    parser.add_argument("--name-floor", type=non_negative_float, default=0.0, metavar="M",
                        help="the pairwise merges' gate: σ (m) of an offset of each name of its own (the sightings' "
                             "systematic error, which their number does not average out), added to its covariance")
    parser.add_argument("--sighting-offset", type=non_negative_float, default=0.0, metavar="M",
                        help="the smoother's offset per chained name, σ in m (0: off; the groups are the names after "
                             "the chain, round 0)")
    parser.add_argument("--offsets-once-tight", action="store_true",
                        help="with --sighting-offset: the rounds run without the offsets until one keeps nothing (the "
                             "map is tight), then go on with them (session 27: on a loose map they let wrong "
                             "pairings through)")
    parser.add_argument("--leave-out-ambiguous", action="store_true",
                        help="after the merges, leave out of the map each name whose gate holds two names that cannot "
                             "be one post (its sightings unnamed), rather than keep it as a second name of one")
    parser.add_argument("--leave-out-unconfirmed", action="store_true",
                        help="last, leave out each name the sensor's record says is not a landmark of its own: "
                             "existence below the filter's removal threshold and, within merge_radius, a name never "
                             "detected with it that the co-visibility test calls the same point")
    parser.add_argument("--out-maps", metavar="DIR", default=None,
                        help="write each robot's final map as DIR/robot<N>.npz (no descriptors, no identities: "
                             "`p3at fuse` aligns them by geometry alone; benchmarks.eval_fusion --mrclam-maps DIR)")
    parser.add_argument("--name-unnamed", action="store_true",
                        help="last: name the sightings no name holds where the final map names them unambiguously "
                             "(the smoother's outlier bound, one name within it)")
    parser.add_argument("--runs-out", action="store_true",
                        help="before the pairwise rounds and after --name-unnamed: take the runs of sightings the "
                             "--honest-names screen flags out of their names (a name's largest run never); after the "
                             "naming, then the pairwise rounds and the naming again")
    parser.add_argument("--audit-parts", type=non_negative_float, default=None, metavar="FLOOR_M",
                        help="audit every kept batch part by part on its merged map (estimation.merge_audit): hold "
                             "back a merged name's part whose split score, with an offset of σ FLOOR_M allowed, is "
                             "beyond chi2_2 Bonferroni over the batch's parts, and in the rounds a part the map cannot "
                             "tell from a post as near as two posts are known to stand; the rest merged again "
                             "(session 31: 0.042)")
    parser.add_argument("--pairwise-alone", action="store_true",
                        help="pairwise: each group merged alone first and left out of the batch when its own cost "
                             "rise is beyond chi2 99 %% for 2 per absorbed name (session 32: a wrong group hides in "
                             "a batch's summed bound)")
    parser.add_argument("--split-ambiguous", action="store_true",
                        help="pairwise: a refused group is judged again without the names whose gate holds two "
                             "names that cannot be one post")
    parser.add_argument("--honest-names", type=positive_float, default=None, metavar="ALPHA",
                        help="pairwise: set aside every group with a member holding a run whose split score is beyond "
                             "chi2_2 at 1 - ALPHA/k (estimation.map_honesty; helper B's screen)")
    parser.add_argument("--honest-rounds", action="store_true",
                        help="with --honest-names: the same screen in the rounds (a matched pass's pairings of a "
                             "flagged name are not merged)")
    parser.add_argument("--hold-two-points", action="store_true",
                        help="with --honest-names: a name sighted twice in one frame (two posts) is flagged too, its "
                             "pairings held back from every round's and pairwise round's merges (session 30)")
    parser.add_argument("--mutual-rounds", action="store_true",
                        help="the rounds merge a cluster of names only when every two of its members are within "
                             "each other's chi2_2 99 %% gate (the pairwise rounds' link); a cluster that is not waits "
                             "(session 31)")
    parser.add_argument("--kept-covisible", action="store_true",
                        help="the pairwise merges: two names are sighted in one frame only by sightings the smoother "
                             "kept (default: every sighting counts)")
    parser.add_argument("--split-bends", action="store_true",
                        help="before the rounds, split names where the odometry bends if the cost falls (step 1b)")
    parser.add_argument("--reguess", action="store_true",
                        help="re-smooth each merge from the known-ID filter on the merged names, not the last solution")
    parser.add_argument("--layout", action="store_true",
                        help="also: how often the passes' true constellations are unique in the true layout")
    parser.add_argument("--ceiling", action="store_true",
                        help="also: the names merged by their barcodes, smoothed (what matching every pass gives)")
    parser.add_argument("--noise", metavar="FILE", default=None,
                        help="the noise model (TOML, see `p3at slam noise`), e.g. fitted on the other robots' logs; "
                             "default: each robot's own, fitted from its log against its ground truth (in sample). "
                             "With --names-cache the chained names and guesses, which depend on it, are kept in "
                             "NAMES_CACHE/noise-<the file's SHA-256, 12 digits>. Kept states record the file and its "
                             "content's SHA-256: a saved run is refused once the file holds other content")
    parser.add_argument("--progress", action="store_true", help="each round on stderr as it ends")
    parser.add_argument("--json", action="store_true")
    parser.set_defaults(noise_sha256=None)     # --noise's file's content, set below
    args = parser.parse_args(argv)
    if args.honest_names is not None and not 0 < args.honest_names < 1:
        parser.error(f"--honest-names: α must be in (0, 1), not {args.honest_names}")
    if args.honest_rounds and args.honest_names is None:
        parser.error("--honest-rounds needs --honest-names ALPHA")
    if args.hold_two_points and args.honest_names is None:
        parser.error("--hold-two-points needs --honest-names ALPHA")
    if args.runs_out and (args.honest_names is None or not args.name_unnamed):
        parser.error("--runs-out needs --honest-names ALPHA and --name-unnamed")
    if args.offsets_once_tight and not args.sighting_offset > 0:
        parser.error("--offsets-once-tight needs --sighting-offset M")
    if args.rival_rounds is not None and not (args.fewer_rival or args.distinct_points):
        parser.error("--rival-rounds needs --fewer-rival or --distinct-points")
    if args.from_round is not None and not args.state_dir:
        parser.error("--from-round needs --state-dir")
    if not os.path.isdir(args.data):
        print(f"mrclam_constellation: no data set at {args.data}", file=sys.stderr)
        return 2
    if args.noise:
        try:
            noise_file(args.noise)
        except NoiseModelError as e:
            print(f"mrclam_constellation: --noise: {e}", file=sys.stderr)
            return 2
        args.noise_sha256 = file_sha256(args.noise)     # recorded beside the path by every kept state
        if args.names_cache:    # one folder per model (each entry also holds the digest of the model it was made with)
            args.names_cache = str(Path(args.names_cache) / f"noise-{args.noise_sha256[:12]}")
    rows = []
    for robot in (int(r) for r in args.robots.split(",")):
        row = run_robot(read_mrclam(args.data, robot), args)
        rows.append(row)
        if not args.json:
            _print(row)
    if args.json:
        print(json.dumps({"seed": args.seed, "drift": list(args.drift), "slip": args.slip, "pass_s": args.pass_seconds,
                          "min_pairs": args.min_pairs, "ratio": args.ratio, "fewer_rival": args.fewer_rival,
                          "distinct_points": args.distinct_points, "rival_rounds": args.rival_rounds,
                          "runs_out": args.runs_out, "hold_two_points": args.hold_two_points,
                          "mutual_rounds": args.mutual_rounds, "fresh_start": args.fresh_start,
                          "audit_parts": args.audit_parts, "pairwise_alone": args.pairwise_alone,
                          "noise": args.noise, "robots": rows}))
    return 0


def _print_scores(label: str, s: dict, file=None) -> None:
    merged = f"{s['merged']} merged ({s['wrong_merges']} wrong), rise {s['cost_rise']:.1f} (bound " \
             f"{s['cost_bound']:.1f}) {'kept' if s['accepted'] else 'undone'}; " if s["merged"] else ""
    print(f"{label}: {merged}names {s['names']} ({s['names_per_post']:.1f} per post, duplicates "
          f"{100 * s['duplicate_fraction']:.0f} %), ATE {s['ate_m']:.3f} m, NEES within "
          f"{100 * s['landmark_nees_within_bound']:.0f} %", file=file, flush=True)


def _print_judged(k: int, j: dict, file=None) -> None:
    print(f"  round {k} passes {j['passes']}: matched {j['matched']} ({j['wrong_passes']} with a wrong pairing; "
          f"{j['pairings']} pairings, {j['wrong_pairings']} wrong), ambiguous {j['ambiguous']}, too few "
          f"{j['too_few']}, incompatible {j['incompatible']}, no earlier pass {j['no_earlier']}; unique "
          f"{100 * j['unique_fraction']:.0f} % of the decided ({j['judge_cpu_s']:.0f} s CPU)", file=file, flush=True)


def _print(row: dict) -> None:
    _print_scores(f"{row['robot']}: chain, smoothed with the drift", row["first_smoothing"])
    for label, u in (row.get("layout") or {}).items():
        print(f"  layout ({label}): of {u['passes']} passes {u['fewer_than_3']} hold < 3 posts; matched right "
              f"{u['matched_right']}, wrong {u['matched_wrong']}, ambiguous {u['ambiguous']}, other {u['other']}")
    if "ceiling" in row:
        _print_scores("  ceiling (names merged by their barcodes)", row["ceiling"])
    for t in row.get("splits", []):
        print(f"  split name {t['name']} at {t['t']:.1f} s (barcodes {t['before']} | {t['after']}): cost drop "
              f"{t['cost_drop']:.1f} {'kept' if t['kept'] else 'not kept'}")
    if "after_splits" in row:
        _print_scores("  after the splits", row["after_splits"])
    for r in row["rounds"]:
        _print_judged(r["round"], r["judged"])
        if "guard" in r:
            _print_guard("   ", r["guard"])
        for key, scores in [("batch", r.get("batch"))] + [("try", t) for t in r.get("tries", [])]:
            if scores:
                _print_scores(f"    {key}", scores)
    for r in row.get("pairwise", []):
        print(f"  pairwise {r['round']}: groups {r['groups']} (of two posts {r['groups_wrong']})")
        if "guard" in r:
            _print_guard("   ", r["guard"])
        for key, scores in [("batch", r.get("batch"))] + [("try", t) for t in r.get("tries", [])]:
            if scores:
                _print_scores(f"    {key}", scores)
    if "offsets_entered" in row:
        _print_scores(f"  sighting offsets entered after round {row['offsets_entered']['after_round']}",
                      row["offsets_entered"]["scores"])
    for key, why in (("left_out", "ambiguous"), ("unconfirmed_out", "unconfirmed")):
        if key in row:
            which = ", ".join(f"{x['name']}: {x['sightings']} sightings" for x in row[key]["names"]) or "-"
            print(f"  left out as {why}: {len(row[key]['names'])} names ({which}); posts lost "
                  f"{len(row[key]['posts_lost'])}")
    f = row["final"]
    print(f"  final: {f['merges']} merges ({f['wrong_merges']} wrong), names {f['names']} "
          f"({f['names_per_post']:.1f} per post, duplicates {100 * f['duplicate_fraction']:.0f} %), ATE "
          f"{f['ate_m']:.3f} m, NEES within {100 * f['landmark_nees_within_bound']:.0f} %, wrong sightings kept "
          f"{f['wrong_sightings_kept']}")


if __name__ == "__main__":
    sys.exit(main())
