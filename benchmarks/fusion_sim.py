"""Simulated landmark maps for the fusion tests, benchmarks and evaluation (not part of the product).

Two sources:

* :func:`building_map` / :func:`building_pair` — the maps two robots would build driving their routes
  through the simulated building (``mocks.world``): the features their camera sees along the route,
  expressed in each robot's start frame, with position noise drawn from a per-landmark covariance that
  grows with range and distance travelled, descriptor noise, and spurious landmarks.  A map can be cut at
  any fraction of the route (the snapshots of the paper's Fig. 2); a landmark's noise draw is fixed, so a
  growing map refines rather than reshuffles.  ``metadata["true_start_pose"]`` carries the truth.
* :func:`random_pair` — two maps of a random point cloud sharing ``n_common`` landmarks, for property
  tests and the speed benchmarks (any size, no building).

Until FastSLAM maps are used, these stand in for them (see docs/fusion.md).
"""
from __future__ import annotations

import functools
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from estimation.geometry import inverse, rot_z, transform_points, wrap_angle  # noqa: E402
from estimation.landmark_map import LandmarkMap  # noqa: E402

DESCRIPTOR_SIZE = 64


@dataclass(frozen=True)
class MapNoise:
    """How a simulated robot's map departs from the truth (metres, per metre of range or travel)."""

    range_sigma: float = 0.02            # along the line of sight: range_sigma + range_growth · range²
    range_growth: float = 0.004
    cross_sigma: float = 0.01            # across it and in z: cross_sigma + cross_growth · range
    cross_growth: float = 0.003
    drift_per_metre: float = 0.002       # isotropic xy std added per metre travelled before first sight
    heading_drift: float = 0.0           # rad/√m: correlated odometry heading random walk (warps the map)
    descriptor_noise: float = 0.4        # expected descriptor distance to the true descriptor
    spurious_fraction: float = 0.1       # extra landmarks that exist nowhere
    camera_height: float = 0.9
    fov: float = 1.0                     # radians, horizontal
    vertical_fov: float = 0.9
    max_range: float = 6.0


@dataclass(frozen=True)
class SimulatedMap:
    """A map and, for each landmark, the index of the world feature it stands for (-1: spurious)."""

    map: LandmarkMap
    feature_index: np.ndarray


@functools.lru_cache(maxsize=4)
def load_world(path: str | None = None):
    from mocks.world import World
    return World.load(path)


def route_poses(start_pose, waypoints, step: float = 0.1, turn_step: float = 0.15) -> tuple[np.ndarray, np.ndarray]:
    """Poses (P, 3) along a waypoint route (turning in place at each waypoint) and distance travelled (P,)."""
    poses, travelled = [np.asarray(start_pose, float)], [0.0]
    x, y, heading = (float(v) for v in start_pose)
    dist = 0.0
    for wx, wy in np.asarray(waypoints, float):
        length = np.hypot(wx - x, wy - y)
        if length < 1e-9:
            continue
        target = np.arctan2(wy - y, wx - x)
        turn = wrap_angle(target - heading)
        for a in np.linspace(0.0, turn, max(2, int(abs(turn) / turn_step) + 1))[1:]:
            poses.append(np.array([x, y, heading + a]))
            travelled.append(dist)
        heading = target
        for s in np.arange(step, length + 1e-9, step):
            poses.append(np.array([x + s * np.cos(heading), y + s * np.sin(heading), heading]))
            travelled.append(dist + s)
        x, y, dist = wx, wy, dist + length
    return np.array(poses), np.array(travelled)


@functools.lru_cache(maxsize=16)
def _sightings(robot: str, noise: MapNoise) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For every pose along the robot's route: (poses (P, 3), travelled (P,), visible (P, K) bool)."""
    world = load_world()
    poses, travelled = route_poses(world.start_poses[robot], world.routes[robot])
    visible = np.array([world.visible_features(p, noise.camera_height, noise.fov, noise.max_range,
                                               noise.vertical_fov) for p in poses])
    return poses, travelled, visible


def _covariance(view_xy: np.ndarray, rng_m: np.ndarray, travelled: np.ndarray, noise: MapNoise) -> np.ndarray:
    """World-frame covariances (N, 3, 3) of landmarks seen along view_xy (N, 2) at range rng_m (N,)."""
    along = noise.range_sigma + noise.range_growth * rng_m ** 2
    across = noise.cross_sigma + noise.cross_growth * rng_m
    drift = noise.drift_per_metre * travelled
    bearing = np.arctan2(view_xy[:, 1], view_xy[:, 0])
    R = rot_z(bearing)
    D = np.zeros((len(rng_m), 3, 3))
    D[:, 0, 0], D[:, 1, 1], D[:, 2, 2] = along ** 2, across ** 2, across ** 2
    P = R @ D @ np.swapaxes(R, -1, -2)
    P[:, 0, 0] += drift ** 2
    P[:, 1, 1] += drift ** 2
    return P


