"""The STH-MDCS2's IIDC (DCAM 1.30) register model as pure code: addresses, bit fields, video modes.

No I/O here: the head (``drivers.videre.head``) reads and writes quadlets through a transport, and the
virtual head (``mocks.stereo_head``) keeps a register file with the same layout. Every address below is
an offset from the IIDC command register base unless it says otherwise; ``COMMAND_BASE`` is that base as an
offset from the config ROM base 0xFFFFF0000000, which is the 24-bit address that goes on the wire.
"""
from __future__ import annotations

from dataclasses import dataclass

from drivers.errors import ProtocolError

CONFIG_ROM_BASE = 0xFFFFF0000000
COMMAND_BASE = 0xF00000  # command_regs_base of the unit directory, in bytes above CONFIG_ROM_BASE

# IIDC over USB (libdc1394's USB backend): vendor control transfers carry register quadlets little-endian,
# wValue = address & 0xFFFF, wIndex = address >> 16; frames come as bulk transfers on endpoint 0x81.
REQUEST_TYPE_READ = 0xC0  # device-to-host | vendor | device
REQUEST_TYPE_WRITE = 0x40  # host-to-device | vendor | device
REQUEST_REGISTER = 0x7F
FRAME_ENDPOINT = 0x81
# No USB model of the head is documented; these are the pid.codes test ids. Pass your own.
DEFAULT_VENDOR_ID = 0x1209
DEFAULT_PRODUCT_ID = 0x0001

# Standard IIDC registers (offsets from COMMAND_BASE).
V_FORMAT_INQ = 0x100
V_MODE_INQ_BASE = 0x180  # + 4 * format
V_RATE_INQ_BASE = 0x200  # + 32 * format + 4 * mode
BASIC_FUNC_INQ = 0x400
FRAME_RATE = 0x600
VIDEO_MODE = 0x604
VIDEO_FORMAT = 0x608
ISO_CHANNEL = 0x60C
CAMERA_POWER = 0x610
ISO_EN = 0x614

# Videre local parameters.
VIDERE_LOCAL = 0xFF000  # vendor command register; the local parameter block starts here
VIDERE_FIRMWARE = VIDERE_LOCAL + 4
VIDERE_DEVICE_FLAGS = VIDERE_LOCAL + 8
STEREO_FLAG_MASK = 0xFF0000
STEREO_FLAG_VALUE = 0x080000
CALIB_BASE = 0xF0000  # erase register for the calibration store
CALIB_TEXT = CALIB_BASE + 0x800  # the SVS parameter text, quadlets MSB first
CALIB_MAX_BYTES = 0x1000
CALIB_BLOCK_BYTES = 512
CALIB_ERASE_MAGIC = 0x5A01F687
CALIB_MIN_FIRMWARE = 0x0201

MODEL_NAME = "MDS-STH"
VENDOR_NAME = "Videre Design"

# Vendor commands written to VIDERE_LOCAL.
CMD_COMPANDING_ON = 0x041C0003
CMD_COMPANDING_OFF = 0x041C0002
CMD_HDR_ON = 0x040F0051
CMD_HDR_OFF = 0x040F0011
CMD_MAX_AUTO_EXPOSURE = 0x04BD0000  # | value
CMD_MAX_AUTO_GAIN = 0x04360000  # | (gain + 16)

# Feature inquiry and control bits.
INQ_PRESENT = 1 << 31
INQ_ABSOLUTE = 1 << 30
INQ_READOUT = 1 << 27
INQ_ON_OFF = 1 << 26
INQ_AUTO = 1 << 25
INQ_MANUAL = 1 << 24
CTRL_PRESENT = 1 << 31
CTRL_ONE_PUSH = 0x04000000
CTRL_ON = 0x02000000
CTRL_AUTO = 0x01000000
FEATURE_INQ_OFFSET = 0x500 - 0x800  # inquiry register = control register + this


@dataclass(frozen=True)
class FeatureSpec:
    """One IIDC feature the head has: its control register and the range its inquiry register reports."""

    name: str
    control: int  # offset of the control register
    minimum: int
    maximum: int
    two_values: bool = False  # white balance carries U/B in bits 12-23 and V/R in bits 0-11

    @property
    def inquiry(self) -> int:
        return self.control + FEATURE_INQ_OFFSET


# Videre's exposure goes through AUTO_EXPOSURE (0x804), not SHUTTER.
FEATURES: dict[str, FeatureSpec] = {
    "brightness": FeatureSpec("brightness", 0x800, 0, 255),
    "exposure": FeatureSpec("exposure", 0x804, 0, 529),
    "white_balance": FeatureSpec("white_balance", 0x80C, 0, 30, two_values=True),
    "gain": FeatureSpec("gain", 0x820, 0, 48),
}


def encode_inquiry(minimum: int, maximum: int, *, auto: bool = True, on_off: bool = False) -> int:
    """The inquiry quadlet of a present, readable, manual (and optionally auto) feature."""
    value = INQ_PRESENT | INQ_READOUT | INQ_MANUAL | ((minimum & 0xFFF) << 12) | (maximum & 0xFFF)
    if auto:
        value |= INQ_AUTO
    if on_off:
        value |= INQ_ON_OFF
    return value


@dataclass(frozen=True)
class FeatureInquiry:
    present: bool
    readout: bool
    auto_capable: bool
    manual_capable: bool
    minimum: int
    maximum: int


