"""Why a rendered demo's alignment misses the truth: each map's frame error, where and when it was made.

Run from the repository root, on ``p3at demo --seed S --out DIR`` folders (robot1.npz, robot2.npz and the TUM files):

    OPENBLAS_NUM_THREADS=1 .venv/bin/python -m benchmarks.demo_frame_errors DIR [DIR ...] [--windows] [--legs]

A map's *frame error* is where its landmarks sit against its robot's true start frame. A map is not one rigid body:
landmarks made at different times carry the robot's pose error of that time (the drift). Printed:

``alignment`` (one row per folder): the robust alignment of the two final maps against the true relative start;
  the best alignment of the two maps' *overlaps* against the truth (each map's landmarks within ``--overlap-radius``
  of its supports that lie within 0.15 m of a true feature, fitted rigidly to those features in the map's true start
  frame, the two fits composed: what a perfect alignment of these maps gives, and its error is the maps' frame error
  where they overlap) and the alignment against it (``own``); per map, its heading error e (its trajectory against
  the truth) when it made the supports, the drift tracker's heading σ there and |e| in those σ, the supports' median
  creation time and how many were made with σθ ≤ 0.01 rad; e₁ − e₂ beside the alignment's signed θ error (a map
  turned by e about its start turns the alignment by e₁ − e₂); map 2's landmarks made with σθ ≤ 0.01 rad and how many
  true features they share with map 1 (does map 2's well-framed part overlap map 1 at all?); the alignment's
  start-frame 1σ (``Alignment.start_covariance``) and its NEES (χ²₃, 95 % bound 7.81) against the truth; and, for step
  (a) of the question, the supports refitted by generalised least squares with each map's landmarks *correlated* by
  the drift they share (the chain model of ``fusion.shape_covariance``: two landmarks share the drift of the one made
  with the smaller drift), which lets landmarks made near a start pin that map's frame.
``--windows``: per map, the rigid fit of its on-feature landmarks grouped by creation time (when the frame went off).
``--legs``: per map, the heading error of the map's own trajectory (the best particle's ancestry, ``trajectory``)
  over each stretch between turns on the spot (median, a second off each end), the turns on the spot (time, angle
  turned, the largest heading error inside), and the odometry's and the map's heading error per radian of net turn
  (a turn-scale bias in the odometry would show in the map as a slope).

Creation time of a landmark: the time of the trajectory's pose nearest to its drift origin (where the robot was when
it made it), made non-decreasing in the landmark's id (ids are issued in order).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from eval_fusion import _feature_fit  # noqa: E402
from fusion_sim import load_world  # noqa: E402

from estimation.geometry import between, compose, inverse, transform_points, wrap_angle  # noqa: E402
from estimation.landmark_map import LandmarkMap  # noqa: E402
from estimation.landmark_scores import rigid_fit_2d  # noqa: E402
from fusion.alignment import align, alignment_error, true_relative_pose  # noqa: E402
from fusion.shape_covariance import _lever, _psd  # noqa: E402  (the chain model's lever and PSD floor)
from runtime.commands.options import non_negative_float, positive_float  # noqa: E402
from runtime.trajectories import planar, read_tum  # noqa: E402

FEATURE_RADIUS = 0.15          # m: a landmark this close to a true feature (after the map's fit) stands for it
WINDOW_EDGES = (0, 10, 20, 30, 45, 60, 80, 100, 120, 1e9)     # s: creation-time windows of --windows
STEADY_SIGMA = 0.01            # rad: supports made while the map's heading σ was at most this (the goal's θ) counted


def creation_times(m: LandmarkMap) -> np.ndarray:
    """(N,) s: each landmark's creation time, from its drift origin and the map's trajectory (module docstring)."""
    if len(m) == 0 or m.drift_origins is None or len(m.trajectory) == 0:
        return np.full(len(m), np.nan)
    tr = m.trajectory
    d2 = (m.drift_origins[:, None, 0] - tr[None, :, 1]) ** 2 + (m.drift_origins[:, None, 1] - tr[None, :, 2]) ** 2
    t = tr[np.argmin(d2, axis=1), 0]
    order = np.argsort(m.ids, kind="stable")
    out = np.empty(len(m))
    out[order] = np.maximum.accumulate(_running_median(t[order], 9))
    return out


def _running_median(x: np.ndarray, size: int) -> np.ndarray:
    h = size // 2
    padded = np.concatenate([np.full(h, x[0]), x, np.full(h, x[-1])])
    return np.median(np.lib.stride_tricks.sliding_window_view(padded, size), axis=1)


def on_features(m: LandmarkMap, features: np.ndarray, fit: np.ndarray, rows: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """The rows (of ``rows``, default all) whose landmark lies within FEATURE_RADIUS of a true feature after the map's
    fit ``fit`` (world frame), and those features (K, 3) in the world."""
    rows = np.arange(len(m)) if rows is None else np.asarray(rows)
    d, k = cKDTree(features).query(transform_points(fit, m.positions[rows]), distance_upper_bound=FEATURE_RADIUS)
    ok = np.isfinite(d)
    return rows[ok], features[k[ok]]


def frame_error(positions: np.ndarray, true_in_start: np.ndarray) -> np.ndarray:
    """(dx, dy, dθ): the rigid motion that carries the map's landmarks (K, ≥2) onto their true places in the true
    start frame (K, ≥2); zero for a map in its start frame. Its θ is minus the map's heading error there."""
    return rigid_fit_2d(np.asarray(positions)[:, :2], np.asarray(true_in_start)[:, :2])