def _noisy_descriptors(desc: np.ndarray, distance: float, rng: np.random.Generator) -> np.ndarray:
    noisy = desc + rng.normal(scale=distance / np.sqrt(desc.shape[1]), size=desc.shape)
    return (noisy / np.linalg.norm(noisy, axis=1, keepdims=True)).astype(np.float32)


def building_map(robot: str, fraction: float = 1.0, seed: int = 0, noise: MapNoise = MapNoise(),
                 exclude_features: np.ndarray | None = None) -> SimulatedMap:
    """The map ``robot`` ("robot1", "robot2", ...) has built after ``fraction`` of its route.

    Deterministic in ``seed``; the same seed gives the same noise for every fraction.  ``exclude_features``
    (feature indices) are left out (to build maps that share nothing).
    """
    world = load_world()
    poses, travelled, visible = _sightings(robot, noise)
    rng = np.random.default_rng([seed, int.from_bytes(robot.encode()[-4:], "little")])
    k = len(world.features)
    # fixed per-landmark draws, so a growing map refines instead of reshuffling
    unit_noise = rng.standard_normal((k, 3))
    desc_all = _noisy_descriptors(world.feature_descriptors, noise.descriptor_noise, rng)
    n_spurious_all = int(round(noise.spurious_fraction * k))
    spurious_at = rng.uniform(0.0, 1.0, n_spurious_all)
    spurious_desc = _noisy_descriptors(rng.standard_normal((n_spurious_all, DESCRIPTOR_SIZE)), 0.0, rng)
    spurious_unit = rng.uniform(0.0, 1.0, (n_spurious_all, 3))

    last = max(1, int(np.ceil(fraction * len(poses))))
    seen = visible[:last]
    observed = seen.any(axis=0)
    if exclude_features is not None:
        observed[np.asarray(exclude_features, np.int64)] = False
    idx = np.flatnonzero(observed)
    # each landmark's best view so far: the closest sighting
    rel = world.features[None, idx, :2] - poses[:last, None, :2]
    dist = np.where(seen[:, idx], np.linalg.norm(rel, axis=2), np.inf)
    best = np.argmin(dist, axis=0)
    first = np.argmax(seen[:, idx], axis=0)
    view = rel[best, np.arange(len(idx))]
    P_world = _covariance(view, dist[best, np.arange(len(idx))], travelled[first], noise)

    start = np.asarray(world.start_poses[robot], float)
    to_start = inverse(start)
    true_world = world.features[idx]
    if noise.heading_drift > 0 and len(idx):
        true_world = _drifted(true_world, poses[:last], travelled[:last], first, noise.heading_drift,
                              np.random.default_rng([seed, int.from_bytes(robot.encode()[-4:], "little"), 7]))
    true_local = transform_points(to_start, true_world)
    Rs = rot_z(to_start[2])
    P = Rs @ P_world @ Rs.T
    positions = true_local + np.einsum("nij,nj->ni", np.linalg.cholesky(P), unit_noise[idx])

    # spurious landmarks: appear along the route, somewhere in the seen region, with typical uncertainty
    n_sp = int(np.sum(spurious_at <= fraction)) if len(idx) else 0
    if n_sp:
        lo, hi = true_local.min(axis=0), true_local.max(axis=0)
        positions = np.vstack([positions, lo + spurious_unit[:n_sp] * (hi - lo)])
        P = np.concatenate([P, np.repeat(np.median(P, axis=0)[None], n_sp, axis=0)])
    descriptors = np.vstack([desc_all[idx], spurious_desc[:n_sp]])
    feature_index = np.concatenate([idx, np.full(n_sp, -1)])
    traj = np.column_stack([np.arange(last) * 0.3, np.asarray([_local(to_start, p) for p in poses[:last]])])
    m = LandmarkMap(positions, P, descriptors, counts=np.ones(len(positions), np.int64), robot=robot,
                    frame=f"{robot}/start", trajectory=traj,
                    metadata={"true_start_pose": [float(v) for v in start], "simulated": True,
                              "route_fraction": float(fraction), "seed": int(seed)})
    return SimulatedMap(m, feature_index)


