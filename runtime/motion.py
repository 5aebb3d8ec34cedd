"""Motion: who decides the velocity command. Pure controllers (pose and sonar in, (v, ω) out, no I/O).

- :class:`PurePursuit` follows a route of waypoints (Coulter 1992), slowing for obstacles the sonar sees.
- :class:`WallFollower` explores: keeps a wall at a set distance on one side, turns away from what is ahead.
- :class:`NoMotion` commands nothing (someone else drives the robot).

Poses are ``(x, y, θ)`` in the robot's odometry frame (REP-103); sonar as ``sonar_poses (S, 3)`` in
base_link and ``ranges (S,)`` metres. The same code drives a real P3-AT and the virtual ones.

Route file format (``.route``, UTF-8 text): one waypoint per line, ``x y`` or ``x, y`` in metres in the
frame the route is given in; blank lines and ``#`` comments are ignored.
"""
from __future__ import annotations

import os
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from estimation.geometry import between, compose, wrap_angle
from runtime.textfile import read_bounded_text


class RouteFileError(ValueError):
    """A route file is missing or malformed; the message names the file and line."""


@dataclass(frozen=True)
class MotionCommand:
    v: float          # m/s forward
    w: float          # rad/s counter-clockwise
    done: bool = False


class Controller(Protocol):
    def command(self, pose: np.ndarray, sonar_poses: np.ndarray | None = None,
                ranges: np.ndarray | None = None) -> MotionCommand: ...


MAX_ROUTE_BYTES = 16 << 20
MAX_WAYPOINTS = 100_000
MAX_ROUTE_COORDINATE = 1e5  # metres


def load_route(path: str | os.PathLike) -> np.ndarray:
    """Waypoints (K, 2) from a route file (see the module docstring); at most MAX_WAYPOINTS, coordinates within
    MAX_ROUTE_COORDINATE, a file of at most MAX_ROUTE_BYTES. Raises RouteFileError naming the file and line."""
    path = Path(path)
    text = read_bounded_text(path, MAX_ROUTE_BYTES, "route file", RouteFileError)
    points = []
    for number, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        fields = line.replace(",", " ").split()
        try:
            if len(fields) != 2:
                raise ValueError(f"expected 2 numbers (x y), got {len(fields)}")
            x, y = float(fields[0]), float(fields[1])
            if not (np.isfinite(x) and np.isfinite(y)):
                raise ValueError("not finite")
            if max(abs(x), abs(y)) > MAX_ROUTE_COORDINATE:
                raise ValueError(f"beyond ±{MAX_ROUTE_COORDINATE:g} m")
        except ValueError as e:
            raise RouteFileError(f"{path}:{number}: bad waypoint {line[:80]!r} ({e})") from None
        points.append((x, y))
        if len(points) > MAX_WAYPOINTS:
            raise RouteFileError(f"{path}:{number}: more than {MAX_WAYPOINTS} waypoints")
    if not points:
        raise RouteFileError(f"{path}: the route has no waypoints")
    return np.array(points, float)


def save_route(path: str | os.PathLike, waypoints: np.ndarray) -> None:
    from estimation.fileio import atomic_write_bytes

    lines = ["# p3at-fusion route: x y (metres)"] + [f"{x:.4f} {y:.4f}" for x, y in np.asarray(waypoints)]
    atomic_write_bytes(path, ("\n".join(lines) + "\n").encode())


def keep_right(waypoints: np.ndarray, offset: float = 0.45, min_length: float = 4.0) -> np.ndarray:
    """The route with every leg longer than ``min_length`` moved ``offset`` m to its right (K', 2).

    Robots whose routes share a corridor in opposite directions then pass each other instead of meeting head
    on; short legs (through doors, into rooms) stay on the route's line.
    """
    waypoints = np.asarray(waypoints, float).reshape(-1, 2)
    out = [waypoints[0]]
    for a, b in zip(waypoints[:-1], waypoints[1:], strict=True):
        d = b - a
        length = float(np.hypot(*d))
        if length < min_length:
            out.append(b)
            continue
        right = np.array([d[1], -d[0]]) / length * offset
        # leave the line, run the leg on the right, and come back to the waypoint at its end
        out += [a + right + d * (offset / length), b + right - d * (offset / length), b]
    return np.array(out)


