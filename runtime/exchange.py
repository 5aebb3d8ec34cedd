"""The map exchange: the only way robots share anything (publish my map, receive the others').

A robot's runtime holds a :class:`MapExchange` and never another robot's objects, so a distributed
transport (a message bus, a file share, DDS...) can replace :class:`InProcessExchange` without changing the
runtime. Messages are whole :class:`~estimation.landmark_map.LandmarkMap` snapshots; a receiver gets copies,
never the publisher's arrays, exactly as it would over a wire.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from estimation.landmark_map import LandmarkMap


@dataclass(frozen=True)
class MapMessage:
    """One published snapshot: who sent it, its sequence number per sender, when (sender's clock, s)."""

    robot: str
    sequence: int
    stamp: float
    landmark_map: LandmarkMap


class MapExchange(Protocol):
    def publish(self, robot: str, landmark_map: LandmarkMap, stamp: float = 0.0) -> None:
        """Offer this robot's latest map to the others."""

    def receive(self, excluding: str | None = None) -> dict[str, MapMessage]:
        """The latest snapshot of every robot except ``excluding``."""


def copy_map(m: LandmarkMap) -> LandmarkMap:
    """A deep copy (fancy indexing copies every array)."""
    copied = m.subset(np.arange(len(m)))
    copied.metadata = dict(m.metadata)
    return copied


class InProcessExchange:
    """Thread-safe in-process exchange: keeps each robot's latest snapshot, hands out copies."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._latest: dict[str, MapMessage] = {}
        self.published = 0

    def publish(self, robot: str, landmark_map: LandmarkMap, stamp: float = 0.0) -> None:
        snapshot = copy_map(landmark_map)
        with self._lock:
            previous = self._latest.get(robot)
            sequence = 0 if previous is None else previous.sequence + 1
            self._latest[robot] = MapMessage(robot, sequence, float(stamp), snapshot)
            self.published += 1

    def receive(self, excluding: str | None = None) -> dict[str, MapMessage]:
        with self._lock:
            messages = {r: m for r, m in self._latest.items() if r != excluding}
        return {r: MapMessage(m.robot, m.sequence, m.stamp, copy_map(m.landmark_map)) for r, m in messages.items()}
