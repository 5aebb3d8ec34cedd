"""The ARCOS codec against the reference's captured bytes, round trips and line noise."""
from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.arcos.codec import (
    CONFIG_FIELDS,
    SIP_OPTIONAL_FIELDS,
    EncoderCounts,
    Identity,
    IoPacket,
    PacketParser,
    RobotConfig,
    Sip,
    checksum,
    decode_command,
    decode_config,
    decode_encoder,
    decode_identity,
    decode_io,
    decode_sip,
    encode_command,
    encode_config,
    encode_encoder,
    encode_identity,
    encode_io,
    encode_packet,
    encode_sip,
    pack_vel2,
    unpack_vel2,
)
from drivers.arcos.commands import Command
from drivers.errors import ProtocolError


def hexbytes(text: str) -> bytes:
    return bytes.fromhex(text.replace("\n", " "))


# --------------------------------------------------------------------------- golden vectors from the reference
GOLDEN_COMMANDS = [
    ("FA FB 03 00 00 00", 0, None),  # SYNC0
    ("FA FB 03 01 00 01", 1, None),  # SYNC1
    ("FA FB 03 02 00 02", 2, None),  # SYNC2
    ("FA FB 06 04 3B 01 00 05 3B", Command.ENABLE, 1),
    ("FA FB 06 0B 1B C8 00 D3 1B", Command.VEL, -200),
    ("FA FB 06 06 3B B8 0B BE 46", Command.SETV, 3000),
    ("FA FB 07 0F 2B 02 05 64 11 54", Command.SAY, bytes([0x05, 0x64])),
]

CAPTURED_SIP = hexbytes("""FA FB 56 32 00 00 00 00 00 00 00 00 00 00 82 00 00 00 00 1E 00 00 10 00 88 13 01 88 13
02 88 13 03 88 13 04 88 13 05 88 13 06 88 13 07 88 13 08 88 13 09 88 13 0A 88 13 0B 88 13 0C 88 13 0D 88 13
0E 88 13 0F 88 13 00 00 00 FF FF 82 00 00 00 00 00 00 00 00 81 00 E7 2B""")

CAPTURED_SYNC2 = b"\xfa\xfb\x18\x02AMRISim\0Pioneer\0p3at\0\xe7\xba"


@pytest.mark.parametrize(("wire", "cmd", "arg"), GOLDEN_COMMANDS)
def test_golden_commands_encode_and_decode_byte_for_byte(wire: str, cmd: int, arg: object) -> None:
    packet = hexbytes(wire)
    assert encode_command(cmd, arg) == packet
    (payload,) = PacketParser().feed(packet)
    assert decode_command(payload) == (cmd, arg)


def test_checksum_worked_examples() -> None:
    assert checksum(bytes.fromhex("043B0100")) == 0x053B
    assert checksum(bytes.fromhex("0F2B020564")) == 0x1154  # odd length: last byte XORed in
    assert checksum(b"") == 0


def test_aria_trailing_nul_on_string_argument_is_accepted() -> None:
    # ARIA sends a NUL after the characters that the length byte does not count.
    payload = bytes([Command.SAY, 0x2B, 2, 0x05, 0x64, 0x00])
    assert decode_command(payload) == (Command.SAY, bytes([0x05, 0x64]))


def test_open_close_estop_with_and_without_integer() -> None:
    for cmd in (Command.OPEN, Command.CLOSE, Command.E_STOP):
        assert decode_command(encode_command(cmd)[3:-2]) == (cmd, None)
        assert decode_command(encode_command(cmd, 1)[3:-2]) == (cmd, 1)


def test_captured_sip_decodes_to_the_described_state() -> None:
    (payload,) = PacketParser().feed(CAPTURED_SIP)
    sip = decode_sip(payload)
    assert not sip.moving and (sip.xpos, sip.ypos, sip.thpos) == (0, 0, 0)
    assert sip.battery == 130  # 13.0 V
    assert sip.flags == 0x1E
    assert sip.sonars == tuple((i, 5000) for i in range(16))
    assert (sip.digin, sip.digout) == (0xFF, 0xFF)
    assert sip.battery_x10 == 130 and sip.temperature == -127 and sip.soc == 0
    assert sip.uc_time is None and sip.flags3 is None  # not sent by this simulator
    assert encode_packet(encode_sip(sip)) == CAPTURED_SIP


def test_captured_sync2_identity() -> None:
    (payload,) = PacketParser().feed(CAPTURED_SYNC2)
    assert decode_identity(payload) == Identity("AMRISim", "Pioneer", "p3at")
    assert encode_packet(encode_identity(Identity("AMRISim", "Pioneer", "p3at"))) == CAPTURED_SYNC2


