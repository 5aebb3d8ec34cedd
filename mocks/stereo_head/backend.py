"""The virtual stereo head as a pyusb backend: ``usb.core.find(backend=VirtualStereoHead(...))`` finds it.

It emulates the USB device the real driver expects (descriptors, strings, IIDC-over-USB vendor control
transfers for registers, bulk endpoint 0x81 for frames) around a ``HeadModel``. Frames are produced when
the host reads them; with ``realtime=True`` the head paces them at the selected frame rate on its clock,
exposes each at its frame slot (the world's pose at that instant) and delivers it ``latency`` seconds later,
as a real head's exposure, read-out and transfer do: the driver's ``StereoHead(latency=...)`` set to the same
value stamps frames with their exposure time. On a lockstep clock (``mocks.simclock``) that is exact; on the
wall clock a render slower than ``latency`` makes that frame late (``late_frames`` counts them), and with
``drop_late`` such frames are dropped at the head instead of delivered with a wrong stamp.
``unplug()`` / ``replug()`` simulate the cable.
"""
from __future__ import annotations

import errno
import math
import threading
import time
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import usb.backend
import usb.core

from drivers.videre import registers as reg
from drivers.videre.calibration import StereoCalibration, format_svs, parse_svs
from drivers.videre.frames import RIGHT_FIRST
from drivers.videre.registers import (
    DEFAULT_PRODUCT_ID,
    DEFAULT_VENDOR_ID,
    FRAME_ENDPOINT,
    REQUEST_REGISTER,
    REQUEST_TYPE_READ,
    REQUEST_TYPE_WRITE,
)
from mocks.simclock import is_lockstep
from mocks.stereo_head.device import HeadModel, RegisterStall, pattern_source

DEFAULT_CALIBRATION_PATH = Path(__file__).resolve().parent / "data" / "sth_mdcs2_default.ini"
_DEFAULT = object()
# exposure -> delivery in realtime mode: above a 640x480 render's ~30 ms on a loaded laptop
DEFAULT_LATENCY = 0.06
_GET_DESCRIPTOR = 6
_LIBUSB_TIMEOUT, _LIBUSB_PIPE, _LIBUSB_NO_DEVICE = -7, -9, -4


def default_calibration_text() -> str:
    """The SVS file the virtual head ships with (the STEREO_DEFAULTS geometry)."""
    return DEFAULT_CALIBRATION_PATH.read_text(encoding="latin-1")


def default_calibration() -> StereoCalibration:
    return parse_svs(default_calibration_text(), str(DEFAULT_CALIBRATION_PATH))