def _drifted(points: np.ndarray, poses: np.ndarray, travelled: np.ndarray, first: np.ndarray, sigma: float,
             rng: np.random.Generator) -> np.ndarray:
    """Where a robot with a drifting heading estimate (random walk, ``sigma`` rad/√m) would put world points
    (N, 3) first seen at pose index ``first`` (N,): about that pose, rotated by the heading error and
    shifted by the position error accumulated so far (dead-reckoning-like, correlated along the route)."""
    steps = np.diff(travelled, prepend=0.0)
    heading_err = np.cumsum(rng.normal(0.0, 1.0, len(steps)) * sigma * np.sqrt(steps))
    h = poses[:, 2]
    pos_err = np.cumsum(heading_err[:, None] * steps[:, None] * np.column_stack([-np.sin(h), np.cos(h)]), axis=0)
    e, c = heading_err[first], poses[first, :2]
    rel = points[:, :2] - c
    cos, sin = np.cos(e), np.sin(e)
    moved = c + pos_err[first] + np.column_stack([cos * rel[:, 0] - sin * rel[:, 1], sin * rel[:, 0] + cos * rel[:, 1]])
    return np.column_stack([moved, points[:, 2]])


def _local(to_start: np.ndarray, pose: np.ndarray) -> np.ndarray:
    from estimation.geometry import compose
    return compose(to_start, pose)


def building_pair(fraction: float = 1.0, seed: int = 0, noise: MapNoise = MapNoise(),
                  robots: tuple[str, str] = ("robot1", "robot2")) -> tuple[SimulatedMap, SimulatedMap]:
    """Both robots' maps after ``fraction`` of their routes."""
    return building_map(robots[0], fraction, seed, noise), building_map(robots[1], fraction, seed, noise)


def non_overlapping_pair(fraction: float = 1.0, seed: int = 0, noise: MapNoise = MapNoise()
                         ) -> tuple[SimulatedMap, SimulatedMap]:
    """Two maps of the same building (same kinds of descriptors) that share no landmark at all."""
    first = building_map("robot1", fraction, seed, noise)
    shared = first.feature_index[first.feature_index >= 0]
    return first, building_map("robot2", fraction, seed, noise, exclude_features=shared)


def true_common(a: SimulatedMap, b: SimulatedMap) -> np.ndarray:
    """Pairs (K, 2) of rows of a and b that stand for the same world feature."""
    rows_b = {int(f): r for r, f in enumerate(b.feature_index) if f >= 0}
    return np.array([(r, rows_b[int(f)]) for r, f in enumerate(a.feature_index) if f >= 0 and int(f) in rows_b],
                    np.int64).reshape(-1, 2)


def random_pair(n_common: int, n_only1: int, n_only2: int, pose, seed: int = 0, sigma: float = 0.03,
                descriptor_noise: float = 0.2, extent: tuple[float, float] = (35.0, 10.0)
                ) -> tuple[LandmarkMap, LandmarkMap, np.ndarray]:
    """Two maps of a random 3-D point cloud; map 2's frame sits at ``pose`` (3,) in map 1's frame.

    Returns map1, map2 and the true common pairs (n_common, 2).  Landmarks have isotropic std ``sigma``
    (varying ±50 % per landmark) and unit descriptors perturbed by ``descriptor_noise`` per map.
    """
    rng = np.random.default_rng(seed)
    n = n_common + n_only1 + n_only2
    world = np.column_stack([rng.uniform(0, extent[0], n), rng.uniform(0, extent[1], n), rng.uniform(0, 2.5, n)])
    desc = rng.standard_normal((n, DESCRIPTOR_SIZE))
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    in1 = np.r_[np.arange(n_common), n_common + np.arange(n_only1)]
    in2 = np.r_[np.arange(n_common), n_common + n_only1 + np.arange(n_only2)]

    def make(rows, frame_pose, robot):
        local = transform_points(inverse(frame_pose), world[rows])
        s = sigma * rng.uniform(0.5, 1.5, len(rows))
        cov = np.eye(3)[None] * (s ** 2)[:, None, None]
        perm = rng.permutation(len(rows))
        m = LandmarkMap(local[perm] + rng.standard_normal((len(rows), 3)) * s[perm, None], cov[perm],
                        _noisy_descriptors(desc[rows[perm]], descriptor_noise, rng), robot=robot,
                        metadata={"true_start_pose": [float(v) for v in frame_pose]})
        return m, perm

    map1, perm1 = make(in1, np.zeros(3), "robot1")
    map2, perm2 = make(in2, np.asarray(pose, float), "robot2")
    row1 = np.argsort(perm1)[:n_common]   # where original row r ended up
    row2 = np.argsort(perm2)[:n_common]
    return map1, map2, np.column_stack([row1, row2]).astype(np.int64)


