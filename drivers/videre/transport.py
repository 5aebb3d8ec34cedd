"""How register quadlets and frames reach the head: a small interface and its pyusb implementation.

The interface (``Transport``) is what ``StereoHead`` needs and nothing more, so an IEEE-1394 transport
through libdc1394 fits beside the USB one. Addresses are 24-bit offsets above the IIDC config ROM base
(``registers.CONFIG_ROM_BASE``), i.e. ``registers.COMMAND_BASE + register``.

USB framing follows libdc1394's IIDC-over-USB backend: a register read is a vendor IN control transfer
(bmRequestType 0xC0, bRequest 0x7F, wValue = address & 0xFFFF, wIndex = address >> 16, 4 bytes, quadlet
little-endian), a write the same with bmRequestType 0x40; frames are bulk transfers on endpoint 0x81.
"""
from __future__ import annotations

import array
import errno
from typing import Any, Protocol

import numpy as np
import usb.core
import usb.util

from drivers.errors import (
    DeviceNotFoundError,
    DriverError,
    DriverTimeoutError,
    NotConnectedError,
    ProtocolError,
)
from drivers.videre.registers import (
    DEFAULT_PRODUCT_ID,
    DEFAULT_VENDOR_ID,
    FRAME_ENDPOINT,
    REQUEST_REGISTER,
    REQUEST_TYPE_READ,
    REQUEST_TYPE_WRITE,
)

_GONE_ERRNOS = {errno.ENODEV, errno.ENXIO, errno.ESHUTDOWN, errno.EIO}
_LIBUSB_NO_DEVICE = -4


class Transport(Protocol):
    """What the head driver needs from a bus."""

    description: str

    def read_register(self, address: int) -> int: ...

    def write_register(self, address: int, value: int) -> None: ...

    def read_frame(self, nbytes: int, timeout: float) -> np.ndarray:
        """One whole frame of ``nbytes`` as a (nbytes,) uint8 array; DriverTimeoutError if none came."""
        ...

    def identity(self) -> tuple[str, str]:
        """(vendor name, model name) as the device reports them."""
        ...

    def close(self) -> None: ...