def _sector_min(sonar_poses: np.ndarray | None, ranges: np.ndarray | None, lo: float, hi: float) -> float:
    """The nearest sonar range among sonars pointing within [lo, hi] rad of the robot's heading."""
    if sonar_poses is None or ranges is None or len(ranges) == 0:
        return np.inf
    angles = wrap_angle(np.asarray(sonar_poses)[:, 2])
    mask = (angles >= lo) & (angles <= hi)
    return float(np.min(np.asarray(ranges)[mask])) if mask.any() else np.inf


class PurePursuit:
    """Follow waypoints (K, 2): steer toward the point ``lookahead`` m ahead on the route.

    Each waypoint is reached (within ``goal_tolerance``) before the next segment starts, so a route that
    turns back on itself is followed. An obstacle nearer than ``avoid_distance`` ahead (another robot in the
    corridor) is passed by a side-step ``detour_side`` m to the right (left if the right is closed) and
    ``detour_forward`` m ahead; the robot slows down for what is ahead and stops short of ``stop_distance``.

    A target more than ``turn_in_place`` rad off the heading is faced on the spot first (a skid-steer robot
    turns in place; driving a wide arc round a corner overshoots the next leg, e.g. into a door frame). A
    robot that is told to drive but has not moved for ``stuck_steps`` commands (a bumper against a door frame
    the sonar cannot see at that angle) backs off ``backup_steps`` commands at ``backup_speed`` when the rear
    sonars show room, then carries on: the next approach starts further away and meets the route's line.
    After ``max_recoveries`` of those on one leg (the pose it steers on is off, so it keeps meeting the frame)
    it gives the leg's waypoint up and goes on with the route (``skipped`` counts them) rather than stay put.
    """

    def __init__(self, waypoints: np.ndarray, *, speed: float = 0.35, lookahead: float = 0.7,
                 max_turn_rate: float = 0.8, goal_tolerance: float = 0.3, stop_distance: float = 0.35,
                 avoid_distance: float = 1.3, side_clearance: float = 0.6, detour_forward: float = 0.6,
                 detour_side: float = 0.7, turn_in_place: float = 0.8, stuck_steps: int = 20,
                 backup_steps: int = 30, backup_speed: float = 0.15, max_recoveries: int = 3) -> None:
        self.waypoints = np.asarray(waypoints, float).reshape(-1, 2)
        if len(self.waypoints) == 0:
            raise ValueError("a route needs at least one waypoint")
        self.speed, self.lookahead, self.max_turn_rate = speed, lookahead, max_turn_rate
        self.goal_tolerance, self.stop_distance = goal_tolerance, stop_distance
        self.avoid_distance, self.side_clearance = avoid_distance, side_clearance
        self.detour_forward, self.detour_side = detour_forward, detour_side
        self.detour: np.ndarray | None = None  # a side-step point (2,) in front of an obstacle, while passing it
        self._detour_budget = 0
        self._detour_cooldown = 0
        self.index = 0  # the segment the robot is on: waypoints[index] -> waypoints[index + 1]
        self.turn_in_place = turn_in_place
        self.stuck_steps, self.backup_steps, self.backup_speed = stuck_steps, backup_steps, backup_speed
        self.max_recoveries = max_recoveries
        self._leg_recoveries = 0  # recoveries on the current leg (self.index)
        self._leg = 0
        self.skipped = 0          # waypoints given up after max_recoveries on their leg
        self._last_v = 0.0
        self._recent: deque[tuple[np.ndarray, bool]] = deque(maxlen=stuck_steps)  # (xy, told to drive) per command
        self._backing = 0       # commands of backing off still to go
        self.recoveries = 0     # times the robot backed off after getting stuck

    def _target(self, xy: np.ndarray) -> np.ndarray:
        # a waypoint counts as reached within the goal tolerance or once passed (the route may turn back on
        # itself into a dead end, so corners are not cut by the look-ahead)
        while self.index < len(self.waypoints) - 1:
            a, b = self.waypoints[self.index], self.waypoints[self.index + 1]
            d = b - a
            passed = d @ d > 1e-12 and (xy - a) @ d / (d @ d) > 1.0 and np.linalg.norm(b - xy) < self.lookahead
            if np.linalg.norm(b - xy) < self.goal_tolerance or passed:
                self.index += 1
            else:
                break
        if self.index == len(self.waypoints) - 1:
            return self.waypoints[-1]
        a, b = self.waypoints[self.index], self.waypoints[self.index + 1]
        # the look-ahead circle's intersection with the segment a->b, furthest along it, clipped at b
        d = b - a
        f = a - xy
        qa, qb, qc = d @ d, 2 * f @ d, f @ f - self.lookahead**2
        disc = qb * qb - 4 * qa * qc
        if qa > 1e-12 and disc >= 0:
            s = (-qb + np.sqrt(disc)) / (2 * qa)
            if s >= 0.0:
                return a + min(s, 1.0) * d
        return a if np.linalg.norm(a - xy) > self.lookahead else b

    def command(self, pose: np.ndarray, sonar_poses: np.ndarray | None = None,
                ranges: np.ndarray | None = None) -> MotionCommand:
        pose = np.asarray(pose, float)
        xy = pose[:2]
        recovery = self._recover(xy, sonar_poses, ranges)
        if recovery is not None:
            return recovery
        command = self._pursue(pose, xy, sonar_poses, ranges)
        self._last_v = command.v
        return command

    def _recover(self, xy: np.ndarray, sonar_poses: np.ndarray | None,
                 ranges: np.ndarray | None) -> MotionCommand | None:
        """Back off after being stuck (see the class docstring); None when driving on as usual."""
        self._recent.append((xy.copy(), self._last_v > 0.05))
        if self._backing > 0:
            self._backing -= 1
            behind = min(_sector_min(sonar_poses, ranges, np.pi - 0.5, np.pi),
                         _sector_min(sonar_poses, ranges, -np.pi, -np.pi + 0.5))
            if behind > self.stop_distance + 0.1:
                self._last_v = -self.backup_speed
                return MotionCommand(-self.backup_speed, 0.0, False)
            self._backing = 0  # no room behind: try forward again
        if self._leg != self.index:
            self._leg, self._leg_recoveries = self.index, 0
        # stuck: told to drive for the whole window and still within 3 cm of where the window began (a window,
        # not step by step, because a pose steered on FastSLAM's estimate jitters by its corrections)
        stuck = len(self._recent) == self.stuck_steps and all(driving for _, driving in self._recent) and \
            max(float(np.linalg.norm(p - self._recent[0][0])) for p, _ in self._recent) < 0.03
        if stuck:
            self._recent.clear()
            self._backing = self.backup_steps
            self.recoveries += 1
            self.detour = None
            self._leg_recoveries += 1
            if self._leg_recoveries > self.max_recoveries and self.index < len(self.waypoints) - 1:
                self.index += 1  # give this leg's waypoint up
                self.skipped += 1
        return None

    def _pursue(self, pose: np.ndarray, xy: np.ndarray, sonar_poses: np.ndarray | None,
                ranges: np.ndarray | None) -> MotionCommand:
        if self.detour is not None:
            self._detour_budget -= 1
            if np.linalg.norm(self.detour - xy) < self.goal_tolerance or self._detour_budget <= 0:
                self.detour = None  # side-stepped (or could not): back to the route
                self._detour_cooldown = 30
        self._detour_cooldown = max(0, self._detour_cooldown - 1)
        if self.detour is None and self.index >= len(self.waypoints) - 1 and \
                np.linalg.norm(self.waypoints[-1] - xy) < self.goal_tolerance:
            return MotionCommand(0.0, 0.0, True)
        target = self.detour if self.detour is not None else self._target(xy)
        ahead = _sector_min(sonar_poses, ranges, -0.45, 0.45)
        waypoint = self.waypoints[min(self.index + 1, len(self.waypoints) - 1)]
        to_target = between(pose, np.array([target[0], target[1], 0.0]))
        facing = abs(np.arctan2(to_target[1], to_target[0])) < 0.5
        blocked = facing and ahead < min(self.avoid_distance, float(np.linalg.norm(waypoint - xy)) - 0.2)
        if blocked and self.detour is None and self._detour_cooldown == 0:
            # something in the way that is not the wall the route leads to (another robot, a person): side-step
            # to the right (to the left if the right is closed), as people do in a corridor, then resume
            right = _sector_min(sonar_poses, ranges, -1.75, -0.45)
            left = _sector_min(sonar_poses, ranges, 0.45, 1.75)
            side = -1.0 if right > self.side_clearance or right >= left else 1.0
            step = compose(pose, np.array([self.detour_forward, side * self.detour_side, 0.0]))
            self.detour = step[:2]
            self._detour_budget = 60  # commands (6 s at 10 Hz) before giving the side-step up
            target = self.detour
        local = between(pose, np.array([target[0], target[1], 0.0]))
        distance = max(float(np.hypot(local[0], local[1])), 1e-6)
        curvature = 2.0 * local[1] / distance**2  # pure pursuit: κ = 2 y / L²
        heading_error = float(np.arctan2(local[1], local[0]))
        v = self.speed * max(0.0, np.cos(heading_error)) if abs(heading_error) < self.turn_in_place else 0.0
        w = v * curvature if v > 0.05 else np.sign(heading_error) * 0.5 * self.max_turn_rate
        if ahead < self.avoid_distance and abs(heading_error) < 0.45:  # slow down near what is ahead
            v *= float(np.clip((ahead - self.stop_distance) / (self.avoid_distance - self.stop_distance), 0, 1))
            if v < 0.05:
                w = np.sign(heading_error or -1.0) * 0.5 * self.max_turn_rate
        w = float(np.clip(w, -self.max_turn_rate, self.max_turn_rate))
        return MotionCommand(float(v), w, False)


