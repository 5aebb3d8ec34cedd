"""MRCLAM: readings the camera repeats word for word (estimation.datasets.repeats): how many, how old, when, and
which stamp is the right one. docs/fastslam-history.md, session 47 (T).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/mrclam_repeated_readings.py [--data DIR] [--robots 1,2,3,4,5]
        [--json]

Per robot, over its landmark sightings (robots' and unknown barcodes dropped by the reader):
1. repeats: sightings whose range and bearing equal their landmark's previous reading (the rule of
   ``repeated_readings``); beside them, sightings equal to an *older* reading of their landmark with another between
   (a–b–a, not repeats), and same-stamp duplicates.
2. ages: a repeat's stamp less its first report's (median, 90 %, max), and the gap to the landmark's previous report.
3. motion, from the dead-reckoned odometry over ±0.12 s (no truth): turning (|ω| > 0.1 rad/s), still (|ω| < 0.01
   rad/s and v < 0.01 m/s), moving otherwise; the share of all sightings and of the repeats in each, and the rate of
   repeats in each.
4. chance or held: between consecutive images of one landmark (< 0.3 s apart), how often (Δrange, Δbearing) is (0, 0)
   in the file's units (1 mm, 1 mrad) against the mean of its four one-unit neighbours, per motion class.
5. which stamp (needs the ground truth; travel heading): for repeats where the truth turned more than 0.02 rad since
   the first report, the bearing error against the truth at the repeat's own stamp and at the first report's.
6. the images holding a repeat (``drop_repeated_readings(whole_images=True)``): how many, their other readings, and
   for those where the truth turned more than 0.02 rad over the repeat's age (the oldest repeat of the image), the
   bearing error at their own stamp and at the stamp less that age.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

from estimation.datasets import DatasetError, read_mrclam, repeated_readings  # noqa: E402
from estimation.geometry import wrap_angle  # noqa: E402

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "mrclam" / "MRCLAM_Dataset2"
HALF_WINDOW_S = 0.12     # the odometry's motion over ±this about a stamp (half the camera's 0.24 s period)
TURNING, STILL_W, STILL_V = 0.1, 0.01, 0.01
CONSECUTIVE_S = 0.3      # two sightings of one landmark this close are consecutive images
TURNED_RAD = 0.02        # the truth turned at least this between a first report and its repeat


def motion_classes(log, times: np.ndarray) -> np.ndarray:
    """(N,) 0 turning, 1 moving, 2 still, from the dead-reckoned odometry over ±HALF_WINDOW_S."""
    before, after = log.odometry_pose(times - HALF_WINDOW_S), log.odometry_pose(times + HALF_WINDOW_S)
    w = np.abs(wrap_angle(after[:, 2] - before[:, 2])) / (2 * HALF_WINDOW_S)
    v = np.hypot(*(after[:, :2] - before[:, :2]).T) / (2 * HALF_WINDOW_S)
    return np.where(w > TURNING, 0, np.where((w < STILL_W) & (v < STILL_V), 2, 1))


def robot_figures(log) -> dict:
    t, ids, r, b = log.sighting_times, log.landmark_ids, log.ranges, log.bearings
    repeat, first = repeated_readings(ids, r, b)
    n = len(t)
    older = np.zeros(n, bool)
    same_stamp = np.zeros(n, bool)
    gap = np.full(n, np.nan)
    seen: dict[int, set] = {}
    previous: dict[int, int] = {}
    pairs = []                                   # (class, Δr mm, Δb mrad) of consecutive images of one landmark
    cls = motion_classes(log, t)
    for k, i in enumerate(ids.tolist()):
        j = previous.get(i)
        if j is not None:
            gap[k] = t[k] - t[j]
            same_stamp[k] = repeat[k] and t[k] == t[j]
            if t[k] - t[j] < CONSECUTIVE_S:
                pairs.append((cls[k], round((r[k] - r[j]) * 1000), round((b[k] - b[j]) * 1000)))
        older[k] = not repeat[k] and (r[k], b[k]) in seen.get(i, set())
        seen.setdefault(i, set()).add((r[k], b[k]))
        previous[i] = k
    ages = t[repeat] - t[first[repeat]]
    names = ("turning", "moving", "still")
    out = {"sightings": int(n), "repeats": int(repeat.sum()), "repeat_fraction": float(repeat.mean()) if n else 0.0,
           "equal_to_an_older_reading": int(older.sum()), "same_stamp_duplicates": int(same_stamp.sum())}
    if repeat.any():
        out |= {"age_median_s": float(np.median(ages)), "age_q90_s": float(np.quantile(ages, 0.9)),
                "age_max_s": float(ages.max()), "gap_median_s": float(np.nanmedian(gap[repeat])),
                "gap_max_s": float(np.nanmax(gap[repeat]))}
    pairs_a = np.array(pairs, dtype=float).reshape(-1, 3)
    for c, name in enumerate(names):
        m = cls == c
        out[f"{name}_share_of_sightings"] = float(m.mean()) if n else 0.0
        out[f"{name}_share_of_repeats"] = float(m[repeat].mean()) if repeat.any() else 0.0
        out[f"{name}_repeat_rate"] = float(repeat[m].mean()) if m.any() else 0.0
        p = pairs_a[pairs_a[:, 0] == c]
        out[f"{name}_consecutive_pairs"] = int(len(p))
        out[f"{name}_zero_difference"] = int(np.sum((p[:, 1] == 0) & (p[:, 2] == 0)))
        out[f"{name}_one_unit_neighbour_mean"] = float(np.mean(
            [np.sum((p[:, 1] == dr) & (p[:, 2] == db)) for dr, db in ((1, 0), (-1, 0), (0, 1), (0, -1))]))
    out |= which_stamp(log, repeat, first)
    out |= image_mates(log, repeat, first)
    return out


def image_mates(log, repeat: np.ndarray, first: np.ndarray) -> dict:
    """The images holding a repeat, their other readings, and (with the truth) whether those are as old."""
    t = log.sighting_times
    age_of: dict[float, float] = {}
    for k in np.flatnonzero(repeat):
        age_of[t[k]] = max(age_of.get(t[k], 0.0), t[k] - t[first[k]])
    mates = np.isin(t, list(age_of)) & ~repeat
    out = {"images_holding_a_repeat": len(age_of), "image_mates": int(mates.sum())}
    if not log.has_ground_truth or not len(log.truth_ids):
        return out
    truth = log.true_landmarks()
    ks = np.flatnonzero(mates)
    ks = ks[[int(log.landmark_ids[k]) in truth for k in ks]]
    ages = np.array([age_of[t[k]] for k in ks])
    turned = np.abs(wrap_angle(log.true_pose(t[ks])[:, 2] - log.true_pose(t[ks] - ages)[:, 2])) > TURNED_RAD
    ks, ages = ks[turned], ages[turned]
    out["turned_mates"] = int(len(ks))
    if len(ks):
        landmarks = np.array([truth[int(log.landmark_ids[k])] for k in ks])
        own, back = (_bearing_errors(log, ks, landmarks, times) for times in (t[ks], t[ks] - ages))
        out |= {"turned_mates_error_own_median_rad": float(np.median(own)),
                "turned_mates_error_earlier_median_rad": float(np.median(back)),
                "turned_mates_earlier_nearer": int(np.sum(back < own))}
    return out


def _bearing_errors(log, ks: np.ndarray, landmarks: np.ndarray, times: np.ndarray) -> np.ndarray:
    """|bearing error| (K,) of sightings ``ks`` against the truth, the robot's true pose taken at ``times``."""
    pose = log.true_pose(times)
    d = landmarks - pose[:, :2]
    return np.abs(wrap_angle(log.bearings[ks] - np.arctan2(d[:, 1], d[:, 0]) + pose[:, 2]))


