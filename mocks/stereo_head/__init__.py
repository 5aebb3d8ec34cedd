"""The virtual Videre STH-MDCS2 stereo head: a pyusb backend that the real driver opens unchanged."""
from __future__ import annotations

from mocks.stereo_head.backend import VirtualStereoHead, default_calibration, default_calibration_text

__all__ = ["VirtualStereoHead", "default_calibration", "default_calibration_text"]
