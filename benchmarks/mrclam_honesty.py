"""MRCLAM without barcodes: does a partly merged map say where it is wrong? Split scores of saved constellation states.

Run from the repository root, on the states ``benchmarks.mrclam_constellation --state-dir DIR`` keeps:

    .venv/bin/python -m benchmarks.mrclam_honesty --state-dir DIR [--robots 1,2,3,4,5] [--seeds 0,2] [--tags round4,...]
        [--gap 5] [--floor 0] [--alpha 0.01] [--top 5] [--groups] [--two-points] [--json]

For every state (a robot's names and the smoother's solution after a round), every landmark's kept sightings are cut
into runs at gaps of more than ``--gap`` s, and each run gets its split score
(:func:`estimation.map_honesty.split_scores`: the first-order drop of the smoother's cost if the run were a name of
its own, χ²₂ under the model). No barcode is used for that. The barcodes and Vicon only score it: a run is **wrong**
when most of its sightings are of another post than most of its name's; a right run lies in a **wrong stretch** when
the smoothed pose at it is confidently wrong (pose NEES against Vicon beyond χ²₃ 99 %, 11.3, at the pose covariance
nearest the run's middle). Printed per state: runs (wrong, right in a wrong stretch), the map-wide threshold (χ²₂ at
1 − α/runs, Bonferroni), runs flagged beyond it — wrong runs / right runs in a wrong stretch / false alarms —, the
rank of the first wrong run among all runs by score, the top score, and the names flagged by the **per-name** test
(a name's largest run score beyond χ²₂ at 1 − α/its runs: the test to apply to the few names of a proposed merge),
with how many of them hold a wrong run, against how many names hold one. ``--top N``: the N highest-scoring runs of
each state with their barcodes, the offset the split would give them and the pose's error at them. ``--groups``: the
pairwise merge groups ``mrclam_constellation --pairwise --kept-covisible`` would propose on the state, each marked
refused when a member name is flagged by the per-name test. ``--two-points``: the names that hold two points
(:func:`two_point_names`: sighted twice in one frame, or a jump between consecutive sightings beyond the calibrated
sensor's χ²₂, Bonferroni), each cut in two, with its split score, scored by the barcodes.

Session 27 (B; docs: "Session 27: … (B)"): robot 3 seed 0's 1253–1275 s stretch rests on one wrong sighting (1252.6
s) whose run scores 15.6 — the top of the map's 328 runs but below the map-wide threshold 20.8; the per-name test
(threshold 10.6 for its two runs) flags it, and with ``--groups`` on the state before session 26's wrong pairwise
merge (pairwise1) the wrong group {10, 71, 121} is refused and the right one passes; on robot 2 seed 0's round 3 the
wrong group {5, 172} is refused and its 3 right groups pass. With ``--floor 0.035`` (each run's own offset σ, the
spread of one post's names session 26 measured) the same two are refused and fewer right groups (robot 5 seed 0
round 6: 1 of 6 instead of 2).
"""
from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import re  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

from benchmarks.eval_mrclam import DATA  # noqa: E402
from benchmarks.mrclam_chained_names import majority  # noqa: E402
from benchmarks.mrclam_constellation import (  # noqa: E402
    load_saved_state,
    saved_state_inputs,
)
from estimation import chi2  # noqa: E402
from estimation.constellation import pairwise_groups  # noqa: E402
from estimation.fastslam import range_bearing_config  # noqa: E402
from estimation.geometry import compose, wrap_angle  # noqa: E402
from estimation.landmark_smoother import joint_landmark_covariance  # noqa: E402
from estimation.map_honesty import (  # noqa: E402
    Run,
    flagged_landmarks,
    self_covisible_frames,
    sighting_jumps,
    sighting_runs,
    split_scores,
    split_threshold,
    two_point_split,
)
from estimation.named_smoothing import covisible_names as _covisible  # noqa: E402
from estimation.noise_model import NoiseModelError  # noqa: E402
from runtime.commands.options import float_where, non_negative_float, positive_int  # noqa: E402

