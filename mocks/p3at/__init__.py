"""The virtual P3-AT: a pure ARCOS robot model (:class:`VirtualP3AT`), thin TCP / pty servers around it, and
robots served from a process of their own (:func:`serve_tcp_process`)."""

from mocks.p3at.model import Link, RobotStats, VirtualP3AT
from mocks.p3at.options import FirmwareDefaults, OdometryErrors, SensorOptions
from mocks.p3at.process import RemoteServer, RobotProcess, RobotProcessError, RobotSpec, serve_tcp_process
from mocks.p3at.servers import PtyServer, TcpServer, serve_pty, serve_tcp

__all__ = [
    "FirmwareDefaults",
    "Link",
    "OdometryErrors",
    "PtyServer",
    "RemoteServer",
    "RobotProcess",
    "RobotProcessError",
    "RobotSpec",
    "RobotStats",
    "SensorOptions",
    "TcpServer",
    "VirtualP3AT",
    "serve_pty",
    "serve_tcp",
    "serve_tcp_process",
]
