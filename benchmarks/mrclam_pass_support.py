"""MRCLAM without barcodes: how many independent passes support each merge group of a constellation round.

Run from the repository root, on the states ``benchmarks.mrclam_constellation --state-dir DIR`` keeps:

    .venv/bin/python -m benchmarks.mrclam_pass_support --state-dir DIR [--robots 1,2,3,4,5] [--seeds 0,2]
        [--rounds 0,1] [--pass-seconds 20] [--min-sightings 2] [--min-pairs 3] [--fewer-rival] [--distinct-points]
        [--visit-gap 2] [--groups] [--json]

For every saved state ``round<K>`` the next round is judged exactly as ``mrclam_constellation``'s rounds judge it
(``passes_of``, ``judge_passes``, ``merges_from``, and the merge groups ``guard_record`` builds: the clusters of the
used passes' pairings, each a set of names to become one); nothing is merged. For each group, its **support**
(:func:`support_of`, no barcode): the passes whose pairings join its names (each a disjoint 20 s span), how many
*visits* they make (passes fewer than ``--visit-gap`` spans apart are one visit: adjacent spans cut one passage in
two), the time between the first and last, each pass's pairings (the best hypothesis's against one earlier pass,
and the union the pass proposes), the smallest log likelihood ratio over a rival, and how loose the map is there (σ
of the members' difference from the root along its widest axis). Beside it, the guard's leave-one-out share and
whether the guard set it aside. The barcodes only score: a group of names of two posts is **wrong**.

Candidate rules that hold a group back for a later round (:data:`RULES`, each decided from the support alone) are
scored over all states: wrong groups held back / right groups held back; so is cutting a group where one visit
alone joins it (:func:`split_by_visits`) and holding whole weak passes out of the round (:data:`PASS_RULES`,
:func:`held_passes`, the groups ``merges_from`` then makes).

Session 28 (B; docs: "Session 28: pass support on loose maps (B)"), rounds 1–2 of robots 1, 4, 5 seed 0 and 1–5
seed 2 (16 states, 271 groups, 20 of two posts): support per group does not separate (one visit: 11 / 20 wrong held
for 78 / 251 right; matched one earlier pass: 10 / 20 for 30 / 251); two visits per join cuts every wrong group but
keeps 63 of 788 right merges. Per pass it does: matched passes whose best hypothesis holds 3 pairings carry 11 of the
20 wrong ones (11 / 117; 4 pairings 0 / 47) — on the chain's map a row of posts shifted by one post pairs one name more
than the truth (robot 4). :func:`held_passes` with ``"< 4 pairings in all"`` in the first round only, end to end:
robot 4 seed 0 13 → 0 wrong merges (ATE 1.60 → 0.088 m), robot 4 seed 2 1 → 0, robots 1 seed 0 and 3 seed 2
unchanged; in every round it loses robot 1 seed 0's loop (shared names are not pairings, so later passes look weak).
The other wrong groups come from strong passes pairing a chained name of two posts or a glimpse: not a support matter.
"""
from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import asdict, dataclass  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

from benchmarks.mrclam_chained_names import majority  # noqa: E402
from benchmarks.mrclam_constellation import (  # noqa: E402
    guard_record,
    load_saved_state,
    saved_state_inputs,
)
from benchmarks.mrclam_honesty import add_state_arguments, states  # noqa: E402
from estimation.fastslam import range_bearing_config  # noqa: E402
from estimation.landmark_smoother import joint_landmark_covariance  # noqa: E402
from estimation.named_smoothing import covisible_names as _covisible  # noqa: E402
from estimation.noise_model import NoiseModelError  # noqa: E402
from estimation.pass_matching import PassVerdict, judge_passes, merges_from, passes_of, without_pairings  # noqa: E402
from runtime.commands.options import positive_float, positive_int  # noqa: E402