POSE_NEES_99 = float(chi2.ppf(0.99, 3))      # a run's stretch is confidently wrong beyond it (11.34)
STATE = re.compile(r"Robot(?P<robot>\d+)-seed(?P<seed>\d+)-(?P<tag>(?P<kind>round|pairwise)(?P<k>\d+))\.npz$")


def probability(text: str) -> float:
    return float_where(text, "a probability in (0, 1)", lambda v: 0 < v < 1)


def states(directory, robots: list[int], seeds: list[int], tags: list[str] | None) -> list[tuple[int, int, str, Path]]:
    """(robot, seed, tag, path) of the saved states in ``directory``, rounds before pairwise rounds."""
    out = []
    for path in sorted(Path(directory).glob("Robot*-seed*-*.npz")):
        m = STATE.search(path.name)
        if m is None:
            continue
        robot, seed, tag = int(m["robot"]), int(m["seed"]), m["tag"]
        if robot in robots and seed in seeds and (tags is None or tag in tags):
            out.append(((robot, seed, m["kind"] == "pairwise", int(m["k"])), (robot, seed, tag, path)))
    return [s for _, s in sorted(out)]


def run_state(log, noise, config, path, gap_s: float, alpha: float, top: int, groups: bool = False,
              floor_m: float = 0.0, two_points: bool = False) -> dict:
    current, _ = load_saved_state(path, log, noise, config)
    named, solution = current.named, current.solution
    problem = named.problem
    started = time.process_time()
    runs = sighting_runs(problem, solution, gap_s)
    details: dict = {}
    scores = split_scores(problem, solution, runs, details, floor_m=floor_m)
    cpu = time.process_time() - started
    barcodes = log.landmark_ids[named.sightings]
    owner = majority(current.names, log.landmark_ids)
    name_post = np.array([owner[int(n)] for n in named.names])
    wrong = np.array([majority(np.zeros(len(r.sightings), np.int64), barcodes[r.sightings])[0]
                      != name_post[r.landmark] for r in runs], bool)
    nees = run_pose_nees(log, named, solution, runs)
    bad_stretch = nees > POSE_NEES_99
    finite = np.isfinite(scores)
    threshold = split_threshold(max(int(finite.sum()), 1), alpha)
    flagged = finite & (scores > threshold)
    order = np.argsort(-np.where(finite, scores, -np.inf), kind="stable")
    rank = np.empty(len(runs), int)
    rank[order] = np.arange(1, len(runs) + 1)
    name_flagged = flagged_landmarks(runs, scores, len(named.names), alpha)      # the per-name test
    name_holds_wrong = np.zeros(len(named.names), bool)
    name_holds_wrong[[runs[i].landmark for i in np.flatnonzero(wrong)]] = True
    row = {"runs": len(runs), "names": len(named.names), "wrong_runs": int(wrong.sum()),
           "wrong_stretch_runs": int((bad_stretch & ~wrong).sum()),
           "threshold": threshold, "flagged": int(flagged.sum()), "hits": int((flagged & wrong).sum()),
           "stretch_hits": int((flagged & ~wrong & bad_stretch).sum()),
           "false_alarms": int((flagged & ~wrong & ~bad_stretch).sum()),
           "first_wrong_rank": int(rank[wrong].min()) if wrong.any() else None,
           "top_score": float(scores[order[0]]) if len(runs) and finite.any() else None,
           "names_flagged": int(name_flagged.sum()),
           "names_flagged_wrong": int((name_flagged & name_holds_wrong).sum()),
           "names_holding_wrong": int(name_holds_wrong.sum()), "split_cpu_s": cpu, "top": []}
    if two_points:
        row["two_points"] = two_point_names(log, noise, named, solution, alpha)
    if groups:
        row["groups"] = merge_groups(problem, solution, name_post, set(np.flatnonzero(name_flagged).tolist()),
                                     named.names)
    if top:
        t = np.concatenate([named.frame_times[:1], named.frame_times])
        true = log.true_pose(t)
        estimate = compose(np.tile(true[0], (len(t), 1)), solution.poses)
        error = true - estimate
        error[:, 2] = wrap_angle(error[:, 2])
        for i in order[:top]:
            r = runs[i]
            codes, counts = np.unique(barcodes[r.sightings], return_counts=True)
            pose = int(np.median(problem.pose_index[r.sightings]))
            row["top"].append({
                "name": int(named.names[r.landmark]), "post": int(name_post[r.landmark]),
                "start_s": float(log.sighting_times[named.sightings[r.sightings[0]]]),
                "end_s": float(log.sighting_times[named.sightings[r.sightings[-1]]]),
                "sightings": len(r.sightings), "barcodes": dict(zip(codes.tolist(), counts.tolist(), strict=True)),
                "score": float(scores[i]), "offset_m": float(np.hypot(*details["offset"][i])), "wrong": bool(wrong[i]),
                "pose_error_m": float(np.hypot(*error[pose, :2])), "heading_error_rad": float(error[pose, 2]),
                "pose_nees": float(nees[i])})
    return row


