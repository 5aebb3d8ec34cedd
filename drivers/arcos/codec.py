"""Sans-I/O ARCOS codec: packet framing, checksums, command arguments and the robot's packets.

Everything here is pure: bytes in, values out. The driver, the virtual robot in ``mocks/`` and the
benchmarks share it. Facts from ``../shared/reference/arcos-protocol.md``.

Framing (both directions): ``0xFA 0xFB | N | ID | args… | CK_hi CK_lo`` where N counts ID, arguments and
the two checksum bytes. A *payload* in this module is the N-2 bytes from ID to the last argument.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, field, fields, make_dataclass
from enum import IntEnum
from typing import Any, NamedTuple

from drivers.arcos.commands import ArgType, Command
from drivers.errors import ProtocolError

HEADER = b"\xfa\xfb"
MAX_PAYLOAD_SEND = 198  # N <= 200, the classic limit every robot accepts
MAX_N_RECEIVE = 255  # ARIA's receiver accepts any N that fits the length byte


class PacketId(IntEnum):
    """IDs of packets sent by the robot."""

    SYNC0 = 0x00
    SYNC1 = 0x01
    SYNC2 = 0x02
    CONFIG = 0x20
    SIP_STOPPED = 0x32
    SIP_MOVING = 0x33
    ENCODER = 0x90
    IO = 0xF0


SIP_IDS = frozenset(range(0x30, 0x35))  # p2os accepts 0x30-0x34; ARCOS sends 0x32 stopped, 0x33 moving


# --------------------------------------------------------------------------- framing
def checksum(payload: bytes) -> int:
    """ARCOS checksum of ``payload`` (ID..last argument): big-endian 16-bit word sum, odd byte XORed in."""
    n = len(payload)
    even = n & ~1
    total = sum(struct.unpack_from(f">{even // 2}H", payload)) & 0xFFFF if even else 0
    if n & 1:
        total ^= payload[-1]
    return total


def encode_packet(payload: bytes) -> bytes:
    """Frame ``payload`` (ID + arguments) as a complete packet with header, length and checksum."""
    if not payload:
        raise ValueError("an ARCOS packet needs at least its ID byte")
    if len(payload) > MAX_PAYLOAD_SEND:
        raise ValueError(f"payload of {len(payload)} bytes exceeds the {MAX_PAYLOAD_SEND}-byte limit (N <= 200)")
    ck = checksum(payload)
    return HEADER + bytes((len(payload) + 2,)) + bytes(payload) + bytes((ck >> 8, ck & 0xFF))


@dataclass
class ParserStats:
    """What a :class:`PacketParser` has seen. Every byte fed is in a packet, dropped, or still buffered."""

    packets: int = 0  # good packets returned
    packet_bytes: int = 0  # bytes of those packets, headers and checksums included
    dropped_bytes: int = 0  # bytes discarded while resynchronising
    bad_checksums: int = 0  # candidate packets whose checksum did not match
    oversize: int = 0  # headers whose length byte exceeded ``max_length``
    undersize: int = 0  # headers whose length byte was below 3 (no room for ID + checksum)
    truncated: int = 0  # incomplete packets abandoned because a complete good packet started inside them


class PacketParser:
    """Streaming packet finder: ``feed(bytes)`` returns the payloads (ID first) of every complete good packet.

    Resynchronises after garbage, truncated and corrupt packets by rescanning from the byte after a rejected
    header; never raises on any input. ``max_length`` bounds the accepted N (default 255, as ARIA).

    Trade-off: an incomplete packet is abandoned as soon as a complete packet with a good checksum starts inside
    it. Without that, a truncated packet would hold back everything after it until its promised length had
    arrived (for a robot hearing a PULSE every 500 ms that is long enough for the watchdog to stop it). The cost
    is that a genuine packet whose bytes happen to contain a complete valid packet, and that arrives split just
    after it, is lost; that needs a checksum match by chance, so it is rare and costs one packet.
    """

    def __init__(self, max_length: int = MAX_N_RECEIVE) -> None:
        self.max_length = max_length
        self.stats = ParserStats()
        self._buf = bytearray()

    @property
    def buffered(self) -> int:
        """Bytes held while waiting for the rest of a packet."""
        return len(self._buf)

    def reset(self) -> None:
        """Forget any partial packet (e.g. after the link was reopened); counts the bytes as dropped."""
        self.stats.dropped_bytes += len(self._buf)
        self._buf.clear()

    def feed(self, data: bytes) -> list[bytes]:
        buf = self._buf
        buf += data
        out: list[bytes] = []
        stats = self.stats
        pos = 0
        end = len(buf)
        while True:
            start = buf.find(HEADER, pos)
            if start < 0:
                # Keep a trailing 0xFA: it may be the first half of a header.
                keep_from = end - 1 if end > pos and buf[end - 1] == 0xFA else end
                stats.dropped_bytes += keep_from - pos
                pos = keep_from
                break
            stats.dropped_bytes += start - pos
            pos = start
            if end - pos < 3:
                break
            n = buf[pos + 2]
            if n < 3 or n > self.max_length:
                if n < 3:
                    stats.undersize += 1
                else:
                    stats.oversize += 1
                stats.dropped_bytes += 1
                pos += 1
                continue
            if end - pos < 3 + n:
                # Incomplete: wait for the rest, unless a complete good packet already starts inside it. Then
                # this one was truncated (a real robot never nests packets), and waiting for the bytes its
                # length promises would hold back good packets for up to 255 bytes of traffic.
                inner = self._complete_packet_after(pos + 1)
                if inner < 0:
                    break
                stats.truncated += 1
                stats.dropped_bytes += inner - pos
                pos = inner
                continue
            payload = bytes(buf[pos + 3 : pos + 1 + n])
            got = (buf[pos + 1 + n] << 8) | buf[pos + 2 + n]
            if checksum(payload) != got:
                stats.bad_checksums += 1
                stats.dropped_bytes += 1
                pos += 1
                continue
            out.append(payload)
            stats.packets += 1
            stats.packet_bytes += 3 + n
            pos += 3 + n
        del buf[:pos]
        return out

    def _complete_packet_after(self, pos: int) -> int:
        """Index of the first header at or after ``pos`` that starts a complete packet with a good checksum."""
        buf = self._buf
        end = len(buf)
        while True:
            q = buf.find(HEADER, pos)
            if q < 0 or end - q < 3:
                return -1
            n = buf[q + 2]
            if 3 <= n <= self.max_length and end - q >= 3 + n:
                if checksum(bytes(buf[q + 3 : q + 1 + n])) == (buf[q + 1 + n] << 8) | buf[q + 2 + n]:
                    return q
            pos = q + 1


# --------------------------------------------------------------------------- commands
class DecodedCommand(NamedTuple):
    """A command as the robot sees it. ``cmd`` is a :class:`Command` when known, else the raw int."""

    cmd: int
    arg: int | bytes | None


def encode_command(cmd: int, arg: int | str | bytes | None = None) -> bytes:
    """Complete packet for command ``cmd`` with no argument, an integer (0x3B / 0x1B) or a string (0x2B).

    Strings are sent bare (length byte then characters, no trailing NUL), as in the reference's SAY example.
    """
    if not 0 <= int(cmd) <= 255:
        raise ValueError(f"command number {cmd} is not a byte")
    payload = bytearray((int(cmd),))
    if arg is None:
        pass
    elif isinstance(arg, bool | int):
        value = int(arg)
        if not -0xFFFF <= value <= 0xFFFF:
            raise ValueError(f"argument {value} of command {cmd} does not fit 16 bits")
        payload.append(ArgType.POSINT if value >= 0 else ArgType.NEGINT)
        payload += abs(value).to_bytes(2, "little")
    elif isinstance(arg, str | bytes | bytearray):
        raw = arg.encode("latin-1") if isinstance(arg, str) else bytes(arg)
        if len(raw) > 255 or len(raw) + 4 > MAX_PAYLOAD_SEND:
            raise ValueError(f"string argument of {len(raw)} bytes is too long")
        payload.append(ArgType.STRING)
        payload.append(len(raw))
        payload += raw
    else:
        raise TypeError(f"argument must be None, int, str or bytes, not {type(arg).__name__}")
    return encode_packet(bytes(payload))


def decode_command(payload: bytes) -> DecodedCommand:
    """Decode a command payload (ID first). Raises :class:`ProtocolError` on a malformed argument.

    Integers come back signed (0x1B applied). Strings come back as bytes without ARIA's optional trailing NUL.
    """
    if not payload:
        raise ProtocolError("empty command packet")
    number = payload[0]
    cmd: int = Command(number) if number in Command._value2member_map_ else number
    if len(payload) == 1:
        return DecodedCommand(cmd, None)
    kind = payload[1]
    if kind in (ArgType.POSINT, ArgType.NEGINT):
        if len(payload) < 4:
            raise ProtocolError(f"command {number}: integer argument truncated ({len(payload) - 2} of 2 bytes)")
        value = payload[2] | (payload[3] << 8)
        return DecodedCommand(cmd, value if kind == ArgType.POSINT else -value)
    if kind == ArgType.STRING:
        if len(payload) < 3:
            raise ProtocolError(f"command {number}: string argument without its length byte")
        length = payload[2]
        raw = payload[3 : 3 + length]
        if len(raw) < length:
            raise ProtocolError(f"command {number}: string argument truncated ({len(raw)} of {length} bytes)")
        return DecodedCommand(cmd, bytes(raw))
    raise ProtocolError(f"command {number}: unknown argument type byte 0x{kind:02X}")


def pack_vel2(left: int, right: int) -> int:
    """VEL2 argument from wheel speeds in Vel2Divisor units (each -128..127): ARIA's ``(left << 8) | right``."""
    if not (-128 <= left <= 127 and -128 <= right <= 127):
        raise ValueError(f"VEL2 wheel values ({left}, {right}) must each fit a signed byte")
    value = ((left & 0xFF) << 8) | (right & 0xFF)
    return value - 0x10000 if value & 0x8000 else value