class UsbTransport:
    """IIDC over USB through pyusb. ``backend`` goes to ``usb.core.find`` (a virtual head passes its own)."""

    def __init__(self, device: Any, description: str):
        self._device = device
        self.description = description
        self._closed = False

    @staticmethod
    def find(vendor_id: int = DEFAULT_VENDOR_ID, product_id: int = DEFAULT_PRODUCT_ID, backend: Any = None,
             serial: str | None = None) -> list[Any]:
        """The USB devices with these ids (and serial), without opening any: DeviceNotFoundError if none, or if
        pyusb has no backend to look with. Its messages name no command-line option (the driver serves every
        command and program): a command adds its own hint."""
        ids = f"{vendor_id:04x}:{product_id:04x}"
        try:
            found = list(usb.core.find(find_all=True, idVendor=vendor_id, idProduct=product_id, backend=backend))
        except usb.core.NoBackendError as exc:
            raise DeviceNotFoundError(
                f"no USB backend to look for stereo head {ids}: pyusb needs the libusb-1.0 library "
                f"(Debian/Ubuntu: sudo apt-get install libusb-1.0-0; Fedora: sudo dnf install libusb1; "
                f"macOS: brew install libusb) ({exc})") from None
        if serial is not None:
            found = [d for d in found if _safe_string(d, d.iSerialNumber) == serial]
        if not found:
            which = f" with serial {serial}" if serial else ""
            raise DeviceNotFoundError(f"no stereo head found at USB {ids}{which} (plugged in? permissions?)")
        return found

    @classmethod
    def open(cls, vendor_id: int = DEFAULT_VENDOR_ID, product_id: int = DEFAULT_PRODUCT_ID,
             backend: Any = None, serial: str | None = None) -> UsbTransport:
        ids = f"{vendor_id:04x}:{product_id:04x}"
        device = cls.find(vendor_id, product_id, backend, serial)[0]
        description = f"USB {ids} bus {device.bus} address {device.address}"
        try:
            device.set_configuration()
            usb.util.claim_interface(device, 0)
        except usb.core.USBError as exc:
            raise _translate(exc, description, "configuring") from None
        return cls(device, description)

    def _check_open(self) -> None:
        if self._closed:
            raise NotConnectedError(f"stereo head transport ({self.description}) is closed")

    def read_register(self, address: int) -> int:
        self._check_open()
        try:
            data = self._device.ctrl_transfer(REQUEST_TYPE_READ, REQUEST_REGISTER, address & 0xFFFF,
                                              (address >> 16) & 0xFFFF, 4, 1000)
        except usb.core.USBError as exc:
            raise _translate(exc, self.description, f"reading register 0x{address:06X}") from None
        if len(data) != 4:
            raise ProtocolError(f"register 0x{address:06X} read returned {len(data)} bytes, expected 4")
        return int.from_bytes(bytes(data), "little")

    def write_register(self, address: int, value: int) -> None:
        self._check_open()
        payload = (value & 0xFFFFFFFF).to_bytes(4, "little")
        try:
            sent = self._device.ctrl_transfer(REQUEST_TYPE_WRITE, REQUEST_REGISTER, address & 0xFFFF,
                                              (address >> 16) & 0xFFFF, payload, 1000)
        except usb.core.USBError as exc:
            raise _translate(exc, self.description, f"writing register 0x{address:06X}") from None
        if sent != 4:
            raise ProtocolError(f"register 0x{address:06X} write sent {sent} bytes, expected 4")

    def read_frame(self, nbytes: int, timeout: float) -> np.ndarray:
        self._check_open()
        buffer = array.array("B", bytes(nbytes))
        got = 0
        view = np.frombuffer(buffer, np.uint8)
        try:
            while got < nbytes:
                chunk = buffer if got == 0 else array.array("B", bytes(nbytes - got))
                count = self._device.read(FRAME_ENDPOINT, chunk, int(timeout * 1000))
                if count <= 0:
                    raise ProtocolError(f"empty bulk transfer from {self.description}")
                if got:
                    view[got:got + count] = np.frombuffer(chunk, np.uint8)[:count]
                got += count
        except usb.core.USBError as exc:
            raise _translate(exc, self.description, "reading a frame") from None
        return view

    def identity(self) -> tuple[str, str]:
        self._check_open()
        try:
            return (_safe_string(self._device, self._device.iManufacturer),
                    _safe_string(self._device, self._device.iProduct))
        except usb.core.USBError as exc:
            raise _translate(exc, self.description, "reading the identification strings") from None

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            usb.util.release_interface(self._device, 0)
        except (usb.core.USBError, ValueError):
            pass  # the device may already be gone; nothing left to release
        try:
            usb.util.dispose_resources(self._device)
        except usb.core.USBError:
            pass


def _safe_string(device: Any, index: int) -> str:
    if not index:
        return ""
    return usb.util.get_string(device, index) or ""


def _translate(exc: usb.core.USBError, description: str, doing: str) -> DriverError:
    if isinstance(exc, usb.core.USBTimeoutError):
        return DriverTimeoutError(f"stereo head ({description}) timed out {doing}")
    if exc.errno in _GONE_ERRNOS or getattr(exc, "backend_error_code", None) == _LIBUSB_NO_DEVICE:
        return NotConnectedError(f"stereo head ({description}) vanished while {doing} (unplugged?): {exc.strerror}; "
                                 "plug it back in and call reopen()")
    if exc.errno == errno.EPIPE:
        return ProtocolError(f"stereo head ({description}) stalled {doing}: the register or request is refused")
    return DriverError(f"stereo head ({description}) USB error while {doing}: {exc}")