def _planar_map(points: np.ndarray, frame_pose, sigma: np.ndarray, descriptors: np.ndarray, robot: str,
                rng: np.random.Generator) -> LandmarkMap:
    """Points (N, 3) in the world seen from ``frame_pose``: noisy positions (std ``sigma`` (N,)), isotropic
    covariances, the given descriptors (N, D), the true start pose in the metadata."""
    local = transform_points(inverse(np.asarray(frame_pose, float)), points)
    noisy = local + rng.standard_normal(local.shape) * sigma[:, None] * np.array([1.0, 1.0, 0.0])
    cov = np.eye(3)[None] * (sigma ** 2)[:, None, None]
    cov[:, 2, 2] = 1e-6
    return LandmarkMap(noisy, cov, descriptors, robot=robot,
                       metadata={"true_start_pose": [float(v) for v in frame_pose]})


def landmark_pair(n_common: int, n_only1: int, n_only2: int, pose, seed: int = 0, sigma: float = 0.05,
                  descriptors: str = "id", extent: tuple[float, float] = (15.0, 8.0),
                  claimed_sigma: float | None = None) -> tuple[LandmarkMap, LandmarkMap, np.ndarray]:
    """Two small planar landmark maps like MRCLAM's (15 barcoded cylinders in 15 × 8 m).

    ``descriptors``: "id" (one-hot identities, as known-ID maps carry), "none" (no descriptors, D = 0).
    Landmarks are at least 1 m apart.  The maps' covariances claim ``claimed_sigma`` (default: the true
    ``sigma``; smaller = overconfident maps).  Returns map1, map2 and the true common pairs (n_common, 2).
    """
    rng = np.random.default_rng(seed)
    n = n_common + n_only1 + n_only2
    pts: list[np.ndarray] = []
    while len(pts) < n:
        p = np.array([rng.uniform(0, extent[0]), rng.uniform(0, extent[1]), 0.0])
        if all(np.hypot(*(p - q)[:2]) >= 1.0 for q in pts):
            pts.append(p)
    world = np.array(pts)
    ids = np.eye(n, dtype=np.float32)
    in1 = np.r_[np.arange(n_common), n_common + np.arange(n_only1)]
    in2 = np.r_[np.arange(n_common), n_common + n_only1 + np.arange(n_only2)]
    maps = []
    for rows, frame, robot in ((in1, np.zeros(3), "robot1"), (in2, np.asarray(pose, float), "robot2")):
        desc = ids[rows] if descriptors == "id" else np.zeros((len(rows), 0), np.float32)
        m = _planar_map(world[rows], frame, np.full(len(rows), sigma), desc, robot, rng)
        if claimed_sigma is not None:
            m.covariances[:, :2, :2] = np.eye(2) * claimed_sigma ** 2
        perm = rng.permutation(len(rows))
        maps.append((m.subset(perm), perm))
    (map1, perm1), (map2, perm2) = maps
    common = np.column_stack([np.argsort(perm1)[:n_common], np.argsort(perm2)[:n_common]]).astype(np.int64)
    return map1, map2, common


def corridor_pair(doors1: range, doors2: range, pose, seed: int = 0, spacing: float = 2.0, sigma: float = 0.02,
                  descriptors: str = "door") -> tuple[LandmarkMap, LandmarkMap]:
    """Two maps of a corridor of identical doors: each door gives its two frame corners on both walls.

    Robot 1 maps doors ``doors1``, robot 2 doors ``doors2`` (door k at x = k · spacing); map 2's frame sits
    at ``pose`` in the corridor frame.  ``descriptors``: "door" (the same four descriptors at every door,
    slightly noisy, as repeated texture gives) or "none".  Repeated structure: shifting by whole doors
    fits as well as the truth wherever the door ranges allow.
    """
    rng = np.random.default_rng(seed)
    base = rng.standard_normal((4, DESCRIPTOR_SIZE))
    base /= np.linalg.norm(base, axis=1, keepdims=True)
    offsets = np.array([[0.0, 0.0], [0.9, 0.0], [0.0, 2.4], [0.9, 2.4]])

    def make(doors, frame, robot):
        pts = np.array([[k * spacing + dx, dy, 1.0] for k in doors for dx, dy in offsets])
        if descriptors == "door":
            desc = _noisy_descriptors(np.tile(base, (len(doors), 1)), 0.05, rng)
        else:
            desc = np.zeros((len(pts), 0), np.float32)
        m = _planar_map(pts, frame, np.full(len(pts), sigma), desc, robot, rng)
        m.positions[:, 2] = 1.0
        return m

    return make(doors1, np.zeros(3), "robot1"), make(doors2, np.asarray(pose, float), "robot2")