@dataclass(frozen=True)
class GroupSupport:
    """Who proposes one merge group: the proposing passes' indices (ascending; pass i spans [i, i + 1) pass
    lengths from the log's start), each pass's pairings in its best hypothesis against one earlier pass (its
    ``strength``), all the pairings it proposes (the union over the earlier passes it matched), how many earlier
    passes it matched, and its smallest log likelihood ratio over a rival (∞: no rival); ``visits``: the passes
    grouped into runs whose neighbours are fewer than ``visit_gap`` passes apart (one passage cut by the grid)."""

    passes: tuple[int, ...]
    best_pairings: tuple[int, ...]
    pass_pairings: tuple[int, ...]
    matched_earlier: tuple[int, ...]
    log_ratios: tuple[float, ...]
    visits: int

    @property
    def span_passes(self) -> int:
        """Pass lengths between the first proposing pass's start and the last's."""
        return self.passes[-1] - self.passes[0] if self.passes else 0

    @property
    def most_pairings(self) -> int:
        return max(self.best_pairings, default=0)


def group_members(group) -> set[int]:
    """The landmark indices a group's pairings (root, member) join."""
    return {int(x) for pair in group for x in pair}


def support_of(verdicts: list[PassVerdict], groups, *, visit_gap: int = 2) -> list[GroupSupport]:
    """Each group's support (:class:`GroupSupport`) among the matched ``verdicts``: a pass supports a group when
    one of its pairings joins two of the group's names. ``groups``: lists of pairings (root, member) as
    ``guard_record`` builds them; ``visit_gap``: passes at least this many spans apart are separate visits."""
    if visit_gap < 1:
        raise ValueError(f"visit_gap counts passes and must be ≥ 1, not {visit_gap}")
    matched = sorted((v for v in verdicts if v.status == "matched"), key=lambda v: v.index)
    out = []
    for group in groups:
        members = group_members(group)
        mine = [v for v in matched if any(int(a) in members and int(b) in members for a, b in v.pairs)]
        indices = [v.index for v in mine]
        visits = len(set(visit_labels(indices, visit_gap).values()))
        out.append(GroupSupport(tuple(indices), tuple(int(v.strength[0]) for v in mine),
                                tuple(len(v.pairs) for v in mine), tuple(int(v.matched_earlier) for v in mine),
                                tuple(float(v.strength[1]) for v in mine), visits))
    return out


def visit_labels(indices, visit_gap: int) -> dict[int, int]:
    """{pass index: its visit} for sorted pass ``indices``: a pass fewer than ``visit_gap`` spans after the previous
    one is the same visit."""
    out, visit = {}, -1
    for k, i in enumerate(indices):
        if k == 0 or i - indices[k - 1] >= visit_gap:
            visit += 1
        out[i] = visit
    return out


def split_by_visits(verdicts: list[PassVerdict], group, *, visit_gap: int = 2) -> tuple[list[set[int]], set]:
    """A merge group cut where a single visit alone joins it: the group's names linked by the matched passes'
    pairings, each pairing labelled with its pass's visit (:func:`visit_labels`); while some visit's pairings are
    the only link between two parts (removing them splits a part), those pairings are held back. Returns the parts
    left (sets of landmark indices, two or more names each: every join in them is made by two visits or more) and
    the held pairings as (a, b, pass index)."""
    members = group_members(group)
    matched = sorted((v for v in verdicts if v.status == "matched"), key=lambda v: v.index)
    edges = sorted({(min(int(a), int(b)), max(int(a), int(b)), v.index) for v in matched for a, b in v.pairs
                    if int(a) in members and int(b) in members})
    visit = visit_labels(sorted({e[2] for e in edges}), visit_gap)
    held: set = set()
    changed = True
    while changed:
        changed = False
        live = [e for e in edges if e not in held]
        before = _components(members, live)
        for v in sorted(set(visit.values())):
            after = _components(members, [e for e in live if visit[e[2]] != v])
            if len(set(after.values())) > len(set(before.values())):
                cut = {e for e in live if visit[e[2]] == v and after[e[0]] != after[e[1]]}
                held |= cut
                changed = True
                break
    parts: dict[int, set[int]] = {}
    for x, root in _components(members, [e for e in edges if e not in held]).items():
        parts.setdefault(root, set()).add(x)
    return [p for p in parts.values() if len(p) > 1], held


