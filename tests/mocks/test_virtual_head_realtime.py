"""The virtual head on the wall clock with ``drop_late``: like an IIDC camera whose host falls behind, it drops
the frames it cannot deliver at exposure + latency, counts them by reason, and never delivers a late stamp."""
from __future__ import annotations

import pytest

from drivers.videre import StereoHead
from mocks.stereo_head import VirtualStereoHead


class StepClock:
    """A clock that moves only when something sleeps on it, or when a test says the host was busy."""

    def __init__(self, start: float = 100.0) -> None:
        self.now = start

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += max(0.0, seconds)


def _head(clock: StepClock, latency: float) -> VirtualStereoHead:
    return VirtualStereoHead(realtime=True, clock=clock, sleep=clock.sleep, latency=latency, drop_late=True)


def test_a_frame_rendered_slower_than_the_latency_is_dropped_and_the_next_one_delivered_on_time():
    clock = StepClock()
    virtual = _head(clock, latency=0.02)
    produce, renders = virtual.model.frame, []

    def frame():
        renders.append(clock())
        if len(renders) == 2:
            clock.sleep(0.03)  # this render takes longer than the 20 ms the head has until delivery
        return produce()

    virtual.model.frame = frame
    with StereoHead.open(backend=virtual, clock=clock, latency=0.02) as head:
        head.start()
        before = head.grab()
        got = head.grab()
    assert virtual.dropped_at_head == {"not deliverable within the latency (the render or the host thread was "
                                       "late)": 1}
    assert got.timestamp == pytest.approx(virtual.last_exposure_time)  # the delivered frame's own exposure
    assert got.received - got.timestamp == pytest.approx(0.02)
    assert got.timestamp - before.timestamp == pytest.approx(2 / 15)  # the slot after the dropped one
    assert got.counter == before.counter + 2 and got.dropped == 1  # the driver sees the gap in the stream too


def test_slots_that_pass_while_the_host_is_not_reading_are_dropped():
    clock = StepClock()
    virtual = _head(clock, latency=0.05)
    with StereoHead.open(backend=virtual, clock=clock, latency=0.05) as head:
        head.start()
        first = head.grab()
        # the host was busy for 0.5 s after the first frame arrived (at 100.05): the slots 1/15 ... 8/15 s
        # after the first exposure went by unread, the one at 9/15 s is still ahead
        clock.now += 0.5
        second = head.grab()
    (reason, count), = virtual.dropped_at_head.items()
    assert reason == "the host was not reading at the frame slot" and count == 8
    assert second.timestamp == pytest.approx(virtual.last_exposure_time)
    assert second.timestamp - first.timestamp == pytest.approx(9 / 15)
    assert second.received - second.timestamp == pytest.approx(0.05)