def windowed_frame_errors(positions, true_in_start, times, edges=WINDOW_EDGES, least: int = 4):
    """[(t0, t1, n, (dx, dy, dθ))] per creation-time window holding at least ``least`` landmarks."""
    out = []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        w = (times >= a) & (times < b)
        if w.sum() >= least:
            out.append((a, b, int(w.sum()), frame_error(positions[w], true_in_start[w])))
    return out


def turns_on_the_spot(rows: np.ndarray, max_speed: float = 0.04, min_rate: float = 0.2, min_duration: float = 1.0
                      ) -> list[tuple[int, int]]:
    """(first, last) frame indices of the stretches where the true trajectory (T, 4: t, x, y, θ) turns at
    ≥ ``min_rate`` rad/s while moving < ``max_speed`` m/s, for at least ``min_duration`` s."""
    rows = np.asarray(rows, float)
    dt = np.maximum(np.diff(rows[:, 0]), 1e-9)
    speed = np.r_[0.0, np.hypot(*np.diff(rows[:, 1:3], axis=0).T) / dt]
    rate = np.r_[0.0, np.abs(wrap_angle(np.diff(rows[:, 3]))) / dt]
    mask = (speed < max_speed) & (rate >= min_rate)
    out, start = [], None
    for k, v in enumerate(np.r_[mask, False]):
        if v and start is None:
            start = k
        elif not v and start is not None:
            if rows[k - 1, 0] - rows[start, 0] >= min_duration:
                out.append((start, k - 1))
            start = None
    return out


def drift_covariance_of_supports(m: LandmarkMap, rows: np.ndarray, floor: float) -> np.ndarray:
    """(2K, 2K): the planar errors of landmarks ``rows`` of one map, correlated through the drift they share (the
    chain model of fusion.shape_covariance: a pair shares the drift D_e of the one made with the smaller drift,
    carried to each by its lever about e's origin), plus each one's local part and ``floor``² (independent)."""
    x = m.positions[rows, :2]
    D, o = m.drift_covariances[rows], m.drift_origins[rows]
    C = _lever(x, o) @ D @ np.swapaxes(_lever(x, o), 1, 2)
    local = _psd(m.covariances[rows, :2, :2] - C, 0.0)
    tr = np.trace(D, axis1=1, axis2=2)
    n = len(rows)
    e = np.where(tr[:, None] <= tr[None, :], np.arange(n)[:, None], np.arange(n)[None, :])   # (n, n) the pair's
    Ha = _lever(x[:, None, :], o[e])                                                           # smaller drift
    Hb = _lever(x[None, :, :], o[e])
    blocks = Ha @ D[e] @ np.swapaxes(Hb, -1, -2)                                               # (n, n, 2, 2)
    idx = np.arange(n)
    blocks[idx, idx] = C + local + floor ** 2 * np.eye(2)
    K = blocks.transpose(0, 2, 1, 3).reshape(2 * n, 2 * n)
    return _psd(K, 1e-12)