def two_point_names(log, noise, named, solution, alpha: float) -> dict:
    """Names that hold two points (session 29), barcode-free: sighted twice in one frame
    (:func:`~estimation.map_honesty.self_covisible_frames`) or with a jump between consecutive sightings beyond χ²₂
    at 1 − α/J (:func:`~estimation.map_honesty.sighting_jumps` under the calibrated sensor, Bonferroni over the
    map's J pairs); each cut by :func:`~estimation.map_honesty.two_point_split` and the split score of its second
    part's kept sightings (χ²₂; "cut" when beyond χ²₂ at 1 − α: the cost says so). Scored by the barcodes: the
    jumps between two barcodes found, the same-barcode pairs flagged, each part's barcodes."""
    problem = named.problem
    sensor = noise.range_bearing
    codes = np.asarray(log.landmark_ids)[named.sightings]
    pairs, jump = sighting_jumps(problem, solution, sensor.range_sigma(problem.ranges), sensor.bearing_sigma_rad,
                                 sensor.range_correlation, sensor.bearing_correlation)
    threshold = float(chi2.isf(alpha / max(len(jump), 1), 2))
    beyond = jump > threshold
    switch = codes[pairs[:, 0]] != codes[pairs[:, 1]]
    frames = self_covisible_frames(problem)
    apart = pairs[beyond]
    candidates = sorted(set(np.flatnonzero(frames).tolist()) | set(problem.landmark_index[apart[:, 0]].tolist()))
    runs, parts = [], []
    for k in candidates:
        mine = np.flatnonzero(problem.landmark_index == k)
        second = two_point_split(problem, solution, k, apart=apart)
        runs.append(Run(k, mine[second & np.asarray(solution.inliers, bool)[mine]], 0.0, 0.0))
        parts.append([_counts(codes[mine[~second]]), _counts(codes[mine[second]])])
    scores = split_scores(problem, solution, runs) if runs else np.zeros(0)
    names = []
    for k, part, score in zip(candidates, parts, scores, strict=True):
        mine = problem.landmark_index == k
        names.append({"name": int(named.names[k]), "frames": int(frames[k]),
                      "jumps": int((problem.landmark_index[apart[:, 0]] == k).sum()), "parts": part,
                      "two_posts": len(np.unique(codes[mine])) > 1, "split_score": float(score),
                      "cut": bool(np.isfinite(score) and score > chi2.isf(alpha, 2))})
    mixed = [int(named.names[k]) for k in range(len(named.names))
             if len(np.unique(codes[problem.landmark_index == k])) > 1]
    return {"pairs": len(jump), "threshold": threshold, "switches": int(switch.sum()),
            "switches_beyond": int((switch & beyond).sum()), "same_beyond": int((~switch & beyond).sum()),
            "names_two_posts": len(mixed), "names_two_posts_found": sum(n["two_posts"] for n in names),
            "names": names}


def _counts(codes: np.ndarray) -> dict[int, int]:
    values, counts = np.unique(codes, return_counts=True)
    return dict(zip(values.tolist(), counts.tolist(), strict=True))


