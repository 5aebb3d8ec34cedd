"""Why a robot's re-sightings of landmarks it made before a turn on the spot are not matched to them, per sighting.

Run from the repository root (a frames cache from ``benchmarks.slam_demo_replay --frames-cache`` replays the
filter alone, minutes; without one the frames are rendered again):

    .venv/bin/python -m benchmarks.demo_relock DEMO_DIR [--robot robot2] [--frames-cache FILE]
        [--filter-seed K] [--render-seed S] [--set KEY=VALUE ...] [--sightings FILE.csv]

The replay is ``benchmarks.slam_demo_replay``'s (the route driven, the odometry the demo gave its filter, each
frame rendered again at the true pose). The synthetic world names each reading's true point. Before each update
the script keeps the particles' poses, unsampled motion covariances and maps; after it, it takes the particle the
update reports as best (its matches are the report's ``best_matches``) and judges each of the frame's readings
of a true point that has a landmark in that particle's map made *before the last turn on the spot* (the oldest
such landmark L; turns: ``demo_frame_errors.turns_on_the_spot`` on the true route). One reason per sighting, in
the association's order:

- ``matched``: the reading went to L (or another pre-turn landmark of the point);
- ``descriptor``: |d − d_L| ≥ ``descriptor_threshold`` (d_L: the landmark's first U-SURF descriptor, or with
  ``--set descriptor_slots=K`` the one it keeps from the nearest view, as the association compares);
- ``gate``: the descriptor passed, the filter's Mahalanobis d² (its S: Σ_L + R Q Rᵀ + the unsampled pose
  term) ≥ ``mahalanobis_gate``;
- ``duplicate``: both passed, the reading went to a newer landmark of the same point;
- ``other``: both passed, it went to a landmark of another point, or to none (mutual exclusion).

Readings of a point seen before the turn whose pre-turn landmarks the particle no longer holds are counted as
``gone`` (removed by misses, or the lineage never made one). For every sighting it also keeps the viewpoint
change (range ratio to the landmark's first sighting, the horizontal angle between the two lines of sight), the
particle's heading error against the truth, the landmark's position error against its true point and d², and
prints per turn the reasons and the medians of these by reason, then a summary over every turn.
``--sightings FILE.csv`` writes every judged sighting (one row each), atomically.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the project root: runs as a file too

from benchmarks.config_overrides import config_overrides
from benchmarks.demo_frame_errors import turns_on_the_spot
from benchmarks.slam_demo_replay import add_replay_arguments, open_replay, predicted_frames, save_frames
from estimation.fastslam import FastSLAM
from estimation.fileio import atomic_write_bytes
from estimation.geometry import wrap_angle

REASONS = ("matched", "descriptor", "gate", "duplicate", "other", "elsewhere", "gone")
SAME = 0.10  # m: a landmark made from a sighting of a true point this close stands for the same point
FIELDS = ("t", "since_turn", "turn", "point", "lid", "reason", "range_ratio", "view_angle", "heading_error",
          "landmark_error", "lateral_offset", "d2", "descriptor_distance", "pose_sigma_theta", "position_gated",
          "position_right", "gone_by", "looks", "nearest_look_angle")


def sighting_reason(matched_old: bool, descriptor_distance: float, d2: float, went_to_same_point: bool,
                    descriptor_threshold: float, gate: float) -> str:
    """The association's first refusal of a pre-turn landmark for one reading (see the module docstring)."""
    if matched_old:
        return "matched"
    if not descriptor_distance < descriptor_threshold:
        return "descriptor"
    if not d2 < gate:
        return "gate"
    return "duplicate" if went_to_same_point else "other"