def _components(members: set[int], edges) -> dict[int, int]:
    """{member: the smallest member of its connected component} under ``edges`` (a, b, label)."""
    parent = {x: x for x in members}

    def find(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for a, b, _ in edges:
        ra, rb = find(a), find(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    return {x: find(x) for x in members}


# Each rule: hold a group back when its support says so (no barcode). Named by what is held back.
RULES = {
    "one pass": lambda s: len(s.passes) < 2,
    "one visit": lambda s: s.visits < 2,
    "< 4 pairings": lambda s: s.most_pairings < 4,
    "one visit and < 4 pairings": lambda s: s.visits < 2 and s.most_pairings < 4,
    "one visit or < 4 pairings": lambda s: s.visits < 2 or s.most_pairings < 4,
    "one earlier pass matched": lambda s: max(s.matched_earlier, default=0) < 2,
}


# Each rule on one matched pass (no barcode): its pairings are held back from the round (the pass is judged again
# next round). ``strength[0]``: the pairings of its best hypothesis against one earlier pass (names both passes hold
# not counted); ``pairs``: every pairing it proposes (the union over the earlier passes it matched).
PASS_RULES = {
    "best < 4 pairings": lambda v: v.strength[0] < 4,
    "< 4 pairings in all": lambda v: len(v.pairs) < 4,
    "one earlier pass matched": lambda v: v.matched_earlier < 2,
}


def held_passes(verdicts: list[PassVerdict], rule: str, *, defer: bool = False) -> list[PassVerdict]:
    """``verdicts`` with the matched passes that ``rule`` (a key of :data:`PASS_RULES`) holds back turned into
    ``"held"`` (no pairings): the verdicts to give ``merges_from`` instead. With ``defer``, weak passes only wait
    behind stronger ones: in a round where every matched pass is weak, none is held (else a loop that only weak
    passes can close is never closed; robot 1 seed 0, session 28).

    Wiring into ``estimation.name_chain`` (its rounds): ``verdicts = held_passes(verdicts, rule, defer=True)`` right
    after ``judge_passes`` (``score_verdicts`` counts the held passes in no status)."""
    test = PASS_RULES[rule]
    weak = [v.status == "matched" and bool(test(v)) for v in verdicts]
    if defer and not any(v.status == "matched" and not w for v, w in zip(verdicts, weak, strict=True)):
        return list(verdicts)
    return [PassVerdict(v.index, "held", [], v.strength, v.matched_earlier, v.unique) if w else v
            for v, w in zip(verdicts, weak, strict=True)]


def hold_back(verdicts: list[PassVerdict], groups, *, rule: str = "one visit", visit_gap: int = 2) -> list[int]:
    """The indices of ``groups`` that ``rule`` (a key of :data:`RULES`) holds back for a later round. (Session 28:
    no group rule separated wrong groups from right ones; :func:`held_passes` is the rule proposed.)

    Wiring into ``estimation.name_chain``'s rounds (after ``clusters, used = merges_from(verdicts, covisible)``):
    build the groups as ``guard_record`` does, ``held = hold_back(used, groups)``, then
    ``used = without_groups(used, [groups[i] for i in held])`` and ``clusters = merges_from(used, covisible)[0]``
    before the guard and the merge; a held group's passes are judged again next round on the merged map."""
    supports = support_of(verdicts, groups, visit_gap=visit_gap)
    return [i for i, s in enumerate(supports) if RULES[rule](s)]


def without_groups(verdicts: list[PassVerdict], groups) -> list[PassVerdict]:
    """The matched ``verdicts`` (``merges_from``'s used passes) with every pairing that joins two names of one of
    ``groups`` removed; a pass left with no pairing is dropped."""
    held = [group_members(g) for g in groups]
    return without_pairings(verdicts, lambda a, b: any(a in m and b in m for m in held))


def judge_state(log, noise, config, path, args) -> dict:
    """The next round of a saved state judged as ``mrclam_constellation`` does, each merge group with its support,
    the guard's share, its looseness and (scoring) whether it joins two posts and which of its passes' pairings do."""
    current, _ = load_saved_state(path, log, noise, config)
    started = time.process_time()
    named, solution = current.named, current.solution
    n = len(named.names)
    covariance = joint_landmark_covariance(named.problem, solution)
    passes = passes_of(named, solution, args.pass_seconds, args.min_sightings)
    covisible = _covisible(named.problem, solution.inliers, n)
    verdicts = judge_passes(solution.landmarks, covariance, covisible, passes, min_pairs=args.min_pairs,
                            ratio=np.inf, fewer_rival=args.fewer_rival, distinct_points=args.distinct_points)
    _, used = merges_from(verdicts, covisible)
    owner = majority(current.names, log.landmark_ids)
    code = np.array([owner.get(int(x), -1) for x in named.names])
    row = {"names": n, "matched": sum(v.status == "matched" for v in verdicts), "used": len(used), "groups": []}
    if not used:
        row["cpu_s"] = time.process_time() - started
        return row
    record, _ = guard_record(current, covariance, used, owner, covisible)
    index = {int(x): k for k, x in enumerate(named.names)}
    groups = [[(index[s["group"][0]], index[m]) for m in s["group"][1:]] for s in record["shares"]]
    aside = {tuple(a["group"]) for a in record["set_aside"]}
    supports = support_of(used, groups, visit_gap=args.visit_gap)
    by_index = {v.index: v for v in used}
    t0 = passes[0].start
    for group, share, support in zip(groups, record["shares"], supports, strict=True):
        sigmas = [_difference_sigma(covariance, a, b) for a, b in group]
        members = group_members(group)
        parts, held = split_by_visits(used, group, visit_gap=args.visit_gap)
        row["groups"].append({
            "names": share["group"], "wrong": bool(share["wrong"]),
            "posts": sorted({int(code[k]) for k in members}),
            "support": asdict(support), "visits": support.visits, "span_s": support.span_passes * args.pass_seconds,
            "pass_starts_s": [passes[i].start - t0 for i in support.passes],
            "pass_wrong_pairings": [sum(code[a] != code[b] for a, b in by_index[i].pairs) for i in support.passes],
            "share_d2": share["d2"], "share_dof": share["dof"], "set_aside": tuple(share["group"]) in aside,
            "sigma_m": float(np.median(sigmas)), "sigma_max_m": float(np.max(sigmas)),
            "held": {name: bool(rule(support)) for name, rule in RULES.items()},
            "split": {"parts": [sorted(int(named.names[k]) for k in p) for p in parts],
                      "wrong_parts": sum(len({int(code[k]) for k in p}) > 1 for p in parts),
                      "merges": len(members) - 1, "merges_kept": sum(len(p) - 1 for p in parts),
                      "held_pairings": len(held), "held_wrong": sum(code[a] != code[b] for a, b, _ in held),
                      "held_passes": sorted({passes[i].start - t0 for _, _, i in held})}})
    row["passes"] = [{"index": v.index, "best_pairings": int(v.strength[0]), "pairings": len(v.pairs),
                      "matched_earlier": int(v.matched_earlier), "wrong_pairings": int(sum(code[a] != code[b]
                                                                                       for a, b in v.pairs))}
                     for v in verdicts if v.status == "matched"]
    row["pass_rules"] = {"none": _batch_groups(verdicts, covisible, code)}
    for rule in PASS_RULES:
        row["pass_rules"][rule] = _batch_groups(held_passes(verdicts, rule), covisible, code)
        row["pass_rules"][f"{rule}, deferred"] = _batch_groups(held_passes(verdicts, rule, defer=True), covisible,
                                                               code)
    row["cpu_s"] = time.process_time() - started
    return row


def _rule_names(rows: list[dict]) -> list[str]:
    """The pass rules the judged states were scored with, in order."""
    return next((list(r["pass_rules"]) for r in rows if "pass_rules" in r), [])


def _batch_groups(verdicts: list[PassVerdict], covisible: np.ndarray, code: np.ndarray) -> dict:
    """The merge groups ``merges_from`` makes of ``verdicts``, scored: passes used, groups, wrong groups (two
    barcodes), merges (names absorbed) in right groups and in wrong ones."""
    clusters, used = merges_from(verdicts, covisible)
    members: dict[int, set[int]] = {}
    for k, r in clusters.items():       # the absorbed names map to their root; the root is not a key
        members.setdefault(r, {r}).add(k)
    wrong = [len({int(code[k]) for k in m}) > 1 for m in members.values()]
    sizes = [len(m) - 1 for m in members.values()]
    return {"passes": len(used), "groups": len(members), "wrong_groups": sum(wrong),
            "right_merges": sum(n for n, w in zip(sizes, wrong, strict=True) if not w),
            "wrong_group_merges": sum(n for n, w in zip(sizes, wrong, strict=True) if w)}


def _difference_sigma(covariance: np.ndarray, a: int, b: int) -> float:
    """σ (m) of the difference of two landmarks' positions along its widest axis."""
    ia, ib = [2 * a, 2 * a + 1], [2 * b, 2 * b + 1]
    s = covariance[np.ix_(ia, ia)] + covariance[np.ix_(ib, ib)] - covariance[np.ix_(ia, ib)] \
        - covariance[np.ix_(ib, ia)]
    return float(np.sqrt(np.max(np.linalg.eigvalsh(0.5 * (s + s.T)))))


def tally(rows: list[dict]) -> dict:
    """Over all judged states: groups, wrong groups, and per rule (also the guard) wrong / right groups held back."""
    groups = [g for r in rows for g in r["groups"]]
    wrong = [g for g in groups if g["wrong"]]
    right = [g for g in groups if not g["wrong"]]
    out = {"groups": len(groups), "wrong": len(wrong), "rules": {}}
    for name in [*RULES, "guard"]:
        def held(g, name=name):
            return g["set_aside"] if name == "guard" else g["held"][name]
        out["rules"][name] = {"wrong_held": sum(held(g) for g in wrong), "right_held": sum(held(g) for g in right)}
    out["split"] = {"wrong_parts_left": sum(g["split"]["wrong_parts"] for g in groups),
                    "wrong_groups_cut_clean": sum(g["split"]["wrong_parts"] == 0 for g in wrong),
                    "right_groups_cut": sum(g["split"]["merges_kept"] < g["split"]["merges"] for g in right),
                    "right_merges": sum(g["split"]["merges"] for g in right),
                    "right_merges_kept": sum(g["split"]["merges_kept"] for g in right),
                    "wrong_group_merges_kept": sum(g["split"]["merges_kept"] for g in wrong)}
    out["passes_by_pairings"] = {}
    for key, label in (("best_pairings", "best"), ("pairings", "all")):
        for r in rows:
            for v in r.get("passes", []):
                bucket = f"{label} {min(v[key], 6)}{'+' if v[key] >= 6 else ''}"
                count = out["passes_by_pairings"].setdefault(bucket, [0, 0])
                count[0] += v["wrong_pairings"] > 0
                count[1] += 1
    out["pass_rules"] = {name: {key: sum(r["pass_rules"][name][key] for r in rows if "pass_rules" in r)
                                for key in ("passes", "groups", "wrong_groups", "right_merges", "wrong_group_merges")}
                         for name in _rule_names(rows)}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_state_arguments(parser)
    parser.add_argument("--rounds", default="0,1",
                        help="judge the round after each of these saved rounds (0: the chain, the loosest map)")
    parser.add_argument("--pass-seconds", type=positive_float, default=20.0, metavar="S", help="a pass's span, s")
    parser.add_argument("--min-sightings", type=positive_int, default=2,
                        help="kept sightings of a name within a pass's span for it to be the pass's")
    parser.add_argument("--min-pairs", type=positive_int, default=3, help="pairings a match needs")
    parser.add_argument("--fewer-rival", action="store_true",
                        help="judge as mrclam_constellation --fewer-rival does (a shifted row refused by its fit)")
    parser.add_argument("--distinct-points", action="store_true",
                        help="judge as mrclam_constellation --distinct-points does (pairings by distinct points)")
    parser.add_argument("--visit-gap", type=positive_int, default=2, metavar="PASSES",
                        help="proposing passes at least this many spans apart are separate visits (2: adjacent "
                             "spans are one visit)")
    parser.add_argument("--groups", action="store_true", help="print every merge group, not only the wrong ones")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    if not os.path.isdir(args.state_dir):
        print(f"mrclam_pass_support: no state folder at {args.state_dir}", file=sys.stderr)
        return 2
    robots = [int(r) for r in args.robots.split(",")]
    seeds = [int(s) for s in args.seeds.split(",")]
    found = states(args.state_dir, robots, seeds, [f"round{int(k)}" for k in args.rounds.split(",")])
    if not found:
        print(f"mrclam_pass_support: no saved round states of robots {args.robots}, seeds {args.seeds}, rounds "
              f"{args.rounds} in {args.state_dir}", file=sys.stderr)
        return 2
    logs: dict = {}
    noises: dict = {}
    rows = []
    for robot, seed, tag, path in found:
        try:     # the model the state's run was given (its --noise file, else in sample)
            log, noise = saved_state_inputs(args.data, robot, path, logs, noises)
        except NoiseModelError as e:
            print(f"mrclam_pass_support: {path.name}: its run's noise model: {e}", file=sys.stderr)
            return 2
        config = range_bearing_config(n_particles=100)
        row = {"robot": robot, "seed": seed, "from": tag, **judge_state(log, noise, config, path, args)}
        rows.append(row)
        if not args.json:
            _print_state(row, every=args.groups)
    summary = tally(rows)
    if args.json:
        print(json.dumps({"states": rows, "tally": summary}, default=float))
    else:
        _print_tally(rows, summary)
    return 0


def _print_state(row: dict, every: bool) -> None:
    wrong = sum(g["wrong"] for g in row["groups"])
    print(f"robot {row['robot']} seed {row['seed']} after {row['from']}: {row['names']} names, {row['matched']} "
          f"passes matched, {row['used']} used, {len(row['groups'])} groups ({wrong} wrong), "
          f"{row['cpu_s']:.0f} s CPU", flush=True)
    for name, t in row.get("pass_rules", {}).items():
        print(f"  passes held: {name}: {t['passes']} used, {t['groups']} groups ({t['wrong_groups']} wrong), merges "
              f"{t['right_merges']} right + {t['wrong_group_merges']} in wrong groups", flush=True)
    for g in row["groups"]:
        if not (every or g["wrong"]):
            continue
        s = g["support"]
        passes = ", ".join(f"{t:.0f} s ({b}/{u} pairings, {e} earlier, ratio {r:.1f}{f', {w} wrong' if w else ''})"
                           for t, b, u, e, r, w in zip(g["pass_starts_s"], s["best_pairings"], s["pass_pairings"],
                                                       s["matched_earlier"], s["log_ratios"],
                                                       g["pass_wrong_pairings"], strict=True))
        print(f"  {'WRONG' if g['wrong'] else 'right'} {len(g['names'])} names (posts {g['posts']}): "
              f"{len(s['passes'])} passes, {g['visits']} visits over {g['span_s']:.0f} s: {passes}; share "
              f"{g['share_d2']:.1f}/{g['share_dof']}{' set aside' if g['set_aside'] else ''}; σ "
              f"{g['sigma_m']:.2f} m (max {g['sigma_max_m']:.2f})", flush=True)
        c = g["split"]
        if c["held_pairings"]:
            print(f"    cut where one visit alone joins it: {c['held_pairings']} pairings held ({c['held_wrong']} "
                  f"wrong; passes at {', '.join(f'{t:.0f}' for t in c['held_passes'])} s), parts {c['parts']} "
                  f"({c['wrong_parts']} of two posts), {c['merges_kept']} of {c['merges']} merges kept", flush=True)


def _print_tally(rows: list[dict], summary: dict) -> None:
    print(f"\n{len(rows)} states, {summary['groups']} groups, {summary['wrong']} wrong")
    print("| rule (held back) | wrong held | right held |")
    print("|---|---|---|")
    for name, t in summary["rules"].items():
        print(f"| {name} | {t['wrong_held']} / {summary['wrong']} | {t['right_held']} / "
              f"{summary['groups'] - summary['wrong']} |")
    counts = ", ".join(f"{k}: {w}/{n}" for k, (w, n) in sorted(summary["passes_by_pairings"].items()))
    print(f"\nmatched passes with a wrong pairing / all, by their best hypothesis's pairings (best) and all their "
          f"pairings (all): {counts}")
    print("\n| pass rule (a pass held back) | passes used | groups | wrong groups | merges in right groups | merges in "
          "wrong groups |")
    print("|---|---|---|---|---|---|")
    for name, t in summary["pass_rules"].items():
        print(f"| {name} | {t['passes']} | {t['groups']} | {t['wrong_groups']} | {t['right_merges']} | "
              f"{t['wrong_group_merges']} |")
    c = summary["split"]
    print(f"cut where one visit alone joins (split_by_visits): wrong groups cut clean {c['wrong_groups_cut_clean']} / "
          f"{summary['wrong']} (parts of two posts left {c['wrong_parts_left']}, merges kept in them "
          f"{c['wrong_group_merges_kept']}); right groups cut {c['right_groups_cut']} / "
          f"{summary['groups'] - summary['wrong']}, right merges kept {c['right_merges_kept']} / {c['right_merges']}")


if __name__ == "__main__":
    sys.exit(main())
