"""Sonar rings gathered over odometry land on the walls they saw, in the frame of the anchor pose."""
from __future__ import annotations

import numpy as np
import pytest

from estimation.geometry import between, compose
from estimation.scanmatch import ScanMatchError, match_scans, sonar_scan
from estimation.scanmatch.common import apply_pose

# An eight-transducer front ring (x, y, heading) in the robot frame, P3-AT-like.
RING = np.array([[0.147, 0.136, np.radians(90)], [0.193, 0.119, np.radians(50)], [0.227, 0.079, np.radians(30)],
                 [0.245, 0.027, np.radians(10)], [0.245, -0.027, np.radians(-10)], [0.227, -0.079, np.radians(-30)],
                 [0.193, -0.119, np.radians(-50)], [0.147, -0.136, np.radians(-90)]])


def drive(ray_caster, start, n=25, step=(0.04, 0.0, 0.02)):
    poses = [np.asarray(start, float)]
    for _ in range(n - 1):
        poses.append(compose(poses[-1], step))
    poses = np.array(poses)
    sensors = compose(poses[:, None, :], RING[None, :, :])                  # (M, K, 3) in the room
    ranges = np.stack([ray_caster(s[:2], np.array([s[2]]))[0] for s in sensors.reshape(-1, 3)])
    return poses, ranges.reshape(len(poses), len(RING))


def test_accumulated_sonar_points_lie_on_the_walls(ray_caster, room):
    poses, ranges = drive(ray_caster, [0.0, 0.0, 0.2])
    odometry = compose([5.0, -3.0, 1.0], poses)           # any odometry frame: only relative motion matters
    scan = sonar_scan(odometry, RING, ranges, max_range=10.0)
    world = apply_pose(poses[-1], scan.points)            # anchor (last pose) frame -> room
    edges = np.stack([room, np.roll(room, -1, axis=0)], axis=1)
    a, b = edges[:, 0], edges[:, 1]
    t = np.clip(np.einsum("nkj,kj->nk", world[:, None] - a, b - a) / np.sum((b - a) ** 2, axis=1), 0, 1)
    distance = np.min(np.linalg.norm(world[:, None] - (a + t[..., None] * (b - a)), axis=-1), axis=1)
    assert len(scan) == ranges.size
    assert np.max(distance) < 1e-9


def test_out_of_range_echoes_are_dropped_and_shapes_checked(ray_caster):
    poses, ranges = drive(ray_caster, [0.0, 0.0, 0.0], n=5)
    ranges[0, :] = np.nan
    assert len(sonar_scan(poses, RING, ranges, max_range=10.0)) == ranges.size - len(RING)
    with pytest.raises(ScanMatchError, match="ranges must have shape"):
        sonar_scan(poses, RING, ranges[:, :3])


def test_two_sonar_stretches_match(ray_caster):
    # Two stretches of driving, each gathered into one scan, matched against each other.
    poses_a, ranges_a = drive(ray_caster, [-1.0, -0.5, 0.3], n=40, step=(0.03, 0.0, 0.05))
    poses_b, ranges_b = drive(ray_caster, [-0.8, -0.4, 0.35], n=40, step=(0.03, 0.0, 0.05))
    scan_a = sonar_scan(poses_a, RING, ranges_a, max_range=10.0)
    scan_b = sonar_scan(poses_b, RING, ranges_b, max_range=10.0)
    truth = between(poses_a[-1], poses_b[-1])
    result = match_scans(scan_a, scan_b, "eicp", initial=compose(truth, [0.05, -0.05, 0.02]))
    d = between(truth, result.pose)
    assert np.hypot(d[0], d[1]) < 0.05 and abs(d[2]) < np.radians(2)
