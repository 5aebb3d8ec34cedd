"""The real driver against the virtual head, through pyusb (``usb.core.find(backend=...)``)."""
from __future__ import annotations

import numpy as np
import pytest

from drivers.errors import DeviceNotFoundError, DriverError, NotConnectedError, ProtocolError
from drivers.videre import LEFT_FIRST, RIGHT_FIRST, NoCalibrationError, StereoHead
from drivers.videre import registers as reg
from drivers.videre.calibration import parse_svs
from mocks.stereo_head import VirtualStereoHead, default_calibration, default_calibration_text
from mocks.stereo_head.device import pattern_source

from .conftest import ManualClock


def test_identification(pattern_head):
    virtual, head = pattern_head
    identity = head.identify()
    assert (identity.vendor, identity.model, identity.stereo) == ("Videre Design", "MDS-STH", True)
    assert identity.firmware_text == "2.3"
    assert "1209:0001" in identity.transport


def test_not_found_and_not_stereo():
    with pytest.raises(DeviceNotFoundError, match="no stereo head found at USB 1209:0002"):
        StereoHead.open(product_id=0x0002, backend=VirtualStereoHead())
    impostor = VirtualStereoHead()
    impostor.strings[2] = "DCAM-X"
    with pytest.raises(ProtocolError, match="not a Videre stereo head"):
        StereoHead.open(backend=impostor)


def test_register_reads_and_writes_reach_the_device(pattern_head):
    virtual, head = pattern_head
    assert head.read_register(reg.VIDERE_DEVICE_FLAGS) & reg.STEREO_FLAG_MASK == reg.STEREO_FLAG_VALUE
    head.set_hdr(True)
    head.set_companding(True)
    head.set_max_auto_exposure(300)
    assert virtual.model.settings.hdr and virtual.model.settings.companding
    assert virtual.model.settings.max_auto_exposure == 300
    assert head.read_register(reg.VIDERE_LOCAL) == reg.CMD_MAX_AUTO_EXPOSURE | 300
    with pytest.raises(ProtocolError, match="stalled"):
        head.read_register(0x0DEAD0)


def test_control_ranges_and_values(pattern_head):
    virtual, head = pattern_head
    ranges = {name: head.controls.range(name) for name in head.controls.names()}
    assert ranges == {"brightness": (0, 255), "exposure": (0, 529), "white_balance": (0, 30), "gain": (0, 48)}
    head.controls.set("exposure", 321)
    head.controls.set("white_balance", 7, 22)
    assert head.controls.get("exposure").value == 321 and virtual.model.settings.exposure == 321
    wb = head.controls.get("white_balance")
    assert (wb.value, wb.value2) == (7, 22)
    head.controls.set_auto("exposure")
    assert head.controls.get("exposure").auto
    with pytest.raises(ValueError, match="outside the head's range 0..48"):
        head.controls.set("gain", 49)
    with pytest.raises(ValueError, match="no automatic mode"):
        head.controls.set_auto("brightness")
    with pytest.raises(ValueError, match="unknown control"):
        head.controls.get("zoom")


@pytest.mark.parametrize("order", [RIGHT_FIRST, LEFT_FIRST])
def test_deinterleaving_a_known_pattern(order):
    virtual = VirtualStereoHead(byte_order=order)
    with StereoHead.open(backend=virtual, byte_order=order) as head:
        head.start()
        frame = head.grab()
    left, right = pattern_source(640, 480)
    assert np.array_equal(frame.left, left) and np.array_equal(frame.right, right)


def test_wrong_byte_order_swaps_the_images():
    with StereoHead.open(backend=VirtualStereoHead(byte_order=LEFT_FIRST), byte_order=RIGHT_FIRST) as head:
        head.start()
        frame = head.grab()
    left, right = pattern_source(640, 480)
    assert np.array_equal(frame.left, right) and np.array_equal(frame.right, left)


def test_every_mode_grabs_its_size(pattern_head):
    virtual, head = pattern_head
    head.start()
    modes = head.modes()
    assert {(m.width, m.height) for m in modes} == {(320, 240), (640, 480), (1024, 768), (1280, 960)}
    assert max(m.rate for m in modes if m.width == 1280) == 7.5
    for width, height, rate in {(m.width, m.height, m.rate) for m in modes if m.rate in (7.5, 15.0)}:
        head.set_mode(width, height, rate)
        frame = head.grab()
        assert frame.left.shape == frame.right.shape == (height, width)
        if width == 320:  # host binning of the 640x480 imager mode
            left, _ = pattern_source(640, 480)
            expected = left.astype(float).reshape(240, 2, 320, 2).mean(axis=(1, 3))
            assert np.abs(frame.left.astype(float) - expected).max() <= 1.0
        else:
            assert np.array_equal(frame.left, pattern_source(width, height)[0])
    with pytest.raises(ValueError, match="no mode 1280x960 at 30 Hz"):
        head.set_mode(1280, 960, 30.0)


