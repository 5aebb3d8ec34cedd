"""The alignment with a rough prior on the robots' relative start (fusion/prior.py), on the rendered demo.

For each demo folder (``p3at demo --seed S --out DIR``: robot1.npz, robot2.npz) the final maps are aligned four
times: without a prior; with the configured start poses (the world's ``start_poses``, where the demo puts its
robots) at σ ``--sigma-xy`` / ``--sigma-yaw`` each; with a *wrong* prior, the truth turned by a half turn about the
centre of the corridor both robots drive (x 9 m, y 5 m in the world: the building's symmetry, the ambiguous rival's
place); and a prior 3 m off the truth along map 1's x axis.  Printed: the decision, supports (needed), the rival
inside the prior and the best hypothesis outside it, the hypotheses tried inside it of all, the error against the
true start poses and the alignment's own error (against the composition of the two maps' best rigid fits to the
simulator's true features, as ``eval_fusion --demo-maps``).  A found alignment more than 0.3 m or 0.1 rad off the
truth is WRONG.  The column "maps alone" says whether a found alignment with a prior rests on the prior (PRIOR: the
maps' own evidence is ambiguous or too weak, fusion.Alignment.prior_backing) or on the data; the summary counts the
prior-backed founds, and how many of the wrong ones are.
``--false-pairs N`` runs the seven kinds of non-overlapping pairs of ``fusion_gate_scale`` with two
priors each: a wide one (10 m / π/2 about the identity) and an adversarial one (1 m / 0.3 rad, centred on the best
hypothesis the maps give without a prior).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.fusion_prior --demo /tmp/lead9/demo /tmp/lead9/demo-s1 ...
    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.fusion_prior --false-pairs 1000

``--self-repeat-gate pair`` runs everything with a map's self-repeat counted in the pair's gate (session 10's option).
``--ratio-sides either`` (or ``both``) runs it with the ratio test on both sides of a match
(AlignmentConfig.ratio_sides, session 45's option); ``--reverse`` aligns each demo folder's maps the other way
(robot2.npz as map 1), so that the two orders can be compared.  The summary counts the found alignments within issue
13's goal, 0.05 m / 0.01 rad of the truth.
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from eval_fusion import _feature_fit  # noqa: E402
from fusion_sim import false_pair_kinds, load_world  # noqa: E402

from estimation.geometry import between, compose, inverse, transform_points  # noqa: E402
from estimation.landmark_map import LandmarkMap  # noqa: E402
from fusion.alignment import align, alignment_error_xy_theta, true_relative_pose  # noqa: E402
from fusion.alignment_config import ROBUST, AlignmentConfig  # noqa: E402
from fusion.evidence import SELF_REPEAT_GATES  # noqa: E402
from fusion.matching import RATIO_SIDES  # noqa: E402
from fusion.prior import StartPrior  # noqa: E402
from runtime.commands.options import non_negative_int, positive_float  # noqa: E402

WRONG_M, WRONG_RAD = 0.3, 0.1          # as eval_fusion: this far off counts as a false alignment
GOAL_M, GOAL_RAD = 0.05, 0.01          # issue 13's goal for the rendered demo's alignment against the truth
SYMMETRY_CENTRE = (9.0, 5.0)           # world metres: the middle of the corridor both demo robots drive (x 2..16)


def half_turned(truth: np.ndarray, start1: np.ndarray) -> np.ndarray:
    """The truth turned by a half turn about the corridor's centre (map 1's frame): where the building's rival is."""
    c = transform_points(inverse(start1), np.array([[*SYMMETRY_CENTRE, 0.0]]))[0, :2]
    return compose(np.array([2 * c[0], 2 * c[1], np.pi]), truth)