def gate_d2(pose: np.ndarray, motion_cov: np.ndarray, z: np.ndarray, q: np.ndarray, mean: np.ndarray,
            cov: np.ndarray) -> float:
    """The filter's gate d² for one reading z (3,) with covariance q (3, 3) (floor included) against a landmark
    (mean (3,), cov (3, 3)) from a particle at ``pose`` with unsampled motion covariance ``motion_cov``:
    ν = R z + t − μ, S = Σ + R Q Rᵀ + H P Hᵀ with H's lever μ − t (``linalg.pose_uncertainty``)."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    nu = rot @ z + np.array([pose[0], pose[1], 0.0]) - mean
    lever = mean[:2] - pose[:2]
    h = np.array([[-1.0, 0.0, lever[1]], [0.0, -1.0, -lever[0]], [0.0, 0.0, 0.0]])
    s_gate = cov + rot @ q @ rot.T + h @ motion_cov @ h.T
    return float(nu @ np.linalg.solve(s_gate, nu))


def gate_d2_many(pose: np.ndarray, motion_cov: np.ndarray, z: np.ndarray, q: np.ndarray, means: np.ndarray,
                 covs: np.ndarray) -> np.ndarray:
    """:func:`gate_d2` of one reading against landmarks (means (L, 3), covs (L, 3, 3)): d² (L,)."""
    if len(means) == 0:
        return np.zeros(0)
    c, s = np.cos(pose[2]), np.sin(pose[2])
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    nu = rot @ z + np.array([pose[0], pose[1], 0.0]) - means                      # (L, 3)
    lever = means[:, :2] - pose[:2]
    h = np.zeros((len(means), 3, 3))
    h[:, 0, 0] = h[:, 1, 1] = -1.0
    h[:, 0, 2], h[:, 1, 2] = lever[:, 1], -lever[:, 0]
    s_gate = covs + rot @ q @ rot.T + h @ motion_cov @ h.transpose(0, 2, 1)
    return np.einsum("li,li->l", nu, np.linalg.solve(s_gate, nu[..., None])[..., 0])


def view_change(point: np.ndarray, camera: np.ndarray, first_camera: np.ndarray) -> tuple[float, float]:
    """(range ratio, angle in rad between the horizontal lines of sight) of a point (2,) seen from ``camera`` (2,)
    against from ``first_camera`` (2,)."""
    now, first = camera - point, first_camera - point
    angle = abs(float(wrap_angle(np.arctan2(now[1], now[0]) - np.arctan2(first[1], first[0]))))
    return float(np.linalg.norm(now) / max(np.linalg.norm(first), 1e-9)), angle


def descriptor_distance(slam: FastSLAM, lid: int, desc: np.ndarray, z: np.ndarray, heading: float) -> float:
    """The distance the association compares with its threshold: to the landmark's first descriptor, or with
    ``descriptor_slots`` > 1 to the one it keeps from the nearest view (appearance.py; the bands as they were at the
    end of the update, so a look learned from this very reading counts)."""
    if slam._bands is None:
        return float(np.linalg.norm(desc - slam._descriptors[lid]))
    return float(slam._bands.distance(np.array([lid]), desc[None], slam._sensor_range(z[None]),
                                      slam._sight_bearing(z[None], heading))[0])


def kept_looks(slam: FastSLAM, lid: int, z: np.ndarray, heading: float) -> dict:
    """With ``descriptor_slots`` > 1: how many looks the landmark keeps, and the angle (rad) from the reading's line
    of sight (world bearing at ``heading``) to the nearest direction one was made from (nan: none known)."""
    bands = slam._bands
    kept = np.isfinite(bands.range[lid])
    phi = float(slam._sight_bearing(z[None], heading)[0])
    gaps = np.abs(wrap_angle(phi - bands.bearing[lid, kept]))
    gaps = gaps[np.isfinite(gaps)]
    return {"looks": int(kept.sum()), "nearest_look_angle": float(gaps.min()) if len(gaps) else float("nan")}


def particle_slots(slam: FastSLAM, table: np.ndarray, n_blocks: np.ndarray, lid: np.ndarray, m: int) -> np.ndarray:
    """Flat slot indices (physical block · B + slot) of particle m's live landmarks in a kept copy of the store."""
    b = slam.store.block_size
    phys = table[m, : n_blocks[m]]
    slots = (phys[:, None] * b + np.arange(b)).ravel()
    return slots[lid.ravel()[slots] >= 0]