class VirtualStereoHead(usb.backend.IBackend):
    """A pyusb backend holding one virtual STH-MDCS2.

    world, robot: render the building from ``world.pose(robot)`` (a ``mocks.world.World``); without a world
    the head shows a fixed test pattern (``device.pattern_source``).
    calibration: what the head's store holds (default: the packaged file; None: an empty store). It also sets
    the optics the renderer uses, unless ``optics`` is given (to simulate a stale stored calibration).
    rng: noise generator. clock/sleep: time source for ``realtime`` pacing (a lockstep ``mocks.simclock.SimClock``
    makes exposure and delivery exact in simulated time; ``sleep`` is then not used).
    latency: seconds from exposure to delivery in ``realtime`` mode (default ``DEFAULT_LATENCY``).
    drop_late: drop frames that cannot be delivered exactly ``latency`` after their exposure (within
    ``stamp_tolerance`` s), counted by reason in ``dropped_at_head``: a wall-clock run on a busy host.
    max_transfer: cap on the bytes one bulk read returns (frames then arrive in pieces, as on a real bus).
    renderer: an existing ``StereoRenderer`` of the same world and optics to share (its texture atlas takes
    about half a second to bake), e.g. for several heads in one building.
    """

    def __init__(self, world=None, robot: str | None = None, *, rng: np.random.Generator | None = None,
                 calibration: StereoCalibration | str | None | object = _DEFAULT,
                 optics: StereoCalibration | None = None, byte_order: str = RIGHT_FIRST, colour: bool = False,
                 firmware: int = 0x0203, vendor_id: int = DEFAULT_VENDOR_ID, product_id: int = DEFAULT_PRODUCT_ID,
                 serial: str = "VIRTUAL-0001", realtime: bool = False, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep, texture_resolution: float = 100.0, bus: int = 1,
                 address: int = 7, renderer=None, max_transfer: int | None = None,
                 latency: float = DEFAULT_LATENCY, drop_late: bool = False, stamp_tolerance: float = 0.01):
        super().__init__()
        if calibration is _DEFAULT:
            text: str | None = default_calibration_text()
        elif isinstance(calibration, StereoCalibration):
            text = format_svs(calibration)
        else:
            text = calibration  # type: ignore[assignment]
        self.optics = optics or (parse_svs(text, "virtual head calibration") if text else default_calibration())
        self.world, self.robot = world, robot
        self._renderer, self._texture_resolution = renderer, texture_resolution
        if world is not None:
            if robot is None:
                raise ValueError("a virtual head in a world needs the name of the robot it is mounted on")
            source = self._render
        else:
            source = pattern_source
        self.model = HeadModel(source, calibration_text=text, rng=rng or np.random.default_rng(0),
                               byte_order=byte_order, colour=colour, firmware=firmware)
        self.vendor_id, self.product_id = vendor_id, product_id
        self.strings = {1: reg.VENDOR_NAME, 2: reg.MODEL_NAME, 3: serial}
        self.realtime, self._clock, self._sleep = realtime, clock, sleep
        if is_lockstep(clock):
            self._sleep_until = clock.sleep_until  # simulated time: exposure and delivery exactly on time
        else:
            self._sleep_until = lambda t: sleep(max(0.0, t - clock()))
        if not 0.0 <= latency < 1.0:
            raise ValueError(f"latency must be in [0, 1) s, got {latency!r}")
        self.latency = float(latency)
        self.drop_late = bool(drop_late)
        self.stamp_tolerance = float(stamp_tolerance)
        self.late_frames = 0
        self.dropped_at_head: dict[str, int] = {}  # reason -> frames (drop_late only)
        self._exposed_at: float | None = None
        self.last_exposure_time: float | None = None
        self.max_transfer = max_transfer
        self._lock = threading.RLock()
        self._plugged = True
        self._open_handles = 0
        self._pending: memoryview | None = None
        self._next_frame_time: float | None = None
        self._skip_frames = 0
        self.last_frame_pose: np.ndarray | None = None
        self._device = SimpleNamespace(
            bLength=18, bDescriptorType=1, bcdUSB=0x0200, bDeviceClass=0xFF, bDeviceSubClass=0,
            bDeviceProtocol=0, bMaxPacketSize0=64, idVendor=vendor_id, idProduct=product_id,
            bcdDevice=firmware, iManufacturer=1, iProduct=2, iSerialNumber=3, bNumConfigurations=1,
            address=address, bus=bus, port_number=1, port_numbers=(1,), speed=3)  # speed 3: high speed
        self._config = SimpleNamespace(bLength=9, bDescriptorType=2, wTotalLength=25, bNumInterfaces=1,
                                       bConfigurationValue=1, iConfiguration=0, bmAttributes=0x80, bMaxPower=250,
                                       extra_descriptors=[])
        self._interface = SimpleNamespace(bLength=9, bDescriptorType=4, bInterfaceNumber=0, bAlternateSetting=0,
                                          bNumEndpoints=1, bInterfaceClass=0xFF, bInterfaceSubClass=0,
                                          bInterfaceProtocol=0, iInterface=0, extra_descriptors=[])
        self._endpoint = SimpleNamespace(bLength=7, bDescriptorType=5, bEndpointAddress=FRAME_ENDPOINT,
                                         bmAttributes=0x02, wMaxPacketSize=512, bInterval=0, bRefresh=0,
                                         bSynchAddress=0, extra_descriptors=[])

    # ------------------------------------------------------------------ test controls
    def unplug(self) -> None:
        """Pull the cable: every transfer fails with ENODEV and ``usb.core.find`` no longer sees the head."""
        with self._lock:
            self._plugged = False
            self._pending = None

    def replug(self) -> None:
        """Plug it back: the head powers on again (registers reset, calibration kept)."""
        with self._lock:
            self._plugged = True
            self.model.power_on()
            self._next_frame_time = None

    def drop_frames(self, count: int) -> None:
        """The next ``count`` frame slots are lost on the bus (realtime pacing skips them)."""
        with self._lock:
            self._skip_frames += int(count)

    @property
    def plugged(self) -> bool:
        return self._plugged

    @property
    def renderer(self):
        """The building renderer (built on first use: baking the textures takes about half a second)."""
        if self._renderer is None and self.world is not None:
            from mocks.stereo_head.renderer import StereoRenderer

            self._renderer = StereoRenderer(self.world, self.optics, self._texture_resolution)
        return self._renderer

    def _render(self, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
        self._exposed_at = self._clock() if self.realtime else None  # the instant the world is sampled
        pose = np.asarray(self.world.pose(self.robot), float)
        self.last_frame_pose = pose
        return self.renderer.render(pose, (width, height))

    def _gone(self) -> usb.core.USBError:
        return usb.core.USBError("No such device (it may have been disconnected)", _LIBUSB_NO_DEVICE, errno.ENODEV)

    def _check(self) -> None:
        if not self._plugged:
            raise self._gone()

    # ------------------------------------------------------------------ IBackend: descriptors
    def enumerate_devices(self):
        if self._plugged:
            yield self._device

    def get_device_descriptor(self, dev):
        return self._device

    def get_configuration_descriptor(self, dev, config):
        if config != 0:
            raise IndexError("configuration index out of range")
        return self._config

    def get_interface_descriptor(self, dev, intf, alt, config):
        if (intf, alt, config) != (0, 0, 0):
            raise IndexError("interface index out of range")
        return self._interface

    def get_endpoint_descriptor(self, dev, ep, intf, alt, config):
        if (ep, intf, alt, config) != (0, 0, 0, 0):
            raise IndexError("endpoint index out of range")
        return self._endpoint

    # ------------------------------------------------------------------ IBackend: handles
    def open_device(self, dev):
        self._check()
        with self._lock:
            self._open_handles += 1
        return SimpleNamespace(device=dev)

    def close_device(self, dev_handle):
        with self._lock:
            self._open_handles = max(0, self._open_handles - 1)

    def set_configuration(self, dev_handle, config_value):
        self._check()
        if config_value != 1:
            raise usb.core.USBError("Invalid parameter", -2, errno.EINVAL)

    def get_configuration(self, dev_handle):
        self._check()
        return 1

    def set_interface_altsetting(self, dev_handle, intf, altsetting):
        self._check()

    def claim_interface(self, dev_handle, intf):
        self._check()

    def release_interface(self, dev_handle, intf):
        self._check()

    def clear_halt(self, dev_handle, ep):
        self._check()

    def reset_device(self, dev_handle):
        self._check()
        self.model.power_on()

    def is_kernel_driver_active(self, dev_handle, intf):
        return False

    def detach_kernel_driver(self, dev_handle, intf):
        pass

    def attach_kernel_driver(self, dev_handle, intf):
        pass

    # ------------------------------------------------------------------ IBackend: transfers
    def ctrl_transfer(self, dev_handle, bmRequestType, bRequest, wValue, wIndex, data, timeout):
        """Fill ``data`` (IN) and return the byte count, or consume it (OUT) and return its length."""
        self._check()
        address = (wIndex << 16) | wValue
        if bmRequestType == 0x80 and bRequest == _GET_DESCRIPTOR and (wValue >> 8) == 3:
            return self._string_descriptor(wValue & 0xFF, data)
        try:
            if bmRequestType == REQUEST_TYPE_READ and bRequest == REQUEST_REGISTER:
                payload = self.model.read(address).to_bytes(4, "little")
                count = min(len(data), 4)
                data[:count] = type(data)("B", payload[:count])
                return count
            if bmRequestType == REQUEST_TYPE_WRITE and bRequest == REQUEST_REGISTER:
                if len(data) != 4:
                    raise RegisterStall("register writes are one quadlet")
                self.model.write(address, int.from_bytes(bytes(data), "little"))
                if address == reg.COMMAND_BASE + reg.ISO_EN:
                    with self._lock:
                        self._pending, self._next_frame_time = None, None
                return 4
        except RegisterStall:
            raise usb.core.USBError("Pipe error", _LIBUSB_PIPE, errno.EPIPE) from None
        raise usb.core.USBError("Pipe error", _LIBUSB_PIPE, errno.EPIPE)

    def _string_descriptor(self, index: int, data) -> int:
        if index == 0:
            payload = bytes([4, 3, 0x09, 0x04])  # LANGID en-US
        elif index in self.strings:
            text = self.strings[index].encode("utf-16-le")
            payload = bytes([2 + len(text), 3]) + text
        else:
            raise usb.core.USBError("Pipe error", _LIBUSB_PIPE, errno.EPIPE)
        count = min(len(data), len(payload))
        data[:count] = type(data)("B", payload[:count])
        return count

    def bulk_read(self, dev_handle, ep, intf, buff, timeout):
        """Fill ``buff`` with the next bytes of the frame stream and return the count."""
        self._check()
        if ep != FRAME_ENDPOINT:
            raise usb.core.USBError("Pipe error", _LIBUSB_PIPE, errno.EPIPE)
        with self._lock:
            pending = self._pending
        if pending is None:
            if not self.model.iso_enabled:
                if self.realtime:
                    self._sleep_until(self._clock() + timeout / 1000.0)
                raise usb.core.USBTimeoutError("Operation timed out", _LIBUSB_TIMEOUT, errno.ETIMEDOUT)
            frame = self._next_frame(timeout / 1000.0)
            self._check()  # unplugged while the frame was being produced
            pending = memoryview(frame.data).cast("B")
        count = min(len(buff), len(pending), self.max_transfer or len(pending))
        np.frombuffer(buff, np.uint8, count)[:] = np.frombuffer(pending[:count], np.uint8)
        with self._lock:
            self._pending = pending[count:] if count < len(pending) else None
        return count

    def _next_frame(self, timeout: float) -> np.ndarray:
        """The next frame of the stream. Without ``realtime``: at once. With it: exposed at the next frame slot
        and delivered ``latency`` after the exposure. With ``drop_late`` (a wall clock that the host may not
        keep up with), frames that cannot be delivered on time are dropped at the head, as an IIDC camera
        whose host does not read drops them: the slots that passed while the host was not reading, and the
        frames whose delivery would come later than exposure + latency + ``stamp_tolerance``. Every delivered
        frame therefore reaches the driver at its exposure time + ``latency``, the stamp the driver gives it."""
        if not self.realtime:
            return self.model.frame()
        give_up = self._clock() + timeout
        while True:
            due = self._pace()
            self._exposed_at = None
            frame = self.model.frame()
            exposure = self._exposed_at if self._exposed_at is not None else due
            self.last_exposure_time = exposure
            if self._deliver_at(exposure + self.latency) or not self.drop_late:
                return frame
            self._drop("not deliverable within the latency (the render or the host thread was late)")
            if self._clock() >= give_up:
                raise usb.core.USBTimeoutError("Operation timed out", _LIBUSB_TIMEOUT, errno.ETIMEDOUT)

    def _drop(self, reason: str, count: int = 1) -> None:
        with self._lock:
            self.dropped_at_head[reason] = self.dropped_at_head.get(reason, 0) + count

    def _pace(self) -> float:
        """Wait for the next frame slot of the selected rate (skipping dropped slots) and return it: the slot,
        or now if the host asked after it (the head waits for a reader; with ``drop_late`` the slots that
        passed are dropped and the next one is waited for)."""
        period = 1.0 / self.model.rate_hz
        with self._lock:
            now = self._clock()
            if self._next_frame_time is None:
                self._next_frame_time = now
            self._next_frame_time += period * self._skip_frames
            self._skip_frames = 0
            due = self._next_frame_time
            missed = 0
            if self.drop_late and due < now - self.stamp_tolerance:
                missed = math.ceil((now - self.stamp_tolerance - due) / period)
                due += missed * period
            self._next_frame_time = max(due, now) + period
        if missed:
            self._drop("the host was not reading at the frame slot", missed)
        if due > now:
            self._sleep_until(due)
        return max(due, now)

    def _deliver_at(self, when: float) -> bool:
        """Wait until ``when``; False (and ``late_frames`` counted) if that moment had already passed, or with
        ``drop_late`` if the wait overshot it by more than ``stamp_tolerance``."""
        delay = when - self._clock()
        if delay < 0.0:
            self.late_frames += 1
            return False
        self._sleep_until(when)
        if self.drop_late and self._clock() - when > self.stamp_tolerance:
            self.late_frames += 1
            return False
        return True

    def bulk_write(self, dev_handle, ep, intf, data, timeout):
        self._check()
        raise usb.core.USBError("Pipe error", _LIBUSB_PIPE, errno.EPIPE)