def unpack_vel2(arg: int) -> tuple[int, int]:
    """Inverse of :func:`pack_vel2`: apply the sign first (done by decode_command), then split the bytes."""
    value = arg & 0xFFFF
    left, right = value >> 8, value & 0xFF
    return (left - 256 if left > 127 else left, right - 256 if right > 127 else right)


# --------------------------------------------------------------------------- field reader / writer
class _Reader:
    """Little-endian cursor over a payload; ``None`` from a read means the packet ended before the field."""

    __slots__ = ("data", "pos")

    def __init__(self, data: bytes, pos: int = 0) -> None:
        self.data = data
        self.pos = pos

    def remaining(self) -> int:
        return len(self.data) - self.pos

    def read(self, kind: str) -> Any:
        if kind == "str":
            if self.pos >= len(self.data):
                return None
            nul = self.data.find(b"\0", self.pos)
            stop = len(self.data) if nul < 0 else nul
            text = self.data[self.pos : stop].decode("latin-1")
            self.pos = stop + 1 if nul >= 0 else stop
            return text
        fmt = _STRUCT[kind]
        if self.remaining() < fmt.size:
            return None
        (value,) = fmt.unpack_from(self.data, self.pos)
        self.pos += fmt.size
        return value


_STRUCT = {k: struct.Struct("<" + c) for k, c in
           {"u8": "B", "s8": "b", "u16": "H", "s16": "h", "u32": "I", "s32": "i"}.items()}