def gls_alignment(m1: LandmarkMap, m2: LandmarkMap, supports: np.ndarray, pose, floor: float = 0.02,
                  iterations: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """The relative pose of the two start frames from the supports (K, 2: rows of map 1, map 2) by generalised least
    squares: residual r = p1 − (R p2 + t), Cov r = K1 + R K2 Rᵀ with K1, K2 each map's supports' joint covariance
    (:func:`drift_covariance_of_supports`, the floor split between the maps). Gauss–Newton from ``pose``. Returns the
    pose (3,) and its covariance (JᵀWJ)⁻¹ (3, 3)."""
    i, j = np.asarray(supports)[:, 0], np.asarray(supports)[:, 1]
    K1 = drift_covariance_of_supports(m1, i, floor / np.sqrt(2))
    K2 = drift_covariance_of_supports(m2, j, floor / np.sqrt(2))
    x1, x2 = m1.positions[i, :2], m2.positions[j, :2]
    pose = np.asarray(pose, float).copy()
    H = np.eye(3)
    for _ in range(iterations):
        c, s = np.cos(pose[2]), np.sin(pose[2])
        R = np.array([[c, -s], [s, c]])
        q = x2 @ R.T
        r = (x1 - q - pose[:2]).ravel()
        J = np.zeros((len(i), 2, 3))
        J[:, 0, 0] = J[:, 1, 1] = 1.0
        J[:, 0, 2], J[:, 1, 2] = -q[:, 1], q[:, 0]
        J = J.reshape(-1, 3)
        RR = np.kron(np.eye(len(i)), R)
        W = np.linalg.inv(K1 + RR @ K2 @ RR.T)
        H = J.T @ W @ J
        step = np.linalg.solve(H, J.T @ W @ r)
        pose += step
        pose[2] = wrap_angle(pose[2])
        if np.max(np.abs(step)) < 1e-10:
            break
    cov = np.linalg.inv(H)
    return pose, 0.5 * (cov + cov.T)


def nees3(pose, covariance, truth) -> float:
    d = np.asarray(pose, float) - np.asarray(truth, float)
    d[2] = wrap_angle(d[2])
    return float(d @ np.linalg.solve(covariance, d))


def _xy_th(e) -> str:
    return f"{np.hypot(e[0], e[1]):.3f} / {abs(e[2]):.4f}"


def _map_truth(folder: Path, m: LandmarkMap) -> tuple[np.ndarray, np.ndarray]:
    """The map's trajectory and the true one on the same frames, both (T, 4) t, x, y, θ in the start frame."""
    truth = planar(read_tum(folder / f"{m.robot}-truth.tum"))
    traj = m.trajectory
    k = np.searchsorted(traj[:, 0], truth[:, 0])
    ok = (k < len(traj)) & (np.abs(traj[np.minimum(k, len(traj) - 1), 0] - truth[:, 0]) < 1e-6)
    return traj[k[ok]], truth[ok]


def overlap_frame(m: LandmarkMap, features: np.ndarray, rows: np.ndarray, radius: float
                  ) -> tuple[np.ndarray, int]:
    """Map ``m``'s frame where it overlaps the other map: the rigid fit, to the true features in the true start frame,
    of its on-feature landmarks within ``radius`` m of one of its supports ``rows``, composed with the true start
    (a world pose, (3,)), and how many landmarks it rests on."""
    start = np.asarray(m.metadata["true_start_pose"], float)
    near = np.flatnonzero(cKDTree(m.positions[rows, :2]).query(m.positions[:, :2])[0] <= radius)
    on, feats = on_features(m, features, _feature_fit(m, features)[0], near)
    if len(on) < 3:
        return np.full(3, np.nan), len(on)
    return compose(start, frame_error(m.positions[on], transform_points(inverse(start), feats))), len(on)


def alignment_rows(folders: list[Path], floor: float, radius: float) -> None:
    world = load_world()
    print("\n### The alignment against the truth, and each map's frame error where the maps overlap\n")
    print(f"Overlap: each map's landmarks within {radius:g} m of a support that lie on a true feature, fitted to those "
          "features in the map's true start frame; their composition is the best alignment of the two overlaps, and "
          "against the truth it is the maps' frame error there ('own' = the alignment against it). e: a map's heading "
          "error (its trajectory against the truth) when it made the supports (median over them), with its heading σ "
          "there (drift tracker), |e| in those σ, the supports' median creation time and how many were made with "
          f"σθ ≤ {STEADY_SIGMA} rad. A map turned by e about its start turns the alignment by e₁ − e₂. Early: map 2's "
          f"landmarks made with σθ ≤ {STEADY_SIGMA} rad (how many on true features), and how many true features they "
          "share with map 1's on-feature landmarks (whether map 2's well-framed part overlaps map 1 at all).\n")
    print("| run | supports | error vs truth xy (m) / θ (rad) | best alignment of the overlaps vs truth (landmarks) | "
          "own | map 1: e mrad (σθ, z; made at; steady) | map 2: e mrad (σθ, z; made at; steady) | e₁ − e₂ vs "
          "signed θ error (mrad) | map 2 early: landmarks; true features shared with map 1 | start-frame 1σ xy / θ "
          "(NEES) | GLS, correlated drift: vs truth (NEES) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for folder in folders:
        m1, m2 = LandmarkMap.load(folder / "robot1.npz"), LandmarkMap.load(folder / "robot2.npz")
        truth = true_relative_pose(m1, m2)
        a = align(m1, m2, "robust", np.random.default_rng(0))
        if not a.found:
            print(f"| {folder.name} | {len(a.supports)} | not found: {a.reason.split(';')[0][:90]} |"
                  + " |" * 8)
            continue
        frames, counts, cells, heading = [], [], [], []
        for m, rows in ((m1, a.supports[:, 0]), (m2, a.supports[:, 1])):
            frame, n_on = overlap_frame(m, world.features, rows, radius)
            frames.append(frame)
            counts.append(n_on)
            made = creation_times(m)[rows]
            traj, truth_rows = _map_truth(folder, m)
            k = np.clip(np.searchsorted(truth_rows[:, 0], made), 0, len(truth_rows) - 1)
            heading.append(float(np.median(wrap_angle(traj[k, 3] - truth_rows[k, 3]))))
            if m.drift_covariances is None:
                cells.append(f"{1000 * heading[-1]:+.0f} (no drift in the file; {np.nanmedian(made):.0f} s)")
                continue
            sig_rows = np.sqrt(m.drift_covariances[rows, 2, 2])
            sig = float(np.median(sig_rows))
            cells.append(f"{1000 * heading[-1]:+.0f} ({sig:.4f}, {abs(heading[-1]) / sig:.1f}; "
                         f"{np.nanmedian(made):.0f} s; {int(np.sum(sig_rows <= STEADY_SIGMA))})")
        best = between(*frames)
        sc = a.start_covariance
        start_txt = (f"{np.sqrt(sc[0, 0] + sc[1, 1]):.3f} / {np.sqrt(sc[2, 2]):.4f} ({nees3(a.pose, sc, truth):.1f})"
                     if sc is not None else "–")
        early_txt, gls_txt = "–", "– (no drift in the files)"
        if m1.drift_covariances is not None and m2.drift_covariances is not None:
            g, gc = gls_alignment(m1, m2, a.supports, a.pose, floor)
            gls_txt = f"{_xy_th(alignment_error(g, truth))} ({nees3(g, gc, truth):.1f})"
            early = np.flatnonzero(np.sqrt(m2.drift_covariances[:, 2, 2]) <= STEADY_SIGMA)
            e_on, e_feats = on_features(m2, world.features, _feature_fit(m2, world.features)[0], early)
            _, m1_feats = on_features(m1, world.features, _feature_fit(m1, world.features)[0])
            shared = {tuple(f) for f in np.round(e_feats, 6)} & {tuple(f) for f in np.round(m1_feats, 6)}
            early_txt = f"{len(early)} ({len(e_on)} on features); {len(shared)}"
        signed = wrap_angle(a.pose[2] - truth[2])
        print(f"| {folder.name} | {len(a.supports)} | {_xy_th(alignment_error(a.pose, truth))} | "
              f"{_xy_th(alignment_error(best, truth))} ({counts[0]} / {counts[1]}) | "
              f"{_xy_th(alignment_error(a.pose, best))} | {cells[0]} | {cells[1]} | "
              f"{1000 * (heading[0] - heading[1]):+.1f} vs {1000 * signed:+.1f} | {early_txt} | {start_txt} | "
              f"{gls_txt} |")


def window_rows(folders: list[Path]) -> None:
    world = load_world()
    print("\n### Each map's frame error by the landmarks' creation time (landmarks on true features)\n")
    print("| run | robot | whole map dx, dy, dθ | by creation window: t0–t1 s (landmarks) dθ |")
    print("|---|---|---|---|")
    for folder in folders:
        for name in ("robot1", "robot2"):
            m = LandmarkMap.load(folder / f"{name}.npz")
            start = np.asarray(m.metadata["true_start_pose"], float)
            fit = _feature_fit(m, world.features)[0]
            on, feats = on_features(m, world.features, fit)
            q = transform_points(inverse(start), feats)
            whole = frame_error(m.positions[on], q)
            parts = windowed_frame_errors(m.positions[on], q, creation_times(m)[on])
            text = "; ".join(f"{a:.0f}–{b if b < 1e8 else 'end'} ({n}) {f[2]:+.4f}" for a, b, n, f in parts)
            print(f"| {folder.name} | {name} | {whole[0]:+.3f}, {whole[1]:+.3f}, {whole[2]:+.4f} | {text} |")


def leg_rows(folders: list[Path]) -> None:
    print("\n### Each map's heading error along its run (mrad; the map's own trajectory against the truth)\n")
    print("| run | robot | each stretch between turns on the spot: [t0–t1 s] median error | turns on the "
          "spot: t s, turned rad, largest error inside | odometry / map heading error per rad of net turn |")
    print("|---|---|---|---|---|")
    for folder in folders:
        for name in ("robot1", "robot2"):
            m = LandmarkMap.load(folder / f"{name}.npz")
            traj, truth = _map_truth(folder, m)
            odo = planar(read_tum(folder / f"{name}-odometry.tum"))
            odo = odo[np.isin(odo[:, 0], truth[:, 0])]
            t = truth[:, 0]
            err = 1000 * wrap_angle(traj[:, 3] - truth[:, 3])
            turns = turns_on_the_spot(truth)
            bounds = [0] + [k for a, b in turns for k in (a, b)] + [len(t) - 1]
            legs = []
            for a, b in zip(bounds[0::2], bounds[1::2], strict=True):
                inner = (t >= t[a] + 1.0) & (t <= t[b] - 1.0)     # a second off each turn's ends
                if t[b] - t[a] >= 3.0:
                    legs.append(f"[{t[a]:.0f}–{t[b]:.0f}] {np.median(err[inner]):+.0f}")
            turned = [f"{t[a]:.0f} s, {np.sum(np.abs(wrap_angle(np.diff(truth[a:b + 1, 3])))):.1f}, "
                      f"{err[a:b + 1][np.argmax(np.abs(err[a:b + 1]))]:+.0f}" for a, b in turns]
            net = np.unwrap(truth[:, 3]) - truth[0, 3]
            n = min(len(odo), len(net))
            slope_odo = np.polyfit(net[:n], np.unwrap(odo[:n, 3]) - np.unwrap(truth[:n, 3]), 1)[0]
            slope_map = np.polyfit(net, err / 1000, 1)[0]
            print(f"| {folder.name} | {name} | {'  '.join(legs)} | {'; '.join(turned)} | "
                  f"{slope_odo:+.4f} / {slope_map:+.4f} |")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folders", nargs="+", type=Path, help="p3at demo output folders")
    parser.add_argument("--windows", action="store_true", help="each map's frame error by creation time")
    parser.add_argument("--legs", action="store_true", help="each map's heading error along its run")
    parser.add_argument("--overlap-radius", type=positive_float, default=1.0,
                        help="m, a map's landmarks this close to one of its supports make its overlap (default 1)")
    parser.add_argument("--floor", type=non_negative_float, default=0.02,
                        help="m, the position floor of the GLS refit (default 0.02, the robust preset's)")
    args = parser.parse_args(argv)
    for f in args.folders:
        if not (f / "robot1.npz").is_file() or not (f / "robot2.npz").is_file():
            parser.error(f"{f}: no robot1.npz / robot2.npz (a p3at demo --out folder)")
    alignment_rows(args.folders, args.floor, args.overlap_radius)
    if args.windows:
        window_rows(args.folders)
    if args.legs:
        leg_rows(args.folders)
    return 0


if __name__ == "__main__":
    sys.exit(main())
