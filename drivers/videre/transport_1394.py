"""IEEE-1394 transport through the system's libdc1394 (v2), loaded with ctypes only when asked for.

Registers go through ``dc1394_get/set_control_registers`` (offsets from the command register base, which
libdc1394 reads from the config ROM); frames through the capture ring (``dc1394_capture_setup/dequeue``).
The transport sets the ring up just before the driver switches ISO transmission on, and tears it down
after it is switched off, because on 1394 the isochronous channel and bandwidth belong to the bus.
Without the library, the 1394 subsystem or a camera, ``open`` raises ``DeviceNotFoundError`` saying which.
Not exercised against hardware in this project (no 1394 bus here); the USB transport is the tested one.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import time

import numpy as np

from drivers.errors import DeviceNotFoundError, DriverError, DriverTimeoutError, NotConnectedError
from drivers.videre import registers as reg

_CAPTURE_FLAGS_DEFAULT = 0x04
_CAPTURE_POLICY_POLL = 673
_RING_BUFFERS = 4
_LIBRARY_NAMES = ("dc1394", "dc1394.so.25", "dc1394.so.22")


class _CameraId(ctypes.Structure):
    _fields_ = [("unit", ctypes.c_uint16), ("guid", ctypes.c_uint64)]


class _CameraList(ctypes.Structure):
    _fields_ = [("num", ctypes.c_uint32), ("ids", ctypes.POINTER(_CameraId))]


class _Camera(ctypes.Structure):
    """The leading fields of dc1394camera_t, up to the vendor and model strings (dc1394/camera.h)."""

    _fields_ = [("guid", ctypes.c_uint64), ("unit", ctypes.c_int), ("unit_spec_ID", ctypes.c_uint32),
                ("unit_sw_version", ctypes.c_uint32), ("unit_sub_sw_version", ctypes.c_uint32),
                ("command_registers_base", ctypes.c_uint32), ("unit_directory", ctypes.c_uint32),
                ("unit_dependent_directory", ctypes.c_uint32), ("advanced_features_csr", ctypes.c_uint64),
                ("PIO_control_csr", ctypes.c_uint64), ("SIO_control_csr", ctypes.c_uint64),
                ("strobe_control_csr", ctypes.c_uint64), ("format7_csr", ctypes.c_uint64 * 8),
                ("iidc_version", ctypes.c_int), ("vendor", ctypes.c_char_p), ("model", ctypes.c_char_p)]


class _Frame(ctypes.Structure):
    """Only the first field of dc1394video_frame_t: the image pointer."""

    _fields_ = [("image", ctypes.POINTER(ctypes.c_uint8))]


def load_library(find=ctypes.util.find_library) -> ctypes.CDLL:
    """The system's libdc1394, or DeviceNotFoundError naming what is missing."""
    for name in _LIBRARY_NAMES:
        path = find(name) if "." not in name else None
        try:
            lib = ctypes.CDLL(path or f"lib{name}")
        except OSError:
            continue
        return _declare(lib)
    raise DeviceNotFoundError("libdc1394 (v2) is not installed, so IEEE-1394 stereo heads cannot be used "
                              "(install libdc1394-25 / libdc1394-dev, or use the USB transport)")


def _declare(lib: ctypes.CDLL) -> ctypes.CDLL:
    p = ctypes.c_void_p
    lib.dc1394_new.restype = p
    lib.dc1394_free.argtypes = [p]
    lib.dc1394_camera_enumerate.argtypes = [p, ctypes.POINTER(ctypes.POINTER(_CameraList))]
    lib.dc1394_camera_free_list.argtypes = [ctypes.POINTER(_CameraList)]
    lib.dc1394_camera_new.restype = ctypes.POINTER(_Camera)
    lib.dc1394_camera_new.argtypes = [p, ctypes.c_uint64]
    lib.dc1394_camera_free.argtypes = [ctypes.POINTER(_Camera)]
    lib.dc1394_get_control_registers.argtypes = [ctypes.POINTER(_Camera), ctypes.c_uint64,
                                                 ctypes.POINTER(ctypes.c_uint32), ctypes.c_uint32]
    lib.dc1394_set_control_registers.argtypes = lib.dc1394_get_control_registers.argtypes
    lib.dc1394_capture_setup.argtypes = [ctypes.POINTER(_Camera), ctypes.c_uint32, ctypes.c_uint32]
    lib.dc1394_capture_stop.argtypes = [ctypes.POINTER(_Camera)]
    lib.dc1394_capture_dequeue.argtypes = [ctypes.POINTER(_Camera), ctypes.c_int,
                                           ctypes.POINTER(ctypes.POINTER(_Frame))]
    lib.dc1394_capture_enqueue.argtypes = [ctypes.POINTER(_Camera), ctypes.POINTER(_Frame)]
    return lib