# -- MRCLAM (real data): maps from each robot's sightings --------------------------------------------------------
def false_pair_kinds() -> dict:
    """Seven kinds of map pairs that share nothing, each ``name -> make(seed) -> (map1, map2)`` (maps or
    SimulatedMaps): the no-false-alignment test of eval_fusion and fusion_gate_scale, one set of generators and
    seeds for both."""
    def far_pose(s):
        r = np.random.default_rng([s, 99])
        return (r.uniform(-10, 10), r.uniform(-5, 5), r.uniform(-np.pi, np.pi))

    def wrong_ids(s):
        m1, m2, _ = landmark_pair(0, 15, 15, far_pose(s), seed=s, sigma=0.05, descriptors="id")
        m1.metadata["external_ids"] = list(range(15))
        m2.metadata["external_ids"] = [int(v) for v in np.random.default_rng([s, 7]).permutation(15)]
        return m1, m2

    return {
        "building, disjoint features, full routes": lambda s: non_overlapping_pair(1.0, s),
        "building, disjoint features, 60 % of routes": lambda s: non_overlapping_pair(0.6, s),
        "random 250 + 300 landmarks, 35 × 10 m": lambda s: random_pair(0, 250, 300, far_pose(s), seed=s)[:2],
        "15 + 15 landmarks, 15 × 8 m, no descriptors": lambda s: landmark_pair(0, 15, 15, far_pose(s), seed=s,
                                                                               descriptors="none")[:2],
        "15 + 15 landmarks, identities shuffled (every one wrong)": wrong_ids,
        "corridor of identical doors, no overlap, no descriptors": lambda s: corridor_pair(
            range(0, 8), range(10 + s % 5, 18 + s % 5), far_pose(s), seed=s, descriptors="none"),
        "corridor of identical doors, no overlap, repeated descriptors": lambda s: corridor_pair(
            range(0, 8), range(10 + s % 5, 18 + s % 5), far_pose(s), seed=s, descriptors="door"),
    }


def drift_walk(n_steps: int, step: float, heading_drift: float) -> np.ndarray:
    """Covariances (n_steps, 3, 3) of a robot's pose error (x, y, θ) along a straight run in +x: heading error a
    random walk of ``heading_drift`` rad/√m, the lateral error its integral (first order)."""
    k = np.arange(n_steps)
    # θ_k = Σ_{i≤k} w_i,  y_k = Σ_{j≤k} θ_j · step = Σ_i w_i (k − i + 1) step  (w_i ~ N(0, σ² step))
    A_theta = (k[:, None] >= k[None, :]).astype(float)
    A_y = A_theta * (k[:, None] - k[None, :] + 1) * step
    var = heading_drift ** 2 * step
    D = np.zeros((n_steps, 3, 3))
    D[:, 1, 1] = np.sum(A_y * A_y, axis=1) * var
    D[:, 2, 2] = np.sum(A_theta * A_theta, axis=1) * var
    D[:, 1, 2] = D[:, 2, 1] = np.sum(A_y * A_theta, axis=1) * var
    return D