def _cell(a, truth, best) -> str:
    if not a.found:
        why = a.reason.split(";")[0].split(" (")[0]
        return f"not found: {why}"
    e = alignment_error_xy_theta(a.pose, truth)
    o = alignment_error_xy_theta(a.pose, best)
    wrong = " **WRONG**" if e[0] > WRONG_M or e[1] > WRONG_RAD else ""
    return f"found{wrong}: {e[0]:.3f} m / {e[1]:.4f} rad; own {o[0]:.3f} / {o[1]:.4f}"


def _alone(a) -> str:
    """What the maps alone decide about a found alignment with a prior (fusion.Alignment.prior_backing): 'data' (the
    maps' evidence finds it too), else 'PRIOR: ' and why; '–' without a prior or when not found."""
    st = a.statistics
    if not a.found or a.prior is None:
        return "–"
    if not st.prior_backed:
        return f"data (10^{st.without_prior_log10_chance_probability:.1f})"
    if st.prior_decides == "ambiguous":
        return (f"PRIOR: ambiguous, rival {st.without_prior_rival_supports} {st.without_prior_rival_shift:.1f} m / "
                f"{st.without_prior_rival_turn:.2f} rad away{' (outside)' if st.without_prior_rival_outside else ''}")
    return f"PRIOR: {st.prior_decides} (10^{st.without_prior_log10_chance_probability:.1f})"


def _strongest_wrong(m1, m2, plain, truth) -> np.ndarray | None:
    """The maps' strongest wrong hypothesis: the winner (the fit of its supports) if it is wrong, else the
    second-best (on the demo, the half turn)."""
    winner = _supports_fit(m1, m2, plain.supports) if len(plain.supports) >= 2 else None
    if winner is not None:
        e = alignment_error_xy_theta(winner, truth)
        if e[0] > WRONG_M or e[1] > WRONG_RAD:
            return winner
    return np.array(plain.statistics.second_best_pose) if plain.statistics.second_best_pose else None


