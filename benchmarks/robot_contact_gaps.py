"""How close the demo's robots came: the smallest body-to-body gap over a finished demo's true trajectories.

For each demo folder (``p3at demo --seed S --out DIR``: ``robotK-truth.tum`` in each robot's start frame, the start
poses in the maps' ``true_start_pose``) every pair of robots' true poses are put in the world frame, interpolated
on a common grid (``--step``, default 10 ms: the physics step; x, y linearly, θ unwrapped) and compared three ways:
the distance between centres; the gap between two discs of ``--radius`` (FirmwareDefaults.collision_radius_m,
0.33 m: the robot-robot contact the mock had before session 12); and the gap between the bodies as the
oriented rectangles ``--length`` x ``--width`` (0.626 x 0.505 m, the P3-AT's, ``mocks.world.footprint_gap``).
A gap <= 0 is a contact (< 0 the bodies overlap). ``held`` counts the grid points at which the disc gap was within
``--held`` (5 mm) of zero: a robot pressed against the other's disc, i.e. a disc contact that happened.

The truth files are sampled at the camera's frames (every 0.27 s at 3.75 Hz), so the interpolated path between
samples is a straight line: the printed minimum is within a few millimetres of the true one for these speeds.

    .venv/bin/python -m benchmarks.robot_contact_gaps /tmp/r11/base-s0 /tmp/r11/base-s1 ...
"""
from __future__ import annotations

import argparse
import itertools
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from estimation.landmark_map import LandmarkMap  # noqa: E402
from mocks.world import footprint_gap  # noqa: E402
from runtime.commands.options import non_negative_float, positive_float  # noqa: E402
from runtime.trajectories import planar, read_tum  # noqa: E402


def world_track(folder: Path, robot: str) -> np.ndarray:
    """(T, 4) t, x, y, θ of ``robot``'s true trajectory in the world frame (θ unwrapped)."""
    start = np.asarray(LandmarkMap.load(folder / f"{robot}.npz").metadata["true_start_pose"], float)
    rows = planar(read_tum(folder / f"{robot}-truth.tum"))
    c, s = np.cos(start[2]), np.sin(start[2])
    x = start[0] + c * rows[:, 1] - s * rows[:, 2]
    y = start[1] + s * rows[:, 1] + c * rows[:, 2]
    return np.column_stack([rows[:, 0], x, y, np.unwrap(rows[:, 3] + start[2])])


def pair_gaps(a: np.ndarray, b: np.ndarray, step: float, radius: float, size: tuple[float, float],
              held: float) -> dict:
    t0, t1 = max(a[0, 0], b[0, 0]), min(a[-1, 0], b[-1, 0])
    if t1 <= t0:
        return {"overlap_s": 0.0}
    t = np.arange(t0, t1 + 1e-9, step)
    pa = np.column_stack([np.interp(t, a[:, 0], a[:, k]) for k in (1, 2, 3)])
    pb = np.column_stack([np.interp(t, b[:, 0], b[:, k]) for k in (1, 2, 3)])
    centre = np.hypot(pa[:, 0] - pb[:, 0], pa[:, 1] - pb[:, 1])
    disc = centre - 2.0 * radius
    # the rectangles only where they could touch (centres within the two half-diagonals)
    reach = 2.0 * float(np.hypot(size[0], size[1])) / 2.0
    body = np.full(len(t), np.inf)
    for i in np.flatnonzero(centre <= reach + 0.01):
        body[i] = footprint_gap(pa[i], size, pb[i], size)
    if not np.isfinite(body).any():  # never near: the body gap is at least the centres' distance minus the reach
        body = centre - reach
    k, j = int(np.argmin(centre)), int(np.argmin(body))
    return {"overlap_s": float(t1 - t0), "min_centre_m": float(centre[k]), "at_centre_s": float(t[k]),
            "min_disc_gap_m": float(disc.min()), "min_body_gap_m": float(body[j]), "at_body_s": float(t[j]),
            "body_contacts": int(np.sum(body <= 0.0)), "disc_held": int(np.sum(np.abs(disc) <= held)),
            "poses_at_body_min": [pa[j].round(3).tolist(), pb[j].round(3).tolist()]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("demos", nargs="+", type=Path, help="demo output folders")
    parser.add_argument("--step", type=positive_float, default=0.01, help="interpolation step, s (default 0.01)")
    parser.add_argument("--radius", type=positive_float, default=0.33, help="the disc's radius, m (default 0.33)")
    parser.add_argument("--length", type=positive_float, default=0.626, help="body length, m (default 0.626)")
    parser.add_argument("--width", type=positive_float, default=0.505, help="body width, m (default 0.505)")
    parser.add_argument("--held", type=non_negative_float, default=0.005, help="a disc gap within this is contact, m")
    args = parser.parse_args(argv)
    size = (args.length, args.width)
    print(f"{'demo':<22} {'pair':<16} {'min centre (m) at s':<22} {'min disc gap':>12} {'held':>5} "
          f"{'min body gap (m) at s':<24} {'body<=0':>7}")
    worst = np.inf
    for folder in args.demos:
        robots = sorted(p.name[: -len("-truth.tum")] for p in folder.glob("*-truth.tum"))
        tracks = {r: world_track(folder, r) for r in robots}
        for ra, rb in itertools.combinations(robots, 2):
            g = pair_gaps(tracks[ra], tracks[rb], args.step, args.radius, size, args.held)
            if g["overlap_s"] == 0.0:
                print(f"{folder.name:<22} {ra}-{rb:<9} never at once")
                continue
            worst = min(worst, g["min_body_gap_m"])
            print(f"{folder.name:<22} {ra + '-' + rb:<16} {g['min_centre_m']:7.3f} at {g['at_centre_s']:7.2f}    "
                  f"{g['min_disc_gap_m']:12.3f} {g['disc_held']:5d} {g['min_body_gap_m']:9.3f} at "
                  f"{g['at_body_s']:7.2f}     {g['body_contacts']:7d}   poses {g['poses_at_body_min']}")
    print(f"smallest body-to-body gap over all: {worst:.3f} m")
    return 0


if __name__ == "__main__":
    sys.exit(main())
