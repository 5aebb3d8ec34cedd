"""How the U-SURF descriptor of one true point changes with the viewing distance, on rendered frames.

Run from the repository root, on the frames that ``eval_slam_rendered --frames-cache DIR`` kept:

    .venv/bin/python -m benchmarks.descriptor_scale DIR [--threshold 0.5] [--json]

For every true point (the observer's 5 cm surface-point clusters) seen in several frames, the distance between
the unit descriptors of two of its sightings is tabulated against |ln(r₂/r₁)|, r the range from the camera:
for all pairs of sightings of one point ("same point") and for pairs of sightings of *distinct* points
5–30 cm apart ("neighbours": what a wider acceptance would join wrongly). Then each point's sightings are
replayed in time order against a landmark's descriptor memory, as the filter would keep it, and the share of
re-sightings that pass the threshold is printed:
- ``first``: the first sighting's descriptor only (the filter's default);
- ``bands K ratio``: up to K descriptors, each with the range it was made at; a sighting is compared with the
  one made at the most similar range, and one that passes from a range more than ``ratio`` away from every kept
  one is kept too (so a landmark learns its look at new distances only through sightings that still matched);
- ``latest``: the latest accepted sighting's (the filter's ``refresh_descriptors``);
- ``min of K``: kept as the bands are, but compared with the nearest of them whatever its range;
- ``any``: the nearest of all earlier sightings (an upper bound no filter reaches).
For the neighbours the same memories are used (built from each point's own sightings that passed), and the
share of a neighbour's sightings that would pass is the false-acceptance rate of each memory.
"""
from __future__ import annotations

import argparse
import json
import zipfile
from pathlib import Path

import numpy as np

from runtime.commands.options import positive_float

SENSOR = np.array([0.12, 0.0, 0.50])   # the virtual head in base_link (FastSLAMConfig.sensor_offset)
RATIO_EDGES = (0.0, 0.05, 0.1, 0.2, 0.3, 0.4, 0.6, 10.0)   # |ln r2/r1|: 0.1 ≈ 10 %, 0.4 ≈ 1.5×


def load_sightings(path: Path) -> dict[str, np.ndarray]:
    """Per observation with a true point: frame, range (m), unit descriptor, true point index, world point."""
    try:
        with np.load(path, allow_pickle=False) as data:
            count, index, points = data["count"], data["index"], data["points"]
            desc, truth = data["descriptors"].astype(np.float32), data["true_points"]
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as error:
        raise SystemExit(f"{path}: not a frames cache of eval_slam_rendered ({error})") from None
    frame = np.repeat(np.arange(len(count)), count)
    ok = index >= 0
    return {"frame": frame[ok], "range": np.linalg.norm(points[ok] - SENSOR, axis=1), "desc": desc[ok],
            "point": index[ok], "xyz": truth[index[ok]]}


def _by_ratio(log_ratio: np.ndarray, dist: np.ndarray, threshold: float) -> list[dict]:
    rows = []
    for lo, hi in zip(RATIO_EDGES[:-1], RATIO_EDGES[1:], strict=True):
        sel = (log_ratio >= lo) & (log_ratio < hi)
        if sel.any():
            d = dist[sel]
            rows.append({"abs_ln_ratio": f"{lo:.2f}-{hi:.2f}", "pairs": int(sel.sum()),
                         "median": float(np.median(d)), "p90": float(np.percentile(d, 90)),
                         "below_threshold": float(np.mean(d < threshold))})
    return rows


def same_point_pairs(s: dict, rng: np.random.Generator, per_point: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """|ln ratio| and descriptor distance of pairs of sightings of one point (at most ``per_point`` per point)."""
    order = np.argsort(s["point"], kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(s["point"][order]) != 0])
    ends = np.r_[starts[1:], len(order)]
    ratios, dists = [], []
    for lo, hi in zip(starts, ends, strict=True):
        if hi - lo < 2:
            continue
        rows = order[lo:hi]
        i, k = np.triu_indices(len(rows), 1)
        if len(i) > per_point:
            pick = rng.choice(len(i), per_point, replace=False)
            i, k = i[pick], k[pick]
        a, b = rows[i], rows[k]
        ratios.append(np.abs(np.log(s["range"][b] / s["range"][a])))
        dists.append(np.linalg.norm(s["desc"][a] - s["desc"][b], axis=1))
    return np.concatenate(ratios), np.concatenate(dists)


class Memory:
    """A landmark's descriptors with the range each was made at (see the module docstring)."""

    def __init__(self, desc: np.ndarray, rng_m: float, slots: int, ratio: float, rule: str = "nearest") -> None:
        self.desc, self.range = [desc], [rng_m]
        self.slots, self.log_ratio, self.rule = slots, np.log(ratio) if ratio > 0 else np.inf, rule

    def distance(self, desc: np.ndarray, rng_m: float) -> float:
        if self.rule == "min":    # the closest of all kept descriptors, whatever the range
            return float(np.min(np.linalg.norm(np.array(self.desc) - desc, axis=1)))
        nearest = int(np.argmin(np.abs(np.log(np.array(self.range) / rng_m))))
        return float(np.linalg.norm(self.desc[nearest] - desc))

    def learn(self, desc: np.ndarray, rng_m: float) -> None:
        if self.rule == "latest":   # the descriptor follows its latest accepted sighting (refresh_descriptors)
            self.desc, self.range = [desc], [rng_m]
            return
        if len(self.desc) < self.slots and np.min(np.abs(np.log(np.array(self.range) / rng_m))) > self.log_ratio:
            self.desc.append(desc)
            self.range.append(rng_m)


