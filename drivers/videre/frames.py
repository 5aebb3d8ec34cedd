"""Pure frame handling: split the interleaved stereo stream, bin, demosaic, number the pairs.

The head puts one byte of each imager in every 16-bit pixel of a YUV422-shaped frame. Which byte is which
imager differs between sources (the ROS driver: byte 0 right, byte 1 left; the old STH-MDCS manual: left
first), so it is a setting: ``RIGHT_FIRST`` (default) or ``LEFT_FIRST``.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from drivers.errors import ProtocolError

RIGHT_FIRST = "right-first"  # byte 0 right, byte 1 left (ROS videre_stereo_cam)
LEFT_FIRST = "left-first"  # byte 0 left, byte 1 right (STH-MDCS manual)
BYTE_ORDERS = (RIGHT_FIRST, LEFT_FIRST)
BAYER_PATTERN = "GRBG"  # colour heads; row 0 is G R G R ..., row 1 B G B G ...
# OpenCV names Bayer patterns by the second row/column, so the GRBG sensor layout is its "GB".
_GRBG_TO_BGR = cv2.COLOR_BayerGB2BGR


def check_byte_order(byte_order: str) -> str:
    if byte_order not in BYTE_ORDERS:
        raise ValueError(f"byte_order must be one of {BYTE_ORDERS}, not {byte_order!r}")
    return byte_order


def deinterleave(raw: bytes | bytearray | memoryview | np.ndarray, width: int, height: int,
                 byte_order: str = RIGHT_FIRST) -> tuple[np.ndarray, np.ndarray]:
    """Split one interleaved frame of ``width * height * 2`` bytes into (left, right), each (height, width) uint8.

    The two images are views of ``raw`` (no copy); copy them if ``raw`` will be reused.
    """
    check_byte_order(byte_order)
    data = np.frombuffer(raw, np.uint8) if not isinstance(raw, np.ndarray) else raw.reshape(-1).view(np.uint8)
    expected = width * height * 2
    if data.size != expected:
        raise ProtocolError(f"frame of {data.size} bytes, expected {expected} for {width}x{height} interleaved")
    pairs = data.reshape(height, width, 2)
    first, second = pairs[:, :, 0], pairs[:, :, 1]
    return (second, first) if byte_order == RIGHT_FIRST else (first, second)


def interleave(left: np.ndarray, right: np.ndarray, byte_order: str = RIGHT_FIRST) -> np.ndarray:
    """Inverse of ``deinterleave``: (H, W) uint8 each -> (H, W, 2) uint8 as the head sends it."""
    check_byte_order(byte_order)
    out = np.empty(left.shape + (2,), np.uint8)
    if byte_order == RIGHT_FIRST:
        out[:, :, 0], out[:, :, 1] = right, left
    else:
        out[:, :, 0], out[:, :, 1] = left, right
    return out


def bin2x2(image: np.ndarray) -> np.ndarray:
    """Average 2x2 blocks: (H, W) -> (H/2, W/2), same dtype. Host-side binning (640x480 -> 320x240)."""
    return cv2.resize(image, (image.shape[1] // 2, image.shape[0] // 2), interpolation=cv2.INTER_AREA)


def demosaic(mosaic: np.ndarray) -> np.ndarray:
    """GRBG Bayer mosaic (H, W) uint8 -> (H, W, 3) uint8 BGR."""
    return cv2.cvtColor(mosaic, _GRBG_TO_BGR)


def mosaic(bgr: np.ndarray) -> np.ndarray:
    """(H, W, 3) BGR -> (H, W) GRBG mosaic, what a colour imager delivers (used by the virtual head)."""
    out = np.empty(bgr.shape[:2], bgr.dtype)
    out[0::2, 0::2] = bgr[0::2, 0::2, 1]
    out[0::2, 1::2] = bgr[0::2, 1::2, 2]
    out[1::2, 0::2] = bgr[1::2, 0::2, 0]
    out[1::2, 1::2] = bgr[1::2, 1::2, 1]
    return out


@dataclass
class FrameSequencer:
    """Numbers frame pairs from their arrival times and counts the frames that never arrived.

    The head streams at a fixed rate, so a gap of about k periods between two pairs means k - 1 were
    dropped. ``counter`` is the head's frame number as if none were dropped.
    """

    rate_hz: float
    counter: int = -1
    dropped_total: int = 0
    last_timestamp: float | None = None

    def next(self, timestamp: float) -> tuple[int, int]:
        """Register a pair that arrived at ``timestamp`` (s); returns (counter, frames dropped before it)."""
        dropped = 0
        if self.last_timestamp is None:
            step = 1
        else:
            step = max(1, int(round((timestamp - self.last_timestamp) * self.rate_hz)))
            dropped = step - 1
        self.counter += step
        self.dropped_total += dropped
        self.last_timestamp = timestamp
        return self.counter, dropped

    def restart(self, rate_hz: float) -> None:
        """A new stream (mode change, restart): the next pair is not compared with the last one."""
        self.rate_hz = rate_hz
        self.last_timestamp = None
