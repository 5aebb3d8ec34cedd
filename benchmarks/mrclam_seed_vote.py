"""MRCLAM without barcodes: the names that several seeds' chain runs agree on, smoothed into one map per robot.

Run from the repository root, after ``benchmarks.mrclam_constellation --state-dir DIR`` has run each robot with each
seed (it keeps every run's final names, ``<Robot>-seed<S>-final.npz``, and its chained names, ``-round0.npz``):

    .venv/bin/python -m benchmarks.mrclam_seed_vote --state-dir DIR [DIR ...] --seeds 0,1,2 [--robots 1,2,3,4,5]
        [--out-maps DIR] [--json]

Why (session 33): the chain's wrong merges and left-over duplicates depend on the filter's seed (session 32: with
session 30's command, seed 0 meets on all five robots, seed 1 on one). :func:`estimation.name_vote.voted_names` keeps
groups of sightings under one name when a majority of the runs does, on average over their pairs, and leaves unnamed
the fragments that no majority of runs has as a name. The runs must come from one command (the vote refuses runs
whose final states record different options). The voted names are then smoothed as the chain's last state is, with
the noise model the runs were given (the file their command's ``--noise`` names, refused in one line if it cannot be
read or no longer holds the content their states record beside it; fitted in sample, as theirs was, for runs made
without one), the smoother's heading drift and slip, path step and heading loss as the runs had them (from their
states), a sighting offset (σ as the runs had it) per group of sightings that every run's chain put under one round-0
name, and last the chain's own ``--name-unnamed`` step (a sighting that exactly one name explains is named). The
barcodes only score.

Printed per robot: each run's final figures (from its state) beside the vote's: names, duplicates, sightings kept
under another post's name, ATE, start-frame landmark NEES within χ²₂ 95 %, the joint NEES; and what the vote
settled: sightings named, sightings a majority of the runs leaves unnamed, sightings of fragments, sightings named
again by the last step, and how many sighting pairs each run names otherwise than the vote; then each *contested*
name, one that fewer than all the runs hold (:func:`estimation.name_vote.name_support`; session 34: every vote of
three that kept a duplicate had one, and the votes of five settled them).
"""
from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

from benchmarks import mrclam_constellation as chain  # noqa: E402
from benchmarks.eval_mrclam import DATA  # noqa: E402
from benchmarks.mrclam_chained_names import majority  # noqa: E402
from estimation.datasets import RangeBearingLog, read_mrclam  # noqa: E402
from estimation.fastslam import range_bearing_config  # noqa: E402
from estimation.name_vote import majority_named  # noqa: E402
from estimation.noise_model import NoiseModelError  # noqa: E402
from estimation.seed_vote import (  # noqa: E402
    offset_groups,  # noqa: F401  (moved to estimation.seed_vote; imported from here by tests)
    pairs_apart,
    vote_runs,
    voted_landmark_map,
)
from runtime.commands.options import non_negative_int  # noqa: E402


def find_state(directories: list[str], log: RangeBearingLog, seed: int, tag: str) -> Path:
    """The state ``tag`` of ``log``'s run with ``seed`` in the first of ``directories`` that has it."""
    for directory in directories:
        path = chain.state_path(directory, log, seed, tag)
        if path.is_file():
            return path
    raise FileNotFoundError(f"no {chain.state_path('DIR', log, seed, tag).name} in {', '.join(directories)} "
                            f"(run benchmarks.mrclam_constellation --state-dir with seed {seed})")


def contested(names: np.ndarray, support: np.ndarray, k: int, log: RangeBearingLog) -> list[dict]:
    """The voted names that fewer than all ``k`` runs hold (:func:`estimation.name_vote.name_support`): each one's
    number, sightings, runs holding it, and first and last sighting (s from the log's start). The vote's sightings,
    before the last step names more."""
    rows = []
    for name in np.flatnonzero(support < k):
        times = log.sighting_times[names == name] - log.start_time
        rows.append({"name": int(name), "sightings": len(times), "held_by": int(support[name]),
                     "from_s": round(float(times.min()), 2), "to_s": round(float(times.max()), 2)})
    return rows