class Dc1394Transport:
    """A ``Transport`` for IEEE-1394 heads. ``guid`` picks a camera (default: the first one)."""

    def __init__(self, lib: ctypes.CDLL, context: int, camera, description: str):
        self._lib, self._context, self._camera = lib, context, camera
        self.description = description
        self._capturing = False

    @classmethod
    def open(cls, guid: int | None = None, lib: ctypes.CDLL | None = None) -> Dc1394Transport:
        lib = lib or load_library()
        context = lib.dc1394_new()
        if not context:
            raise DeviceNotFoundError("libdc1394 found no IEEE-1394 subsystem (no FireWire card or driver?)")
        listing = ctypes.POINTER(_CameraList)()
        if lib.dc1394_camera_enumerate(context, ctypes.byref(listing)) != 0 or not listing:
            lib.dc1394_free(context)
            raise DeviceNotFoundError("libdc1394 could not enumerate IEEE-1394 cameras")
        guids = [listing.contents.ids[i].guid for i in range(listing.contents.num)]
        lib.dc1394_camera_free_list(listing)
        chosen = guids[0] if guid is None and guids else guid if guid in guids else None
        if chosen is None:
            lib.dc1394_free(context)
            which = f" with GUID {guid:016x}" if guid is not None else ""
            raise DeviceNotFoundError(f"no IEEE-1394 camera{which} found ({len(guids)} on the bus)")
        camera = lib.dc1394_camera_new(context, chosen)
        if not camera:
            lib.dc1394_free(context)
            raise NotConnectedError(f"IEEE-1394 camera {chosen:016x} could not be opened")
        return cls(lib, context, camera, f"IEEE-1394 GUID {chosen:016x}")

    def _live(self):
        if self._camera is None:
            raise NotConnectedError(f"stereo head transport ({self.description}) is closed")
        return self._camera

    def read_register(self, address: int) -> int:
        value = ctypes.c_uint32()
        if self._lib.dc1394_get_control_registers(self._live(), address - reg.COMMAND_BASE, ctypes.byref(value), 1):
            raise NotConnectedError(f"stereo head ({self.description}) did not answer a read of "
                                    f"register 0x{address - reg.COMMAND_BASE:X} (unplugged?); call reopen()")
        return int(value.value)

    def write_register(self, address: int, value: int) -> None:
        camera = self._live()
        starting = address == reg.COMMAND_BASE + reg.ISO_EN and value & (1 << 31)
        if starting and not self._capturing:
            if self._lib.dc1394_capture_setup(camera, _RING_BUFFERS, _CAPTURE_FLAGS_DEFAULT):
                raise DriverError(f"stereo head ({self.description}): could not set up capture "
                                  "(isochronous bandwidth or channel not available)")
            self._capturing = True
        quadlet = ctypes.c_uint32(value & 0xFFFFFFFF)
        if self._lib.dc1394_set_control_registers(camera, address - reg.COMMAND_BASE, ctypes.byref(quadlet), 1):
            raise NotConnectedError(f"stereo head ({self.description}) did not accept a write of "
                                    f"register 0x{address - reg.COMMAND_BASE:X} (unplugged?); call reopen()")
        if address == reg.COMMAND_BASE + reg.ISO_EN and not value & (1 << 31) and self._capturing:
            self._lib.dc1394_capture_stop(camera)
            self._capturing = False

    def read_frame(self, nbytes: int, timeout: float) -> np.ndarray:
        camera = self._live()
        frame = ctypes.POINTER(_Frame)()
        deadline = time.monotonic() + timeout
        while True:
            if self._lib.dc1394_capture_dequeue(camera, _CAPTURE_POLICY_POLL, ctypes.byref(frame)):
                raise NotConnectedError(f"stereo head ({self.description}) stopped delivering frames "
                                        "(unplugged?); call reopen()")
            if frame:
                break
            if time.monotonic() > deadline:
                raise DriverTimeoutError(f"stereo head ({self.description}) sent no frame in {timeout} s")
            time.sleep(0.002)
        try:
            return np.ctypeslib.as_array(frame.contents.image, shape=(nbytes,)).copy()
        finally:
            self._lib.dc1394_capture_enqueue(camera, frame)

    def identity(self) -> tuple[str, str]:
        camera = self._live().contents
        return ((camera.vendor or b"").decode("latin-1"), (camera.model or b"").decode("latin-1"))

    def close(self) -> None:
        if self._camera is None:
            return
        if self._capturing:
            self._lib.dc1394_capture_stop(self._camera)
            self._capturing = False
        self._lib.dc1394_camera_free(self._camera)
        self._lib.dc1394_free(self._context)
        self._camera = None
