"""The co-location test (fusion/colocation.py, AlignmentConfig.colocation) measured on saved maps.

    .venv/bin/python -m benchmarks.colocation_eval demo /tmp/r11/base-s{0..9}
    .venv/bin/python -m benchmarks.colocation_eval mrclam /tmp/mrclam-maps/id [--data DIR]
    .venv/bin/python -m benchmarks.colocation_eval false-pairs 1000
    .venv/bin/python -m benchmarks.colocation_eval eval-fusion -- --trust-only --false-pairs 1000 --seeds 20 ...

Maps saved before session 12 carry no ``clock`` / ``footprint_radius_m``; this benchmark adds what the map's maker
writes now, and says so on every row:
* demo (p3at demo): both robots' trajectories are in seconds since the one mission's start (the mission's shared
  clock), footprint 0.2525 m (the P3-AT's 505 mm width / 2, /work/shared/reference/arcos-protocol.md);
* MRCLAM (dataset_slam): the dataset's shared time (all five logs start at 0 on 0.02 s ticks), footprint 0.16495 m
  (the iRobot Create's base cylinder, turtlebot/turtlebot_create create_description/urdf/create.urdf.xacro); a map
  made before session 12 labels its first row t = 0 although it is the pose at the first sighting (the next row's
  time), so that row is dropped (dataset_slam now stamps it with the first sighting's time).
``demo`` aligns robot 2 to robot 1 with the option off and on (the final fusion's pair); ``mrclam`` every pair of
the five maps, with the true alignment's largest d² and the robots' true smallest separation from the Vicon poses
(a check of the shared clock); ``eval-fusion`` runs benchmarks/eval_fusion.py with the robust preset's option on.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

from estimation.landmark_map import LandmarkMap
from fusion import alignment_config
from fusion.alignment import align, align_at, alignment_error_xy_theta, true_relative_pose
from fusion.alignment_config import ROBUST
from fusion.colocation import colocation_test
from runtime.commands.options import positive_int

P3AT_INSCRIBED_RADIUS = 0.2525
CREATE_RADIUS = 0.16495


def _with_body(m: LandmarkMap, clock: str, radius: float, drop_first_row: bool = False) -> LandmarkMap:
    m.metadata.setdefault("clock", clock)
    m.metadata.setdefault("footprint_radius_m", radius)
    if drop_first_row and len(m.trajectory) > 1 and m.trajectory[0, 0] == 0.0 < m.trajectory[1, 0]:
        m.trajectory = m.trajectory[1:]
    return m


def _row(m1: LandmarkMap, m2: LandmarkMap, label: str) -> dict:
    truth = true_relative_pose(m1, m2)
    out = {"pair": label}
    for on in (False, True):
        t0 = time.perf_counter()
        a = align(m1, m2, dataclasses.replace(ROBUST, colocation=on), np.random.default_rng(0))
        st = a.statistics
        err = alignment_error_xy_theta(a.pose, truth) if a.found and truth is not None else None
        err = None if err is None else tuple(float(v) for v in err)
        out["on" if on else "off"] = {"found": a.found, "supports": len(a.supports), "rival": st.second_best_supports,
                                      "rival_pose": list(st.second_best_pose),
                                      "removed": st.colocation_removed_supports, "error": err,
                                      "reason": a.reason, "note": st.colocation,
                                      "seconds": time.perf_counter() - t0}
    return out


def _print(rows: list[dict]) -> None:
    print("| pair | off: found (supports / rival) | on: found (supports / rival, removed) | error xy / θ (on) | "
          "seconds off / on | on: reason (not found) | the test |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        off, on = r["off"], r["on"]
        err = "—" if on["error"] is None else f"{on['error'][0]:.3f} / {on['error'][1]:.4f}"
        why = "" if on["found"] else on["reason"][:100]
        print(f"| {r['pair']} | {'found' if off['found'] else 'no'} ({off['supports']} / {off['rival']}) | "
              f"{'found' if on['found'] else 'no'} ({on['supports']} / {on['rival']}, {on['removed']}) | {err} | "
              f"{off['seconds']:.1f} / {on['seconds']:.1f} | {why} | {on['note'][:110]} |")
    changed = sum(r["off"]["found"] != r["on"]["found"] for r in rows)

    def far(side: str) -> int:
        return sum(r[side]["found"] and r[side]["error"] is not None
                   and (r[side]["error"][0] > 0.3 or r[side]["error"][1] > 0.1) for r in rows)

    print(f"\n{len(rows)} pairs: found off {sum(r['off']['found'] for r in rows)}, on "
          f"{sum(r['on']['found'] for r in rows)} ({changed} changed); found more than 0.3 m or 0.1 rad from the true "
          f"start poses: off {far('off')}, on {far('on')}")


def _truth_tum(path: Path) -> np.ndarray:
    """(T, 3) t, x, y of a TUM file (robotN-truth.tum: the true trajectory in the robot's start frame)."""
    return np.loadtxt(path)[:, :3]


def demo(folders: list[Path]) -> None:
    rows, rivals = [], []
    for folder in folders:
        maps = [_with_body(LandmarkMap.load(folder / f"robot{r}.npz"), f"p3at demo {folder.name}: mission time",
                           P3AT_INSCRIBED_RADIUS) for r in (1, 2)]
        rows.append(_row(maps[0], maps[1], folder.name))
        if not rows[-1]["off"]["found"] and rows[-1]["off"]["rival_pose"]:
            rivals.append((folder, maps, np.array(rows[-1]["off"]["rival_pose"])))
    _print(rows)
    if rivals:
        _rival_table(rivals)


def _rival_table(rivals) -> None:
    """For each pair left ambiguous: where the rival would put robot 2, and what the test would need to call it.
    The true trajectories (robotN-truth.tum, one clock) under the rival: their smallest separation and when; the
    rival's largest d² as the test computes it (the dead-reckoning bound, the true alignment's start-frame covariance
    from align_at), with exact trajectories (no trajectory term), and with exact trajectories and the alignment's own
    precision (``covariance``) instead of its start-frame covariance."""
    print("\n| pair | rival (tx, ty, θ) | robot 2's start under it: m from robot 1's | true paths under it: smallest "
          "separation (m) at t (s) | rival's d²: as tested / exact paths / exact paths + own covariance (bound) | "
          "1σ of both paths there (m) |")
    print("|---|---|---|---|---|---|")
    for folder, maps, rp in rivals:
        test, why = colocation_test(*maps)
        if test is None:
            test, _ = colocation_test(*[_unflagged(m) for m in maps])
        at = align_at(maps[0], maps[1], true_relative_pose(*maps), ROBUST)
        if not at.found:
            print(f"| {folder.name} | {rp[0]:+.2f}, {rp[1]:+.2f}, {rp[2]:+.3f} | {np.hypot(*rp[:2]):.2f} | the true "
                  f"alignment is not found at the truth either ({at.reason[:60]}) | | |")
            continue
        t1, t2 = (_truth_tum(folder / f"robot{r}-truth.tum") for r in (1, 2))
        n = min(len(t1), len(t2))
        c, s = np.cos(rp[2]), np.sin(rp[2])
        q = t2[:n, 1:] @ np.array([[c, -s], [s, c]]).T + rp[:2]
        sep = np.hypot(*(t1[:n, 1:] - q).T)
        k = int(np.argmin(sep))
        exact = dataclasses.replace(test, var1=np.zeros_like(test.var1), var2=np.zeros_like(test.var2))
        d2s = [float(test.d2(rp, at.start_covariance)[0][0]), float(exact.d2(rp, at.start_covariance)[0][0]),
               float(exact.d2(rp, at.covariance)[0][0])]
        w = int(test.d2(rp, at.start_covariance)[1][0])
        sig = f"{np.sqrt(test.var1[w]):.2f}, {np.sqrt(test.var2[w]):.2f}" if w >= 0 else "—"
        print(f"| {folder.name} | {rp[0]:+.2f}, {rp[1]:+.2f}, {rp[2]:+.3f} | {np.hypot(*rp[:2]):.2f} | "
              f"{sep[k]:.3f} at {t1[k, 0]:.1f} | {d2s[0]:.2f} / {d2s[1]:.2f} / {d2s[2]:.1f} ({test.bound:.1f}) | "
              f"{sig} |")


def _unflagged(m: LandmarkMap) -> LandmarkMap:
    """The map with its self-check verdict set aside (the diagnosis only: the test refuses flagged maps)."""
    out = m.subset(np.ones(len(m), bool))
    out.metadata = {k: v for k, v in m.metadata.items() if k != "self_check"}
    return out


def _vicon(data: Path, robot: int) -> np.ndarray:
    from estimation.datasets import read_mrclam
    return read_mrclam(data, robot).ground_truth


def mrclam(folder: Path, data: Path | None) -> None:
    maps = [_with_body(LandmarkMap.load(folder / f"robot{r}.npz"), "MRCLAM_Dataset2 log time", CREATE_RADIUS, True)
            for r in range(1, 6)]
    rows, checks = [], []
    truth = [_vicon(data, r) for r in range(1, 6)] if data is not None and data.is_dir() else None
    for i in range(5):
        for j in range(i + 1, 5):
            rows.append(_row(maps[i], maps[j], f"robot{i + 1}-robot{j + 1}"))
            test, why = colocation_test(maps[i], maps[j])
            at = align_at(maps[i], maps[j], true_relative_pose(maps[i], maps[j]), ROBUST)
            d2 = float(test.d2(true_relative_pose(maps[i], maps[j]), at.start_covariance)[0][0]) \
                if test is not None and at.start_covariance is not None else float("nan")
            sep = float("nan")
            if truth is not None:
                a, b = truth[i], truth[j]
                t = np.arange(max(a[0, 0], b[0, 0]), min(a[-1, 0], b[-1, 0]), 0.1)
                pa = np.column_stack([np.interp(t, a[:, 0], a[:, k]) for k in (1, 2)])
                pb = np.column_stack([np.interp(t, b[:, 0], b[:, k]) for k in (1, 2)])
                sep = float(np.min(np.hypot(*(pa - pb).T)))
            checks.append((rows[-1]["pair"], len(test.times) if test else 0, d2, test.bound if test else float("nan"),
                           sep, why))
    _print(rows)
    print("\n| pair | common times | the true alignment's largest d² (bound) | true smallest separation (Vicon, m) |")
    print("|---|---|---|---|")
    for pair, n, d2, bound, sep, why in checks:
        print(f"| {pair} | {n} | {d2:.2f} ({bound:.1f}) | {sep:.3f} |" + (f" {why}" if why else ""))


def false_pairs(total: int) -> None:
    """eval_fusion's non-overlapping pairs (fusion_sim.false_pair_kinds, the same seeds) with the option off and on;
    the maps that carry a trajectory (the building's: the robots' true routes, 0.3 s a row on both) are given one
    clock, P3-AT footprints and the demo's noise model (a bound for an exact trajectory), so the test runs on them."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from fusion_sim import false_pair_kinds

    noise = {"odom_xy_var_per_m": 0.0009, "odom_theta_var_per_rad": 0.0025, "odom_theta_var_per_m": 0.0004,
             "odom_var_floor": 1e-8}
    kinds = false_pair_kinds()
    per = max(1, -(-total // len(kinds)))
    print(f"| maps ({per} pairs each) | tested | found off | found on | rivals removed (pairs) |")
    print("|---|---|---|---|---|")
    totals = np.zeros(4, int)
    for name, make in kinds.items():
        counts = np.zeros(4, int)
        for seed in range(per):
            m1, m2 = make(seed)
            m1, m2 = getattr(m1, "map", m1), getattr(m2, "map", m2)
            if len(m1.trajectory) and len(m2.trajectory):
                for m in (m1, m2):
                    m.metadata.update({"clock": f"false pair {seed}", "footprint_radius_m": P3AT_INSCRIBED_RADIUS,
                                       "fastslam": dict(noise)})
            off = align(m1, m2, ROBUST, np.random.default_rng(seed))
            on = align(m1, m2, dataclasses.replace(ROBUST, colocation=True), np.random.default_rng(seed))
            counts += [colocation_test(m1, m2)[0] is not None, off.found, on.found,
                       on.statistics.colocation_removed_supports > 0]
        print(f"| {name} | {counts[0]} | {counts[1]} | {counts[2]} | {counts[3]} |")
        totals += counts
    print(f"\n{per * len(kinds)} non-overlapping pairs: tested {totals[0]}, found off {totals[1]}, on {totals[2]}; "
          f"a rival removed on {totals[3]}")


def eval_fusion(argv: list[str]) -> None:
    """benchmarks/eval_fusion.py with the robust preset's co-location option on (the PRESETS entry every caller
    resolves 'robust' through, p3at fuse included)."""
    alignment_config.PRESETS["robust"] = dataclasses.replace(ROBUST, colocation=True)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import eval_fusion
    sys.argv = ["eval_fusion.py", *argv]
    print("(robust preset with colocation=True)")
    eval_fusion.main()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="what", required=True)
    p = sub.add_parser("demo")
    p.add_argument("folders", type=Path, nargs="+")
    p = sub.add_parser("mrclam")
    p.add_argument("folder", type=Path)
    p.add_argument("--data", type=Path,
                   default=Path(__file__).resolve().parents[2] / "shared/data/mrclam/MRCLAM_Dataset2")
    p = sub.add_parser("false-pairs")
    p.add_argument("total", type=positive_int, nargs="?", default=1000)
    p = sub.add_parser("eval-fusion")
    p.add_argument("rest", nargs=argparse.REMAINDER)
    args = parser.parse_args()
    if args.what == "demo":
        demo(args.folders)
    elif args.what == "mrclam":
        mrclam(args.folder, args.data)
    elif args.what == "false-pairs":
        false_pairs(args.total)
    else:
        eval_fusion([a for a in args.rest if a != "--"])


if __name__ == "__main__":
    from estimation.errors import MapFileError

    try:
        main()
    except MapFileError as e:   # a map file of a given folder missing or unreadable: one line naming it
        print(f"{Path(__file__).name}: {e}", file=sys.stderr)
        sys.exit(2)