def replay(s: dict, threshold: float, memories: list[tuple[str, int, float, str]], radius: tuple[float, float] = (0.05,
           0.30)) -> dict:
    """Share of re-sightings each memory accepts (same point), and of neighbours' sightings (distinct points)."""
    order = np.lexsort((s["frame"], s["point"]))
    points = s["point"][order]
    starts = np.flatnonzero(np.r_[True, np.diff(points) != 0])
    ends = np.r_[starts[1:], len(order)]
    out = {}
    seen_xyz = np.array([s["xyz"][order[lo]] for lo in starts])
    for name, slots, ratio, rule in memories:
        accepted = total = 0
        built = []
        for lo, hi in zip(starts, ends, strict=True):
            rows = order[lo:hi]
            mem = Memory(s["desc"][rows[0]], s["range"][rows[0]], slots, ratio, rule)
            for r in rows[1:]:
                d = mem.distance(s["desc"][r], s["range"][r])
                total += 1
                if d < threshold:
                    accepted += 1
                    mem.learn(s["desc"][r], s["range"][r])
            built.append(mem)
        false = tried = 0
        for pi, (lo, hi) in enumerate(zip(starts, ends, strict=True)):
            gap = np.linalg.norm(seen_xyz - seen_xyz[pi], axis=1)
            for qi in np.flatnonzero((gap > radius[0]) & (gap < radius[1])):
                for r in order[lo:hi][:20]:       # at most 20 sightings of p against q's memory
                    tried += 1
                    false += built[qi].distance(s["desc"][r], s["range"][r]) < threshold
        out[name] = {"resightings": total, "accepted": accepted / max(total, 1),
                     "neighbour_sightings": tried, "neighbours_accepted": false / max(tried, 1)}
    return out


def any_prior(s: dict, threshold: float) -> float:
    """Share of re-sightings within the threshold of some earlier sighting of the same point (an upper bound)."""
    order = np.lexsort((s["frame"], s["point"]))
    points = s["point"][order]
    starts = np.flatnonzero(np.r_[True, np.diff(points) != 0])
    ends = np.r_[starts[1:], len(order)]
    ok = total = 0
    for lo, hi in zip(starts, ends, strict=True):
        d = s["desc"][order[lo:hi]]
        for k in range(1, hi - lo):
            total += 1
            ok += np.min(np.linalg.norm(d[:k] - d[k], axis=1)) < threshold
    return ok / max(total, 1)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cache", type=Path, help="eval_slam_rendered --frames-cache DIR (its .npz files)")
    parser.add_argument("--threshold", type=positive_float, default=0.5, help="descriptor distance (the filter's gate)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    files = sorted(args.cache.glob("*.npz"))
    if not files:
        raise SystemExit(f"{args.cache}: no .npz frames (run eval_slam_rendered --frames-cache {args.cache} first)")
    memories = [("first", 1, 0.0, "nearest"), ("latest", 1, 0.0, "latest"),
                ("bands 2 x1.25", 2, 1.25, "nearest"), ("bands 4 x1.15", 4, 1.15, "nearest"),
                ("bands 4 x1.25", 4, 1.25, "nearest"), ("bands 8 x1.15", 8, 1.15, "nearest"),
                ("min of 4 x1.15", 4, 1.15, "min")]
    report = {}
    for path in files:
        s = load_sightings(path)
        ratio, dist = same_point_pairs(s, np.random.default_rng(0))
        report[path.stem] = {"sightings": len(s["point"]), "points": int(len(np.unique(s["point"]))),
                             "same_point_by_ratio": _by_ratio(ratio, dist, args.threshold),
                             "memories": replay(s, args.threshold, memories),
                             "any_earlier_sighting": any_prior(s, args.threshold)}
    if args.json:
        print(json.dumps(report, indent=1))
        return 0
    for name, r in report.items():
        print(f"\n{name}: {r['sightings']} sightings of {r['points']} true points")
        print("| abs ln(r2/r1) | pairs | distance median | p90 | share < threshold |")
        print("|---|---|---|---|---|")
        for row in r["same_point_by_ratio"]:
            print(f"| {row['abs_ln_ratio']} | {row['pairs']} | {row['median']:.3f} | {row['p90']:.3f} | "
                  f"{100 * row['below_threshold']:.0f} % |")
        print("\n| memory | re-sightings accepted | neighbours' sightings accepted (5-30 cm) |")  # a table of its own
        print("|---|---|---|")
        for m, v in r["memories"].items():
            print(f"| {m} | {100 * v['accepted']:.1f} % of {v['resightings']} | "
                  f"{100 * v['neighbours_accepted']:.2f} % of {v['neighbour_sightings']} |")
        print(f"| any earlier sighting | {100 * r['any_earlier_sighting']:.1f} % | |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