def run_pose_nees(log, named, solution, runs) -> np.ndarray:
    """(R,) the smoothed pose's NEES against Vicon (in the start frame, χ²₃) at each run: the pose covariance
    nearest the run's middle sighting (the solution keeps every 10th), its error there."""
    t = np.concatenate([named.frame_times[:1], named.frame_times])
    true = log.true_pose(t)
    estimate = compose(np.tile(true[0], (len(t), 1)), solution.poses)
    error = true - estimate
    error[:, 2] = wrap_angle(error[:, 2])
    c, s = np.cos(true[0, 2]), np.sin(true[0, 2])
    rot = np.array([[c, -s], [s, c]])
    out = np.full(len(runs), np.nan)
    for i, r in enumerate(runs):
        pose = int(np.median(named.problem.pose_index[r.sightings]))
        near = int(np.argmin(np.abs(solution.covariance_poses - pose)))
        p = solution.pose_covariances[near].copy()
        p[:2, :2] = rot @ p[:2, :2] @ rot.T
        p[:2, 2] = rot @ p[:2, 2]
        p[2, :2] = p[:2, 2]
        e = error[solution.covariance_poses[near]]
        out[i] = float(e @ np.linalg.solve(p, e))
    return out


def merge_groups(problem, solution, name_post: np.ndarray, flagged: set[int], names: np.ndarray) -> list[dict]:
    """The pairwise merges ``mrclam_constellation --pairwise --kept-covisible`` would propose on this state
    (:func:`estimation.constellation.pairwise_groups`, status merge), each with its names, whether it joins two posts
    (the barcodes), and whether the per-name split test refuses it (a member name flagged)."""
    n = len(solution.landmarks)
    covariance = joint_landmark_covariance(problem, solution)
    covisible = _covisible(problem, solution.inliers, n, kept_only=True)
    seen = np.flatnonzero(np.isfinite(np.diagonal(covariance)).reshape(n, 2).all(axis=1))
    out = []
    for g in pairwise_groups(solution.landmarks, covariance, seen, allowed=~covisible):
        if g.status != "merge":
            continue
        members = [int(m) for m in g.members]
        out.append({"names": [int(names[m]) for m in members], "posts": sorted({int(name_post[m]) for m in members}),
                    "two_posts": len({int(name_post[m]) for m in members}) > 1,
                    "refused": any(m in flagged for m in members)})
    return out


