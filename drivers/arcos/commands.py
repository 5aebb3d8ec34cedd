"""ARCOS client command numbers and the kind of argument each one takes (pure constants, no I/O).

Source: ``../shared/reference/arcos-protocol.md`` (ARIA ``ArCommands.h``, the Pioneer 3 Operations Manual).
"""
from __future__ import annotations

from enum import Enum, IntEnum


class Command(IntEnum):
    """Client-to-robot command numbers (the ID byte of a command packet)."""

    PULSE = 0  # also the SYNC0 packet on the wire
    OPEN = 1  # also SYNC1
    CLOSE = 2  # also SYNC2
    POLLING = 3
    ENABLE = 4
    SETA = 5
    SETV = 6
    SETO = 7
    MOVE = 8
    ROTATE = 9
    SETRV = 10
    VEL = 11
    HEAD = 12
    DHEAD = 13
    SAY = 15
    CONFIG = 18
    ENCODER = 19
    RVEL = 21
    DCHEAD = 22
    SETRA = 23
    SONAR = 28
    STOP = 29
    DIGOUT = 30
    VEL2 = 32
    ADSEL = 35
    IOREQUEST = 40
    BUMPSTALL = 44
    HOSTBAUD = 50
    E_STOP = 55
    BATTERYINFO = 62
    SOUNDTOG = 92


# The three handshake packets are bare commands 0, 1, 2.
SYNC0 = 0
SYNC1 = 1
SYNC2 = 2


class ArgType(IntEnum):
    """The type byte that follows the command number."""

    POSINT = 0x3B  # positive integer, u16 little-endian
    NEGINT = 0x1B  # negative integer sent as its absolute value, u16 little-endian
    STRING = 0x2B  # length byte then the characters


class ArgKind(Enum):
    """What argument a command takes."""

    NONE = "none"
    INT = "int"  # non-negative integer
    SINT = "sint"  # signed integer
    STR = "str"
    NONE_OR_INT = "none/int"  # OPEN, CLOSE, E_STOP: the manual says none, ARIA sends 1


ARG_KIND: dict[Command, ArgKind] = {
    Command.PULSE: ArgKind.NONE,
    Command.OPEN: ArgKind.NONE_OR_INT,
    Command.CLOSE: ArgKind.NONE_OR_INT,
    Command.POLLING: ArgKind.STR,
    Command.ENABLE: ArgKind.INT,
    Command.SETA: ArgKind.SINT,
    Command.SETV: ArgKind.INT,
    Command.SETO: ArgKind.NONE,
    Command.MOVE: ArgKind.SINT,
    Command.ROTATE: ArgKind.SINT,
    Command.SETRV: ArgKind.INT,
    Command.VEL: ArgKind.SINT,
    Command.HEAD: ArgKind.INT,
    Command.DHEAD: ArgKind.SINT,
    Command.SAY: ArgKind.STR,
    Command.CONFIG: ArgKind.INT,
    Command.ENCODER: ArgKind.INT,
    Command.RVEL: ArgKind.SINT,
    Command.DCHEAD: ArgKind.SINT,
    Command.SETRA: ArgKind.SINT,
    Command.SONAR: ArgKind.INT,
    Command.STOP: ArgKind.NONE,
    Command.DIGOUT: ArgKind.INT,
    Command.VEL2: ArgKind.SINT,  # (left << 8) | right packed into one signed integer
    Command.ADSEL: ArgKind.INT,
    Command.IOREQUEST: ArgKind.INT,
    Command.BUMPSTALL: ArgKind.INT,
    Command.HOSTBAUD: ArgKind.INT,
    Command.E_STOP: ArgKind.NONE_OR_INT,
    Command.BATTERYINFO: ArgKind.INT,
    Command.SOUNDTOG: ArgKind.INT,
}

# HOSTBAUD argument codes (also the CONFIG HostBaud/Aux*Baud fields).
BAUD_CODES: dict[int, int] = {0: 9600, 1: 19200, 2: 38400, 3: 57600, 4: 115200}