def replay_sightings(demo: Path, robot: str, filter_seed: int, render_seed: int, cache: Path | None,
                     overrides: dict | None = None
                     ) -> tuple[list[dict], list[tuple[float, float]], dict[int, int], list[int]]:
    """Replay the robot's run and judge every sighting after each turn on the spot (module docstring)."""
    start, config, truth, odometry, observer, slam = open_replay(demo, robot, filter_seed, render_seed, cache,
                                                                 overrides)
    turns = [(truth[a, 0], truth[b, 0]) for a, b in turns_on_the_spot(truth)]
    c0, s0 = np.cos(start[2]), np.sin(start[2])
    origin: dict[int, int] = {}          # landmark id -> true point of its first sighting
    born: dict[int, float] = {}          # landmark id -> time made
    first_camera: dict[int, np.ndarray] = {}   # landmark id -> true camera position (world) when it was made
    first_seen: dict[int, float] = {}    # true point -> time first observed
    confirmed_at: dict[int, float] = {}  # landmark id -> time it was first seen confirm_count times (any particle)
    unconfirmed: dict[int, int] = {}     # turn -> sightings of points seen before it with no confirmed landmark
    new_points: list[int] = []           # per reading of a point the best particle has no landmark of (after the
    #                                      first turn): how many of its landmarks pass the gate on position alone
    rows: list[dict] = []
    ox, oy, _ = config.sensor_offset
    for _, t, pose, world_pose, observations, index in predicted_frames(start, truth, odometry, observer, slam):
        store = slam.store
        kept = (slam.poses.copy(), slam._motion_cov.copy(), store.table.copy(), store.n_blocks.copy(),
                store.lid.copy(), store.state.copy())
        view_heading = float(slam.poses[slam._best, 2])   # the heading the association's views are taken at
        report = slam.update(observations)
        points = observer.points
        camera = world_pose[:2] + np.array([[np.cos(world_pose[2]), -np.sin(world_pose[2])],
                                            [np.sin(world_pose[2]), np.cos(world_pose[2])]]) @ np.array([ox, oy])
        for j in np.flatnonzero(report.new_landmark_ids >= 0):
            lid = int(report.new_landmark_ids[j])
            origin.setdefault(lid, int(index[j]))
            born.setdefault(lid, float(t))
            first_camera.setdefault(lid, camera)
        for point in index[index >= 0]:
            first_seen.setdefault(int(point), float(t))
        confirmed = np.unique(store.flat_lid[(store.flat_count >= config.confirm_count) & (store.flat_lid >= 0)])
        for lid in confirmed.tolist():
            confirmed_at.setdefault(lid, float(t))
        past = [k for k, (_, end) in enumerate(turns) if end < t]
        if not past:
            continue
        turn = past[-1]
        turn_start = turns[turn][0]
        poses, motion_cov, table, n_blocks, lid_table, state = kept
        best = int(slam._history[-1][2][slam._best])     # the update's best particle, before resampling
        slots = particle_slots(slam, table, n_blocks, lid_table, best)
        lids = lid_table.ravel()[slots]
        # the landmarks confirmed before the turn (anywhere), made from a sighting of a point within SAME of
        # this one; those the best particle holds, with their slots
        made = np.array([lid for lid in born if born[lid] < turn_start and confirmed_at.get(lid, np.inf) < turn_start
                         and lid in origin], np.int64)
        made_xyz = points[[origin[lid] for lid in made.tolist()]] if len(made) else np.zeros((0, 3))
        used = lid_table[np.unique(table[table >= 0])]        # blocks some particle references (not freed ones)
        alive_anywhere = set(np.unique(used[used >= 0]).tolist())
        slot_of = dict(zip(lids.tolist(), slots.tolist(), strict=True))
        z_all = np.asarray(observations.points, float)
        q_all = config.observation_cov_scale * np.asarray(observations.covariances, float) \
            + config.observation_var_floor * np.eye(3)
        desc = np.asarray(observations.descriptors, np.float32).reshape(len(z_all), config.descriptor_size)
        heading_error = float(wrap_angle(poses[best, 2] - pose[2]))
        best_mean = state.reshape(-1, 9)[slots, :3]
        best_cov = state.reshape(-1, 9)[slots, 3:][:, [0, 1, 2, 1, 3, 4, 2, 4, 5]].reshape(-1, 3, 3)
        held_xyz = points[[origin.get(lid, 0) for lid in lids.tolist()]] if len(lids) else np.zeros((0, 3))
        known = np.array([lid in origin for lid in lids.tolist()], bool)
        for j in np.flatnonzero((index >= 0) & (report.best_matches < 0)):
            # a reading the best particle made a new landmark of, of a point it holds no landmark of: would
            # position alone have matched it to some landmark (a wrong match)?
            p = int(index[j])
            if np.any(known & (np.linalg.norm(held_xyz - points[p], axis=1) < SAME)):
                continue
            d2_all = gate_d2_many(poses[best], motion_cov[best], z_all[j], q_all[j], best_mean, best_cov)
            new_points.append(int(np.count_nonzero(d2_all < config.mahalanobis_gate)))
        for j in np.flatnonzero(index >= 0):
            p = int(index[j])
            if first_seen[p] >= turn_start:
                continue
            row = {"t": float(t), "turn": turn, "point": p, "since_turn": float(t - turns[turn][1])}
            near = made[np.linalg.norm(made_xyz - points[p], axis=1) < SAME] if len(made) else made
            if len(near) == 0:
                unconfirmed[turn] = unconfirmed.get(turn, 0) + 1
                continue
            held = [lid for lid in near.tolist() if lid in slot_of]
            if not held:
                oldest = int(min(near.tolist(), key=lambda k: born[k]))
                ratio, angle = view_change(points[p][:2], camera, first_camera[oldest])
                rows.append({**row, "reason": "gone" if not alive_anywhere & set(near.tolist()) else "elsewhere",
                             "lid": oldest, "range_ratio": ratio, "view_angle": angle})
                continue
            lid = min(held, key=lambda k: born[k])
            slot = slot_of[lid]
            went = int(report.best_matches[j])
            mean = state.reshape(-1, 9)[slot, :3]
            cov6 = state.reshape(-1, 9)[slot, 3:]
            cov = cov6[[0, 1, 2, 1, 3, 4, 2, 4, 5]].reshape(3, 3)
            d2 = gate_d2(poses[best], motion_cov[best], z_all[j], q_all[j], mean, cov)
            dd = descriptor_distance(slam, lid, desc[j], z_all[j], view_heading)
            if slam._bands is not None:   # the looks the landmark keeps, and how far the nearest is in direction
                row |= kept_looks(slam, lid, z_all[j], view_heading)
            went_same = went in origin and np.linalg.norm(points[origin[went]] - points[p]) < SAME
            if not dd < config.descriptor_threshold:   # what position alone would choose among the particle's
                d2_all = gate_d2_many(poses[best], motion_cov[best], z_all[j], q_all[j], best_mean, best_cov)
                inside = np.flatnonzero(d2_all < config.mahalanobis_gate)
                nearest = int(lids[inside[np.argmin(d2_all[inside])]]) if len(inside) else -1
                row |= {"position_gated": len(inside), "position_right": int(nearest in held)}
            true_world = points[p]
            true_start = np.array([c0 * (true_world[0] - start[0]) + s0 * (true_world[1] - start[1]),
                                   -s0 * (true_world[0] - start[0]) + c0 * (true_world[1] - start[1])])
            ratio, angle = view_change(true_world[:2], camera, first_camera[lid])
            # the landmark's offset across the line of sight, as the particle sees it (what a heading error moves)
            c, s = np.cos(poses[best, 2]), np.sin(poses[best, 2])
            seen = np.array([c * z_all[j, 0] - s * z_all[j, 1], s * z_all[j, 0] + c * z_all[j, 1]]) + poses[best, :2]
            sight = seen - poses[best, :2]
            unit, off = sight / max(np.linalg.norm(sight), 1e-9), mean[:2] - seen
            lateral = float(unit[0] * off[1] - unit[1] * off[0])
            rows.append({**row, "lid": lid, "reason": sighting_reason(
                went in held, dd, d2, went_same, config.descriptor_threshold,
                config.mahalanobis_gate),
                "range_ratio": ratio, "view_angle": angle,
                "heading_error": heading_error, "landmark_error": float(np.linalg.norm(mean[:2] - true_start)),
                "lateral_offset": lateral, "d2": d2, "descriptor_distance": dd,
                "pose_sigma_theta": float(np.sqrt(max(report.pose_covariance[2, 2], 0.0)))})
    merged_away = {newer for _, newer, _ in slam.merged_pairs}
    for r in rows:   # a landmark no particle holds any more: merged into another id, or removed by its misses
        if r["reason"] == "gone":
            r["gone_by"] = "merged" if r["lid"] in merged_away else "removed"
    save_frames(observer, cache)
    return rows, turns, unconfirmed, new_points


