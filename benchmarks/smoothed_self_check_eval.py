"""Does the self-check re-run along the smoothed trajectory (estimation.smoothed_self_check) flag the smoothed demo maps
that lost their frame, and only those? And what does the demo's final fusion do with the re-checked maps?

Run from the repository root on ``benchmarks.demo_smoothing``'s output folders (ROOT/demoS: robot1/2.npz, the replay
caches robotN-replay.npz + .map.npz and links to the TUM files):

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.smoothed_self_check_eval ROOT/demo0 ... [--out DIR]

Per robot: the replay cache is smoothed again with ``estimation.stereo_readings.smoothed_map`` (the association and the
inlier cut, checked to give the folder's smoothed map), which re-runs the self-check on it
(``estimation.smoothed_self_check``), and both verdicts, the filter's (the folder's map's ``filter_self_check``, or its
``self_check`` when smoothed before session 50) and the re-run's, printed beside the truth: the smoothed trajectory's
heading error against ``<robot>-truth.tum``, its median over the 10 s before the (first) alarm's onset and over the
frames after the alarm, the largest change between the two, and its rms over the run. A map is lost by the truth when
the two medians differ by more than ``LOST_HEADING`` (0.05 rad): on these maps the healthy flagged ones differ by ≤ 3
mrad, seed 4's robot 1 (which lost its frame) by 96–138 mrad.

Per seed: the demo's final fusion (``runtime.fusion_report.fuse_maps``, robust, default_rng(seed): the generator
that reproduced the demo's own final alignment in session 49), with the filter's verdict and with the re-run's: found,
what the split check decided, the error against the true start poses.

``--out DIR``: the re-checked maps (the smoothed map with ``self_check`` = the re-run's verdict and
``filter_self_check`` = the filter's) as DIR/demoS/robotN.npz with links to the TUM files, for ``p3at fuse``.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

LOST_HEADING = 0.05     # rad: the heading after the alarm this far from before it: the map lost its frame
ROBOTS = ("robot1", "robot2")


def load_replay(cache: Path):
    """(StereoReadings, the best particle's trajectory, the exported map, the particle-covariance export's positions
    and covariances, FastSLAMConfig) from a ``benchmarks.demo_smoothing`` replay cache."""
    from estimation.fastslam import FastSLAMConfig
    from estimation.landmark_map import LandmarkMap
    from estimation.stereo_readings import StereoReadings

    z = np.load(cache, allow_pickle=False)
    meta = json.loads(bytes(z["meta"]).decode())
    readings = StereoReadings(z["times"], z["odometry"], z["counts"], z["points"], z["covariances"],
                              z["descriptors"], z["pixels"])
    return (readings, z["trajectory"], LandmarkMap.load(cache.with_suffix(".map.npz")), z["particle_positions"],
            z["particle_covariances"], FastSLAMConfig.from_dict(meta["fastslam"]))


def heading_error(folder: Path, m) -> tuple[np.ndarray, np.ndarray]:
    """(times, heading error rad) of the map's trajectory against the truth on the same frames."""
    from estimation.geometry import wrap_angle
    from runtime.trajectories import planar, read_tum

    truth = planar(read_tum(folder / f"{m.robot}-truth.tum"))
    traj = m.trajectory
    k = np.searchsorted(traj[:, 0], truth[:, 0])
    ok = (k < len(traj)) & (np.abs(traj[np.minimum(k, len(traj) - 1), 0] - truth[:, 0]) < 1e-6)
    traj, truth = traj[k[ok]], truth[ok]
    return traj[:, 0], wrap_angle(traj[:, 3] - truth[:, 3])


def truth_at(t: np.ndarray, e: np.ndarray, alarm: dict | None) -> dict:
    """The heading error before the alarm's onset (10 s) and after the alarm (median), the largest change."""
    out = {"rms": float(np.sqrt(np.mean(e ** 2))), "max": float(np.max(np.abs(e)))}
    if alarm is None:
        return out
    before = (t >= alarm["since"] - 10.0) & (t < alarm["since"])
    after = t >= alarm["t"]
    if before.any() and after.any():
        b = float(np.median(e[before]))
        out |= {"before": b, "after": float(np.median(e[after])), "change": float(np.max(np.abs(e[after] - b)))}
        out["lost"] = abs(out["after"] - b) > LOST_HEADING
    return out


def fusion(maps: dict, seed: int) -> dict:
    from runtime.fusion_report import fuse_maps

    pair = fuse_maps(maps, "robust", 1, 0.0, np.random.default_rng(seed)).pairs[0]
    return {"found": bool(pair.aligned), "supports": pair.supports, "split": pair.split_decision,
            "error": None if pair.error_xy is None else (pair.error_xy, pair.error_theta), "note": pair.note[:120]}