def which_stamp(log, repeat: np.ndarray, first: np.ndarray) -> dict:
    """Bearing errors against the truth of the repeats where the truth turned since their first report: at their own
    stamp and at the first report's (empty without ground truth)."""
    if not log.has_ground_truth or not len(log.truth_ids):
        return {}
    truth = log.true_landmarks()
    ks = np.flatnonzero(repeat)
    ks = ks[[int(log.landmark_ids[k]) in truth for k in ks]]
    fs = first[ks]
    t = log.sighting_times
    turned = np.abs(wrap_angle(log.true_pose(t[ks])[:, 2] - log.true_pose(t[fs])[:, 2])) > TURNED_RAD
    ks, fs = ks[turned], fs[turned]
    if not len(ks):
        return {"turned_repeats": 0}
    landmarks = np.array([truth[int(log.landmark_ids[k])] for k in ks])
    own, at_first = (_bearing_errors(log, ks, landmarks, times) for times in (t[ks], t[fs]))
    return {"turned_repeats": int(len(ks)), "turned_error_own_median_rad": float(np.median(own)),
            "turned_error_first_median_rad": float(np.median(at_first)),
            "turned_first_nearer": int(np.sum(at_first < own))}


def print_table(rows: dict) -> None:
    print("robot  sightings  repeats        a-b-a  same-stamp  age median/q90/max (s)  gap max (s)")
    for robot, f in rows.items():
        ages = (f"{f['age_median_s']:.2f} / {f['age_q90_s']:.2f} / {f['age_max_s']:.2f}" if f["repeats"] else "-")
        print(f"{robot:>5}  {f['sightings']:>9}  {f['repeats']:>4} ({100 * f['repeat_fraction']:.1f} %)"
              f"  {f['equal_to_an_older_reading']:>5}  {f['same_stamp_duplicates']:>10}  {ages:>22}"
              f"  {f.get('gap_max_s', float('nan')):>11.2f}")
    print("\nmotion (odometry ±0.12 s): share of sightings -> share of repeats; rate of repeats")
    for robot, f in rows.items():
        print(f"{robot:>5}  " + "; ".join(
            f"{name} {100 * f[f'{name}_share_of_sightings']:.0f} -> {100 * f[f'{name}_share_of_repeats']:.0f} %, "
            f"rate {100 * f[f'{name}_repeat_rate']:.1f} %" for name in ("turning", "moving", "still")))
    print("\nconsecutive images of one landmark: Δ = (0, 0) against its one-unit neighbours' mean (1 mm, 1 mrad)")
    for robot, f in rows.items():
        print(f"{robot:>5}  " + "; ".join(
            f"{name} {f[f'{name}_zero_difference']} vs {f[f'{name}_one_unit_neighbour_mean']:.1f} "
            f"(of {f[f'{name}_consecutive_pairs']})" for name in ("turning", "moving", "still")))
    print(f"\nrepeats where the truth turned > {TURNED_RAD} rad since the first report: |bearing error| median at "
          "the repeat's stamp vs the first report's")
    for robot, f in rows.items():
        if f.get("turned_repeats"):
            print(f"{robot:>5}  {f['turned_repeats']} repeats: {f['turned_error_own_median_rad']:.3f} vs "
                  f"{f['turned_error_first_median_rad']:.3f} rad; the first report's stamp nearer in "
                  f"{f['turned_first_nearer']}")
        elif "turned_repeats" in f:
            print(f"{robot:>5}  none")
    print("\nimages holding a repeat: their other readings; those where the truth turned > "
          f"{TURNED_RAD} rad over the repeat's age: |bearing error| median at their stamp vs the stamp less the age")
    for robot, f in rows.items():
        line = (f"{robot:>5}  {f['images_holding_a_repeat']} images, {f['image_mates']} other readings "
                f"({100 * f['image_mates'] / max(f['sightings'], 1):.1f} % of the sightings)")
        if f.get("turned_mates"):
            line += (f"; {f['turned_mates']} turned: {f['turned_mates_error_own_median_rad']:.3f} vs "
                     f"{f['turned_mates_error_earlier_median_rad']:.3f} rad, earlier nearer in "
                     f"{f['turned_mates_earlier_nearer']}")
        elif "turned_mates" in f:
            line += "; none turned"
        print(line)


def _robots(text: str) -> list[int]:
    try:
        robots = [int(part) for part in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a list of robot numbers: {text!r}") from None
    if not robots or min(robots) < 1:
        raise argparse.ArgumentTypeError(f"robot numbers are positive: {text!r}")
    return robots


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DATA, help="the MRCLAM data set folder")
    parser.add_argument("--robots", type=_robots, default=[1, 2, 3, 4, 5], metavar="R,R,...")
    parser.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    args = parser.parse_args(argv)
    rows = {}
    for robot in args.robots:
        try:
            log = read_mrclam(args.data, robot, truth_heading="travel")
        except DatasetError as e:
            print(f"mrclam_repeated_readings: {e}", file=sys.stderr)
            return 2
        rows[robot] = robot_figures(log)
    if args.json:
        print(json.dumps(rows, indent=1))
    else:
        print_table(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