class WallFollower:
    """Explore by following a wall on ``side`` ("right" or "left") at ``distance`` m with the sonar.

    A proportional law on the side range and its trend; anything nearer than ``front_clearance`` ahead
    makes the robot turn away on the spot. With no wall in sight it drives straight, curving gently
    toward the side to find one.
    """

    def __init__(self, *, side: str = "right", distance: float = 0.8, speed: float = 0.3,
                 front_clearance: float = 0.8, max_turn_rate: float = 0.7, gain: float = 1.2) -> None:
        if side not in ("right", "left"):
            raise ValueError(f"side must be 'right' or 'left', not {side!r}")
        self.sign = -1.0 if side == "right" else 1.0  # the wall's side as a sign of y
        self.distance, self.speed = distance, speed
        self.front_clearance, self.max_turn_rate, self.gain = front_clearance, max_turn_rate, gain

    def command(self, pose: np.ndarray, sonar_poses: np.ndarray | None = None,
                ranges: np.ndarray | None = None) -> MotionCommand:
        ahead = _sector_min(sonar_poses, ranges, -0.5, 0.5)
        lo, hi = sorted((self.sign * 1.2, self.sign * 1.75))
        side = _sector_min(sonar_poses, ranges, lo, hi)
        lo, hi = sorted((self.sign * 0.5, self.sign * 1.0))
        diagonal = _sector_min(sonar_poses, ranges, lo, hi)
        if ahead < self.front_clearance:
            return MotionCommand(0.0, float(-self.sign * self.max_turn_rate))
        if not np.isfinite(side) or side > 3.0 * self.distance:
            return MotionCommand(self.speed, float(self.sign * 0.2))
        # nearer than wanted (side or diagonal) -> turn away from the wall (ω of sign -self.sign)
        nearest = min(side, diagonal / np.sqrt(2.0))
        error = nearest - self.distance
        w = float(np.clip(self.sign * self.gain * error, -self.max_turn_rate, self.max_turn_rate))
        return MotionCommand(self.speed * (1.0 - 0.5 * min(1.0, abs(w) / self.max_turn_rate)), w)


class NoMotion:
    """Leaves the robot alone (someone drives it, or it stays put)."""

    def command(self, pose: np.ndarray, sonar_poses: np.ndarray | None = None,
                ranges: np.ndarray | None = None) -> MotionCommand:
        return MotionCommand(0.0, 0.0, False)