def add_state_arguments(parser: argparse.ArgumentParser) -> None:
    """The options that say which saved states a tool reads: the data set, the state folder, robots and seeds."""
    parser.add_argument("--data", default=str(DATA))
    parser.add_argument("--state-dir", metavar="DIR", required=True,
                        help="the saved states (benchmarks.mrclam_constellation --state-dir)")
    parser.add_argument("--robots", default="1,2,3,4,5")
    parser.add_argument("--seeds", default="0,2")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_state_arguments(parser)
    parser.add_argument("--tags", default=None, help="only these states, e.g. round4,pairwise1 (default: all)")
    parser.add_argument("--gap", type=non_negative_float, default=5.0, metavar="S",
                        help="a landmark's sightings more than S s apart start a new run")
    parser.add_argument("--floor", type=non_negative_float, default=0.0, metavar="M",
                        help="σ of an offset each run may have of its own (split_scores' floor_m; session 26 measured "
                             "≈ 0.035 m between one post's names; default 0: none)")
    parser.add_argument("--alpha", type=probability, default=0.01, metavar="PROBABILITY",
                        help="false-alarm probability of the map-wide test (Bonferroni over its runs) and per name")
    parser.add_argument("--top", type=positive_int, default=None, metavar="N",
                        help="also print each state's N highest-scoring runs with their truth (default: none)")
    parser.add_argument("--groups", action="store_true",
                        help="also the pairwise merge groups of each state (as mrclam_constellation --pairwise "
                             "--kept-covisible would propose them), each refused when a member is flagged by the "
                             "per-name split test")
    parser.add_argument("--two-points", action="store_true",
                        help="also the names that hold two points (sighted twice in one frame, or a jump between "
                             "consecutive sightings beyond the calibrated sensor's χ²₂ Bonferroni), each cut in two "
                             "and its split score (session 29)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    if not os.path.isdir(args.data):
        print(f"mrclam_honesty: no data set at {args.data}", file=sys.stderr)
        return 2
    if not os.path.isdir(args.state_dir):
        print(f"mrclam_honesty: no state folder at {args.state_dir}", file=sys.stderr)
        return 2
    robots = [int(r) for r in args.robots.split(",")]
    seeds = [int(s) for s in args.seeds.split(",")]
    found = states(args.state_dir, robots, seeds, args.tags.split(",") if args.tags else None)
    if not found:
        print(f"mrclam_honesty: no saved states of robots {args.robots}, seeds {args.seeds} in {args.state_dir}",
              file=sys.stderr)
        return 2
    logs: dict = {}
    noises: dict = {}
    rows = []
    if not args.json:
        print(f"split scores, runs cut at gaps > {args.gap:g} s, offset floor {args.floor:g} m, α {args.alpha:g} "
              "(map-wide: Bonferroni over runs; per name: over the name's runs)")
        print("| state | names | runs (wrong, right in a wrong stretch) | threshold | flagged: wrong runs / right "
              "runs in a wrong stretch / false alarms | first wrong run's rank "
              "| top score | names flagged (holding a wrong run) / names holding one |")
        print("|---|---|---|---|---|---|---|---|")
    for robot, seed, tag, path in found:
        try:     # the model the state's run was given (its --noise file, else in sample)
            log, noise = saved_state_inputs(args.data, robot, path, logs, noises)
        except NoiseModelError as e:
            print(f"mrclam_honesty: {path.name}: its run's noise model: {e}", file=sys.stderr)
            return 2
        row = {"robot": robot, "seed": seed, "tag": tag,
               **run_state(log, noise, range_bearing_config(n_particles=100), path, args.gap, args.alpha,
                           args.top or 0, args.groups, args.floor, args.two_points)}
        rows.append(row)
        if not args.json:
            _print(row)
    if args.json:
        print(json.dumps({"gap_s": args.gap, "alpha": args.alpha, "states": rows}))
    return 0


def _print(row: dict) -> None:
    rank = row["first_wrong_rank"] if row["first_wrong_rank"] is not None else "–"
    top = f"{row['top_score']:.1f}" if row["top_score"] is not None else "–"
    print(f"| robot {row['robot']} s{row['seed']} {row['tag']} | {row['names']} | {row['runs']} ({row['wrong_runs']}, "
          f"{row['wrong_stretch_runs']}) | {row['threshold']:.1f} | {row['flagged']}: {row['hits']} / "
          f"{row['stretch_hits']} / {row['false_alarms']} | {rank} | {top} "
          f"| {row['names_flagged']} ({row['names_flagged_wrong']}) / {row['names_holding_wrong']} |", flush=True)
    for t in row["top"]:
        print(f"    score {t['score']:6.1f}  name {t['name']} (post {t['post']}) {t['start_s']:.1f}–{t['end_s']:.1f} "
              f"s, "
              f"{t['sightings']} sightings {t['barcodes']}{' WRONG' if t['wrong'] else ''}; split offset "
              f"{t['offset_m']:.3f} m; pose err {t['pose_error_m']:.3f} m, {t['heading_error_rad']:+.3f} rad, "
              f"NEES {t['pose_nees']:.1f}", flush=True)
    if "two_points" in row:
        t = row["two_points"]
        print(f"    two points: {t['pairs']} consecutive pairs, jump threshold {t['threshold']:.1f}: barcode switches "
              f"beyond it {t['switches_beyond']} / {t['switches']}, same-barcode pairs beyond it {t['same_beyond']}; "
              f"names of two barcodes found {t['names_two_posts_found']} / {t['names_two_posts']}", flush=True)
        for n in t["names"]:
            print(f"      name {n['name']}: {n['frames']} frames of two, {n['jumps']} jumps; parts {n['parts'][0]} | "
                  f"{n['parts'][1]}; split score {n['split_score']:.1f}{' cut' if n['cut'] else ''}"
                  f"{'' if n['two_posts'] else ' (one barcode)'}", flush=True)
    for g in row.get("groups", []):
        print(f"    merge group {g['names']} (posts {g['posts']}){' TWO POSTS' if g['two_posts'] else ''}: "
              f"{'refused (a name flagged)' if g['refused'] else 'passes'}", flush=True)


if __name__ == "__main__":
    sys.exit(main())
