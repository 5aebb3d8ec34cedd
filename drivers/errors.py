"""Errors raised by the drivers. Each is also the matching builtin, so callers may catch either."""


class DriverError(Exception):
    """Root of every error a driver raises."""


class NotConnectedError(DriverError, ConnectionError):
    """The device is not open, was closed, or vanished (unplugged, link lost)."""


class DriverTimeoutError(DriverError, TimeoutError):
    """The device did not answer in time."""


class ProtocolError(DriverError, ValueError):
    """The device answered with something the protocol does not allow."""


class BadFileError(DriverError, ValueError):
    """A parameter or calibration file is malformed; the message names the file, line and field."""


class DeviceNotFoundError(DriverError, LookupError):
    """No device matched the given URL or identifiers."""