def run(folders: list[Path], out: Path | None) -> list[dict]:
    from estimation.landmark_map import LandmarkMap
    from estimation.smoothed_self_check import FILTER_KEY, rechecked_metadata
    from estimation.stereo_readings import smoothed_map

    rows = []
    for folder in folders:
        seed = int("".join(c for c in folder.name if c.isdigit()) or 0)
        smoothed, rechecked, robots = {}, {}, {}
        for name in ROBOTS:
            readings, trajectory, exported, positions, covariances, config = load_replay(folder / f"{name}-replay.npz")
            sm = smoothed_map(readings, trajectory, exported, positions, covariances, config)
            saved = LandmarkMap.load(folder / f"{name}.npz")
            same = (np.allclose(sm.landmark_map.positions, saved.positions, atol=1e-9)
                    and np.allclose(sm.landmark_map.trajectory, saved.trajectory, atol=1e-9))
            verdict = sm.landmark_map.metadata["self_check"]   # smoothed_map re-runs the self-check
            # the filter's verdict: kept beside the re-run's in a folder smoothed since session 50, alone before
            filt = saved.metadata.get(FILTER_KEY, saved.metadata.get("self_check"))
            t, e = heading_error(folder, saved)
            robots[name] = {"filter": filt, "rerun": verdict, "same_smoothing": bool(same),
                            "truth_filter": truth_at(t, e, filt["alarms"][0] if filt and filt["lost"] else None),
                            "truth_rerun": truth_at(t, e, verdict["alarms"][0] if verdict["lost"] else None)}
            smoothed[name] = saved
            again = LandmarkMap.load(folder / f"{name}.npz")
            again.metadata = rechecked_metadata(again.metadata, verdict)
            rechecked[name] = again
            if out is not None:
                d = out / folder.name
                d.mkdir(parents=True, exist_ok=True)
                again.save(d / f"{name}.npz")
                for suffix in ("-truth.tum", "-odometry.tum", ".tum"):
                    link = d / f"{name}{suffix}"
                    if (folder / f"{name}{suffix}").exists() and not link.exists():
                        link.symlink_to((folder / f"{name}{suffix}").resolve())
        rows.append({"folder": folder.name, "seed": seed, "robots": robots,
                     "fusion_filter_verdict": fusion(smoothed, seed), "fusion_rerun": fusion(rechecked, seed)})
        print(f"{folder.name}: done", file=sys.stderr)
    return rows


def _verdict(v: dict | None) -> str:
    if v is None:
        return "none"
    if not v["lost"]:
        at = f" at {v['max_statistic_t']:.0f} s" if v["max_statistic_t"] is not None else ""
        return f"holds (max S {v['max_statistic']:.1f}{at}; {v['frames_tested']} frames tested)"
    a = v["alarms"][0]
    return (f"**flags** at {a['t']:.1f} s (since {a['since']:.1f} s; S {a['statistic']:.1f}; {a['redetected']} of "
            f"{a['predicted']} re-detected, {a['expected']:.0f} expected; {v['n_alarms']} alarm(s))")


def _truth(x: dict) -> str:
    if "before" not in x:
        return f"rms {1000 * x['rms']:.0f}, max {1000 * x['max']:.0f}"
    lost = "**lost**" if x["lost"] else "holds"
    return f"{lost}: {1000 * x['before']:+.0f} → {1000 * x['after']:+.0f} (max change {1000 * x['change']:.0f})"


def _fusion(f: dict) -> str:
    if not f["found"]:
        return f"not found ({f['note'][:60]})"
    split = f"; split: {f['split']}" if f["split"] else ""
    err = (f"{f['error'][0]:.3f} m / {f['error'][1]:.4f} rad" if f["error"] is not None
           else "error not comparable (a part after a gap)")
    return f"{err} ({f['supports']} supports{split})"


def print_table(rows: list[dict]) -> None:
    print("\n### The self-check re-run along the smoothed trajectory (benchmarks.smoothed_self_check_eval)\n")
    print("| run | robot | the filter's verdict | the re-run's verdict | truth at the filter's alarm: heading error "
          "mrad, before → after | truth at the re-run's alarm |")
    print("|---|---|---|---|---|---|")
    for row in rows:
        for name, r in row["robots"].items():
            print(f"| {row['folder']} | {name} | {_verdict(r['filter'])} | {_verdict(r['rerun'])} | "
                  f"{_truth(r['truth_filter'])} | {_truth(r['truth_rerun'])} |")
    print("\n| run | final fusion, the filter's verdicts | final fusion, the re-run's verdicts |")
    print("|---|---|---|")
    for row in rows:
        print(f"| {row['folder']} | {_fusion(row['fusion_filter_verdict'])} | {_fusion(row['fusion_rerun'])} |")
    flagged = [(row["folder"], n, r) for row in rows for n, r in row["robots"].items()]
    for key, name in (("filter", "the filter's"), ("rerun", "the re-run's")):
        lost = [x for x in flagged if x[2][key] and x[2][key]["lost"]]
        right = sum(1 for x in lost if x[2][f"truth_{key}"].get("lost"))
        print(f"- {name}: {len(lost)} of {len(flagged)} maps flag, {right} of them lost by the truth")
    print("- the smoothing re-made equals the folder's on "
          f"{sum(r['same_smoothing'] for row in rows for r in row['robots'].values())} of {len(flagged)} maps")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folders", nargs="+", type=Path, help="benchmarks.demo_smoothing output folders (ROOT/demoS)")
    parser.add_argument("--out", type=Path, default=None, help="write the re-checked maps here (DIR/demoS/robotN.npz)")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = parser.parse_args(argv)
    for f in args.folders:
        missing = [p for n in ROBOTS for p in (f"{n}.npz", f"{n}-replay.npz", f"{n}-replay.map.npz",
                                               f"{n}-truth.tum") if not (f / p).exists()]
        if missing:
            parser.error(f"{f}: no {', '.join(missing)} (a benchmarks.demo_smoothing output folder)")
    rows = run(args.folders, args.out)
    if args.json:
        print(json.dumps(rows, indent=1, default=float))
    else:
        print_table(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
