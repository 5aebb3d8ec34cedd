"""MRCLAM in unknown association: names for the sightings from short submaps joined by the fusion's alignment.

Run from the repository root:

    .venv/bin/python -m benchmarks.mrclam_submap_association [--robots 1,2,3,4,5] [--window 40] [--seed 0]
        [--calibrated] [--prior [--prior-xy A,B] [--prior-theta C,E]] [--significance P] [--max-gap K]
        [--until S] [--smooth auto|always|never] [--known-id] [--json]

The hypothesis (docs/fastslam.md, "Session 17: names from submaps (V)"): over a short stretch of the log the odometry
drifts little, so association by position alone is (nearly) right within it; the fusion's alignment, whose "found" was
built never to report a wrong alignment, then joins the stretches' maps. Per robot:

1. **Windows.** The log is cut into windows of ``--window`` seconds from its first sighting; each window is run
   through the unknown-association filter from its own start (:mod:`fusion.submap_names`), and every sighting of it is
   named by the window map's landmark it falls on (the best particle's trajectory, nearest within χ²₂ 99 %, one per
   landmark a frame). Scored against the barcodes (which never decide): landmarks, duplicates, sightings unnamed, and
   sightings whose landmark stands for another barcode ("wrong": the landmark's barcode is the majority of its
   sightings').
2. **Joined.** The window maps are aligned pairwise, every pair (``--max-gap K``: windows at most K apart) by
   :func:`fusion.align`, robust preset (``--significance``: its false-alarm bound replaced, a diagnosis only);
   ``--prior``: with a start prior from the calibrated odometry between the windows' frames, σ_xy = A + B·d,
   σ_θ = C + E·d for a path d (:func:`fusion.submap_names.odometry_prior`); a found alignment's supports are
   correspondences, joined by union-find; a join that would put two landmarks of one window under one name refuses
   the whole alignment (:func:`fusion.submap_names.join_window_maps`). Scored: alignments found, refused, their
   error against the true relative pose of the windows' frames; joins (landmark pairs) and the wrong ones (two
   barcodes); windows left unjoined; the names' sightings of another barcode (wrong), duplicates (names of one
   barcode beyond the first, among names with ≥ 5 sightings).
3. **Smoothed** (``--smooth auto``: only when fewer than 1 % of the named sightings are wrong and fewer than 5 % of
   the names are duplicates; ``always``; ``never``):
   the names given as ids to the known-ID filter and smoother (``run_landmark_log(association="id", smooth=True)``,
   the unnamed sightings left out), scored like eval_mrclam's known-ID runs (each name's barcode is the majority of
   its sightings'), beside the known-ID smoothed run with the barcodes, on the same noise model.

``--calibrated``: each robot's noise model fits the range calibration, heading bias, odometry lag and the turns'
variance (the known-ID recipe, docs/fastslam.md "Session 16: the odometry's variance in turns"); default: the plain
fit (as ``mrclam_unknown_association``).
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks.eval_mrclam import DATA  # noqa: E402
from estimation.dataset_slam import run_landmark_log, sighted_true_ids  # noqa: E402
from estimation.datasets import RangeBearingLog, read_mrclam  # noqa: E402
from estimation.fastslam import range_bearing_config  # noqa: E402
from estimation.geometry import between, dead_reckoning, wrap_angle  # noqa: E402
from estimation.landmark_scores import map_scores  # noqa: E402
from estimation.noise_model import estimate_noise  # noqa: E402
from fusion.alignment import align, align_at  # noqa: E402
from fusion.alignment_config import ROBUST  # noqa: E402
from fusion.submap_names import join_window_maps, odometry_prior, run_windows, sighting_names, with_names  # noqa: E402
from runtime.commands.options import non_negative_int, positive_int  # noqa: E402

MIN_NAME_SIGHTINGS = 5       # a name with fewer sightings is not counted as a duplicate (a glimpse, not a landmark)
RIGHT_ENOUGH = 0.01          # the brief's bar for smoothing with the names: wrong well under 1 % of the sightings


def majority(names: np.ndarray, barcodes: np.ndarray) -> dict[int, int]:
    """Each name's barcode: the one most of its sightings are of (ties: the smaller barcode)."""
    out = {}
    for name in np.unique(names[names >= 0]):
        codes, counts = np.unique(barcodes[names == name], return_counts=True)
        out[int(name)] = int(codes[np.argmax(counts)])
    return out