def _write(out: bytearray, kind: str, value: Any) -> None:
    if kind == "str":
        out += str(value).encode("latin-1") + b"\0"
    else:
        out += _STRUCT[kind].pack(value)


def _write_fields(out: bytearray, source: Any, table: tuple[tuple[str, str], ...]) -> None:
    """Append ``source``'s fields named in ``table`` in order, stopping at the first ``None``."""
    for name, kind in table:
        value = getattr(source, name)
        if value is None:
            break
        _write(out, kind, value)


def _read_fields(reader: _Reader, table: tuple[tuple[str, str], ...]) -> dict[str, Any]:
    """Fields of ``table`` in order until the packet ends (a field cut short counts as absent)."""
    values: dict[str, Any] = {}
    for name, kind in table:
        value = reader.read(kind)
        if value is None:
            break
        values[name] = value
    return values


# --------------------------------------------------------------------------- SYNC2 identity
@dataclass(frozen=True)
class Identity:
    """The SYNC2 reply: robot name, type (class) and subtype, e.g. ("AMRISim", "Pioneer", "p3at")."""

    name: str
    type: str
    subtype: str


def encode_identity(identity: Identity) -> bytes:
    """SYNC2 reply payload (ID 0x02 + three NUL-terminated strings)."""
    out = bytearray((PacketId.SYNC2,))
    for text in (identity.name, identity.type, identity.subtype):
        _write(out, "str", text)
    return bytes(out)


