"""How often does a demo map cut into two halves that share nothing give a wrong "found"? (session 52)

Run from the repository root, on the rendered demo's folders (``p3at demo --seed S --out DIR``, robot1/2.npz):

    OPENBLAS_NUM_THREADS=1 nice -n 5 .venv/bin/python -m benchmarks.halves_false_found DIR [DIR ...] \
        [--gaps 1 3] [--rng-seeds 0 1 2] [--radius 0.5]

Each robot map is cut at the median x and at the median y; landmarks within gap/2 of the cut are dropped, each half
keeps the map's metadata (``LandmarkMap.subset``). Each half pair is aligned with the default robust preset
(``fusion.align(a, b, "robust", rng)``) at each rng seed. The halves share no landmark, so any "found" is wrong.

Prints one line per found (map, axis, gap, rng seed, half sizes, pose, supports vs required, rival and self-repeat
supports, and the overlap under the wrong pose: how many of half b's landmarks, placed by the pose, fall within
``--radius`` of some landmark of half a), then the totals: cases, founds, founds per axis and gap.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from estimation.landmark_map import LandmarkMap
from fusion import align
from runtime.commands.options import non_negative_float, positive_float, whole_number_at_least


def cut_masks(values: np.ndarray, gap: float) -> tuple[np.ndarray, np.ndarray]:
    """Masks of the two halves of ``values`` cut at the median, dropping those within gap/2 of the cut."""
    mid = float(np.median(values))
    return values < mid - gap / 2, values > mid + gap / 2


def place(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Points (n, 2) moved by the planar pose (x, y, theta)."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return points @ np.array([[c, s], [-s, c]]) + pose[:2]


def overlap_count(a: np.ndarray, b: np.ndarray, radius: float) -> int:
    """How many points of ``b`` (n, 2) lie within ``radius`` of some point of ``a`` (m, 2)."""
    if len(a) == 0 or len(b) == 0:
        return 0
    d2 = ((b[:, None, :] - a[None, :, :]) ** 2).sum(axis=2)
    return int((d2.min(axis=1) <= radius * radius).sum())


def overlap_under(al, a: LandmarkMap, b: LandmarkMap, radius: float) -> int:
    """Overlap of half b placed by the alignment's pose on half a (the direction the supports agree with)."""
    pa, pb = a.positions[:, :2], b.positions[:, :2]
    pose = np.asarray(al.pose, dtype=float)
    sup = np.asarray(al.supports)
    inv_t = -place(pose[None, :2], np.array([0.0, 0.0, -pose[2]]))[0]
    inverse = np.array([inv_t[0], inv_t[1], -pose[2]])
    best = pose
    if len(sup):
        res = [np.median(np.linalg.norm(place(pb[sup[:, 1]], p) - pa[sup[:, 0]], axis=1)) for p in (pose, inverse)]
        best = pose if res[0] <= res[1] else inverse
    return overlap_count(pa, place(pb, best), radius)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dirs", nargs="+", type=Path, help="demo output folders holding robot1.npz / robot2.npz")
    ap.add_argument("--gaps", nargs="+", type=non_negative_float, default=[1.0, 3.0], help="m between the halves")
    ap.add_argument("--rng-seeds", nargs="+", type=whole_number_at_least(0), default=[0, 1, 2])
    ap.add_argument("--radius", type=positive_float, default=0.5, help="overlap radius (m)")
    args = ap.parse_args(argv)
    for d in args.dirs:
        if not d.is_dir():
            print(f"no such folder: {d}", file=sys.stderr)
            return 2
    cases = founds = 0
    per: dict[tuple[str, float], list[int]] = {}
    print("map axis gap rng |a| |b| pose(x,y,th) supports/required rival self_repeat overlap")
    for d in args.dirs:
        for robot in ("robot1", "robot2"):
            path = d / f"{robot}.npz"
            if not path.exists():
                continue
            m = LandmarkMap.load(path)
            for axis, col in (("x", 0), ("y", 1)):
                for gap in args.gaps:
                    ma, mb = cut_masks(m.positions[:, col], gap)
                    a, b = m.subset(ma), m.subset(mb)
                    for seed in args.rng_seeds:
                        al = align(a, b, "robust", rng=np.random.default_rng(seed))
                        cases += 1
                        tally = per.setdefault((axis, gap), [0, 0])
                        tally[0] += 1
                        if not al.found:
                            continue
                        founds += 1
                        tally[1] += 1
                        st = al.statistics
                        pose = np.round(np.asarray(al.pose, dtype=float), 3)
                        print(
                            f"{d.name}/{robot} {axis} {gap:g} {seed} {len(a)} {len(b)} {tuple(pose.tolist())} "
                            f"{st.supports}/{st.required_supports} {st.second_best_supports} "
                            f"{st.self_repeat_supports} {overlap_under(al, a, b, args.radius)}",
                            flush=True,
                        )
    print(f"total: {founds} found (all wrong) of {cases} half pairs")
    for (axis, gap), (n, f) in sorted(per.items()):
        print(f"  cut {axis}, gap {gap:g} m: {f} / {n}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
