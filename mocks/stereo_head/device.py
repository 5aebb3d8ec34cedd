"""The virtual STH-MDCS2's insides, with no USB: its register file, its sensor and its frame stream.

``HeadModel`` answers register reads/writes at the addresses ``drivers.videre.registers`` defines and
produces interleaved frames of the selected video mode from an image source (the building renderer, or a
fixed pattern). The sensor model makes the feature registers matter: exposure and gain scale brightness,
gain raises the noise, brightness sets the black level, white balance tints a colour head.
"""
from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drivers.videre import registers as reg
from drivers.videre.frames import RIGHT_FIRST, interleave, mosaic


class RegisterStall(Exception):
    """The head refuses a register access (a USB stall on the real bus)."""


@dataclass
class SensorSettings:
    exposure: int = 200
    exposure_auto: bool = False
    gain: int = 0
    gain_auto: bool = False
    brightness: int = 32
    white_balance_ub: int = 15
    white_balance_vr: int = 15
    max_auto_exposure: int = 529
    companding: bool = False
    hdr: bool = False


def gain_factor(gain: int) -> float:
    """Gain register units are 0.5 dB."""
    return float(10.0 ** (gain * 0.5 / 20.0))


class NoisePool:
    """Standard normal noise fields, cheaply: each field is a random window of one pool drawn once per size.

    Drawing 2 x 307k normals per 640x480 pair costs more than rendering it; windows at random offsets of a
    pool twice the field's size look independent frame to frame and stay deterministic given the Generator.
    """

    def __init__(self, rng: np.random.Generator):
        self.rng = rng
        self._pools: dict[int, np.ndarray] = {}

    def field(self, shape: tuple[int, ...]) -> np.ndarray:
        n = int(np.prod(shape))
        pool = self._pools.get(n)
        if pool is None:
            pool = self._pools[n] = self.rng.standard_normal(2 * n + 4099, dtype=np.float32)
        start = int(self.rng.integers(0, len(pool) - n))
        return pool[start:start + n].reshape(shape)


def expose(radiance: np.ndarray, settings: SensorSettings, noise: np.ndarray) -> np.ndarray:
    """Radiance (H, W) float32 0..1 -> digital numbers (H, W) uint8: scale by exposure and gain, add shot and
    read noise (amplified by the gain), black level from brightness, optional companding/HDR knee.
    noise: (H, W) float32 standard normal."""
    g = gain_factor(settings.gain)
    electrons = radiance * np.float32(220.0 * settings.exposure / 200.0)  # DN before gain
    sigma = np.sqrt(np.float32(0.6 * 0.6) * g * g + np.float32(0.05) * g * g * electrons)
    signal = electrons * np.float32(g) + noise * sigma
    if settings.companding:
        signal = np.sqrt(np.maximum(signal, 0.0) / np.float32(255.0)) * np.float32(255.0)
    if settings.hdr:
        knee = np.float32(180.0)
        signal = np.where(signal > knee, knee + (signal - knee) * np.float32(0.25), signal)
    signal += np.float32(settings.brightness / 4.0)
    return np.clip(signal + np.float32(0.5), 0.0, 255.0).astype(np.uint8)