def decode_inquiry(quadlet: int) -> FeatureInquiry:
    return FeatureInquiry(
        present=bool(quadlet & INQ_PRESENT),
        readout=bool(quadlet & INQ_READOUT),
        auto_capable=bool(quadlet & INQ_AUTO),
        manual_capable=bool(quadlet & INQ_MANUAL),
        minimum=(quadlet >> 12) & 0xFFF,
        maximum=quadlet & 0xFFF,
    )


@dataclass(frozen=True)
class FeatureControl:
    """A decoded control register. ``value2`` is white balance's V/R part (``value`` is U/B)."""

    value: int
    auto: bool = False
    on: bool = True
    value2: int | None = None


def encode_control(control: FeatureControl, two_values: bool = False) -> int:
    quadlet = CTRL_PRESENT
    if control.on:
        quadlet |= CTRL_ON
    if control.auto:
        quadlet |= CTRL_AUTO
    if two_values:
        second = control.value if control.value2 is None else control.value2
        quadlet |= ((control.value & 0xFFF) << 12) | (second & 0xFFF)
    else:
        quadlet |= control.value & 0xFFF
    return quadlet


def decode_control(quadlet: int, two_values: bool = False) -> FeatureControl:
    auto = bool(quadlet & CTRL_AUTO)
    on = bool(quadlet & CTRL_ON)
    if two_values:
        return FeatureControl((quadlet >> 12) & 0xFFF, auto, on, quadlet & 0xFFF)
    return FeatureControl(quadlet & 0xFFF, auto, on)


# --- video formats, modes and rates --------------------------------------------------------------

FRAME_RATES: tuple[float, ...] = (1.875, 3.75, 7.5, 15.0, 30.0, 60.0)  # IIDC rate index -> Hz


@dataclass(frozen=True)
class VideoMode:
    """An IIDC format/mode the head streams: every one is YUV422-shaped, 2 bytes (one per imager) a pixel."""

    fmt: int
    mode: int
    width: int
    height: int
    decimation: int  # on-imager decimation of the 1280x960 sensor
    max_rate: float

    @property
    def frame_bytes(self) -> int:
        return self.width * self.height * 2


# The head's modes (IIDC format 0 mode 3, format 1 mode 3, format 2 mode 0). 320x240 is not an imager mode:
# it is 640x480 binned 2x2 on the host (see ``OutputMode``).
VIDEO_MODES: tuple[VideoMode, ...] = (
    VideoMode(0, 3, 640, 480, 2, 30.0),
    VideoMode(1, 3, 1024, 768, 1, 15.0),
    VideoMode(2, 0, 1280, 960, 1, 7.5),
)
HEAD_RATES: tuple[float, ...] = (3.75, 7.5, 15.0, 30.0)


def find_video_mode(fmt: int, mode: int) -> VideoMode:
    for candidate in VIDEO_MODES:
        if (candidate.fmt, candidate.mode) == (fmt, mode):
            return candidate
    raise ProtocolError(f"IIDC format {fmt} mode {mode} is not a mode of the STH-MDCS2")


def rate_index(rate_hz: float) -> int:
    for index, rate in enumerate(FRAME_RATES):
        if abs(rate - rate_hz) < 1e-6:
            return index
    raise ValueError(f"frame rate {rate_hz} Hz is not an IIDC rate (one of {FRAME_RATES})")


def encode_index(index: int) -> int:
    """FRAME_RATE, VIDEO_MODE and VIDEO_FORMAT hold their index in bits 31-29."""
    return (index & 0x7) << 29


def decode_index(quadlet: int) -> int:
    return (quadlet >> 29) & 0x7


def bit_mask(indices: list[int] | tuple[int, ...]) -> int:
    """V_FORMAT_INQ / V_MODE_INQ / V_RATE_INQ: index i is bit 31 - i."""
    mask = 0
    for index in indices:
        mask |= 1 << (31 - index)
    return mask


def mask_indices(quadlet: int, count: int = 8) -> list[int]:
    return [i for i in range(count) if quadlet & (1 << (31 - i))]


def mode_inquiry_address(fmt: int) -> int:
    return V_MODE_INQ_BASE + 4 * fmt


def rate_inquiry_address(fmt: int, mode: int) -> int:
    return V_RATE_INQ_BASE + 32 * fmt + 4 * mode


# --- the calibration text stored on the head -----------------------------------------------------

def text_to_quadlets(text: bytes) -> list[int]:
    """Pack the SVS text into quadlets MSB first, padded with zero bytes, ending with a zero quadlet."""
    if len(text) + 4 > CALIB_MAX_BYTES:
        raise ValueError(f"calibration text of {len(text)} bytes does not fit the head's {CALIB_MAX_BYTES} bytes")
    if b"\0" in text:
        raise ValueError("calibration text must not contain NUL bytes")
    padded = text + b"\0" * (-len(text) % 4)
    quadlets = [int.from_bytes(padded[i:i + 4], "big") for i in range(0, len(padded), 4)]
    return quadlets + [0]


def quadlets_to_text(quadlets: list[int]) -> bytes | None:
    """Inverse of ``text_to_quadlets``: stop at 0 or 0xFFFFFFFF; ``None`` if the first quadlet is 0xFFFFFFFF."""
    if quadlets and quadlets[0] == 0xFFFFFFFF:
        return None
    out = bytearray()
    for quadlet in quadlets:
        if quadlet in (0, 0xFFFFFFFF):
            break
        out += quadlet.to_bytes(4, "big")
    return bytes(out).rstrip(b"\0")
