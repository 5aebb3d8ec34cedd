"""The pure IIDC register codecs and the frame helpers."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.errors import ProtocolError
from drivers.videre import registers as reg
from drivers.videre.frames import (
    LEFT_FIRST,
    RIGHT_FIRST,
    FrameSequencer,
    bin2x2,
    deinterleave,
    demosaic,
    interleave,
    mosaic,
)

values = st.integers(0, 0xFFF)


@given(values, values, st.booleans(), st.booleans())
def test_control_round_trip(value, value2, auto, on):
    control = reg.FeatureControl(value, auto, on)
    assert reg.decode_control(reg.encode_control(control)) == control
    two = reg.FeatureControl(value, auto, on, value2)
    assert reg.decode_control(reg.encode_control(two, True), True) == two


@given(values, values, st.booleans())
def test_inquiry_round_trip(lo, hi, auto):
    inquiry = reg.decode_inquiry(reg.encode_inquiry(lo, hi, auto=auto))
    assert (inquiry.present, inquiry.minimum, inquiry.maximum, inquiry.auto_capable) == (True, lo, hi, auto)


def test_inquiry_golden_bits():
    # presence bit 31, readout bit 27, manual bit 24, min 0 in bits 12-23, max 529 in bits 0-11
    assert reg.encode_inquiry(0, 529, auto=False) == 0x89000211
    assert reg.FEATURES["exposure"].control == 0x804 and reg.FEATURES["exposure"].inquiry == 0x504
    assert reg.encode_control(reg.FeatureControl(5, auto=True)) == 0x80000000 | 0x02000000 | 0x01000000 | 5


@given(st.binary(max_size=reg.CALIB_MAX_BYTES - 8).map(lambda b: b.replace(b"\0", b"x")))
def test_calibration_text_quadlets_round_trip(text):
    quadlets = reg.text_to_quadlets(text)
    assert quadlets[-1] == 0
    assert reg.quadlets_to_text(quadlets) == text


def test_calibration_quadlets_are_msb_first_and_empty_store():
    assert reg.text_to_quadlets(b"# SV")[0] == 0x23205356
    assert reg.quadlets_to_text([0xFFFFFFFF, 0]) is None
    with pytest.raises(ValueError):
        reg.text_to_quadlets(b"x" * reg.CALIB_MAX_BYTES)


@given(st.integers(0, 7))
def test_index_registers(index):
    assert reg.decode_index(reg.encode_index(index)) == index
    assert reg.mask_indices(reg.bit_mask([index])) == [index]


def test_unknown_mode_is_a_protocol_error():
    with pytest.raises(ProtocolError):
        reg.find_video_mode(0, 0)


@pytest.mark.parametrize("order", [RIGHT_FIRST, LEFT_FIRST])
def test_interleave_round_trip(order):
    rng = np.random.default_rng(0)
    left, right = rng.integers(0, 256, (2, 6, 8), dtype=np.uint8)
    raw = interleave(left, right, order)
    first = raw[:, :, 0]
    assert np.array_equal(first, right if order == RIGHT_FIRST else left)
    back_left, back_right = deinterleave(raw.tobytes(), 8, 6, order)
    assert np.array_equal(back_left, left) and np.array_equal(back_right, right)


def test_deinterleave_rejects_wrong_size_and_order():
    with pytest.raises(ProtocolError, match="expected 96"):
        deinterleave(bytes(95), 8, 6)
    with pytest.raises(ValueError):
        deinterleave(bytes(96), 8, 6, "sideways")


def test_bayer_round_trip_keeps_colour_of_flat_patches():
    bgr = np.zeros((8, 8, 3), np.uint8)
    bgr[...] = (30, 120, 220)
    assert np.abs(demosaic(mosaic(bgr))[2:-2, 2:-2].astype(int) - bgr[2:-2, 2:-2]).max() <= 1


def test_binning_averages_blocks():
    image = np.arange(16, dtype=np.uint8).reshape(4, 4) * 10
    assert bin2x2(image).tolist() == [[25, 45], [105, 125]]


def test_sequencer_counts_gaps():
    seq = FrameSequencer(15.0)
    assert seq.next(0.0) == (0, 0)
    assert seq.next(1 / 15) == (1, 0)
    assert seq.next(4 / 15 + 0.01) == (4, 2)
    assert seq.dropped_total == 2
    seq.restart(7.5)
    assert seq.next(100.0) == (5, 0)


class _RecordingDevice:
    """Stands in for a pyusb Device to pin the wire framing to the reference (a golden vector)."""

    def __init__(self):
        self.calls = []

    def ctrl_transfer(self, *args):
        self.calls.append(args)
        return bytes([0x78, 0x56, 0x34, 0x12]) if args[0] == 0xC0 else 4


def test_usb_register_framing_golden():
    from drivers.videre.transport import UsbTransport

    device = _RecordingDevice()
    transport = UsbTransport(device, "recording")
    assert transport.read_register(0xFFF004) == 0x12345678  # quadlet little-endian
    transport.write_register(0xF00614, 0x80000000)
    assert device.calls[0] == (0xC0, 0x7F, 0xF004, 0x00FF, 4, 1000)  # wValue = addr & 0xFFFF, wIndex = addr >> 16
    assert device.calls[1] == (0x40, 0x7F, 0x0614, 0x00F0, bytes([0, 0, 0, 0x80]), 1000)