def demo_table(folders: list[Path], sigma_xy: float, sigma_yaw: float, config: AlignmentConfig = ROBUST,
               reverse: bool = False) -> None:
    """``reverse``: robot2.npz is map 1 (the other order of the same maps)."""
    world = load_world()
    order = "robot 2's map first" if reverse else "robot 1's map first"
    print(f"\n### Rendered demo with a start prior (σ {sigma_xy} m / {sigma_yaw} rad per robot; {order})\n")
    print("| run | prior | decision: error vs truth xy / θ; own error | supports (needed) | rival inside | "
          "best outside the prior | hypotheses inside / tried | maps alone |")
    print("|---|---|---|---|---|---|---|---|")
    summary: dict[str, list] = {}
    for folder in folders:
        m1, m2 = LandmarkMap.load(folder / "robot1.npz"), LandmarkMap.load(folder / "robot2.npz")
        if reverse:
            m1, m2 = m2, m1
        truth = true_relative_pose(m1, m2)
        start1 = np.asarray(world.start_poses[m1.robot], float)
        start2 = np.asarray(world.start_poses[m2.robot], float)
        fits = [_feature_fit(m, world.features)[0] for m in (m1, m2)]
        best = between(fits[0], fits[1])
        configured = StartPrior.between_starts(start1, start2, sigma_xy, sigma_yaw, source="configured starts")
        cov = configured.covariance
        plain = align(m1, m2, config, np.random.default_rng(0))
        strongest_wrong = _strongest_wrong(m1, m2, plain, truth)
        priors = {
            "none": None,
            "configured starts": configured,
            "half-turned (wrong)": StartPrior(half_turned(truth, start1), cov, source="half-turned"),
            "at the strongest wrong hypothesis (wrong)": None if strongest_wrong is None else StartPrior(
                strongest_wrong, cov, source="strongest wrong"),
            "3 m off in x (wrong)": StartPrior(truth + np.array([3.0, 0.0, 0.0]), cov, source="3 m off"),
            # the same offset with starts known to 0.3 m / 0.1 rad: the truth is then outside the prior
            "3 m off in x, σ 0.3 m / 0.1 rad (wrong)": StartPrior(
                truth + np.array([3.0, 0.0, 0.0]),
                StartPrior.between_starts(start1, start2, 0.3, 0.1).covariance, source="3 m off, tight"),
        }
        for name, prior in priors.items():
            if prior is None and name != "none":
                continue
            a = align(m1, m2, config, np.random.default_rng(0), prior=prior)
            st = a.statistics
            inside = f"{st.prior_hypotheses} / {st.iterations}" if prior is not None else f"– / {st.iterations}"
            outside = st.outside_prior_supports if prior is not None else "–"
            print(f"| {folder.name} | {name} | {_cell(a, truth, best)} | {st.supports} ({st.required_supports}) | "
                  f"{st.second_best_supports} | {outside} | {inside} | {_alone(a)} |")
            e = alignment_error_xy_theta(a.pose, truth) if a.found else None
            o = alignment_error_xy_theta(a.pose, best) if a.found else None
            summary.setdefault(name, []).append((a.found, e, o, st.prior_backed))
    print()
    for name, rows in summary.items():
        found = [r for r in rows if r[0]]
        wrong = [r for r in found if r[1][0] > WRONG_M or r[1][1] > WRONG_RAD]
        goal = sum(1 for r in found if r[1][0] <= GOAL_M and r[1][1] <= GOAL_RAD)
        line = (f"- {name}: found {len(found)} of {len(rows)}, wrong {len(wrong)}, within {GOAL_M} m / {GOAL_RAD} rad "
                f"{goal}")
        if name != "none":        # found only because of the prior (the maps alone would not), of all and of the wrong
            line += (f"; prior-backed {sum(1 for r in found if r[3])} of the found, "
                     f"{sum(1 for r in wrong if r[3])} of the wrong")
        if found:
            e, o = np.array([r[1] for r in found]), np.array([r[2] for r in found])
            line += (f"; vs truth median {np.median(e[:, 0]):.3f} m / {np.median(e[:, 1]):.4f} rad, worst "
                     f"{e[:, 0].max():.3f} / {e[:, 1].max():.4f}; own median {np.median(o[:, 0]):.3f} m / "
                     f"{np.median(o[:, 1]):.4f} rad, worst {o[:, 0].max():.3f} / {o[:, 1].max():.4f}")
        print(line)


