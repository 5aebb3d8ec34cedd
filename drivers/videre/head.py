"""The STH-MDCS2 stereo head: identification, controls, video modes, streaming, stored calibration.

``StereoHead`` talks to any ``Transport``; ``StereoHead.open`` builds the pyusb one. Time is injected
(``clock``: a callable returning seconds), so frame timestamps and dropped-frame counts are reproducible.

Frame timestamps are the exposure time, not the arrival time: a pair reaches the host a fixed pipeline
delay after it was exposed (exposure, read-out, USB transfer; tens of milliseconds at 640×480), and a
robot moving at 0.5 m/s and 1 rad/s has moved 2.5 cm and turned 3° in 50 ms -- enough to break data
association in SLAM. ``latency`` (seconds) is that delay; it is subtracted from the arrival time. The
STH-MDCS2 reports no timestamp of its own, so the delay is a setting, measured once per head and mode
(the virtual head states its own; ROS camera1394 calls the same thing ``time_offset``).
"""
from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.errors import DriverError, NotConnectedError, ProtocolError
from drivers.videre import registers as reg
from drivers.videre.calibration import StereoCalibration, format_svs, parse_svs
from drivers.videre.frames import (
    RIGHT_FIRST,
    FrameSequencer,
    bin2x2,
    check_byte_order,
    deinterleave,
    demosaic,
)
from drivers.videre.transport import DEFAULT_PRODUCT_ID, DEFAULT_VENDOR_ID, Transport, UsbTransport


class NoCalibrationError(DriverError, LookupError):
    """The head holds no calibration text (its store reads 0xFFFFFFFF)."""


@dataclass(frozen=True)
class HeadIdentity:
    vendor: str
    model: str
    firmware: int  # e.g. 0x0203 = 2.3
    stereo: bool
    transport: str

    @property
    def firmware_text(self) -> str:
        return f"{self.firmware >> 8}.{self.firmware & 0xFF}"


@dataclass(frozen=True)
class OutputMode:
    """A size/rate the driver delivers: an imager video mode, optionally binned on the host."""

    width: int
    height: int
    rate: float
    video_mode: reg.VideoMode
    binning: int = 1

    def __str__(self) -> str:
        how = f"host binning {self.binning}x{self.binning} of " if self.binning > 1 else ""
        return (f"{self.width}x{self.height} @ {self.rate:g} Hz ({how}IIDC format {self.video_mode.fmt} "
                f"mode {self.video_mode.mode}, imager decimation {self.video_mode.decimation})")


@dataclass(frozen=True)
class StereoFrame:
    """One stereo pair. left, right: (H, W) uint8 (mono) or (H, W, 3) uint8 BGR (colour heads).

    timestamp: seconds of the injected clock when the pair was exposed (arrival minus the head's ``latency``);
    counter: frame number in the stream (gaps when frames were dropped); dropped: frames lost just before
    this one; received: seconds of the injected clock when the last byte of the pair arrived.
    """

    left: np.ndarray
    right: np.ndarray
    timestamp: float
    counter: int
    dropped: int
    received: float


@dataclass(frozen=True)
class ControlState:
    name: str
    value: int
    auto: bool
    minimum: int
    maximum: int
    value2: int | None = None  # white balance: V/R (value is U/B)


class Controls:
    """The head's feature controls (exposure, gain, brightness, white_balance) with their inquiry ranges."""

    def __init__(self, head: StereoHead):
        self._head = head
        self._ranges: dict[str, reg.FeatureInquiry] = {}

    def names(self) -> list[str]:
        return list(reg.FEATURES)

    def range(self, name: str) -> tuple[int, int]:
        inquiry = self._inquiry(name)
        return inquiry.minimum, inquiry.maximum

    def _spec(self, name: str) -> reg.FeatureSpec:
        if name not in reg.FEATURES:
            raise ValueError(f"unknown control {name!r}; the head has {', '.join(reg.FEATURES)}")
        return reg.FEATURES[name]

    def _inquiry(self, name: str) -> reg.FeatureInquiry:
        if name not in self._ranges:
            spec = self._spec(name)
            inquiry = reg.decode_inquiry(self._head._read(spec.inquiry))
            if not inquiry.present:
                raise ProtocolError(f"the head reports no {name} feature (inquiry 0x{spec.inquiry:03X})")
            self._ranges[name] = inquiry
        return self._ranges[name]

    def get(self, name: str) -> ControlState:
        spec = self._spec(name)
        inquiry = self._inquiry(name)
        control = reg.decode_control(self._head._read(spec.control), spec.two_values)
        return ControlState(name, control.value, control.auto, inquiry.minimum, inquiry.maximum, control.value2)

    def set(self, name: str, value: int, value2: int | None = None) -> None:
        """Manual value (white balance: value = U/B, value2 = V/R, default the same); ValueError if out of range."""
        spec = self._spec(name)
        lo, hi = self.range(name)
        for v in (value,) if value2 is None else (value, value2):
            if not lo <= int(v) <= hi:
                raise ValueError(f"{name} {v} is outside the head's range {lo}..{hi}")
        self._head._write_setting(spec.control, reg.encode_control(
            reg.FeatureControl(int(value), auto=False, on=True, value2=value2), spec.two_values))

    def set_auto(self, name: str, auto: bool = True) -> None:
        spec = self._spec(name)
        if auto and not self._inquiry(name).auto_capable:
            raise ValueError(f"{name} has no automatic mode")
        current = reg.decode_control(self._head._read(spec.control), spec.two_values)
        self._head._write_setting(spec.control, reg.encode_control(
            reg.FeatureControl(current.value, auto=auto, on=True, value2=current.value2), spec.two_values))

    def all(self) -> list[ControlState]:
        return [self.get(name) for name in reg.FEATURES]


