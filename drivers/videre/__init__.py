"""Driver for the Videre Design STH-MDCS2 stereo head (IIDC register model, pyusb transport, calibration)."""
from __future__ import annotations

from drivers.videre.calibration import StereoCalibration, load, parse_svs, save
from drivers.videre.frames import LEFT_FIRST, RIGHT_FIRST
from drivers.videre.head import (
    ControlState,
    HeadIdentity,
    NoCalibrationError,
    OutputMode,
    StereoFrame,
    StereoHead,
)
from drivers.videre.transport import DEFAULT_PRODUCT_ID, DEFAULT_VENDOR_ID, Transport, UsbTransport

__all__ = [
    "DEFAULT_PRODUCT_ID", "DEFAULT_VENDOR_ID", "LEFT_FIRST", "RIGHT_FIRST", "ControlState", "HeadIdentity",
    "NoCalibrationError", "OutputMode", "StereoCalibration", "StereoFrame", "StereoHead", "Transport",
    "UsbTransport", "load", "parse_svs", "save",
]