def warped_pair(seed: int = 0, heading_drift: float = 0.01, sigma: float = 0.03, honest: bool = True,
                corridor: float = 20.0, reach1: float = 14.0, reach2: float = 8.0, landmarks: int = 60
                ) -> tuple[LandmarkMap, LandmarkMap]:
    """Two maps of a straight corridor (landmarks on both walls, 2 m either side), each bent by its robot's
    heading drift (a random walk, ``heading_drift`` rad/√m, first order): robot 1 starts at x = 0 facing +x and
    maps up to ``reach1``; robot 2 starts at x = ``corridor`` facing −x and maps down to ``reach2``.  Where they
    overlap (reach2..reach1) robot 1 has driven far, so its part of the map is off its start frame as a whole
    while locally rigid.  A landmark is created when its robot is 3 m short of it, with the pose error the
    robot has then (as estimation.fastslam.drift models it).  ``honest``: the covariances carry that drift
    (σ² I + H D Hᵀ, the export 'mixture+drift'); otherwise only σ² I (a map that does not know it is bent).
    Distinct unit descriptors; metadata true_start_pose."""
    rng = np.random.default_rng(seed)
    xs = rng.uniform(0.0, corridor, landmarks)
    world = np.column_stack([xs, rng.choice([-2.0, 2.0], landmarks) + rng.normal(0, 0.1, landmarks),
                             rng.uniform(0.3, 2.0, landmarks)])
    desc = rng.standard_normal((landmarks, DESCRIPTOR_SIZE))
    desc /= np.linalg.norm(desc, axis=1, keepdims=True)
    step = 0.1
    maps = []
    for robot, start, reach in (("robot1", np.array([0.0, 0.0, 0.0]), reach1),
                                ("robot2", np.array([corridor, 0.0, np.pi]), corridor - reach2)):
        local = transform_points(inverse(start), world)              # the robot drives along +x of its frame
        keep = (local[:, 0] > 0.5) & (local[:, 0] <= reach)
        local = local[keep]
        n_steps = int(np.ceil(reach / step)) + 1
        D = drift_walk(n_steps, step, heading_drift)
        # one random walk per map: draw the increments and integrate (the same model as drift_walk)
        w = rng.normal(0.0, heading_drift * np.sqrt(step), n_steps)
        theta = np.cumsum(w)
        lateral = np.cumsum(theta) * step
        at = np.clip(np.floor(np.maximum(local[:, 0] - 3.0, 0.0) / step).astype(int), 0, n_steps - 1)
        robot_xy = np.column_stack([at * step, np.zeros(len(at))])
        rel = local[:, :2] - robot_xy
        e = theta[at]
        moved = robot_xy + np.column_stack([np.zeros(len(at)), lateral[at]]) + np.column_stack(
            [np.cos(e) * rel[:, 0] - np.sin(e) * rel[:, 1], np.sin(e) * rel[:, 0] + np.cos(e) * rel[:, 1]])
        positions = np.column_stack([moved + rng.normal(0, sigma, (len(at), 2)), local[:, 2]])
        H = np.zeros((len(at), 3, 3))
        H[:, 0, 0] = H[:, 1, 1] = 1.0
        H[:, 0, 2], H[:, 1, 2] = -rel[:, 1], rel[:, 0]
        cov = np.repeat(np.eye(3)[None] * sigma ** 2, len(at), axis=0)
        if honest:
            cov = cov + H @ D[at] @ np.swapaxes(H, 1, 2)
        cov[:, 2, 2] = sigma ** 2
        d = _noisy_descriptors(desc[keep], 0.2, rng)
        maps.append(LandmarkMap(positions, cov, d, robot=robot,
                                metadata={"true_start_pose": [float(v) for v in start], "simulated": True}))
    return maps[0], maps[1]


def half_turn_pair(seed: int = 0, sigma: float = 0.03, pattern: int = 20, repeated_in_map1: int = 8,
                   seen_by_map2: int = 12, shared: int = 3, pose=(3.0, 1.0, 0.5)) -> tuple[LandmarkMap, LandmarkMap]:
    """A building symmetric under a half turn whose two halves look alike (as the rendered demo's): a pattern of
    ``pattern`` landmarks around (5, 0) and its copy turned by π about (10, 0), same descriptors.  Map 1 holds the
    whole first half and the last ``repeated_in_map1`` of the copy (so it repeats itself); map 2, whose frame is
    at ``pose``, holds the first ``seen_by_map2`` of the copy and truly shares only ``shared`` other landmarks
    with map 1 (too few to align).  Map 2's copy matches map 1's first half one-to-one: the wrong, half-turned
    alignment gathers ``seen_by_map2`` supports."""
    rng = np.random.default_rng(seed)
    a = np.column_stack([rng.uniform(2.0, 8.0, pattern), rng.uniform(-2.0, 2.0, pattern),
                         rng.uniform(0.3, 2.0, pattern)])
    b = np.column_stack([20.0 - a[:, 0], -a[:, 1], a[:, 2]])          # the half turn about (10, 0)
    desc = rng.standard_normal((pattern, DESCRIPTOR_SIZE))
    shared_pts = np.column_stack([rng.uniform(22.0, 26.0, shared), rng.uniform(-2.0, 2.0, shared),
                                  rng.uniform(0.3, 2.0, shared)])
    own = [np.column_stack([rng.uniform(x0, x0 + 4.0, 10), rng.uniform(-2.0, 2.0, 10), rng.uniform(0.3, 2.0, 10)])
           for x0 in (-6.0, 28.0)]
    unique = rng.standard_normal((shared + 20, DESCRIPTOR_SIZE))
    d_shared, d_own1, d_own2 = unique[:shared], unique[shared:shared + 10], unique[shared + 10:]
    pts1 = np.vstack([a, b[pattern - repeated_in_map1:], shared_pts, own[0]])
    d1 = np.vstack([desc, desc[pattern - repeated_in_map1:], d_shared, d_own1])
    pts2 = np.vstack([b[:seen_by_map2], shared_pts, own[1]])
    d2 = np.vstack([desc[:seen_by_map2], d_shared, d_own2])
    maps = []
    for pts, d, frame, robot in ((pts1, d1, np.zeros(3), "robot1"), (pts2, d2, np.asarray(pose, float), "robot2")):
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
        maps.append(_planar_map(pts, frame, np.full(len(pts), sigma), _noisy_descriptors(d, 0.2, rng), robot, rng))
    return maps[0], maps[1]