def naming_scores(names: np.ndarray, barcodes: np.ndarray) -> dict:
    """Sightings named, wrong (their name stands for another barcode), names, duplicates (names of one barcode beyond
    the first, among names of ≥ MIN_NAME_SIGHTINGS sightings)."""
    named = names >= 0
    owner = majority(names, barcodes)
    wrong = np.array([owner[int(n)] != int(b) for n, b in zip(names[named], barcodes[named], strict=True)], bool)
    counts = {n: int(np.sum(names == n)) for n in owner}
    real = [n for n, c in counts.items() if c >= MIN_NAME_SIGHTINGS]
    codes = [owner[n] for n in real]
    # a wrong sighting whose barcode no name stands for: its post was absorbed by a neighbour's landmark
    absorbed = ~np.isin(barcodes[named], list(owner.values())) if owner else np.ones(int(named.sum()), bool)
    return {"sightings": int(len(names)), "named": int(named.sum()), "unnamed": int((~named).sum()),
            "wrong": int(wrong.sum()), "wrong_absorbed": int((wrong & absorbed).sum()),
            "wrong_fraction": float(wrong.mean()) if named.any() else float("nan"),
            "names": len(owner), "names_min_sightings": len(real),
            "duplicates": int(len(codes) - len(set(codes))),
            "duplicate_fraction": float((len(codes) - len(set(codes))) / len(codes)) if codes else 0.0}


def rescored(run, log: RangeBearingLog, owner: dict[int, int]) -> dict:
    """The smoothed run's figures with each map landmark attributed to its name's barcode."""
    m = run.map
    attributed = np.array([owner.get(int(n), -1) for n in m.metadata["external_ids"]], np.int64)
    t0 = float(m.metadata.get("true_start_time", run.metrics["start_time"]))
    scores = map_scores(m.positions, m.covariances, attributed, np.asarray(run.metrics["true_start_pose"]),
                        log.truth_ids, log.truth_positions, sighted_true_ids(log, t0, None))
    keys = ("ate_m", "pose_nees_median", "pose_nees_within_chi2_95", "smoother_outliers", "smoother_sightings",
            "smoother_chi2_per_dof", "filter_ate_m")
    return {**{k: run.metrics.get(k) for k in keys}, **_map_keys(scores)}


def _map_keys(metrics: dict) -> dict:
    keys = ("landmarks", "true_landmarks", "duplicate_fraction", "landmark_error_median_m",
            "landmark_error_rigid_median_m", "landmark_nees_within_bound", "landmark_nees_rigid_within_bound",
            "landmark_nees_median")
    return {k: metrics.get(k) for k in keys}


def run_robot(log: RangeBearingLog, args) -> dict:
    fit = dict(range_calibration=True, heading_bias=True, odometry_lag=True, turn_variance=True) \
        if args.calibrated else {}
    noise = estimate_noise([log], **fit).model
    config = range_bearing_config(n_particles=args.particles)
    started = time.perf_counter()
    windows = run_windows(log, args.window, config, noise, seed=args.seed)
    window_seconds = time.perf_counter() - started
    barcodes = log.landmark_ids
    per_window = []
    for w in windows:
        codes = barcodes[w.sightings]
        score = naming_scores(w.sighting_landmark, codes)
        score.update(start=w.start_time, seconds=w.seconds, map_landmarks=len(w.map),
                     distinct_barcodes=int(len(np.unique(codes))))
        per_window.append(score)
    # the windows' own names, before any join: the floor any join starts from
    local = np.full(len(log), -1, np.int64)
    offset = 0
    for w in windows:
        named = w.sighting_landmark >= 0
        local[w.sightings[named]] = w.sighting_landmark[named] + offset
        offset += len(w.map)
    started = time.perf_counter()
    priors = odometry_prior(*_odometry_starts(log, noise, windows), args.prior_xy, args.prior_theta) \
        if args.prior else None
    preset = ROBUST if args.significance is None else dataclasses.replace(ROBUST, significance=args.significance)
    joined = join_window_maps([w.map for w in windows], rng=np.random.default_rng(args.seed), max_gap=args.max_gap,
                              priors=priors, preset=preset, align_fn=_at_prior if args.at_odometry else align)
    join_seconds = time.perf_counter() - started
    names = sighting_names(windows, joined, len(log))
    # the joins against the barcodes: each window landmark's barcode is its sightings' majority
    landmark_code = []
    for w in windows:
        owner = majority(w.sighting_landmark, barcodes[w.sightings])
        landmark_code.append([owner.get(k, -1) for k in range(len(w.map))])
    wrong_joins = [(a, b) for a, b in joined.joins
                   if -1 not in (landmark_code[a[0]][a[1]], landmark_code[b[0]][b[1]])
                   and landmark_code[a[0]][a[1]] != landmark_code[b[0]][b[1]]]
    errors = []
    for i, j, alignment in joined.found:
        true = between(log.true_pose([windows[i].first_time])[0], log.true_pose([windows[j].first_time])[0])
        d = alignment.pose - true
        errors.append((float(np.hypot(d[0], d[1])), float(abs(wrap_angle(d[2])))))
    errors = np.array(errors).reshape(-1, 2)
    row = {"robot": log.name, "window_s": args.window, "windows": len(windows),
           "window_seconds_cpu": window_seconds, "join_seconds_cpu": join_seconds,
           "per_window": per_window, "windows_total": _window_totals(per_window),
           "local_names": naming_scores(local, barcodes),
           "alignments_tried": joined.tried, "alignments_found": len(joined.found) + len(joined.refused),
           "alignments_applied": len(joined.found),
           "alignments_refused": len(joined.refused),
           "alignment_error_median": [float(v) for v in np.median(errors, axis=0)] if len(errors) else None,
           "alignment_error_max": [float(v) for v in errors.max(axis=0)] if len(errors) else None,
           "joins": len(joined.joins),
           "joins_wrong": len(wrong_joins), "joins_unattributed": sum(
               -1 in (landmark_code[a[0]][a[1]], landmark_code[b[0]][b[1]]) for a, b in joined.joins),
           "windows_unjoined": int(sum(1 for c in joined.window_links if c == 0)),
           "window_components": joined.window_components,
           "refused": [{"windows": list(r.windows), "supports": r.supports, "why": r.why} for r in joined.refused],
           "joined_names": naming_scores(names, barcodes)}
    right = row["joined_names"]["wrong_fraction"] < RIGHT_ENOUGH and row["joined_names"]["duplicate_fraction"] < 0.05
    if args.smooth == "always" or (args.smooth == "auto" and right):
        row["smoothed_names"] = _smoothed(with_names(log, names), log, config, noise, args.seed,
                                          majority(names, barcodes))
    if args.smooth != "never" and (right or args.smooth == "always" or args.known_id):
        run = run_landmark_log(log, config, np.random.default_rng(args.seed), noise=noise, association="id",
                               robot=log.name, smooth=True)
        row["smoothed_known_id"] = {**{k: run.metrics.get(k) for k in (
            "ate_m", "pose_nees_median", "pose_nees_within_chi2_95", "filter_ate_m")}, **_map_keys(run.metrics)}
    return row