def false_pairs(total: int, only: str | None = None, config: AlignmentConfig = ROBUST) -> None:
    """fusion_gate_scale's seven kinds (same generators and seeds), each with a wide and an adversarial prior;
    ``only``: the kinds whose name holds it (each keeps its share of ``total``)."""
    kinds = false_pair_kinds()
    share = len(kinds)
    if only:
        kinds = {k: v for k, v in kinds.items() if only in k}
    per = max(1, -(-total // share))
    print(f"\n### No false alignment with a start prior ({per * len(kinds)} pairs: {per} of each kind)\n")
    print("| maps | found: no prior | wide prior (10 m / 1.57 rad about the identity) | adversarial prior "
          "(1 m / 0.3 rad about the best hypothesis) |")
    print("|---|---|---|---|")
    totals, backed_totals = np.zeros(3, int), np.zeros(3, int)
    for name, make in kinds.items():
        found, backed = np.zeros(3, int), np.zeros(3, int)     # backed: found only because of the prior
        for seed in range(per):
            m1, m2 = make(seed)
            m1, m2 = getattr(m1, "map", m1), getattr(m2, "map", m2)
            plain = align(m1, m2, config, np.random.default_rng(seed))
            found[0] += plain.found
            wide = StartPrior.from_sigmas(np.zeros(3), 10.0, np.pi / 2, source="wide")
            a = align(m1, m2, config, np.random.default_rng(seed), prior=wide)
            found[1] += a.found
            backed[1] += a.statistics.prior_backed
            centre = plain.pose if plain.found else _best_pose(m1, m2, seed, config)
            if centre is not None:
                tight = StartPrior.from_sigmas(centre, 1.0, 0.3, source="adversarial")
                a = align(m1, m2, config, np.random.default_rng(seed), prior=tight)
                found[2] += a.found
                backed[2] += a.statistics.prior_backed
        totals += found
        backed_totals += backed
        cells = [f"{found[k]}/{per}" + (f" ({backed[k]} prior-backed)" if backed[k] else "") for k in range(3)]
        print(f"| {name} | {' | '.join(cells)} |")
    print(f"\nFound on {per * len(kinds)} non-overlapping pairs: no prior {totals[0]}, wide prior {totals[1]} "
          f"({backed_totals[1]} prior-backed), adversarial prior {totals[2]} ({backed_totals[2]} prior-backed)")


def _best_pose(m1: LandmarkMap, m2: LandmarkMap, seed: int, config: AlignmentConfig) -> np.ndarray | None:
    """The pose of the best rejected hypothesis (the fit of its supports), for an adversarial prior."""
    a = align(m1, m2, config, np.random.default_rng(seed))
    return _supports_fit(m1, m2, a.supports) if len(a.supports) >= 2 else None


def _supports_fit(m1: LandmarkMap, m2: LandmarkMap, supports: np.ndarray) -> np.ndarray:
    """A closed-form 2-D rigid fit of map 2's frame in map 1's from support pairs (S, 2), then one weighted
    refinement."""
    from fusion.ransac import refine_pose

    i, j = supports[:, 0], supports[:, 1]
    p1, p2 = m1.positions[i], m2.positions[j]
    c1, c2 = p1[:, :2].mean(0), p2[:, :2].mean(0)
    h = (p2[:, :2] - c2).T @ (p1[:, :2] - c1)
    theta = np.arctan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    r = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    pose = np.array([*(c1 - r @ c2), theta])
    return refine_pose(p1, m1.covariances[i], p2, m2.covariances[j], pose)[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--demo", type=Path, nargs="*", default=[], help="demo output folders (robot1/2.npz)")
    parser.add_argument("--sigma-xy", type=positive_float, default=1.0, help="σ of each start, metres (default 1)")
    parser.add_argument("--sigma-yaw", type=positive_float, default=0.3, help="σ of each start, rad (default 0.3)")
    parser.add_argument("--false-pairs", type=non_negative_int, default=0,
                        help="non-overlapping pairs, over seven kinds")
    parser.add_argument("--kind", default=None, help="only the kinds of non-overlapping pairs whose name holds this")
    parser.add_argument("--self-repeat-gate", choices=SELF_REPEAT_GATES, default=ROBUST.self_repeat_gate,
                        help="where a map's self-repeat is counted (AlignmentConfig.self_repeat_gate; default: the "
                             "robust preset's)")
    parser.add_argument("--ratio-sides", choices=RATIO_SIDES, default=ROBUST.ratio_sides,
                        help="whose ratio test a match must pass: map 1's landmark, both landmarks' or either's "
                             "(AlignmentConfig.ratio_sides; default: the robust preset's)")
    parser.add_argument("--reverse", action="store_true",
                        help="align each demo folder's maps the other way: robot2.npz as map 1")
    args = parser.parse_args()
    config = replace(ROBUST, self_repeat_gate=args.self_repeat_gate, ratio_sides=args.ratio_sides)
    print(f"robust preset, self_repeat_gate={config.self_repeat_gate}, ratio_sides={config.ratio_sides}")
    t0 = time.perf_counter()
    if args.demo:
        demo_table(args.demo, args.sigma_xy, args.sigma_yaw, config, args.reverse)
    if args.false_pairs:
        false_pairs(args.false_pairs, args.kind, config)
    print(f"\n({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    from estimation.errors import MapFileError

    try:
        main()
    except MapFileError as e:   # a map file of a given folder missing or unreadable: one line naming it
        print(f"{Path(__file__).name}: {e}", file=sys.stderr)
        sys.exit(2)