# --------------------------------------------------------------------------- argument edge cases
def test_vel2_packs_like_aria_and_unpacks_after_the_sign() -> None:
    assert pack_vel2(1, -1) == 0x01FF
    assert pack_vel2(-1, 1) == -255
    wire = encode_command(Command.VEL2, pack_vel2(-1, 1))
    assert wire[4] == 0x1B  # negative integer on the wire
    cmd, arg = decode_command(wire[3:-2])
    assert unpack_vel2(arg) == (-1, 1)
    with pytest.raises(ValueError, match="signed byte"):
        pack_vel2(128, 0)


@given(st.integers(-128, 127), st.integers(-128, 127))
def test_vel2_round_trip(left: int, right: int) -> None:
    _, arg = decode_command(encode_command(Command.VEL2, pack_vel2(left, right))[3:-2])
    assert unpack_vel2(arg) == (left, right)


def test_bad_arguments_are_rejected_clearly() -> None:
    with pytest.raises(ValueError, match="16 bits"):
        encode_command(Command.VEL, 70000)
    with pytest.raises(TypeError):
        encode_command(Command.VEL, 1.5)  # type: ignore[arg-type]
    with pytest.raises(ProtocolError, match="unknown argument type"):
        decode_command(bytes([11, 0x4C, 1, 0]))
    with pytest.raises(ProtocolError, match="truncated"):
        decode_command(bytes([11, 0x3B, 1]))
    with pytest.raises(ProtocolError, match="truncated"):
        decode_command(bytes([15, 0x2B, 5, 1]))


def test_unknown_command_number_decodes_as_plain_int() -> None:
    cmd, arg = decode_command(bytes([200, 0x3B, 7, 0]))
    assert cmd == 200 and not isinstance(cmd, Command) and arg == 7


# --------------------------------------------------------------------------- round trips
@given(st.integers(0, 255), st.one_of(st.none(), st.integers(-0xFFFF, 0xFFFF), st.binary(max_size=150)))
def test_command_round_trip(cmd: int, arg: int | bytes | None) -> None:
    packet = encode_command(cmd, arg)
    (payload,) = PacketParser().feed(packet)
    assert decode_command(payload) == (cmd, arg)


u8 = st.integers(0, 0xFF)
u16 = st.integers(0, 0xFFFF)
s16 = st.integers(-0x8000, 0x7FFF)
KIND = {"u8": u8, "s8": st.integers(-128, 127), "u16": u16, "s16": s16, "u32": st.integers(0, 0xFFFFFFFF),
        "str": st.text(st.characters(min_codepoint=1, max_codepoint=255), max_size=12)}


@st.composite
def sips(draw: st.DrawFn) -> Sip:
    n_optional = draw(st.integers(0, len(SIP_OPTIONAL_FIELDS)))
    optional = {name: draw(KIND[kind]) for name, kind in SIP_OPTIONAL_FIELDS[:n_optional]}
    return Sip(moving=draw(st.booleans()), xpos=draw(st.integers(0, 0x7FFF)), ypos=draw(st.integers(0, 0x7FFF)),
               thpos=draw(s16), lvel=draw(s16), rvel=draw(s16), battery=draw(u8), stall_bumpers=draw(u16),
               control=draw(s16), flags=draw(u16), compass=draw(u8),
               sonars=tuple(draw(st.lists(st.tuples(st.integers(0, 31), u16), max_size=32))),
               grip_state=draw(u8), anport=draw(u8), analog=draw(u8), digin=draw(u8), digout=draw(u8), **optional)


@given(sips())
def test_sip_round_trip(sip: Sip) -> None:
    (payload,) = PacketParser().feed(encode_packet(encode_sip(sip)))
    assert decode_sip(payload) == sip


@st.composite
def configs(draw: st.DrawFn) -> object:
    n = draw(st.integers(0, len(CONFIG_FIELDS)))
    return RobotConfig(**{name: draw(KIND[kind]) for name, kind in CONFIG_FIELDS[:n]})


@settings(max_examples=60)
@given(configs())
def test_config_round_trip_ending_after_any_field(config: object) -> None:
    payload = encode_config(config)
    if len(payload) <= 198:
        (payload,) = PacketParser().feed(encode_packet(payload))
    assert decode_config(payload) == config


def test_config_truncated_inside_a_field_keeps_the_fields_before() -> None:
    full = RobotConfig(**{name: ("x" if kind == "str" else 1) for name, kind in CONFIG_FIELDS[:8]})
    payload = encode_config(full)
    cut = decode_config(payload[:-1])  # last u16 is half there
    assert cut.rot_accel_top == 1 and cut.trans_accel_top is None


@given(st.integers(-2**31, 2**31 - 1), st.integers(-2**31, 2**31 - 1))
def test_encoder_round_trip(left: int, right: int) -> None:
    assert decode_encoder(encode_encoder((left, right))) == EncoderCounts(left, right)


