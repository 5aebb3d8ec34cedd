"""Pioneer P3-AT over ARCOS.

Pure protocol modules, safe for the virtual robot in ``mocks/`` to import: ``commands`` (command numbers,
argument kinds), ``codec`` (framing, parser, SIP/CONFIG/ENCODER/IO/SYNC2), ``params`` (parameter sets), ``state``
(SIP -> RobotState), ``motion`` (SI -> clamped commands). The I/O driver is ``robot.P3AT``.

The names below are re-exported lazily so that importing a pure module never pulls in pyserial or threads.
"""
from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "P3AT": "drivers.arcos.robot",
    "LinkEvent": "drivers.arcos.robot",
    "ClampWarning": "drivers.arcos.robot",
    "RobotState": "drivers.arcos.state",
    "SonarReading": "drivers.arcos.state",
    "RobotParams": "drivers.arcos.params",
    "load_params": "drivers.arcos.params",
    "builtin_params": "drivers.arcos.params",
    "Identity": "drivers.arcos.codec",
    "RobotConfig": "drivers.arcos.codec",
    "EncoderCounts": "drivers.arcos.codec",
    "IoPacket": "drivers.arcos.codec",
    "Command": "drivers.arcos.commands",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'drivers.arcos' has no attribute {name!r}")