def _at_prior(map1, map2, preset, rng, prior):
    """``--at-odometry``: map 2 tested at the odometry's relative pose alone (:func:`fusion.alignment.align_at`: one
    hypothesis from outside, no search, no Bonferroni factor)."""
    return align_at(map1, map2, prior.mean, preset, rng)


def _odometry_starts(log: RangeBearingLog, noise, windows) -> tuple[np.ndarray, np.ndarray]:
    """Each window frame's pose by the calibrated odometry (as the filter is given it) and the path length there."""
    times = np.unique(log.sighting_times)
    odometry = log.odometry_pose(noise.odometry_times(times))
    increments = noise.calibrate_increments(between(odometry[:-1], odometry[1:]))
    poses = dead_reckoning(increments)
    travelled = np.concatenate([[0.0], np.cumsum(np.hypot(increments[:, 0], increments[:, 1]))])
    rows = np.searchsorted(times, [w.first_time for w in windows])
    return poses[rows], travelled[rows]


def _smoothed(log: RangeBearingLog, original: RangeBearingLog, config, noise, seed: int, owner: dict) -> dict:
    run = run_landmark_log(log, config, np.random.default_rng(seed), noise=noise, association="id", robot=log.name,
                           smooth=True)
    return rescored(run, original, owner)


def _window_totals(rows: list[dict]) -> dict:
    named = sum(r["named"] for r in rows)
    wrong = sum(r["wrong"] for r in rows)
    lm = [r["names_min_sightings"] for r in rows]
    return {"named": named, "unnamed": sum(r["unnamed"] for r in rows), "wrong": wrong,
            "wrong_absorbed": sum(r["wrong_absorbed"] for r in rows),
            "wrong_fraction": wrong / named if named else float("nan"),
            "duplicates": sum(r["duplicates"] for r in rows), "landmarks": int(sum(lm)),
            "duplicate_fraction": sum(r["duplicates"] for r in rows) / max(sum(lm), 1),
            "windows_with_wrong": sum(1 for r in rows if r["wrong"]),
            "windows_with_duplicates": sum(1 for r in rows if r["duplicates"])}


def _pose_error(error) -> str:
    return "-" if error is None else f"{error[0]:.2f} m, {error[1]:.3f} rad"