def test_grab_needs_start_and_times_out_when_stopped(pattern_head):
    virtual, head = pattern_head
    with pytest.raises(DriverError, match="not streaming"):
        head.grab()
    head.start()
    head.grab()
    virtual.model.iso_enabled = False  # the head stops sending without being told
    with pytest.raises(TimeoutError):
        head.grab(timeout=0.01)


def test_calibration_read_from_the_head_equals_the_file(pattern_head):
    virtual, head = pattern_head
    assert head.read_calibration_text() == default_calibration_text().rstrip("\0")
    assert head.read_calibration() == default_calibration()


def test_write_calibration_erases_and_stores(pattern_head):
    virtual, head = pattern_head
    new = default_calibration().scaled(1280, 960)
    head.write_calibration(new)
    assert head.read_calibration() == new
    assert parse_svs(virtual.model.calibration_text) == new
    # writing without the erase would AND into the flash: the driver's read-back check would catch it
    assert virtual.model._calibration[0] != 0xFFFFFFFF


def test_empty_store_and_old_firmware():
    with StereoHead.open(backend=VirtualStereoHead(calibration=None)) as head:
        with pytest.raises(NoCalibrationError, match="holds no calibration"):
            head.read_calibration()
    with StereoHead.open(backend=VirtualStereoHead(firmware=0x0105)) as head:
        with pytest.raises(ProtocolError, match="firmware 1.5 cannot store"):
            head.write_calibration(default_calibration())


def test_exposure_and_gain_change_brightness_and_noise(world):
    virtual = VirtualStereoHead(world, "robot1", rng=np.random.default_rng(0))
    with StereoHead.open(backend=virtual) as head:
        head.start()
        head.controls.set("exposure", 100)
        dim = head.grab().left.astype(float)
        head.controls.set("exposure", 200)
        mid_a = head.grab().left.astype(float)
        mid_b = head.grab().left.astype(float)
        head.controls.set("gain", 12)  # +6 dB
        head.controls.set("exposure", 100)
        gained_a = head.grab().left.astype(float)
        gained_b = head.grab().left.astype(float)
    unsaturated = (mid_a < 200) & (mid_a > 20)
    assert mid_a[unsaturated].mean() / dim[unsaturated].mean() == pytest.approx(2.0, rel=0.1)
    assert gained_a[unsaturated].mean() == pytest.approx(mid_a[unsaturated].mean(), rel=0.05)
    # same brightness, but gain amplifies the read noise: frame-to-frame differences grow
    assert np.std(gained_a - gained_b) > 1.3 * np.std(mid_a - mid_b)


def test_colour_head_delivers_bgr_tinted_by_white_balance(world):
    virtual = VirtualStereoHead(world, "robot1", colour=True, rng=np.random.default_rng(0))
    with StereoHead.open(backend=virtual, colour=True) as head:
        head.start()
        head.controls.set("white_balance", 15, 30)  # U/B neutral, V/R up
        frame = head.grab()
    assert frame.left.shape == (480, 640, 3)
    blue, green, red = (frame.left[..., i].astype(float).mean() for i in range(3))
    assert red > 1.2 * green and abs(blue - green) < 0.1 * green


def test_dropped_frames_are_counted_with_realtime_pacing():
    clock = ManualClock()
    virtual = VirtualStereoHead(realtime=True, clock=clock, sleep=clock.sleep)
    with StereoHead.open(backend=virtual, clock=clock) as head:
        head.start()
        frames = [head.grab() for _ in range(3)]
        virtual.drop_frames(2)
        frames.append(head.grab())
        frames.append(head.grab())
    assert [f.counter for f in frames] == [0, 1, 2, 5, 6]
    assert [f.dropped for f in frames] == [0, 0, 0, 2, 0]
    assert frames[1].timestamp - frames[0].timestamp == pytest.approx(1 / 15)
    assert head.dropped_frames == 2


