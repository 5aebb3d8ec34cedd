"""A stereo head that was unplugged and never came back does not spoil the mission's end (session 47, F).

`p3at run` with its head unplugged for good mapped on (the camera stage counts the errors and retries, as it should)
until Ctrl-C; then closing the camera raised: `VidereCamera.close` stopped streaming through the head's registers,
and a head the driver had already released after the unplug answers that with NotConnectedError. The exception
left the mission as `p3at run: mission failed: stereo head is closed; open it or call reopen()`, exit 1, without
the summary, the final map and the recording's summary. `StereoHead.close` already stops streaming if the head
is still there and releases it either way: the camera now just closes it.
"""
from __future__ import annotations

import numpy as np
import pytest

from drivers.errors import DriverError
from drivers.videre.head import StereoHead
from mocks.stereo_head import VirtualStereoHead
from runtime.adapters import VidereCamera


def test_a_camera_whose_head_was_unplugged_for_good_closes_without_raising():
    virtual = VirtualStereoHead(rng=np.random.default_rng(0))  # test pattern, no world
    camera = VidereCamera(StereoHead.open(backend=virtual), rate=15.0)
    assert camera.read(timeout=1.0) is not None
    virtual.unplug()
    for _ in range(2):  # the camera stage's retries: the head is released, and reopening it fails
        with pytest.raises(DriverError):
            camera.read(timeout=0.2)
    camera.close()
    camera.close()  # and twice, as every close
    assert not camera.head.is_open


def test_a_streaming_head_is_still_stopped_when_the_camera_closes():
    virtual = VirtualStereoHead(rng=np.random.default_rng(0))
    camera = VidereCamera(StereoHead.open(backend=virtual), rate=15.0)
    assert camera.read(timeout=1.0) is not None
    assert camera.head.streaming
    camera.close()
    assert not camera.head.streaming and not camera.head.is_open