def decode_identity(payload: bytes) -> Identity:
    if not payload or payload[0] != PacketId.SYNC2:
        raise ProtocolError("SYNC2 reply must start with ID 0x02")
    reader = _Reader(payload, 1)
    parts = [reader.read("str") for _ in range(3)]
    return Identity(*(p or "" for p in parts))


# --------------------------------------------------------------------------- SIP
# Optional trailing fields, in wire order; each is present only if bytes remain.
SIP_OPTIONAL_FIELDS: tuple[tuple[str, str], ...] = (
    ("battery_x10", "u16"),
    ("charge_state", "u8"),
    ("rotvel", "s16"),  # deg/s x 10
    ("fault_flags", "u16"),
    ("latvel", "s16"),
    ("temperature", "s8"),  # -127 = not available
    ("soc", "u8"),
    ("uc_time", "u32"),  # µs
    ("flags3", "u32"),
)


@dataclass
class Sip:
    """A standard server information packet in raw robot units (conversion to SI is the driver's job).

    ``sonars`` holds only the readings new in this SIP: ``(sonar number, raw range)`` pairs.
    Optional trailing fields are ``None`` when the robot did not send them; when encoding, fields are written
    up to (not including) the first ``None``.
    """

    moving: bool = False  # ID 0x33 (else 0x32)
    xpos: int = 0  # u16, low 15 bits meaningful
    ypos: int = 0
    thpos: int = 0  # s16 angle units
    lvel: int = 0  # s16
    rvel: int = 0
    battery: int = 0  # u8 decivolts
    stall_bumpers: int = 0  # u16
    control: int = 0  # s16 heading setpoint
    flags: int = 0  # u16
    compass: int = 0  # u8 degrees / 2
    sonars: tuple[tuple[int, int], ...] = ()
    grip_state: int = 0
    anport: int = 0
    analog: int = 0
    digin: int = 0
    digout: int = 0
    battery_x10: int | None = None
    charge_state: int | None = None
    rotvel: int | None = None
    fault_flags: int | None = None
    latvel: int | None = None
    temperature: int | None = None
    soc: int | None = None
    uc_time: int | None = None
    flags3: int | None = None
    packet_id: int | None = field(default=None, compare=False)  # the ID as received (0x30-0x34)


_SIP_HEAD = struct.Struct("<HHhhhBHhHBB")  # xpos..compass, sonar count
_SIP_TAIL = struct.Struct("<BBBBB")  # grip_state, anport, analog, digin, digout
_SONAR = struct.Struct("<BH")


def encode_sip(sip: Sip) -> bytes:
    """SIP payload (ID first) with every field of ``sip``; optional fields up to the first ``None``."""
    out = bytearray((PacketId.SIP_MOVING if sip.moving else PacketId.SIP_STOPPED,))
    out += _SIP_HEAD.pack(sip.xpos & 0xFFFF, sip.ypos & 0xFFFF, sip.thpos, sip.lvel, sip.rvel, sip.battery,
                          sip.stall_bumpers, sip.control, sip.flags, sip.compass, len(sip.sonars))
    for number, rng in sip.sonars:
        out += _SONAR.pack(number, rng)
    out += _SIP_TAIL.pack(sip.grip_state, sip.anport, sip.analog, sip.digin, sip.digout)
    _write_fields(out, sip, SIP_OPTIONAL_FIELDS)
    return bytes(out)