def _median(rows: list[dict], key: str) -> str:
    values = [r[key] for r in rows if key in r]
    return f"{np.median(values):.2f}" if values else "–"


def _counts(rows: list[dict]) -> str:
    n = max(len(rows), 1)
    return " | ".join(f"{c} ({100 * c / n:.0f} %)" for c in (sum(r["reason"] == k for r in rows) for k in REASONS))


def print_table(rows: list[dict], turns: list[tuple[float, float]], unconfirmed: dict[int, int], label: str,
                early: float = 3.0) -> None:
    print(f"## {label}: sightings of points with a landmark confirmed before the last turn on the spot, by the "
          "association's refusal")
    print("| turn (s) | no confirmed landmark | sightings | " + " | ".join(REASONS) + " | first "
          f"{early:g} s: matched / judged | median range ratio / view angle (rad) of descriptor-refused | median d² / "
          "lateral offset (m) / heading error (rad) of gate-refused |")
    print("|---|---|---|" + "---|" * len(REASONS) + "---|---|---|")
    for k, (a, b) in enumerate(turns):
        sel = [r for r in rows if r["turn"] == k]
        if not sel and not unconfirmed.get(k):
            continue
        desc = [r for r in sel if r["reason"] == "descriptor"]
        gate = [r for r in sel if r["reason"] == "gate"]
        first = [r for r in sel if r["since_turn"] <= early]
        print(f"| {a:.1f}–{b:.1f} | {unconfirmed.get(k, 0)} | {len(sel)} | {_counts(sel)} | "
              f"{sum(r['reason'] == 'matched' for r in first)} / {len(first)} | {_median(desc, 'range_ratio')} / "
              f"{_median(desc, 'view_angle')} | {_median(gate, 'd2')} / {_median(gate, 'lateral_offset')} / "
              f"{_median(gate, 'heading_error')} |")
    counts = [sum(r["reason"] == name for r in rows) for name in REASONS]
    total = max(len(rows), 1)
    print(f"all: {len(rows)} sightings; " + ", ".join(f"{n} {c} ({100 * c / total:.1f} %)"
                                                     for n, c in zip(REASONS, counts, strict=True)))
    for name in ("matched", "descriptor", "gate", "duplicate", "other"):
        sel = [r for r in rows if r["reason"] == name]
        if sel:
            print(f"  {name}: median range ratio {_median(sel, 'range_ratio')}, view angle {_median(sel, 'view_angle')}"
                  f" rad, descriptor distance {_median(sel, 'descriptor_distance')}, d² {_median(sel, 'd2')}, "
                  f"|heading error| {np.median([abs(r['heading_error']) for r in sel]):.3f} rad, landmark error "
                  f"{_median(sel, 'landmark_error')} m")
    with_looks = [r for r in rows if "looks" in r and r["reason"] in ("matched", "descriptor")]
    if with_looks:
        print("  looks kept (descriptor_slots > 1), matched / descriptor-refused sightings:")
        for name in ("matched", "descriptor"):
            sel = [r for r in with_looks if r["reason"] == name]
            looks = np.array([r["looks"] for r in sel])
            angle = np.array([r["nearest_look_angle"] for r in sel])
            if len(sel):
                print(f"    {name}: landmarks with 1 / 2–3 / 4+ looks {np.sum(looks == 1)} / "
                      f"{np.sum((looks >= 2) & (looks <= 3))} / {np.sum(looks >= 4)}; median angle to the nearest "
                      f"look {np.nanmedian(angle):.2f} rad (first look {_median(sel, 'view_angle')}), nearest look "
                      f"< 0.1 / 0.1–0.3 / > 0.3 rad: {np.sum(angle < 0.1)} / {np.sum((angle >= 0.1) & (angle < 0.3))}"
                      f" / {np.sum(angle >= 0.3)}")
    gone = [r for r in rows if r["reason"] == "gone"]
    if gone:
        merged = sum(r["gone_by"] == "merged" for r in gone)
        print(f"  gone: {len(gone) - merged} removed by misses, {merged} merged into another id; view angle to the "
              f"landmark's first sighting < 0.1 / 0.1–0.3 / > 0.3 rad: {sum(r['view_angle'] < 0.1 for r in gone)} / "
              f"{sum(0.1 <= r['view_angle'] < 0.3 for r in gone)} / {sum(r['view_angle'] >= 0.3 for r in gone)}")
    judged = [r for r in rows if "view_angle" in r and r["reason"] in ("matched", "descriptor")]
    print("  descriptor refusals among sightings matched or refused by descriptor, by the change of view:")
    for lo, hi in ((0.0, 0.1), (0.1, 0.3), (0.3, 0.6), (0.6, 1.0), (1.0, np.pi)):
        sel = [r for r in judged if lo <= r["view_angle"] < hi]
        refused = sum(r["reason"] == "descriptor" for r in sel)
        print(f"    view angle {lo:.1f}–{hi:.1f} rad: {refused} of {len(sel)} "
              f"({100 * refused / max(len(sel), 1):.0f} %)")
    for lo, hi in ((0.0, 0.67), (0.67, 0.83), (0.83, 1.2), (1.2, 1.5), (1.5, np.inf)):
        sel = [r for r in judged if lo <= r["range_ratio"] < hi and r["view_angle"] < 0.3]
        refused = sum(r["reason"] == "descriptor" for r in sel)
        print(f"    range ratio {lo:.2f}–{hi:.2f} (view angle < 0.3 rad): {refused} of {len(sel)} "
              f"({100 * refused / max(len(sel), 1):.0f} %)")