def vote_robot(log: RangeBearingLog, directories: list[str], seeds: list[int], out_maps: str | None = None) -> dict:
    """The vote of ``log``'s runs with ``seeds`` (their final and round-0 states in ``directories``), smoothed with
    the noise model the runs were given (:func:`benchmarks.mrclam_constellation.saved_run_noise`: their command's
    ``--noise`` file, else fitted in sample as theirs was; a file that cannot be read is refused,
    :class:`estimation.noise_model.NoiseModelError`); the row of figures."""
    paths = [find_state(directories, log, seed, "final") for seed in seeds]
    metas = [chain.saved_meta(path) for path in paths]
    settings = {json.dumps([m["drift"], m["path_step_s"], m["sighting_offset_m"], m.get("command")], sort_keys=True)
                for m in metas}
    if len(settings) > 1:
        raise SystemExit(f"{log.name}: the runs of seeds {seeds} were made with different commands or smoother "
                         f"settings; a vote needs runs of one command")
    try:
        noise = chain.saved_run_noise(log, metas[0])
    except NoiseModelError as e:
        raise NoiseModelError(f"{log.name}: the runs' noise model (their command's --noise): {e}") from None
    config = range_bearing_config(n_particles=100)      # the chain's (its named problems read it)
    finals, round0 = [], []
    for seed, path in zip(seeds, paths, strict=True):
        finals.append(chain.load_saved_state(path, log, noise, config)[0])
        with np.load(find_state(directories, log, seed, "round0"), allow_pickle=False) as data:
            round0.append(data["names"])
    path_step_s, offset_m = metas[0]["path_step_s"], metas[0]["sighting_offset_m"]
    drift, loss = chain.saved_drift(metas[0]), chain.saved_heading_loss(metas[0])
    runs = np.stack([s.names for s in finals])
    vote = vote_runs(log, noise, config, finals, np.stack(round0), drift, path_step_s, offset_m, heading_loss=loss)
    names, support, apart, nearest = vote.names, vote.support, vote.apart, vote.nearest
    voted, state, proposed = vote.voted, vote.state, vote.proposed
    named_again = chain.named_again_record(log, voted, state, proposed)
    final = chain.final_scores(log, state, majority(state.names, log.landmark_ids))
    majority_unnamed = ~majority_named(runs)
    alike = all(np.array_equal(r >= 0, runs[0] >= 0) and pairs_apart(r, runs[0]) == 0 for r in runs)
    figures = ("names", "duplicate_fraction", "wrong_merges", "wrong_sightings_kept", "ate_m",
               "landmark_nees_within_bound", "landmark_joint_nees", "landmark_joint_dof")
    each = [{"seed": seed, **{k: meta["scores"].get(k) for k in figures},
             "pairs_apart_from_vote": a}
            for seed, meta, a in zip(seeds, metas, apart, strict=True)]
    row = {"robot": log.name, "seeds": seeds, "runs": each,
           "vote": {"sightings": int(len(names)), "named": int(np.sum(names >= 0)),
                    "all_runs_alike": alike,
                    "unnamed_by_majority": int(np.sum(majority_unnamed)),
                    "fragments": int(np.sum((names < 0) & ~majority_unnamed)),
                    "started_from_seed": seeds[nearest], "named_again": named_again,
                    "held_by": support.tolist(), "contested": contested(names, support, len(runs), log)},
           "final": final}
    if out_maps:
        path = Path(out_maps) / f"robot{chain._robot_number(log)}.npz"
        voted_map = voted_landmark_map(log, vote, seeds, f"robot{chain._robot_number(log)}")
        voted_map.save(path)
        row["map"] = str(path)
    return row


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.mrclam_seed_vote", description=__doc__.split("\n")[0])
    parser.add_argument("--data", default=str(DATA))
    parser.add_argument("--state-dir", nargs="+", required=True, metavar="DIR",
                        help="where mrclam_constellation --state-dir kept the runs' states")
    parser.add_argument("--seeds", required=True, help="the runs to vote, e.g. 0,1,2")
    parser.add_argument("--robots", default="1,2,3,4,5")
    parser.add_argument("--out-maps", metavar="DIR", default=None,
                        help="write each robot's voted map (no identities) for p3at fuse")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    try:
        seeds = [non_negative_int(s) for s in args.seeds.split(",")]
        robots = [int(r) for r in args.robots.split(",")]
    except (ValueError, argparse.ArgumentTypeError) as exc:
        parser.error(f"--seeds/--robots: {exc}")
    if len(set(seeds)) != len(seeds):
        parser.error(f"--seeds: a seed named twice in {args.seeds}")
    if not os.path.isdir(args.data):
        print(f"mrclam_seed_vote: no data set at {args.data}", file=sys.stderr)
        return 2
    rows = []
    for robot in robots:
        try:
            row = vote_robot(read_mrclam(args.data, robot), args.state_dir, seeds, args.out_maps)
        except (FileNotFoundError, NoiseModelError) as exc:
            print(f"mrclam_seed_vote: {exc}", file=sys.stderr)
            return 2
        rows.append(row)
        if not args.json:
            _print(row)
    if args.json:
        print(json.dumps({"seeds": seeds, "robots": rows}))
    return 0


def _figures(s: dict) -> str:
    return (f"names {s['names']:.0f}, duplicates {100 * s['duplicate_fraction']:.0f} %, wrong sightings kept "
            f"{s['wrong_sightings_kept']:.0f}, ATE {s['ate_m']:.3f} m, NEES within "
            f"{100 * s['landmark_nees_within_bound']:.0f} %, joint {s['landmark_joint_nees']:.1f} on "
            f"{s['landmark_joint_dof']:.0f}")


def _print(row: dict) -> None:
    print(f"{row['robot']}:")
    for r in row["runs"]:
        print(f"  seed {r['seed']}: {r['wrong_merges']:.0f} wrong merges, {_figures(r)}; "
              f"{r['pairs_apart_from_vote']} sighting pairs named otherwise than the vote")
    v = row["vote"]
    print(f"  vote of seeds {','.join(map(str, row['seeds']))}: {v['named']} of {v['sightings']} sightings named, "
          f"{v['unnamed_by_majority']} left unnamed by the majority, {v['fragments']} in fragments, named again "
          f"{v['named_again']['kept']}; "
          f"{_figures(row['final'])}")
    k = len(row["seeds"])
    for c in v["contested"]:
        print(f"  contested: name {c['name']} ({c['sightings']} sightings, {c['from_s']:.0f}-{c['to_s']:.0f} s) "
              f"held by {c['held_by']} of {k} runs; a vote of more seeds decides it")


if __name__ == "__main__":
    sys.exit(main())
