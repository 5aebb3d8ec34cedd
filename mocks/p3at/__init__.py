"""The virtual P3-AT: a pure ARCOS robot model (:class:`VirtualP3AT`) and thin TCP / pty servers around it."""

from mocks.p3at.model import Link, RobotStats, VirtualP3AT
from mocks.p3at.options import FirmwareDefaults, OdometryErrors, SensorOptions
from mocks.p3at.servers import PtyServer, TcpServer, serve_pty, serve_tcp

__all__ = [
    "FirmwareDefaults",
    "Link",
    "OdometryErrors",
    "PtyServer",
    "RobotStats",
    "SensorOptions",
    "TcpServer",
    "VirtualP3AT",
    "serve_pty",
    "serve_tcp",
]
