"""Synthetic robots for fleet tests and benchmarks: map publishers without sensors, one Zenoh session each.

A shared ground truth (landmarks with 64-D descriptors in a square building) is seen by every robot from its own
start pose, which none of them knows: robot k's map holds the landmarks it has "explored" so far, in its start
frame, with a fixed per-landmark noise (so a landmark not re-observed does not change, and deltas stay small) and
``metadata.true_start_pose`` for scoring. Each step adds ``grow`` landmarks and re-observes ``reobserve`` old ones.

``python -m runtime.fleet.synthetic --names robot1,robot2 --exchange zenoh:CONFIG`` runs them; it prints
``ready`` when its sessions are open and ``published`` after ``--steps`` updates, then idles as a runtime robot
whose mission has ended (its status once a second, naming its last map) until SIGTERM or Ctrl-C.
"""
from __future__ import annotations

import argparse
import signal
import sys
import threading
import time

import numpy as np

from estimation.landmark_map import LandmarkMap
from runtime.fleet.mapwire import encode_full
from runtime.json_output import json_text

DESCRIPTOR = 64


def ground_truth(n: int = 600, size: float = 20.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Landmark positions (n, 3) in the world and unit descriptors (n, 64)."""
    rng = np.random.default_rng(seed)
    positions = np.column_stack([rng.uniform(-size / 2, size / 2, (n, 2)), rng.uniform(0.2, 2.5, n)])
    descriptors = rng.normal(size=(n, DESCRIPTOR))
    return positions, (descriptors / np.linalg.norm(descriptors, axis=1, keepdims=True)).astype(np.float32)


def start_pose(index: int, seed: int = 0) -> np.ndarray:
    """Robot ``index``'s true start pose in the world (x, y, θ)."""
    rng = np.random.default_rng(seed * 1000 + 17 + index)
    return np.array([*rng.uniform(-2.0, 2.0, 2), rng.uniform(-np.pi, np.pi)])  # starts close: maps overlap


def to_frame(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """World points (n, 3) in the frame of ``pose`` (x, y, θ)."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    d = points[:, :2] - pose[:2]
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], points[:, 2]])


class SyntheticRobot:
    """Robot ``index``'s growing map: landmarks ordered by distance from its start, ``grow`` more per step."""

    def __init__(self, name: str, index: int, seed: int = 0, landmarks: int = 600, grow: int = 20,
                 reobserve: int = 5, noise: float = 0.02) -> None:
        self.name, self.index = name, index
        self.truth, self.descriptors = ground_truth(landmarks, seed=seed)
        self.start = start_pose(index, seed)
        self.order = np.argsort(np.hypot(*(self.truth[:, :2] - self.start[:2]).T))
        rng = np.random.default_rng(seed * 7919 + index)
        self.noise = rng.normal(0.0, noise, self.truth.shape)
        self.descriptor_noise = rng.normal(0.0, 0.05, self.descriptors.shape).astype(np.float32)
        self.counts = np.zeros(landmarks, np.int64)
        self.rng = rng
        self.grow, self.reobserve = grow, reobserve
        self.step_count = 0

    def step(self) -> LandmarkMap:
        """The map after one more step of exploration."""
        self.step_count += 1
        seen = self.order[: min(len(self.order), self.grow * self.step_count)]
        self.counts[seen[self.counts[seen] == 0]] = 3
        again = self.rng.choice(seen, size=min(len(seen), self.reobserve), replace=False)
        self.counts[again] += 1
        self.noise[again] *= 0.9  # a re-observed landmark's estimate moves (and improves)
        positions = to_frame(self.start, self.truth[seen]) + self.noise[seen]
        cov = np.tile(np.eye(3) * 0.02**2, (len(seen), 1, 1)) / self.counts[seen, None, None]
        trajectory = np.array([[float(k), 0.1 * k, 0.0, 0.0] for k in range(self.step_count)])
        return LandmarkMap(positions, cov, self.descriptors[seen] + self.descriptor_noise[seen], seen.astype(np.int64),
                           self.counts[seen].copy(), self.name, "start", trajectory=trajectory,
                           metadata={"true_start_pose": [float(v) for v in self.start], "synthetic": True})


def main(argv: list[str] | None = None) -> int:
    from runtime.fleet.options import open_exchange

    p = argparse.ArgumentParser(prog="python -m runtime.fleet.synthetic", description=__doc__.splitlines()[0])
    p.add_argument("--names", required=True, help="comma-separated robot names; robot k is the k-th name")
    p.add_argument("--first-index", type=int, default=0, help="index of the first name in the fleet")
    p.add_argument("--exchange", default="zenoh")
    p.add_argument("--fleet", default="p3at")
    p.add_argument("--period", type=float, default=0.5, help="s between two map updates of a robot")
    p.add_argument("--steps", type=int, default=20, help="updates per robot, then idle until stopped (0: forever)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--landmarks", type=int, default=600)
    p.add_argument("--grow", type=int, default=20)
    p.add_argument("--full-every", type=int, default=10)
    p.add_argument("--report", action="store_true",
                   help="at the end, print one JSON line: bytes sent per robot by kind, and what full snapshots "
                        "alone would have sent")
    args = p.parse_args(argv)
    names = args.names.split(",")
    robots = [SyntheticRobot(n, args.first_index + k, args.seed, args.landmarks, args.grow)
              for k, n in enumerate(names)]
    exchanges = [open_exchange(args.exchange, args.fleet, "robot") for _ in robots]
    for exchange in exchanges:
        exchange.full_every = args.full_every
    stop = threading.Event()
    for s in (signal.SIGTERM, signal.SIGINT):
        signal.signal(s, lambda *_: stop.set())
    print("ready", flush=True)
    step = 0
    next_time = started = next_status = time.monotonic()
    full_only = dict.fromkeys(names, 0)
    sizes = dict.fromkeys(names, 0)
    sent = None  # bytes sent by the updates (and their statuses) alone: what --report gives
    try:
        while not stop.is_set():
            if args.steps == 0 or step < args.steps:
                for robot, exchange in zip(robots, exchanges, strict=True):
                    m = robot.step()
                    exchange.publish(robot.name, m, stamp=time.time())  # wall clock: shared by processes
                    sizes[robot.name] = len(m)
                    if args.report:
                        full_only[robot.name] += len(encode_full(robot.name, "0" * 16, step, 0.0, m))
                step += 1
                if step == args.steps:
                    sent = [dict(e.bytes_sent) for e in exchanges]
                    print("published", flush=True)
            elif time.monotonic() >= next_status:
                # as a robot whose mission has ended (runtime/fleet/status.py): a status once a second names the
                # last map, so a receiver that lost it on the wire (maps go with CongestionControl.DROP) asks for it
                next_status = time.monotonic() + 1.0
                for robot, exchange in zip(robots, exchanges, strict=True):
                    exchange.publish_status(robot.name, time.time(), landmarks=sizes[robot.name])
            next_time += args.period
            stop.wait(max(0.0, next_time - time.monotonic()))
    finally:
        for exchange in exchanges:
            exchange.close()
    if args.report:
        sent = sent or [dict(e.bytes_sent) for e in exchanges]
        print(json_text({"seconds": time.monotonic() - started, "robots": {
            r.name: {"sent": s, "full_only": full_only[r.name]} for r, s in zip(robots, sent, strict=True)}}),
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