@given(st.lists(u8, max_size=8), st.lists(u8, max_size=8), st.lists(st.integers(0, 1023), max_size=8))
def test_io_round_trip(din: list[int], dout: list[int], analog: list[int]) -> None:
    io = IoPacket(tuple(din), tuple(dout), tuple(analog))
    assert decode_io(encode_io(io)) == io


def test_truncated_packets_raise_protocol_error() -> None:
    sip = encode_sip(Sip(sonars=((0, 1000), (1, 2000))))
    with pytest.raises(ProtocolError, match="sonar"):
        decode_sip(sip[:-7])
    with pytest.raises(ProtocolError, match="fixed part"):
        decode_sip(sip[:10])
    with pytest.raises(ProtocolError):
        decode_io(bytes([0xF0, 3, 1]))
    with pytest.raises(ProtocolError):
        decode_encoder(bytes([0x90, 1, 2]))


# --------------------------------------------------------------------------- the streaming parser
def test_parser_handles_split_bytes_one_at_a_time() -> None:
    parser = PacketParser()
    got = [p for b in CAPTURED_SIP + CAPTURED_SYNC2 for p in parser.feed(bytes([b]))]
    assert [p[0] for p in got] == [0x32, 0x02]
    assert parser.stats.dropped_bytes == 0 and parser.buffered == 0


def test_parser_resyncs_after_garbage_truncation_and_corruption() -> None:
    good = encode_command(Command.VEL, 100)
    corrupt = bytearray(good)
    corrupt[5] ^= 0x40
    stream = b"\x00\xfa\x12garbage" + CAPTURED_SIP[:40] + good + bytes(corrupt) + b"\xfa\xfb\xf0" + good
    parser = PacketParser(max_length=200)
    payloads = parser.feed(stream)
    assert [decode_command(p) for p in payloads] == [(Command.VEL, 100), (Command.VEL, 100)]
    assert parser.stats.truncated == 1 and parser.stats.bad_checksums >= 1 and parser.stats.oversize == 1
    s = parser.stats
    assert s.packet_bytes + s.dropped_bytes + parser.buffered == len(stream)


def test_truncated_packet_does_not_hold_back_the_next_good_one() -> None:
    # A command cut short, then a PULSE: the PULSE must come out now, not after 255 more bytes of traffic.
    parser = PacketParser()
    got = parser.feed(encode_command(Command.SAY, b"x" * 100)[:20] + encode_command(Command.PULSE))
    assert got == [bytes([Command.PULSE])]
    assert parser.stats.truncated == 1 and parser.buffered == 0


@settings(max_examples=150)
@given(st.binary(max_size=600), st.lists(st.integers(1, 64), max_size=20))
def test_random_streams_never_raise_and_recover_at_the_next_good_packet(noise: bytes, cuts: list[int]) -> None:
    parser = PacketParser()
    # Flush any partial header the noise left with enough filler for the longest possible N.
    stream = noise + bytes(258) + encode_command(Command.SETO)
    got: list[bytes] = []
    pos = 0
    for cut in cuts + [len(stream)]:
        got += parser.feed(stream[pos : pos + cut])
        pos += cut
    got += parser.feed(stream[pos:])
    assert got[-1] == bytes([Command.SETO])
    s = parser.stats
    assert s.packet_bytes + s.dropped_bytes + parser.buffered == len(stream)


@settings(max_examples=150)
@given(st.data())
def test_mutated_packet_streams_never_raise(data: st.DataObject) -> None:
    packets = [encode_command(Command.VEL, -200), CAPTURED_SIP, CAPTURED_SYNC2, encode_command(Command.SAY, b"ab")]
    stream = bytearray(b"".join(data.draw(st.lists(st.sampled_from(packets), min_size=1, max_size=8))))
    for _ in range(data.draw(st.integers(0, 6))):
        op = data.draw(st.sampled_from(["flip", "delete", "insert"]))
        i = data.draw(st.integers(0, len(stream) - 1)) if stream else 0
        if op == "flip" and stream:
            stream[i] ^= data.draw(st.integers(1, 255))
        elif op == "delete" and stream:
            del stream[i]
        else:
            stream.insert(i, data.draw(u8))
    trailer = bytes(258) + CAPTURED_SYNC2
    parser = PacketParser()
    got = parser.feed(bytes(stream) + trailer)
    for payload in got:  # decoding what the parser passed must not raise anything but ProtocolError
        try:
            if payload[0] in (0x32, 0x33):
                decode_sip(payload)
            elif payload[0] == 0x02:
                decode_identity(payload)
            else:
                decode_command(payload)
        except ProtocolError:
            pass
    assert got[-1] == CAPTURED_SYNC2[3:-2]


def test_parser_buffer_stays_bounded_on_endless_noise() -> None:
    parser = PacketParser()
    for _ in range(200):
        parser.feed(b"\xfa\xfb\xff" + bytes(100))
    assert parser.buffered <= 258
