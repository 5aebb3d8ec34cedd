"""``StereoHead.reopen()`` on a head that never went away (session 48, D). A transient USB error (EIO reads as
"vanished") makes the runtime's camera reopen a head that is still powered and still streaming; IIDC refuses a
video format/mode/rate change while streaming (a stall), so reopen's restore of the mode failed with
``ProtocolError: ... stalled writing register 0xF00608`` and the camera stage could never get its head back.
docs/stereo-head.md's own example (``head.start(); head.grab(); ...; head.reopen()``) raised it."""
from __future__ import annotations

import numpy as np

from drivers.videre import StereoHead
from mocks.stereo_head import VirtualStereoHead


def test_reopen_of_a_streaming_head_restores_mode_and_streaming():
    virtual = VirtualStereoHead(rng=np.random.default_rng(3))
    with StereoHead.open(vendor_id=virtual.vendor_id, product_id=virtual.product_id, backend=virtual) as head:
        head.set_mode(320, 240, 7.5)
        head.controls.set("gain", 20)
        head.start()
        head.grab()
        head.reopen()   # the head is still there and still streaming
        assert head.streaming and virtual.model.iso_enabled
        assert (head.mode.width, head.mode.height, head.mode.rate) == (320, 240, 7.5)
        assert head.controls.get("gain").value == 20
        assert head.grab().left.shape == (240, 320)


def test_reopen_of_an_open_head_that_was_not_streaming_leaves_it_stopped():
    virtual = VirtualStereoHead(rng=np.random.default_rng(3))
    with StereoHead.open(vendor_id=virtual.vendor_id, product_id=virtual.product_id, backend=virtual) as head:
        head.set_mode(640, 480, 15.0)
        head.reopen()
        assert not head.streaming and not virtual.model.iso_enabled
        head.start()
        assert head.grab().left.shape == (480, 640)