def decode_sip(payload: bytes) -> Sip:
    """Decode a SIP payload (ID 0x30-0x34 first). Raises :class:`ProtocolError` if a mandatory field is missing."""
    if not payload or payload[0] not in SIP_IDS:
        raise ProtocolError(f"not a SIP: ID 0x{payload[0] if payload else 0:02X}")
    if len(payload) < 1 + _SIP_HEAD.size:
        raise ProtocolError(f"SIP truncated: {len(payload)} bytes, the fixed part needs {1 + _SIP_HEAD.size}")
    (xpos, ypos, thpos, lvel, rvel, battery, stall_bumpers, control, flags, compass,
     count) = _SIP_HEAD.unpack_from(payload, 1)
    pos = 1 + _SIP_HEAD.size
    need = pos + count * _SONAR.size + _SIP_TAIL.size
    if len(payload) < need:
        raise ProtocolError(f"SIP truncated: {count} sonar readings announced, {len(payload)} of {need} bytes")
    sonars = tuple(_SONAR.unpack_from(payload, pos + i * _SONAR.size) for i in range(count))
    pos += count * _SONAR.size
    grip_state, anport, analog, digin, digout = _SIP_TAIL.unpack_from(payload, pos)
    optional = _read_fields(_Reader(payload, pos + _SIP_TAIL.size), SIP_OPTIONAL_FIELDS)
    return Sip(moving=payload[0] == PacketId.SIP_MOVING, xpos=xpos, ypos=ypos, thpos=thpos, lvel=lvel, rvel=rvel,
               battery=battery, stall_bumpers=stall_bumpers, control=control, flags=flags, compass=compass,
               sonars=sonars, grip_state=grip_state, anport=anport, analog=analog, digin=digin, digout=digout,
               packet_id=payload[0], **optional)


# --------------------------------------------------------------------------- CONFIG
# Fields of the CONFIG packet (0x20) in wire order; a reader accepts a packet that ends after any field.
CONFIG_FIELDS: tuple[tuple[str, str], ...] = (
    ("type", "str"), ("subtype", "str"), ("serial_num", "str"), ("unused", "u8"),
    ("rot_vel_top", "u16"), ("trans_vel_top", "u16"), ("rot_accel_top", "u16"), ("trans_accel_top", "u16"),
    ("pwm_max", "u16"), ("name", "str"), ("sip_cycle", "u8"), ("host_baud", "u8"), ("aux1_baud", "u8"),
    ("has_gripper", "u16"), ("front_sonar", "u16"), ("rear_sonar", "u8"), ("low_battery", "u16"),
    ("rev_count", "u16"), ("watchdog", "u16"), ("normal_mpacs", "u8"),
    ("stall_val", "u16"), ("stall_count", "u16"), ("joy_vel", "u16"), ("joy_rot_vel", "u16"),
    ("rot_vel_max", "u16"), ("trans_vel_max", "u16"), ("rot_accel", "u16"), ("rot_decel", "u16"),
    ("rot_kp", "u16"), ("rot_kv", "u16"), ("rot_ki", "u16"),
    ("trans_accel", "u16"), ("trans_decel", "u16"), ("trans_kp", "u16"), ("trans_kv", "u16"), ("trans_ki", "u16"),
    ("front_bumps", "u8"), ("rear_bumps", "u8"), ("has_charger", "u8"), ("sonar_cycle", "u8"),
    ("auto_baud", "u8"), ("gyro_type", "u8"), ("drift_factor", "s16"), ("aux2_baud", "u8"), ("aux3_baud", "u8"),
    ("ticks_mm", "u16"), ("shutdown_volts", "u16"), ("firmware_version", "str"),
    ("gyro_cw", "u16"), ("gyro_ccw", "u16"), ("kinematics_delay", "u8"),
    ("lat_vel_top", "u16"), ("lat_accel_top", "u16"), ("lat_vel_max", "u16"), ("lat_accel", "u16"),
    ("lat_decel", "u16"), ("powerbot_charge_threshold", "u16"),
    ("pdb_port", "u8"), ("gyro_rate_limit", "u16"), ("high_temp_shutdown", "s8"), ("power_bits", "u16"),
    ("battery_type", "u8"), ("soc_low", "u16"), ("soc_shutdown", "u16"), ("bootloader_version", "str"),
    ("config_flags", "u32"), ("gyro_fw_version", "s16"),
)