def test_frames_are_stamped_with_their_exposure_time():
    """The virtual head delivers each pair ``latency`` after exposing it; a driver told that latency stamps
    the pair with the exposure time and keeps the arrival time apart."""
    clock = ManualClock()
    virtual = VirtualStereoHead(realtime=True, clock=clock, sleep=clock.sleep, latency=0.05)
    with StereoHead.open(backend=virtual, clock=clock, latency=0.05) as head:
        head.start()
        for _ in range(3):
            frame = head.grab()
            assert frame.timestamp == pytest.approx(virtual.last_exposure_time)
            assert frame.received - frame.timestamp == pytest.approx(0.05)
    assert virtual.late_frames == 0


def test_a_render_slower_than_the_latency_delivers_a_late_frame():
    clock = ManualClock()
    virtual = VirtualStereoHead(realtime=True, clock=clock, sleep=clock.sleep, latency=0.02)
    produce = virtual.model.frame

    def slow_frame():
        clock.sleep(0.03)  # the render takes 30 ms of the head's clock
        return produce()

    virtual.model.frame = slow_frame
    with StereoHead.open(backend=virtual, clock=clock, latency=0.02) as head:
        head.start()
        frame = head.grab()
    assert frame.received - virtual.last_exposure_time == pytest.approx(0.03)
    assert virtual.late_frames == 1


@pytest.mark.parametrize("latency", [-0.01, 1.5, float("nan")])
def test_an_impossible_latency_is_refused(latency):
    with pytest.raises(ValueError, match="latency"):
        VirtualStereoHead(latency=latency)
    virtual = VirtualStereoHead()
    with StereoHead.open(backend=virtual) as head, pytest.raises(ValueError, match="latency"):
        head.latency = latency


def test_unplug_mid_stream_then_reopen(pattern_head):
    virtual, head = pattern_head
    head.set_mode(320, 240, 15.0)
    head.controls.set("gain", 20)
    head.controls.set_auto("exposure")
    head.set_hdr(True)
    head.start()
    head.grab()
    virtual.unplug()
    with pytest.raises(NotConnectedError, match=r"vanished while reading a frame \(unplugged\?\).*reopen\(\)"):
        head.grab()
    with pytest.raises(DeviceNotFoundError):
        head.reopen()
    virtual.replug()
    assert not virtual.model.iso_enabled  # the head powered up fresh
    head.reopen()
    assert head.streaming and virtual.model.iso_enabled
    assert head.controls.get("gain").value == 20 and head.controls.get("exposure").auto
    assert virtual.model.settings.hdr
    frame = head.grab()
    assert frame.left.shape == (240, 320)
    head.close()
    head.close()
    with pytest.raises(NotConnectedError, match="closed"):
        head.grab()


def test_ieee1394_transport_fails_clearly_without_libdc1394(monkeypatch):
    from drivers.videre import transport_1394

    monkeypatch.setattr(transport_1394, "_LIBRARY_NAMES", ("no-such-dc1394-library",))
    with pytest.raises(DeviceNotFoundError, match="libdc1394 .* is not installed"):
        StereoHead.open_1394()


def test_auto_exposure_brings_a_dark_image_up(world):
    virtual = VirtualStereoHead(world, "robot1", rng=np.random.default_rng(0))
    with StereoHead.open(backend=virtual) as head:
        head.set_mode(320, 240, 15.0)
        head.start()
        head.controls.set("exposure", 25)
        dark = head.grab().left.mean()
        head.set_max_auto_exposure(400)
        head.controls.set_auto("exposure")
        for _ in range(8):
            bright = head.grab().left.mean()
        state = head.controls.get("exposure")
    assert state.auto and 25 < state.value <= 400
    assert dark < 60 and 90 < bright < 130  # steered towards the 110 DN target


def test_frames_arriving_in_pieces_are_reassembled():
    virtual = VirtualStereoHead(max_transfer=16384)
    with StereoHead.open(backend=virtual) as head:
        head.start()
        first, second = head.grab(), head.grab()
    left, right = pattern_source(640, 480)
    for frame in (first, second):
        assert np.array_equal(frame.left, left) and np.array_equal(frame.right, right)


def test_a_head_left_in_a_foreign_mode_opens_in_the_default_mode():
    virtual = VirtualStereoHead()
    virtual.model.fmt, virtual.model.mode = 0, 0  # 160x120 YUV444: not a stereo mode
    with StereoHead.open(backend=virtual) as head:
        assert (head.mode.width, head.mode.height, head.mode.rate) == (640, 480, 15.0)
        assert (virtual.model.fmt, virtual.model.mode) == (0, 3)
