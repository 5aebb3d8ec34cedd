"""MRCLAM: how large is the sightings' systematic error per post, per visit and per chained name (against the truth)?

Run from the repository root:

    .venv/bin/python -m benchmarks.mrclam_sighting_offset [--data DIR] [--robots 1,2,3,4,5] [--gap 10]
        [--state-dir DIR --seed 0]

The smoother's :class:`estimation.landmark_smoother.SightingOffset` gives each group of sightings a common offset
of prior σ (session 27, A). This measures σ from the data with the barcodes and the motion-capture truth (no
smoothing, no tuning): each sighting's point (the true pose at its time, interpolated, plus its calibrated range
and bearing, ``noise.range_bearing.corrected`` as the smoother takes them) less the true post gives its error
e (2,) in the world frame. Each group's mean error ē_g, over n_g sightings, holds the group's offset plus the mean
of the sightings' own noise, whose covariance is Σ C_s / n_g² if they are independent (C_s the sensor's (σ_r, r σ_φ)
turned into the world frame, without the noise model's inflation for correlated sightings: its correlation is what
is measured here). So σ² per axis ≈ mean_g(|ē_g|² − tr Σ C_s / n_g²) / 2 over groups of at least ``--min`` sightings.

Groups: ``post`` (all of a robot's sightings of one post: the constant part, e.g. a post always seen from one side),
``visit`` (a post's sightings with no gap over ``--gap`` s: one pass by it), and with ``--state-dir`` ``name`` (the
chained names of ``mrclam_constellation --state-dir``'s round-0 state, each name's sightings of its majority post:
the groups the constellation's ``--sighting-offset`` uses). ``visit about post``: the visits' means less their post's
mean (the part that differs between visits). Sightings whose error exceeds ``--outlier`` m are left out (counted).

Printed per robot and group kind: groups, σ per axis (m), the median |ē_g| and the noise's share.

``--known-id post|visit --offset M``: instead, ``benchmarks.eval_mrclam --association id --defaults`` (the protected
known-ID figures' code path, its table printed) with the smoother given the offsets, one group per post (``post``:
the MAP is the option-off one, each post's covariance + σ² I) or per visit (``visit``: the estimate moves).
Measured through a stand-in for ``estimation.dataset_smoothing.smooth`` set for this process only (the data set
pipeline has no such option: that is a proposal, not wired); ``--known-id off`` runs it unchanged.
"""
from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import sys  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

from benchmarks.eval_mrclam import DATA  # noqa: E402
from estimation.datasets import read_mrclam  # noqa: E402
from estimation.map_honesty import sighting_times  # noqa: E402
from estimation.noise_estimation import DATASET_CALIBRATIONS, estimate_noise  # noqa: E402
from runtime.commands.options import non_negative_int, positive_float, positive_int  # noqa: E402