RobotConfig = make_dataclass(
    "RobotConfig",
    [(name, str | None if kind == "str" else int | None, field(default=None)) for name, kind in CONFIG_FIELDS],
    frozen=True,
)
RobotConfig.__doc__ = (
    "The CONFIG packet (0x20) in raw robot units; every field is ``None`` when the packet ended before it. "
    "Field names and order: ``CONFIG_FIELDS``."
)
RobotConfig.__module__ = __name__


def encode_config(config: Any) -> bytes:
    """CONFIG payload (ID 0x20 first) with the fields of ``config`` up to the first ``None``."""
    out = bytearray((PacketId.CONFIG,))
    _write_fields(out, config, CONFIG_FIELDS)
    return bytes(out)


def decode_config(payload: bytes) -> Any:
    """Decode a CONFIG payload into a ``RobotConfig``; a packet may end after any field."""
    if not payload or payload[0] != PacketId.CONFIG:
        raise ProtocolError("CONFIG packet must start with ID 0x20")
    return RobotConfig(**_read_fields(_Reader(payload, 1), CONFIG_FIELDS))


def config_to_dict(config: Any) -> dict[str, Any]:
    """The fields of a ``RobotConfig`` that the robot sent, in wire order."""
    return {f.name: getattr(config, f.name) for f in fields(config) if getattr(config, f.name) is not None}


# --------------------------------------------------------------------------- ENCODER and IO
class EncoderCounts(NamedTuple):
    left: int
    right: int


def encode_encoder(counts: EncoderCounts | tuple[int, int]) -> bytes:
    return bytes((PacketId.ENCODER,)) + struct.pack("<ii", *counts)


def decode_encoder(payload: bytes) -> EncoderCounts:
    if len(payload) < 9 or payload[0] != PacketId.ENCODER:
        raise ProtocolError(f"ENCODER packet must be ID 0x90 + two s32, got {len(payload)} bytes")
    return EncoderCounts(*struct.unpack_from("<ii", payload, 1))


class IoPacket(NamedTuple):
    digital_in: tuple[int, ...]  # u8 each
    digital_out: tuple[int, ...]  # u8 each
    analog: tuple[int, ...]  # u16 each, 10-bit 0-1023 for 0-5 V


def encode_io(io: IoPacket) -> bytes:
    out = bytearray((PacketId.IO, len(io.digital_in), *io.digital_in, len(io.digital_out), *io.digital_out))
    out.append(len(io.analog))
    out += struct.pack(f"<{len(io.analog)}H", *io.analog)
    return bytes(out)


def decode_io(payload: bytes) -> IoPacket:
    if not payload or payload[0] != PacketId.IO:
        raise ProtocolError("IO packet must start with ID 0xF0")
    pos = 1
    groups: list[tuple[int, ...]] = []
    for size, name in ((1, "digital inputs"), (1, "digital outputs"), (2, "analog values")):
        if pos >= len(payload):
            raise ProtocolError(f"IO packet ends before the count of {name}")
        count = payload[pos]
        pos += 1
        if pos + count * size > len(payload):
            raise ProtocolError(f"IO packet announces {count} {name} but is truncated")
        fmt = f"<{count}{'B' if size == 1 else 'H'}"
        groups.append(struct.unpack_from(fmt, payload, pos))
        pos += count * size
    return IoPacket(*groups)