class HeadModel:
    """Registers, sensor and stream of one virtual head. Thread-safe.

    source(width, height) -> (left, right): float32 radiance (sensor model applied) or uint8 (passed through
    unchanged, for known-pattern tests). calibration_text: the SVS text in the head's store, None for none.
    """

    def __init__(self, source: Callable[[int, int], tuple[np.ndarray, np.ndarray]], *,
                 calibration_text: str | None, rng: np.random.Generator, byte_order: str = RIGHT_FIRST,
                 colour: bool = False, firmware: int = 0x0203):
        self.source = source
        self.rng = rng
        self.noise = NoisePool(rng)
        self.byte_order = byte_order
        self.colour = colour
        self.firmware = firmware
        self._lock = threading.RLock()
        self._calibration = [0xFFFFFFFF] * (reg.CALIB_MAX_BYTES // 4)  # erased flash
        if calibration_text is not None:
            for i, quadlet in enumerate(reg.text_to_quadlets(calibration_text.encode("latin-1"))):
                self._calibration[i] = quadlet
        self.power_on()
        self.frames_produced = 0

    def power_on(self) -> None:
        """Registers to their power-on values (the calibration store is flash: it survives)."""
        with self._lock:
            self.settings = SensorSettings()
            self.fmt, self.mode, self.rate_index = 0, 3, reg.rate_index(15.0)
            self.iso_enabled = False
            self.last_vendor_command = 0
            self._erase_armed = False

    # ------------------------------------------------------------------ registers
    def video_mode(self) -> reg.VideoMode:
        return reg.find_video_mode(self.fmt, self.mode)

    @property
    def rate_hz(self) -> float:
        return reg.FRAME_RATES[self.rate_index]

    def _rates(self, video_mode: reg.VideoMode) -> list[int]:
        return [reg.rate_index(r) for r in reg.HEAD_RATES if r <= video_mode.max_rate]

    def read(self, address: int) -> int:
        """Quadlet at a wire address (offset above the config ROM base)."""
        with self._lock:
            offset = address - reg.COMMAND_BASE
            if offset == reg.V_FORMAT_INQ:
                return reg.bit_mask(sorted({m.fmt for m in reg.VIDEO_MODES}))
            for m in reg.VIDEO_MODES:
                if offset == reg.mode_inquiry_address(m.fmt):
                    return reg.bit_mask([x.mode for x in reg.VIDEO_MODES if x.fmt == m.fmt])
                if offset == reg.rate_inquiry_address(m.fmt, m.mode):
                    return reg.bit_mask(self._rates(m))
            if reg.V_MODE_INQ_BASE <= offset < reg.V_RATE_INQ_BASE + 32 * 8:
                return 0
            if offset == reg.BASIC_FUNC_INQ:
                return 0
            for spec in reg.FEATURES.values():
                if offset == spec.inquiry:
                    return reg.encode_inquiry(spec.minimum, spec.maximum, auto=spec.name in ("exposure", "gain"))
                if offset == spec.control:
                    return reg.encode_control(self._control(spec.name), spec.two_values)
            if offset == reg.FRAME_RATE:
                return reg.encode_index(self.rate_index)
            if offset == reg.VIDEO_MODE:
                return reg.encode_index(self.mode)
            if offset == reg.VIDEO_FORMAT:
                return reg.encode_index(self.fmt)
            if offset == reg.ISO_EN:
                return (1 << 31) if self.iso_enabled else 0
            if offset == reg.VIDERE_LOCAL:
                return self.last_vendor_command
            if offset == reg.VIDERE_FIRMWARE:
                return self.firmware
            if offset == reg.VIDERE_DEVICE_FLAGS:
                return reg.STEREO_FLAG_VALUE | (0x1 if self.colour else 0x0)
            if reg.CALIB_TEXT <= offset < reg.CALIB_TEXT + reg.CALIB_MAX_BYTES and offset % 4 == 0:
                return self._calibration[(offset - reg.CALIB_TEXT) // 4]
            raise RegisterStall(f"read of unknown register 0x{offset:X}")

    def _control(self, name: str) -> reg.FeatureControl:
        s = self.settings
        if name == "brightness":
            return reg.FeatureControl(s.brightness)
        if name == "exposure":
            return reg.FeatureControl(s.exposure, auto=s.exposure_auto)
        if name == "gain":
            return reg.FeatureControl(s.gain, auto=s.gain_auto)
        return reg.FeatureControl(s.white_balance_ub, value2=s.white_balance_vr)

    def write(self, address: int, value: int) -> None:
        with self._lock:
            offset = address - reg.COMMAND_BASE
            s = self.settings
            for spec in reg.FEATURES.values():
                if offset == spec.control:
                    control = reg.decode_control(value, spec.two_values)
                    clamp = lambda v, spec=spec: int(min(max(v, spec.minimum), spec.maximum))  # noqa: E731
                    if spec.name == "brightness":
                        s.brightness = clamp(control.value)
                    elif spec.name == "exposure":
                        s.exposure, s.exposure_auto = clamp(control.value), control.auto
                    elif spec.name == "gain":
                        s.gain, s.gain_auto = clamp(control.value), control.auto
                    else:
                        s.white_balance_ub, s.white_balance_vr = clamp(control.value), clamp(control.value2 or 0)
                    return
            if offset in (reg.FRAME_RATE, reg.VIDEO_MODE, reg.VIDEO_FORMAT):
                if self.iso_enabled:
                    raise RegisterStall("video format/mode/rate cannot change while streaming")
                index = reg.decode_index(value)
                if offset == reg.FRAME_RATE:
                    self.rate_index = index
                elif offset == reg.VIDEO_MODE:
                    self.mode = index
                else:
                    self.fmt = index
                return
            if offset == reg.ISO_EN:
                start = bool(value & (1 << 31))
                if start:
                    try:
                        video_mode = self.video_mode()
                    except ValueError as exc:
                        raise RegisterStall(str(exc)) from None
                    if self.rate_index not in self._rates(video_mode):
                        raise RegisterStall(f"{self.rate_hz} Hz is not a rate of {video_mode}")
                self.iso_enabled = start
                return
            if offset == reg.VIDERE_LOCAL:
                self._vendor_command(value)
                return
            if offset == reg.CALIB_BASE:
                self._erase_armed = value == reg.CALIB_ERASE_MAGIC
                return
            if reg.CALIB_TEXT <= offset < reg.CALIB_TEXT + reg.CALIB_MAX_BYTES and offset % 4 == 0:
                if self.firmware < reg.CALIB_MIN_FIRMWARE:
                    raise RegisterStall("this firmware cannot store a calibration")
                index = (offset - reg.CALIB_TEXT) // 4
                block = (offset - reg.CALIB_TEXT) % reg.CALIB_BLOCK_BYTES == 0
                if self._erase_armed and block and value == (~reg.CALIB_ERASE_MAGIC & 0xFFFFFFFF):
                    for i in range(index, index + reg.CALIB_BLOCK_BYTES // 4):
                        self._calibration[i] = 0xFFFFFFFF
                else:
                    self._calibration[index] &= value  # flash: a write can only clear bits
                self._erase_armed = False
                return
            raise RegisterStall(f"write of unknown register 0x{offset:X}")

    def _vendor_command(self, value: int) -> None:
        s = self.settings
        if value in (reg.CMD_COMPANDING_ON, reg.CMD_COMPANDING_OFF):
            s.companding = value == reg.CMD_COMPANDING_ON
        elif value in (reg.CMD_HDR_ON, reg.CMD_HDR_OFF):
            s.hdr = value == reg.CMD_HDR_ON
        elif value & 0xFFFF0000 == reg.CMD_MAX_AUTO_EXPOSURE:
            s.max_auto_exposure = value & 0xFFFF
        elif value & 0xFFFF0000 == reg.CMD_MAX_AUTO_GAIN:
            pass  # accepted; the model has no auto gain loop
        else:
            raise RegisterStall(f"unknown Videre vendor command 0x{value:08X}")
        self.last_vendor_command = value

    @property
    def calibration_text(self) -> str | None:
        with self._lock:
            text = reg.quadlets_to_text(self._calibration)
        return None if text is None else text.decode("latin-1")

    # ------------------------------------------------------------------ frames
    def frame(self) -> np.ndarray:
        """One interleaved frame of the current mode: (height * width * 2,) uint8, as on the wire."""
        with self._lock:
            video_mode = self.video_mode()
            settings = SensorSettings(**vars(self.settings))
        left, right = self.source(video_mode.width, video_mode.height)
        images = []
        for image in (left, right):
            if image.dtype != np.uint8:
                if self.colour:
                    tint = np.array([0.5 + settings.white_balance_ub / 30.0, 1.0,
                                     0.5 + settings.white_balance_vr / 30.0], np.float32)  # B, G, R
                    image = mosaic(image[:, :, None] * tint[None, None, :])
                image = expose(image, settings, self.noise.field(image.shape))
            images.append(image)
        if settings.exposure_auto:
            self._auto_expose(float(images[0].mean()))
        self.frames_produced += 1
        return interleave(images[0], images[1], self.byte_order).reshape(-1)

    def _auto_expose(self, mean_dn: float) -> None:
        with self._lock:
            s = self.settings
            target = 110.0
            scale = np.sqrt(target / max(mean_dn, 1.0))
            s.exposure = int(np.clip(round(s.exposure * scale), 1, min(529, s.max_auto_exposure)))


def pattern_source(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """A known pair for de-interleaving tests: left = (u + 3v) mod 256, right = 255 - (2u + v) mod 256."""
    u, v = np.meshgrid(np.arange(width), np.arange(height))
    return ((u + 3 * v) % 256).astype(np.uint8), (255 - (2 * u + v) % 256).astype(np.uint8)