class StereoHead:
    """A Videre STH-MDCS2 on some transport. Use ``StereoHead.open(...)`` or wrap a ``Transport``."""

    def __init__(self, transport_factory: Callable[[], Transport], *, byte_order: str = RIGHT_FIRST,
                 colour: bool = False, clock: Callable[[], float] = time.monotonic, latency: float = 0.0):
        self._factory = transport_factory
        self.byte_order = check_byte_order(byte_order)
        self.colour = colour
        self._clock = clock
        self.latency = latency
        self._transport: Transport | None = None
        self._mode: OutputMode | None = None
        self._streaming = False
        self._resume_streaming = False
        self._settings: dict[tuple[int, int], int] = {}  # what the user set, re-applied by reopen()
        self._sequencer = FrameSequencer(15.0)
        self.controls = Controls(self)
        self._connect()

    @classmethod
    def open(cls, vendor_id: int = DEFAULT_VENDOR_ID, product_id: int = DEFAULT_PRODUCT_ID, backend: Any = None,
             byte_order: str = RIGHT_FIRST, colour: bool = False, serial: str | None = None,
             clock: Callable[[], float] = time.monotonic, latency: float = 0.0) -> StereoHead:
        """Find the head on USB (``backend`` is passed to ``usb.core.find``) and check it is a stereo head."""
        return cls(lambda: UsbTransport.open(vendor_id, product_id, backend, serial), byte_order=byte_order,
                   colour=colour, clock=clock, latency=latency)

    @classmethod
    def open_1394(cls, guid: int | None = None, byte_order: str = RIGHT_FIRST, colour: bool = False,
                  clock: Callable[[], float] = time.monotonic, latency: float = 0.0) -> StereoHead:
        """Open an IEEE-1394 head through the system's libdc1394 (DeviceNotFoundError if it or a camera is
        missing)."""
        from drivers.videre.transport_1394 import Dc1394Transport

        return cls(lambda: Dc1394Transport.open(guid), byte_order=byte_order, colour=colour, clock=clock,
                   latency=latency)

    # --- lifecycle ---
    def _connect(self) -> None:
        self._transport = self._factory()
        try:
            identity = self.identify()
            if not identity.stereo or identity.model != reg.MODEL_NAME:
                raise ProtocolError(f"{identity.transport}: {identity.vendor} {identity.model!r} is not a Videre "
                                    f"stereo head (model {reg.MODEL_NAME!r} with the stereo flag)")
            if self._mode is None:
                try:
                    self._mode = self._current_mode()
                except (ProtocolError, IndexError):  # left in a mode this driver cannot split: use the default
                    self._mode = self.set_mode(640, 480, 15.0)
        except BaseException:
            self._transport.close()
            self._transport = None
            raise

    def reopen(self) -> None:
        """Close and find the head again (after an unplug), restoring the controls and vendor settings made
        through this object, its mode and its streaming state."""
        was_streaming, mode = self._streaming or self._resume_streaming, self._mode
        self._resume_streaming = was_streaming  # kept if this attempt fails (head still unplugged)
        if self._transport is not None:
            self._transport.close()
            self._transport = None
        self._streaming = False
        self._connect()
        # a head that never went away (a transient USB error) still streams, and IIDC refuses a mode change
        # while it does (a stall): stop it first; on a head that was power-cycled this changes nothing
        self._write(reg.ISO_EN, 0)
        self.controls = Controls(self)
        for (register, _), value in self._settings.items():
            self._write(register, value)
        if mode is not None:
            self.set_mode(mode.width, mode.height, mode.rate)
        if was_streaming:
            self.start()
        self._resume_streaming = False

    def close(self) -> None:
        """Stop streaming (if the head is still there) and release it; safe to call twice."""
        if self._transport is None:
            return
        try:
            if self._streaming:
                self._write(reg.ISO_EN, 0)
        except DriverError:
            pass  # closing a vanished head must still release the handle
        finally:
            self._streaming = False
            self._transport.close()
            self._transport = None

    @property
    def is_open(self) -> bool:
        return self._transport is not None

    def __enter__(self) -> StereoHead:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- registers ---
    def _live(self) -> Transport:
        if self._transport is None:
            raise NotConnectedError("stereo head is closed; open it or call reopen()")
        return self._transport

    def _read(self, register: int) -> int:
        return self._live().read_register(reg.COMMAND_BASE + register)

    def _write(self, register: int, value: int) -> None:
        self._live().write_register(reg.COMMAND_BASE + register, value)

    def _write_setting(self, register: int, value: int) -> None:
        """Write a control or vendor command and remember it, so that ``reopen`` restores it after a power
        cycle (a vendor command is remembered per command family, its upper 16 bits)."""
        self._write(register, value)
        key = (register, value >> 16 if register == reg.VIDERE_LOCAL else 0)
        self._settings.pop(key, None)  # keep the order of the latest writes
        self._settings[key] = value

    def read_register(self, register: int) -> int:
        """Raw quadlet at an offset from the IIDC command base (for diagnostics)."""
        return self._read(register)

    def write_register(self, register: int, value: int) -> None:
        self._write(register, value)

    # --- identification ---
    def identify(self) -> HeadIdentity:
        transport = self._live()
        vendor, model = transport.identity()
        firmware = self._read(reg.VIDERE_FIRMWARE) & 0xFFFF
        flags = self._read(reg.VIDERE_DEVICE_FLAGS)
        stereo = (flags & reg.STEREO_FLAG_MASK) == reg.STEREO_FLAG_VALUE
        return HeadIdentity(vendor, model, firmware, stereo, transport.description)

    # --- vendor commands ---
    def set_companding(self, on: bool) -> None:
        self._write_setting(reg.VIDERE_LOCAL, reg.CMD_COMPANDING_ON if on else reg.CMD_COMPANDING_OFF)

    def set_hdr(self, on: bool) -> None:
        self._write_setting(reg.VIDERE_LOCAL, reg.CMD_HDR_ON if on else reg.CMD_HDR_OFF)

    def set_max_auto_exposure(self, value: int) -> None:
        if not 0 <= value <= 0xFFFF:
            raise ValueError(f"max auto exposure {value} outside 0..65535")
        self._write_setting(reg.VIDERE_LOCAL, reg.CMD_MAX_AUTO_EXPOSURE | value)

    def set_max_auto_gain(self, gain: int) -> None:
        lo, hi = self.controls.range("gain")
        if not lo <= gain <= hi:
            raise ValueError(f"max auto gain {gain} outside {lo}..{hi}")
        self._write_setting(reg.VIDERE_LOCAL, reg.CMD_MAX_AUTO_GAIN | (gain + 16))

    # --- modes ---
    def modes(self) -> list[OutputMode]:
        """Every size/rate the head offers (from its inquiry registers) plus host binning of 640x480."""
        out: list[OutputMode] = []
        formats = reg.mask_indices(self._read(reg.V_FORMAT_INQ))
        for fmt in formats:
            for mode in reg.mask_indices(self._read(reg.mode_inquiry_address(fmt))):
                try:
                    video_mode = reg.find_video_mode(fmt, mode)
                except ProtocolError:
                    continue  # a mode this driver does not know how to split
                for rate_idx in reg.mask_indices(self._read(reg.rate_inquiry_address(fmt, mode))):
                    rate = reg.FRAME_RATES[rate_idx]
                    out.append(OutputMode(video_mode.width, video_mode.height, rate, video_mode))
                    if (video_mode.width, video_mode.height) == (640, 480):
                        out.append(OutputMode(320, 240, rate, video_mode, binning=2))
        return sorted(out, key=lambda m: (m.width * m.height, m.rate))

    @property
    def mode(self) -> OutputMode:
        if self._mode is None:
            raise NotConnectedError("stereo head is closed")
        return self._mode

    def _current_mode(self) -> OutputMode:
        fmt = reg.decode_index(self._read(reg.VIDEO_FORMAT))
        mode = reg.decode_index(self._read(reg.VIDEO_MODE))
        rate = reg.FRAME_RATES[reg.decode_index(self._read(reg.FRAME_RATE))]
        video_mode = reg.find_video_mode(fmt, mode)
        return OutputMode(video_mode.width, video_mode.height, rate, video_mode)

    def set_mode(self, width: int, height: int, rate: float = 15.0) -> OutputMode:
        """Select a size and rate from ``modes()``; streaming pauses and resumes around the change."""
        choices = self.modes()
        chosen = next((m for m in choices if (m.width, m.height) == (width, height) and abs(m.rate - rate) < 1e-6),
                      None)
        if chosen is None:
            offered = ", ".join(f"{w}x{h}@{r:g}" for w, h, r in sorted({(m.width, m.height, m.rate) for m in choices}))
            raise ValueError(f"the head has no mode {width}x{height} at {rate:g} Hz; it offers {offered}")
        was_streaming = self._streaming
        if was_streaming:
            self.stop()
        self._write(reg.VIDEO_FORMAT, reg.encode_index(chosen.video_mode.fmt))
        self._write(reg.VIDEO_MODE, reg.encode_index(chosen.video_mode.mode))
        self._write(reg.FRAME_RATE, reg.encode_index(reg.rate_index(chosen.rate)))
        self._mode = chosen
        if was_streaming:
            self.start()
        return chosen

    @property
    def latency(self) -> float:
        """Seconds from exposure to arrival, subtracted from arrival times to stamp frames (see module doc)."""
        return self._latency

    @latency.setter
    def latency(self, seconds: float) -> None:
        seconds = float(seconds)
        if not 0.0 <= seconds < 1.0:
            raise ValueError(f"camera latency must be in [0, 1) s, got {seconds!r}")
        self._latency = seconds

    # --- streaming ---
    def start(self) -> None:
        self._sequencer.restart(self.mode.rate)
        self._write(reg.ISO_EN, 1 << 31)
        self._streaming = True

    def stop(self) -> None:
        self._write(reg.ISO_EN, 0)
        self._streaming = False

    @property
    def streaming(self) -> bool:
        return self._streaming

    @property
    def dropped_frames(self) -> int:
        """Frames lost since the head was opened."""
        return self._sequencer.dropped_total

    def grab(self, timeout: float = 1.0) -> StereoFrame:
        """Wait for the next pair. DriverTimeoutError if none came, NotConnectedError if the head vanished."""
        transport = self._live()
        if not self._streaming:
            raise DriverError("the stereo head is not streaming; call start() first")
        mode = self.mode
        raw = transport.read_frame(mode.video_mode.frame_bytes, timeout)
        received = float(self._clock())
        left, right = deinterleave(raw, mode.video_mode.width, mode.video_mode.height, self.byte_order)
        if self.colour:
            left, right = demosaic(left), demosaic(right)
        if mode.binning == 2:
            left, right = bin2x2(left), bin2x2(right)
        elif not self.colour:
            left, right = left.copy(), right.copy()  # contiguous and independent of the transfer buffer
        counter, dropped = self._sequencer.next(received)
        return StereoFrame(left, right, received - self.latency, counter, dropped, received)

    # --- calibration stored on the head ---
    def read_calibration_text(self) -> str | None:
        """The SVS parameter text kept on the head, or None if it holds none."""
        quadlets: list[int] = []
        for offset in range(0, reg.CALIB_MAX_BYTES, 4):
            quadlet = self._read(reg.CALIB_TEXT + offset)
            quadlets.append(quadlet)
            if quadlet in (0, 0xFFFFFFFF):
                break
        text = reg.quadlets_to_text(quadlets)
        return None if text is None else text.decode("latin-1")

    def read_calibration(self) -> StereoCalibration:
        text = self.read_calibration_text()
        if text is None:
            raise NoCalibrationError(f"stereo head ({self._live().description}) holds no calibration")
        return parse_svs(text, f"calibration stored on the head ({self._live().description})")

    def write_calibration(self, calib: StereoCalibration | str) -> None:
        """Store an SVS calibration on the head (firmware >= 2.1): erase each 512-byte block, write, verify."""
        text = calib if isinstance(calib, str) else format_svs(calib)
        parse_svs(text, "calibration to write")  # never store something the head's readers would reject
        firmware = self.identify().firmware
        if firmware < reg.CALIB_MIN_FIRMWARE:
            raise ProtocolError(f"firmware {firmware >> 8}.{firmware & 0xFF} cannot store a calibration "
                                f"(needs {reg.CALIB_MIN_FIRMWARE >> 8}.{reg.CALIB_MIN_FIRMWARE & 0xFF})")
        quadlets = reg.text_to_quadlets(text.encode("latin-1"))
        nbytes = len(quadlets) * 4
        for block in range(0, nbytes, reg.CALIB_BLOCK_BYTES):
            self._write(reg.CALIB_BASE, reg.CALIB_ERASE_MAGIC)
            self._write(reg.CALIB_TEXT + block, ~reg.CALIB_ERASE_MAGIC & 0xFFFFFFFF)
        for index, quadlet in enumerate(quadlets):
            self._write(reg.CALIB_TEXT + 4 * index, quadlet)
        stored = self.read_calibration_text()
        if stored != text.rstrip("\0"):
            raise ProtocolError("the calibration read back from the head differs from what was written")