def _print(rows: list[dict]) -> None:
    for r in rows:
        t, loc, j = r["windows_total"], r["local_names"], r["joined_names"]
        print(f"## {r['robot']}: {r['windows']} windows of {r['window_s']:g} s "
              f"({r['window_seconds_cpu']:.0f} s filter, {r['join_seconds_cpu']:.0f} s joins)")
        print(f"- windows: {t['landmarks']} landmarks (>= {MIN_NAME_SIGHTINGS} sightings), duplicates "
              f"{t['duplicates']} ({100 * t['duplicate_fraction']:.1f} %, in {t['windows_with_duplicates']} windows); "
              f"sightings named {t['named']}, unnamed {t['unnamed']}, of another barcode {t['wrong']} "
              f"({100 * t['wrong_fraction']:.2f} %, in {t['windows_with_wrong']} windows; {t['wrong_absorbed']} of "
              f"them of a post with no landmark of its own in the window)")
        print(f"- alignments: {r['alignments_tried']} tried, {r['alignments_found']} found, "
              f"{r['alignments_refused']} of them refused (a window's two landmarks under one name); error against "
              f"the truth median / max {_pose_error(r['alignment_error_median'])} / "
              f"{_pose_error(r['alignment_error_max'])}; joins {r['joins']}, wrong {r['joins_wrong']}, unattributed "
              f"{r['joins_unattributed']}; windows unjoined {r['windows_unjoined']}, components "
              f"{r['window_components']}")
        print(f"- names: before joins {loc['names_min_sightings']} (>= {MIN_NAME_SIGHTINGS} sightings), after "
              f"{j['names_min_sightings']}, duplicates {j['duplicates']} ({100 * j['duplicate_fraction']:.1f} %); "
              f"sightings of another barcode {j['wrong']} of {j['named']} ({100 * j['wrong_fraction']:.2f} %)")
        for key, label in (("smoothed_names", "smoothed, the names"), ("smoothed_known_id", "smoothed, the barcodes")):
            s = r.get(key)
            if s:
                print(f"- {label}: ATE {s['ate_m']:.3f} m, landmarks {s['landmarks']}/{s['true_landmarks']}, "
                      f"duplicates {100 * s['duplicate_fraction']:.1f} %, "
                      f"rigid {s['landmark_error_rigid_median_m']:.3f} m, start-frame NEES within "
                      f"{100 * s['landmark_nees_within_bound']:.0f} %, pose NEES median {s['pose_nees_median']:.2f}")


def _pair(text: str) -> tuple[float, float]:
    a, b = (float(v) for v in text.split(","))
    return a, b


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--robots", default="1,2,3,4,5")
    parser.add_argument("--window", type=float, default=40.0, help="window length, s")
    parser.add_argument("--seed", type=non_negative_int, default=0)
    parser.add_argument("--particles", type=positive_int, default=100)
    parser.add_argument("--calibrated", action="store_true",
                        help="the known-ID recipe's calibrations in each robot's noise model")
    parser.add_argument("--prior", action="store_true", help="align with a start prior from the odometry")
    parser.add_argument("--prior-xy", type=_pair, default=(0.2, 0.1), metavar="A,B",
                        help="the prior's σ_xy = A + B·d (m), d the odometry's path between the windows' frames")
    parser.add_argument("--prior-theta", type=_pair, default=(0.1, 0.02), metavar="C,E",
                        help="the prior's σ_θ = C + E·d (rad)")
    parser.add_argument("--significance", type=float, default=None,
                        help="the alignment's largest false-alarm probability (a diagnosis; default: the robust "
                             "preset's 1e-6)")
    parser.add_argument("--at-odometry", action="store_true",
                        help="test each pair at the odometry's relative pose alone (align_at; implies --prior)")
    parser.add_argument("--max-gap", type=positive_int, default=None,
                        help="align only windows at most this many apart (default: every pair)")
    parser.add_argument("--smooth", choices=("auto", "always", "never"), default="auto")
    parser.add_argument("--known-id", action="store_true", help="run the known-ID smoothed comparison anyway")
    parser.add_argument("--until", type=float, default=None, help="read only the logs' first part (s)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    args.prior = args.prior or args.at_odometry
    if not args.data.is_dir():
        print(f"mrclam_submap_association: no data set at {args.data}", file=sys.stderr)
        return 2
    rows = [run_robot(read_mrclam(args.data, int(r), until=args.until), args) for r in args.robots.split(",")]
    if args.json:
        print(json.dumps({"seed": args.seed, "window_s": args.window, "calibrated": args.calibrated,
                          "prior": [*args.prior_xy, *args.prior_theta] if args.prior else None,
                          "significance": args.significance, "at_odometry": args.at_odometry,
                          "max_gap": args.max_gap,
                          "particles": args.particles, "rows": rows}))
        return 0
    print(f"MRCLAM submap association, windows of {args.window:g} s, seed {args.seed}"
          + (", calibrated" if args.calibrated else ""))
    _print(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