MRCLAM_DATASET2 = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "mrclam" / "MRCLAM_Dataset2"


@dataclass(frozen=True)
class SightingMap:
    """A map made from one robot's real sightings, and the truth to score it.

    map: landmarks in the robot's start frame (its true pose at its first sighting), no descriptors, covariances
    the sightings' scatter / count (as overconfident as FastSLAM's per-particle ones); identities (N,): the
    landmark each row stands for (put in ``metadata["external_ids"]`` only when ``identities`` was asked);
    true_start (3,) world pose of the frame; truth: landmark id -> true world (x, y).
    """

    map: LandmarkMap
    identities: np.ndarray
    true_start: np.ndarray
    truth: dict


def mrclam_sighting_map(folder, robot: int, identities: bool = True, until: float | None = None,
                        min_sightings: int = 3, truth_heading: str = "mocap") -> SightingMap:
    """Robot ``robot``'s landmarks from its real range-bearing sightings placed from its Vicon poses.

    Not a SLAM map: the poses are the truth, so the errors are the camera's (range bias, outliers) only.  It
    isolates the fusion from the filter; FastSLAM maps (``p3at slam dataset``) are evaluated beside it.
    Each landmark: the mean of its sightings within 0.5 m of their median (outliers dropped).
    ``truth_heading``: read_mrclam's (``travel``: the Vicon heading turned onto the direction of travel).
    """
    from estimation.datasets import read_mrclam
    from estimation.geometry import between, compose

    log = read_mrclam(folder, robot, until=until, truth_heading=truth_heading)
    t0 = float(log.sighting_times[0])
    start = log.true_pose([t0])[0]
    poses = log.true_pose(log.sighting_times)
    local = np.column_stack([log.ranges * np.cos(log.bearings), log.ranges * np.sin(log.bearings),
                             np.zeros(len(log))])
    in_start = between(start, compose(poses, local))[:, :2]
    truth = log.true_landmarks()
    rows, ids, covs = [], [], []
    for lid in np.unique(log.landmark_ids):
        if int(lid) not in truth:
            continue
        pts = in_start[log.landmark_ids == lid]
        near = pts[np.linalg.norm(pts - np.median(pts, axis=0), axis=1) < 0.5]
        if len(near) < min_sightings:
            continue
        rows.append(near.mean(axis=0))
        cov = np.cov(near.T) / len(near) + np.eye(2) * 1e-8
        covs.append(np.pad(cov, ((0, 1), (0, 1))) + np.diag([0.0, 0.0, 1e-6]))
        ids.append(int(lid))
    positions = np.column_stack([np.array(rows).reshape(-1, 2), np.zeros(len(rows))])
    meta = {"true_start_pose": [float(v) for v in start], "truth_heading": log.truth_heading, "dataset": log.name,
            "simulated": False,
            "map_source": "real sightings placed from Vicon poses (not SLAM)"
            + ("; their heading turned onto the direction of travel" if truth_heading == "travel" else "")}
    if identities:
        meta["external_ids"] = list(ids)
    m = LandmarkMap(positions, np.array(covs).reshape(-1, 3, 3), np.zeros((len(rows), 0), np.float32),
                    robot=f"robot{robot}", frame=f"robot{robot}/start", metadata=meta)
    return SightingMap(m, np.array(ids, np.int64), start, truth)