def print_position_only(rows: list[dict], new_points: list[int]) -> None:
    """What an association on position alone (the gate, no descriptor) would do where the descriptor refused."""
    refused = [r for r in rows if "position_gated" in r and r["reason"] == "descriptor"]
    if not refused:
        return
    gated = np.array([r["position_gated"] for r in refused])
    right = np.array([r["position_right"] for r in refused], bool)
    print(f"  position alone, on the {len(refused)} descriptor-refused sightings: landmarks in the gate 0 / 1 / 2+: "
          f"{np.sum(gated == 0)} / {np.sum(gated == 1)} / {np.sum(gated >= 2)}; the nearest is the pre-turn "
          f"landmark in {right.sum()} ({100 * right.mean():.0f} %), and is it with a unique candidate in "
          f"{np.sum(right & (gated == 1))}")
    new = np.array(new_points)
    if len(new):
        print(f"  position alone, on the {len(new)} readings of points the best particle holds no landmark of (made "
              f"new today): some landmark in the gate {np.sum(new >= 1)} ({100 * np.mean(new >= 1):.0f} %), exactly "
              f"one {np.sum(new == 1)} ({100 * np.mean(new == 1):.0f} %): wrong matches")


def write_csv(rows: list[dict], path: Path) -> None:
    """Every judged sighting, one row each (empty cells for ``gone``), written atomically."""
    lines = [",".join(FIELDS)]
    for r in rows:
        lines.append(",".join(str(r.get(k, "")) for k in FIELDS))
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, ("\n".join(lines) + "\n").encode())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_replay_arguments(parser)
    parser.add_argument("--set", dest="settings", action="append", default=[], metavar="KEY=VALUE",
                        help="a FastSLAM setting over the demo's, e.g. descriptor_slots=4")
    parser.add_argument("--sightings", type=Path, default=None, metavar="FILE.csv",
                        help="write every judged sighting to this CSV file")
    args = parser.parse_args(argv)
    for name in (f"{args.robot}.npz", f"{args.robot}-truth.tum", f"{args.robot}-odometry.tum"):
        if not (args.demo / name).is_file():
            raise SystemExit(f"{args.demo}: no {name} (a `p3at demo --out` folder of a mock run is needed)")
    cv2.setNumThreads(1)
    rows, turns, unconfirmed, new_points = replay_sightings(args.demo, args.robot, args.filter_seed, args.render_seed,
                                                args.frames_cache, config_overrides(args.settings))
    print_table(rows, turns, unconfirmed, f"{args.demo} {args.robot}")
    print_position_only(rows, new_points)
    if args.sightings is not None:
        write_csv(rows, args.sightings)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
