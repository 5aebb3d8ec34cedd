"""Shared fixtures: the building (loaded once) and a virtual head + real driver pair."""
from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from drivers.videre import StereoHead
from mocks.stereo_head import VirtualStereoHead
from mocks.world import World


class ManualClock:
    """A clock that only moves when something sleeps on it (drives realtime pacing in tests)."""

    def __init__(self, start: float = 100.0):
        self.now = start

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += max(0.0, seconds)


@pytest.fixture(scope="session")
def world() -> World:
    w = World.load()
    w.add_robot("robot1", w.start_poses["robot1"])
    return w


@pytest.fixture
def pattern_head() -> Iterator[tuple[VirtualStereoHead, StereoHead]]:
    """A virtual head showing the known test pattern, opened by the real driver through pyusb."""
    virtual = VirtualStereoHead(rng=np.random.default_rng(3))
    head = StereoHead.open(vendor_id=virtual.vendor_id, product_id=virtual.product_id, backend=virtual)
    yield virtual, head
    head.close()