def corrupt_map(m: LandmarkMap, rng: np.random.Generator, duplicates: int = 3, outliers: int = 3,
                offset: tuple[float, float] = (0.3, 1.0)) -> LandmarkMap:
    """A copy of ``m`` with injected faults: ``duplicates`` landmarks copied ``offset`` metres away (a duplicate
    the filter failed to merge, same identity) and ``outliers`` landmarks at random places in the map's extent
    carrying the identity of a random real landmark (the worst kind: a wrong identity)."""
    n = len(m)
    ids = m.metadata.get("external_ids")
    src = rng.choice(n, min(duplicates, n), replace=False)
    angle = rng.uniform(-np.pi, np.pi, len(src))
    dist = rng.uniform(*offset, len(src))
    dup = m.positions[src] + np.column_stack([dist * np.cos(angle), dist * np.sin(angle), np.zeros(len(src))])
    lo, hi = m.positions.min(axis=0), m.positions.max(axis=0)
    out = lo + rng.uniform(0, 1, (outliers, 3)) * (hi - lo)
    cov = np.concatenate([m.covariances, m.covariances[src], np.repeat(np.median(m.covariances, 0)[None], outliers, 0)])
    meta = dict(m.metadata)
    if ids is not None:
        ids = np.asarray(ids)
        meta["external_ids"] = [int(v) for v in np.concatenate([ids, ids[src], rng.choice(ids, outliers)])]
    desc = np.zeros((n + len(src) + outliers, m.descriptor_size), np.float32)
    return LandmarkMap(np.vstack([m.positions, dup, out]), cov, desc, robot=m.robot, frame=m.frame, metadata=meta)


def start_heading_refusal(maps, sightings: list[SightingMap], truth_heading: str) -> str | None:
    """None, or one line saying which of ``maps`` (robot 1-5's, in order) was scored against another truth heading
    than ``sightings``' (``mrclam_sighting_map(..., truth_heading=truth_heading)``): its ``true_start_pose`` is its
    robot's true pose at the first sighting (the sighting map's start) in x, y but not in θ.  A map whose start is
    elsewhere (another frame, another data set) is not judged."""
    for m, s in zip(maps, sightings, strict=True):
        start = m.metadata.get("true_start_pose")
        if start is None:
            continue
        d = np.asarray(start, float).reshape(3) - s.true_start
        turn = float(np.arctan2(np.sin(d[2]), np.cos(d[2])))
        if np.all(np.abs(d[:2]) < 1e-6) and abs(turn) > 1e-6:
            return (f"{m.robot}'s true_start_pose heading is {turn:+.4f} rad off the {truth_heading} truth's at the "
                    "same place: the map was scored against the other truth heading (give the --truth-heading "
                    "its maps were made with: p3at slam dataset --truth-heading)")
    return None


def main(argv: list[str] | None = None) -> int:
    """``python benchmarks/fusion_sim.py mrclam --out OUT_DIR [--data DIR] [--no-ids]``: the five MRCLAM sighting
    maps as files ``OUT_DIR/robot1.npz`` ... ``robot5.npz``.  An output folder that is the data set folder or inside
    it is refused (exit 2, one line): a benchmark never writes into its input."""
    import argparse

    parser = argparse.ArgumentParser(description="write simulated or real-sighting landmark maps as files")
    parser.add_argument("kind", choices=("mrclam",))
    parser.add_argument("--out", type=Path, required=True,
                        help="folder to write robot1.npz ... robot5.npz into (not the data set folder nor inside it)")
    parser.add_argument("--data", type=Path, default=MRCLAM_DATASET2, help="MRCLAM dataset folder (only read)")
    parser.add_argument("--no-ids", action="store_true", help="leave the identities out (geometry alone)")
    args = parser.parse_args(argv)
    from benchmarks.output_paths import output_refusal

    refusal = output_refusal("fusion_sim.py", "--out", args.out, args.data)
    if refusal:
        print(refusal, file=sys.stderr)
        return 2
    from estimation.datasets import DatasetError

    try:  # all five read before anything is written: an unreadable data set leaves no half-filled folder
        maps = [mrclam_sighting_map(args.data, r, identities=not args.no_ids).map for r in range(1, 6)]
    except DatasetError as error:
        print(f"fusion_sim.py: error: {error}", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    for r, m in enumerate(maps, start=1):
        m.save(args.out / f"robot{r}.npz")
        print(f"{args.out / f'robot{r}.npz'}: {len(m)} landmarks")
    return 0


if __name__ == "__main__":
    sys.exit(main())