def sighting_errors(log, noise) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each sighting's error (N, 2) (m, world frame) against the true post, its noise covariance (N, 2, 2), and
    whether it could be scored (N,) (a post with a true position, within the truth's time span)."""
    truth = log.ground_truth
    t = log.sighting_times
    ok = (t >= truth[0, 0]) & (t <= truth[-1, 0]) & np.isin(log.landmark_ids, log.truth_ids)
    x = np.interp(t, truth[:, 0], truth[:, 1])
    y = np.interp(t, truth[:, 0], truth[:, 2])
    theta = np.interp(t, truth[:, 0], np.unwrap(truth[:, 3]))
    sensor = noise.range_bearing
    ranges, bearings = sensor.corrected(log.ranges, log.bearings)
    angle = theta + bearings
    point = np.column_stack([x + ranges * np.cos(angle), y + ranges * np.sin(angle)])
    where = {int(i): k for k, i in enumerate(log.truth_ids)}
    post = np.array([where.get(int(i), 0) for i in log.landmark_ids])
    error = point - log.truth_positions[post]
    sr, sb = sensor.range_sigma(ranges), sensor.bearing_sigma_rad * ranges
    c, s = np.cos(angle), np.sin(angle)
    rot = np.stack([np.column_stack([c, -s]), np.column_stack([s, c])], axis=1)         # (N, 2, 2)
    local = np.zeros((len(t), 2, 2))
    local[:, 0, 0], local[:, 1, 1] = sr ** 2, sb ** 2
    return error, rot @ local @ rot.transpose(0, 2, 1), ok


def group_sigma(error: np.ndarray, cov: np.ndarray, groups: np.ndarray, min_size: int,
                about: np.ndarray | None = None) -> dict:
    """σ per axis of the groups' common offset (module docstring); ``about`` (N, 2): subtracted from each sighting's
    error first (the post's mean, for the visits about their post)."""
    e = error - (about if about is not None else 0.0)
    ids, inverse, counts = np.unique(groups, return_inverse=True, return_counts=True)
    keep = counts >= min_size
    means = np.zeros((len(ids), 2))
    np.add.at(means, inverse, e)
    means /= counts[:, None]
    noise = np.zeros(len(ids))
    np.add.at(noise, inverse, np.trace(cov, axis1=1, axis2=2))
    noise /= counts ** 2
    norm2 = np.sum(means ** 2, axis=1)[keep]
    excess = np.mean(norm2 - noise[keep]) / 2 if keep.any() else float("nan")
    return {"groups": int(keep.sum()), "sigma_m": float(np.sqrt(max(excess, 0.0))),
            "median_mean_m": float(np.median(np.sqrt(norm2))) if keep.any() else float("nan"),
            "noise_share": float(np.sum(noise[keep]) / max(np.sum(norm2), 1e-12)),
            "median_size": float(np.median(counts[keep])) if keep.any() else float("nan")}


def gap_labels(keys: np.ndarray, times: np.ndarray, gap: float) -> np.ndarray:
    """(N,) a label per item: the items of one key in time order, cut wherever two are more than ``gap`` s apart,
    each stretch its own label (labels count up by key, then by time)."""
    out = np.zeros(len(keys), np.int64)
    label = 0
    for key in np.unique(keys):
        rows = np.flatnonzero(keys == key)
        rows = rows[np.argsort(times[rows], kind="stable")]
        breaks = np.concatenate([[True], np.diff(times[rows]) > gap])
        out[rows] = label + np.cumsum(breaks) - 1
        label += int(breaks.sum())
    return out


def visits(log, gap: float) -> np.ndarray:
    """(N,) a visit label per sighting: a post's sightings with no gap over ``gap`` s."""
    return gap_labels(log.landmark_ids, log.sighting_times, gap)


def run_robot(folder, robot: int, args) -> dict:
    log = read_mrclam(folder, robot)
    noise = estimate_noise([log], **DATASET_CALIBRATIONS).model
    error, cov, ok = sighting_errors(log, noise)
    inlier = ok & (np.hypot(*error.T) <= args.outlier)
    row = {"robot": log.name, "sightings": int(ok.sum()), "outliers": int((ok & ~inlier).sum())}
    e, c = error[inlier], cov[inlier]
    post = log.landmark_ids[inlier]
    visit = visits(log, args.gap)[inlier]
    row["post"] = group_sigma(e, c, post, args.min)
    row["visit"] = group_sigma(e, c, visit, args.min)
    ids, inverse = np.unique(post, return_inverse=True)
    post_mean = np.zeros((len(ids), 2))
    np.add.at(post_mean, inverse, e)
    post_mean /= np.bincount(inverse)[:, None]
    row["visit about post"] = group_sigma(e, c, visit, args.min, about=post_mean[inverse])
    if args.state_dir:
        path = Path(args.state_dir) / f"{Path(log.name).name}-seed{args.seed}-round0.npz"
        if path.exists():
            with np.load(path, allow_pickle=False) as data:
                names = data["names"][inlier]
            named = names >= 0
            owner = {}
            for name in np.unique(names[named]):
                codes, counts = np.unique(post[names == name], return_counts=True)
                owner[int(name)] = int(codes[np.argmax(counts)])
            mine = named & (post == np.array([owner.get(int(n), -1) for n in names]))
            row["name"] = group_sigma(e[mine], c[mine], names[mine], args.min)
    return row


def visit_groups(problem, gap: float) -> np.ndarray:
    """(S,) a visit per sighting of a smoothing problem: a landmark's sightings with no gap over ``gap`` s (the
    poses' times from the problem's increment durations)."""
    return gap_labels(problem.landmark_index, sighting_times(problem), gap)


def known_id(args) -> int:
    """eval_mrclam's known-ID defaults with the smoother's sighting offsets (module docstring)."""
    import dataclasses

    from benchmarks import eval_mrclam
    from estimation import dataset_smoothing
    from estimation.landmark_smoother import SightingOffset, smooth

    if args.known_id != "off":
        option = SightingOffset(args.offset)

        def with_offsets(problem, *a, **kw):
            if args.known_id == "visit":
                problem = dataclasses.replace(problem, offset_index=visit_groups(problem, args.gap))
            return smooth(problem, *a, sighting_offset=option, **kw)

        dataset_smoothing.smooth = with_offsets
    return eval_mrclam.main(["--data", args.data, "--robots", args.robots, "--association", "id", "--defaults",
                             "--maps", args.maps, "--seed", str(args.seed)])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", default=str(DATA))
    parser.add_argument("--robots", default="1,2,3,4,5")
    parser.add_argument("--gap", type=positive_float, default=10.0, help="a visit ends at a gap over this, s")
    parser.add_argument("--min", type=positive_int, default=5, help="sightings a group needs to count")
    parser.add_argument("--outlier", type=positive_float, default=1.0, help="sightings farther off are left out, m")
    parser.add_argument("--state-dir", metavar="DIR", default=None,
                        help="mrclam_constellation's states: group by the round-0 names too")
    parser.add_argument("--seed", type=non_negative_int, default=0, help="the states' seed (and --known-id's)")
    parser.add_argument("--known-id", choices=("off", "post", "visit"), default=None,
                        help="eval_mrclam's known-ID defaults with offsets per post or per visit (module docstring)")
    parser.add_argument("--offset", type=positive_float, default=0.03, help="--known-id's offset σ per axis, m")
    parser.add_argument("--maps", default="/tmp/mrclam-offset-maps", help="--known-id: eval_mrclam's --maps")
    args = parser.parse_args(argv)
    if not Path(args.data).is_dir():
        print(f"no MRCLAM data at {args.data}", file=sys.stderr)
        return 2
    if args.known_id is not None:
        return known_id(args)
    kinds = ("post", "visit", "visit about post", "name")
    sigmas: dict[str, list[float]] = {k: [] for k in kinds}
    for robot in (int(r) for r in args.robots.split(",")):
        row = run_robot(args.data, robot, args)
        print(f"{row['robot']}: {row['sightings']} sightings, {row['outliers']} beyond {args.outlier:g} m")
        for kind in kinds:
            if kind in row:
                g = row[kind]
                sigmas[kind].append(g["sigma_m"])
                print(f"  {kind:16s} {g['groups']:4d} groups (median {g['median_size']:.0f} sightings): σ per axis "
                      f"{g['sigma_m']:.3f} m, median |mean| {g['median_mean_m']:.3f} m, noise share "
                      f"{g['noise_share']:.2f}")
    for kind in kinds:
        if sigmas[kind]:
            print(f"{kind}: σ per axis, median over robots {np.median(sigmas[kind]):.3f} m "
                  f"(range {min(sigmas[kind]):.3f}–{max(sigmas[kind]):.3f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
