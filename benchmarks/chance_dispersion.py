"""How steady the decoys' dispersion is (session 52): on demo maps, session 51's moment φ on 1,000 decoys against the
upper bound (fusion.evidence.dispersion_bound) on 20,000, over draws of the decoys, and what makes φ scatter.

For each demo folder (p3at demo --out DIR: robot1.npz, robot2.npz): the two robots' maps, and each map cut at the
median x into halves 1 m apart that share nothing.  The decoy problem is the one align's evidence scores
(chance_model="negative_binomial", rng 0); then per case: φ of 200,000 decoys (the reference), the share of their
squared deviations from the top 0.1 % decoys, and over ``--draws`` draws: the moment φ on 1,000 (range, sd, how often
φ̂ + 1.645 se covers the reference, its correlation with the draw's top-1 % share) and the bound on 20,000 (range,
sd, coverage).

    OPENBLAS_NUM_THREADS=1 python -m benchmarks.chance_dispersion /tmp/demo52/seed9 [--draws 50]
"""
from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

import fusion.evidence as ev
from estimation.landmark_map import LandmarkMap
from fusion import ROBUST, align
from runtime.commands.options import positive_int

NB = replace(ROBUST, chance_model="negative_binomial")


def decoy_problem(a: LandmarkMap, b: LandmarkMap):
    """(problem, map1, map2, mask) of align's first decoy draw, or None (nothing scored)."""
    seen = []
    real = ev.decoy_null

    def spy(problem, m1, m2, config, rng, mask=None):
        seen.append((problem, m1, m2, None if mask is None else np.asarray(mask, bool).copy()))
        return real(problem, m1, m2, config, rng, mask)

    ev.decoy_null = spy
    try:
        align(a, b, NB, np.random.default_rng(0))
    finally:
        ev.decoy_null = real
    return seen[0] if seen else None


def moment(k: np.ndarray) -> tuple[float, float]:
    """(φ̂, its delta-method standard error from the sample's own influence values)."""
    mu, s2 = k.mean(), k.var(ddof=1)
    if mu == 0:
        return 1.0, 0.0
    inf = ((k - mu) ** 2 - s2) / mu - s2 * (k - mu) / mu ** 2
    return float(s2 / mu), float(inf.std(ddof=1) / np.sqrt(len(k)))


def cases(folder: Path):
    maps = {r: LandmarkMap.load(folder / f"robot{r}.npz") for r in (1, 2)}
    yield f"{folder.name} r1-r2", maps[1], maps[2]
    for r, m in maps.items():
        x = m.positions[:, 0]
        mid = np.median(x)
        yield f"{folder.name} r{r} halves", m.subset(x < mid - 0.5), m.subset(x > mid + 0.5)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", type=Path, nargs="+", help="demo output folders (robot1.npz, robot2.npz)")
    parser.add_argument("--draws", type=positive_int, default=50, help="draws of the decoys per case (50)")
    args = parser.parse_args(argv)
    print("| case | K | mean | φ (200,000) | top 0.1 % share | moment φ on 1,000: range (sd) | covers | corr top 1 % "
          "| bound on 20,000: range (sd) | covers |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for folder in args.folders:
        for name, a, b in cases(folder):
            got = decoy_problem(a, b)
            if got is None:
                print(f"| {name} | no decoys scored |")
                continue
            problem, m1, m2, mask = got
            _, ref = ev.decoy_counts(problem, m1, m2, 200_000, np.random.default_rng(7), mask)
            phi = float(ref.var(ddof=1) / ref.mean())
            dev = np.sort((ref - ref.mean()) ** 2)[::-1]
            old, new = [], []
            for d in range(args.draws):
                _, k = ev.decoy_counts(problem, m1, m2, 1000, np.random.default_rng(100 + d), mask)
                f, se = moment(k)
                dd = np.sort((k - k.mean()) ** 2)[::-1]
                old.append((f, f + 1.645 * se >= phi, dd[:10].sum() / max(dd.sum(), 1e-300)))
                _, k = ev.decoy_counts(problem, m1, m2, 20_000, np.random.default_rng(100 + d), mask)
                new.append(ev.dispersion_bound(k))
            o, n = np.array(old), np.array(new)
            print(f"| {name} | {len(problem.i)} | {ref.mean():.3f} | {phi:.2f} | {dev[:200].sum() / dev.sum():.2f} | "
                  f"{o[:, 0].min():.2f}-{o[:, 0].max():.2f} ({o[:, 0].std():.2f}) | {o[:, 1].mean():.2f} | "
                  f"{np.corrcoef(o[:, 0], o[:, 2])[0, 1]:+.2f} | {n.min():.2f}-{n.max():.2f} ({n.std():.2f}) | "
                  f"{np.mean(n >= phi):.2f} |", flush=True)


if __name__ == "__main__":
    main()
