"""The virtual P3-AT at the byte level, spoken to with the driver's sans-I/O codec (no sockets)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.arcos.codec import (
    PacketParser,
    decode_config,
    decode_encoder,
    decode_identity,
    decode_io,
    decode_sip,
    encode_command,
    encode_packet,
    pack_vel2,
)
from drivers.arcos.commands import Command
from mocks.p3at import Link, OdometryErrors, SensorOptions, VirtualP3AT
from mocks.world import World

QUIET = SensorOptions(sonar_noise_m=0.0, sonar_noise_fraction=0.0, sonar_beam_rad=0.0)


def open_world(size: float = 100.0) -> World:
    """A big square room: nothing nearby."""
    s = size
    walls = [[-s, -s, s, -s], [s, -s, s, s], [s, s, -s, s], [-s, s, -s, -s]]
    return World("open", np.array(walls, float), np.full(4, 3.0))


def box_world() -> World:
    """A 10 × 4 m room."""
    walls = [[0, 0, 10, 0], [10, 0, 10, 4], [10, 4, 0, 4], [0, 4, 0, 0]]
    return World("box", np.array(walls, float), np.full(4, 2.5))


class Client:
    """Drives a model like a client would: sends packets at simulated times, collects decoded packets."""

    def __init__(self, model: VirtualP3AT) -> None:
        self.model = model
        self.parser = PacketParser()
        self.t = 0.0
        self.received: list[bytes] = []

    def send(self, data: bytes) -> list[bytes]:
        got = self.parser.feed(self.model.receive(data, self.t))
        self.received += got
        return got

    def cmd(self, cmd: int, arg=None) -> list[bytes]:
        return self.send(encode_command(cmd, arg))

    def run(self, seconds: float, pulse: bool = True) -> list[bytes]:
        """Let time pass; PULSE every 0.5 s like ARIA unless told not to."""
        got: list[bytes] = []
        end = self.t + seconds
        while self.t < end - 1e-9:
            self.t = min(end, self.t + 0.5)
            if pulse:
                got += self.send(encode_command(Command.PULSE))
            else:
                got += self.parser.feed(self.model.advance(self.t))
        self.received += got
        return got

    def connect(self, motors: bool = True) -> None:
        for sync in (0, 1, 2):
            self.send(encode_packet(bytes([sync])))
        self.cmd(Command.OPEN, 1)
        if motors:
            self.cmd(Command.ENABLE, 1)

    def sips(self, packets: list[bytes]):
        return [decode_sip(p) for p in packets if p[0] in (0x32, 0x33)]

    def last_sip(self):
        return self.sips(self.run(0.2))[-1]


def robot(world: World | None = None, pose=(0.0, 0.0, 0.0), **kw) -> VirtualP3AT:
    kw.setdefault("sensors", QUIET)
    return VirtualP3AT(world or open_world(), "r1", np.array(pose, float), **kw)


# ------------------------------------------------------------------ handshake
def test_handshake_bytes_match_the_reference() -> None:
    model = VirtualP3AT(open_world(), "AMRISim", np.zeros(3), subtype="p3at")
    assert model.receive(bytes.fromhex("FAFB03000000"), 0.0) == bytes.fromhex("FAFB03000000")
    assert model.receive(bytes.fromhex("FAFB03010001"), 0.0) == bytes.fromhex("FAFB03010001")
    reply = model.receive(bytes.fromhex("FAFB03020002"), 0.0)
    # the reference's captured AMRISim reply
    assert reply == bytes.fromhex("FAFB1802") + b"AMRISim\0Pioneer\0p3at\0" + bytes.fromhex("E7BA")


def test_default_identity_is_p3at_sh() -> None:
    client = Client(robot())
    for sync in (0, 1):
        client.send(encode_packet(bytes([sync])))
    (reply,) = client.send(encode_packet(b"\x02"))
    ident = decode_identity(reply)
    assert (ident.name, ident.type, ident.subtype) == ("r1", "Pioneer", "p3at-sh")


def test_out_of_order_sync_restarts_the_handshake() -> None:
    client = Client(robot())
    assert client.send(encode_packet(b"\x01")) == []  # SYNC1 before SYNC0: ignored
    assert client.send(encode_packet(b"\x02")) == []
    assert client.model.stats.ignored == 2
    client.connect()
    assert client.model.link == Link.OPEN


def test_no_sips_before_open_then_every_100_ms() -> None:
    client = Client(robot())
    for sync in (0, 1, 2):
        client.send(encode_packet(bytes([sync])))
    assert client.run(3.0, pulse=False) == []
    client.cmd(Command.OPEN)  # bare OPEN, as p2os sends it
    sips = client.sips(client.run(1.0))
    assert len(sips) == 10
    assert all(s.packet_id == 0x32 for s in sips)  # motors stopped


@pytest.mark.parametrize("arg", [None, 1])
def test_close_with_or_without_argument_stops_sips(arg) -> None:
    client = Client(robot())
    client.connect()
    client.cmd(Command.VEL, 200)
    client.run(1.0)
    client.cmd(Command.CLOSE, arg)
    assert client.run(1.0, pulse=False) == []
    assert client.model.link == Link.WAIT_SYNC0
    assert client.model.v == 0.0


def test_sip_carries_every_optional_field() -> None:
    client = Client(robot())
    client.connect()
    sip = client.last_sip()
    assert sip.flags3 is not None and sip.uc_time is not None
    assert sip.battery == 130 and sip.battery_x10 == 130 and sip.temperature == -127
    assert sip.flags & 1  # motors enabled


# ------------------------------------------------------------------ motion
def test_velocity_command_moves_robot_and_sip_reports_it() -> None:
    client = Client(robot())
    client.connect()
    client.cmd(Command.VEL, 300)
    client.run(3.0)
    sip = client.last_sip()
    assert sip.moving and sip.lvel == 300 and sip.rvel == 300
    true = client.model.true_pose()
    # 1 s ramp at 300 mm/s² (0.15 m) then 0.3 m/s for the rest of the 3.2 s
    assert true[0] == pytest.approx(0.15 + 0.3 * 2.2, abs=0.005)
    assert sip.xpos == pytest.approx(true[0] * 1000, abs=1)  # p3at-sh: mm, no odometry error configured
    assert sip.ypos == 0 and sip.thpos == 0


def test_rotation_and_vel2() -> None:
    client = Client(robot())
    client.connect()
    client.cmd(Command.SETRA, 300)
    client.cmd(Command.RVEL, 30)
    client.run(2.0)
    sip = client.last_sip()
    assert sip.rotvel == pytest.approx(300, abs=2)  # deg/s × 10
    client.cmd(Command.VEL2, pack_vel2(-10, 10))  # ±200 mm/s
    client.run(2.0)
    sip = client.last_sip()
    assert (sip.lvel, sip.rvel) == (-200, 200)
    assert sip.rotvel == pytest.approx(math.degrees(0.4 / client.model.track_m) * 10, abs=2)


def test_velocity_limits_clamp() -> None:
    client = Client(robot())
    client.connect()
    client.cmd(Command.SETV, 200)
    client.cmd(Command.SETA, 1000)
    client.cmd(Command.VEL, 900)
    client.run(2.0)
    assert client.last_sip().lvel == 200
    client.cmd(Command.SETV, 5000)  # above TransVelTop: clamped to 1200
    config = decode_config(client.cmd(Command.CONFIG, 1)[0])
    assert config.trans_vel_max == 1200 and config.trans_accel == 1000


def test_acceleration_limit_sets_the_ramp() -> None:
    client = Client(robot())
    client.connect()
    client.cmd(Command.SETA, 100)  # 100 mm/s²: 3 s to reach 300 mm/s
    client.cmd(Command.VEL, 300)
    client.run(1.5)
    assert client.model.v == pytest.approx(0.15, abs=0.002)
    client.cmd(Command.SETA, -1000)  # deceleration
    client.cmd(Command.VEL, 0)
    client.run(0.5)
    assert client.model.v == 0.0


def test_move_is_position_control() -> None:
    client = Client(robot())
    client.connect()
    client.cmd(Command.MOVE, -1000)
    client.run(8.0)
    assert client.model.true_pose()[0] == pytest.approx(-1.0, abs=0.003)
    assert client.model.v == 0.0 and not client.last_sip().moving


@pytest.mark.parametrize(
    ("commands", "expected_deg"),
    [([(Command.HEAD, 90)], 90), ([(Command.DHEAD, -45)], -45), ([(Command.DCHEAD, 30), (Command.DCHEAD, 30)], 60)],
)
def test_heading_control(commands, expected_deg) -> None:
    client = Client(robot())
    client.connect()
    for cmd, arg in commands:
        client.cmd(cmd, arg)
    client.run(5.0)
    assert math.degrees(client.model.odometry[2]) == pytest.approx(expected_deg, abs=0.6)
    sip = client.last_sip()
    assert sip.control == pytest.approx(math.radians(expected_deg) / client.model.params.angle_conv_factor, abs=2)


def test_seto_resets_odometry_not_ground_truth() -> None:
    client = Client(robot())
    client.connect()
    client.cmd(Command.VEL, 300)
    client.run(2.0)
    client.cmd(Command.STOP)
    client.run(2.0)
    client.cmd(Command.SETO)
    sip = client.last_sip()
    assert (sip.xpos, sip.ypos, sip.thpos) == (0, 0, 0)
    assert client.model.true_pose()[0] > 0.4


def test_e_stop_with_or_without_argument() -> None:
    for arg in (None, 1):
        client = Client(robot())
        client.connect()
        client.cmd(Command.VEL, 500)
        client.run(2.0)
        client.cmd(Command.E_STOP, arg)
        assert client.model.v == 0.0
        client.run(0.5)
        assert client.model.v == 0.0


def test_enable_zero_stops_and_motors_flag() -> None:
    client = Client(robot())
    client.connect()
    client.cmd(Command.VEL, 300)
    client.run(2.0)
    client.cmd(Command.ENABLE, 0)
    sip = client.last_sip()
    assert not sip.flags & 1 and sip.lvel == 0


def test_position_wraps_at_15_bits() -> None:
    client = Client(robot(open_world(60)))
    client.connect()
    client.cmd(Command.SETV, 1200)
    client.cmd(Command.SETA, 2000)
    client.cmd(Command.VEL, 1200)
    raw, total, prev = [], 0, None
    for _ in range(32):
        sip = client.sips(client.run(1.0))[-1]
        if prev is not None:
            diff = sip.xpos - prev
            diff += -0x8000 if diff > 0x1000 else (0x8000 if diff < -0x1000 else 0)
            total += diff
        prev = sip.xpos
        raw.append(sip.xpos)
    assert max(raw) <= 0x7FFF and any(b < a for a, b in zip(raw, raw[1:], strict=False))  # it wrapped
    assert total + raw[0] == pytest.approx(client.model.odometry[0] * 1000, abs=2)


# ------------------------------------------------------------------ watchdog
def test_watchdog_stops_a_silent_client() -> None:
    client = Client(robot())
    client.connect()
    client.cmd(Command.VEL, 300)
    client.run(1.9, pulse=False)
    assert client.model.v > 0
    client.run(1.5, pulse=False)  # 2 s without a packet, then the deceleration
    assert client.model.v == 0.0 and client.model.stats.watchdog_stops == 1
    client.run(3.0)  # PULSEs alone do not restart the motion
    assert client.model.v == 0.0


def test_pulses_keep_the_robot_moving() -> None:
    client = Client(robot())
    client.connect()
    client.cmd(Command.VEL, 300)
    client.run(5.0)
    assert client.model.v == pytest.approx(0.3) and client.model.stats.watchdog_stops == 0


# ------------------------------------------------------------------ collisions
def test_collision_stops_robot_and_sets_stall_and_bumper_flags() -> None:
    client = Client(robot(box_world(), pose=(5.0, 2.0, 0.0)))
    client.connect()
    client.cmd(Command.VEL, 400)
    client.run(20.0)
    radius = client.model.firmware.collision_radius_m
    assert client.model.true_pose()[0] == pytest.approx(10.0 - radius, abs=0.01)
    sip = client.last_sip()
    assert sip.stall_bumpers & 0x0001 and sip.stall_bumpers & 0x0100  # both wheels stall
    assert sip.stall_bumpers & 0xFE00 == 1 << 11  # the middle one of five front bumpers
    assert sip.lvel == 0 and client.model.stats.collisions == 1
    client.cmd(Command.VEL, -200)  # backing away is allowed and clears the flags
    client.run(2.0)
    assert client.last_sip().stall_bumpers == 0 and client.model.true_pose()[0] < 10.0 - radius - 0.1


def test_bumpstall_disables_motors_on_a_bump() -> None:
    client = Client(robot(box_world(), pose=(8.0, 2.0, 0.0)))
    client.connect()
    client.cmd(Command.BUMPSTALL, 1)
    client.cmd(Command.VEL, 400)
    client.run(10.0)
    assert not client.last_sip().flags & 1


def test_robots_collide_with_each_other() -> None:
    world = open_world()
    other = VirtualP3AT(world, "r2", np.array([2.0, 0.0, 0.0]))
    client = Client(robot(world))
    client.connect()
    client.cmd(Command.VEL, 300)
    client.run(12.0)
    # the bodies meet (robot_contact="footprint", the default): two 626 mm robots head to tail stop 0.626 m apart
    assert client.model.true_pose()[0] == pytest.approx(2.0 - client.model.params.length_m, abs=0.01)
    other.close()


# ------------------------------------------------------------------ odometry
def test_odometry_systematic_errors() -> None:
    client = Client(robot(odometry=OdometryErrors(distance_scale=0.9, wheelbase_scale=1.1)))
    client.connect()
    client.cmd(Command.MOVE, 1000)  # position control uses the (wrong) odometry: drives 1/0.9 m
    client.run(8.0)
    assert client.model.odometry[0] == pytest.approx(1.0, abs=0.003)
    assert client.model.true_pose()[0] == pytest.approx(1.0 / 0.9, abs=0.005)
    client.cmd(Command.DHEAD, 90)  # believes 90°, turns 90 × 1.1 / 0.9
    client.run(6.0)
    assert math.degrees(client.model.true_pose()[2]) == pytest.approx(90 * 1.1 / 0.9, abs=1.0)


def test_odometry_noise_is_seeded() -> None:
    def drive(seed: int) -> np.ndarray:
        client = Client(robot(odometry=OdometryErrors(noise=0.02), rng=np.random.default_rng(seed)))
        client.connect()
        client.cmd(Command.VEL, 300)
        client.cmd(Command.RVEL, 10)
        client.run(5.0)
        return client.model.odometry.copy()

    np.testing.assert_array_equal(drive(1), drive(1))
    assert not np.array_equal(drive(1), drive(2))


def test_encoder_stream() -> None:
    client = Client(robot())
    client.connect()
    client.cmd(Command.ENCODER, 1)
    client.cmd(Command.VEL, 100)
    packets = client.run(2.0)
    counts = [decode_encoder(p) for p in packets if p[0] == 0x90]
    assert len(counts) == len(client.sips(packets)) == 20
    assert counts[-1].left == counts[-1].right > counts[0].left > 0
    assert counts[-1].left == pytest.approx(client.model.true_pose()[0] * 1000 * 128, rel=0.02)
    client.cmd(Command.ENCODER, 0)
    assert not any(p[0] == 0x90 for p in client.run(1.0))


def test_iorequest_once_and_continuous() -> None:
    client = Client(robot())
    client.connect()
    client.cmd(Command.DIGOUT, 0x0F05)
    client.cmd(Command.IOREQUEST, 1)
    io = [decode_io(p) for p in client.run(1.0) if p[0] == 0xF0]
    assert len(io) == 1 and io[0].digital_out[0] == 0x05 and len(io[0].analog) == 8
    client.cmd(Command.IOREQUEST, 2)
    assert sum(p[0] == 0xF0 for p in client.run(1.0)) == 10
    client.cmd(Command.IOREQUEST, 0)
    assert sum(p[0] == 0xF0 for p in client.run(1.0)) == 0


# ------------------------------------------------------------------ sonar
def test_sonar_sees_wall_at_hand_computed_range() -> None:
    client = Client(robot(box_world(), pose=(5.0, 2.0, 0.0)))
    client.connect()
    packets = client.run(1.0)
    readings = {n: r for sip in client.sips(packets) for n, r in sip.sonars}
    assert set(readings) == set(range(16))  # one sonar every 40 ms: all 16 within a second
    # sonar 3 at (245, 27) mm heading 10°: east wall x = 10
    assert readings[3] == pytest.approx((5.0 - 0.245) / math.cos(math.radians(10)) * 1000, abs=1)
    # sonar 0 at (147, 136) mm heading 90°: north wall y = 4
    assert readings[0] == pytest.approx((2.0 - 0.136) * 1000, abs=1)
    # a few sonars per SIP, as the firmware fires them
    assert all(2 <= len(s.sonars) <= 3 for s in client.sips(packets))


def test_sonar_max_range_and_noise() -> None:
    client = Client(VirtualP3AT(open_world(), "r1", np.zeros(3), rng=np.random.default_rng(3)))
    client.connect()
    readings = [r for sip in client.sips(client.run(1.0)) for _, r in sip.sonars]
    assert readings and all(r == 5000 for r in readings)  # nothing within 5 m
    near = Client(VirtualP3AT(box_world(), "r1", np.array([5.0, 2.0, 0.0]), rng=np.random.default_rng(3)))
    near.connect()
    front = [r for sip in near.sips(near.run(4.0)) for n, r in sip.sonars if n == 3]
    assert np.std(front) > 5  # noisy (mm)


def test_polling_and_sonar_off() -> None:
    client = Client(robot(box_world(), pose=(5.0, 2.0, 0.0)))
    client.connect()
    client.cmd(Command.POLLING, bytes([4, 5]))  # 1-based: sonars 3 and 4
    client.run(0.2)
    assert {n for sip in client.sips(client.run(1.0)) for n, _ in sip.sonars} == {3, 4}
    client.cmd(Command.SONAR, 0)
    client.run(0.2)
    sips = client.sips(client.run(1.0))
    assert all(not s.sonars for s in sips) and not sips[-1].flags & 0b0110


# ------------------------------------------------------------------ CONFIG and odds and ends
def test_config_reply_has_every_field() -> None:
    client = Client(robot())
    client.connect()
    (payload,) = [p for p in client.cmd(Command.CONFIG, 1) if p[0] == 0x20]
    config = decode_config(payload)
    assert config.gyro_fw_version is not None  # the last field: nothing was cut short
    assert (config.type, config.subtype, config.name) == ("Pioneer", "p3at-sh", "r1")
    assert (config.sip_cycle, config.watchdog, config.auto_baud) == (100, 2000, 2)


def test_battery_drains() -> None:
    client = Client(robot())
    client.connect()
    client.cmd(Command.VEL, 500)
    start = client.model.battery_volts
    client.run(30.0)
    assert client.model.battery_volts < start - 0.01


def test_accepted_commands_without_effect_and_hostbaud() -> None:
    client = Client(robot())
    client.connect()
    for cmd, arg in [(Command.SAY, b"\x05\x40"), (Command.SOUNDTOG, 0), (Command.BATTERYINFO, 1),
                     (Command.ADSEL, 3), (Command.HOSTBAUD, 2)]:
        client.cmd(cmd, arg)
    assert client.model.stats.unknown_commands == 0 and client.model.stats.bad_arguments == 0
    assert client.model.host_baud == 2 and client.last_sip().anport == 3


def test_unknown_commands_bad_arguments_and_bad_checksums_are_counted() -> None:
    client = Client(robot())
    client.connect()
    client.send(encode_packet(bytes([99, 0x3B, 1, 0])))  # unknown command 99
    client.send(encode_packet(bytes([Command.VEL, 0x2B, 1, 65])))  # VEL with a string
    client.send(encode_packet(bytes([Command.VEL])))  # VEL without its argument
    good = bytearray(encode_command(Command.VEL, 300))
    good[-1] ^= 0xFF
    client.send(bytes(good))  # bad checksum
    stats = client.model.stats
    assert (stats.unknown_commands, stats.bad_arguments) == (1, 2)
    assert client.model.parser.stats.bad_checksums == 1
    client.run(1.0)
    assert client.model.v == 0.0  # none of them moved the robot
    client.cmd(Command.VEL, 100)  # and it still obeys
    client.run(2.0)
    assert client.model.v > 0


@settings(max_examples=150, deadline=None)
@given(st.lists(st.binary(max_size=80), max_size=20), st.integers(0, 2**32 - 1))
def test_garbage_never_crashes(chunks, seed) -> None:
    model = VirtualP3AT(box_world(), "r1", np.array([5.0, 2.0, 0.0]), rng=np.random.default_rng(seed))
    client = Client(model)
    for chunk in chunks[:3]:  # before the handshake too
        client.send(chunk)
    client.connect()
    rng = np.random.default_rng(seed)
    for chunk in chunks:
        # mix random bytes with well-framed packets of random command numbers and arguments
        client.send(chunk)
        cmd = int(rng.integers(0, 256))
        arg = [None, int(rng.integers(-0xFFFF, 0xFFFF)), bytes(rng.integers(0, 256, 5, dtype=np.uint8))][seed % 3]
        client.send(encode_command(cmd, arg))
        client.t += 0.05
    client.run(1.0)
    assert model.stats.internal_errors == 0
    x, y, _ = model.true_pose()
    assert 0 < x < 10 and 0 < y < 4  # still inside the room
    assert client.model.world.distance_to_walls(np.array([x, y]))[0] >= model.firmware.collision_radius_m - 0.02


def test_close_removes_robot_from_world() -> None:
    world = open_world()
    with VirtualP3AT(world, "r1", np.zeros(3)):
        assert world.robot_names() == ["r1"]
    assert world.robot_names() == []


def test_start_pose_from_world() -> None:
    world = World.load()
    model = VirtualP3AT(world, "robot2")
    np.testing.assert_array_equal(world.pose("robot2"), world.start_poses["robot2"])
    model.close()
    with pytest.raises(ValueError, match="robot1"):
        VirtualP3AT(world, "nobody")


def test_sonar_sees_another_robot() -> None:
    world = open_world()
    other = VirtualP3AT(world, "r2", np.array([2.0, 0.1, 0.0]))
    client = Client(robot(world))
    client.connect()
    readings = {n: r for sip in client.sips(client.run(1.0)) for n, r in sip.sonars}
    # sonar 3 at (0.245, 0.027) heading 10°: centre offset (1.755, 0.073), along-ray 1.741 m, miss distance
    # 0.233 m, so the 0.33 m disc is entered sqrt(0.33² − 0.233²) = 0.234 m earlier: 1.507 m
    assert readings[3] == pytest.approx(1507, abs=3)
    assert readings[12] == 5000  # nothing behind
    other.close()


def test_p3at_subtype_reports_position_units() -> None:
    client = Client(robot(subtype="p3at"))  # old P2OS units: DistConvFactor 0.465 mm per unit
    client.connect()
    client.cmd(Command.MOVE, 1000)  # 1000 units = 465 mm
    client.run(6.0)
    assert client.model.true_pose()[0] == pytest.approx(0.465, abs=0.002)
    assert client.last_sip().xpos == pytest.approx(1000, abs=3)


def test_encoder_and_io_packets_follow_their_sip() -> None:
    client = Client(robot())
    client.connect()
    client.cmd(Command.ENCODER, 2)
    client.cmd(Command.IOREQUEST, 2)
    ids = [p[0] for p in client.run(0.5)]
    assert ids and ids == [0x32, 0x90, 0xF0] * (len(ids) // 3)


def test_sip_bytes_follow_the_reference_layout() -> None:
    """Assembled by hand from the reference's SIP table (not with the codec), so a shared bug cannot hide."""
    client = Client(robot())
    client.connect(motors=False)
    client.cmd(Command.SONAR, 0)
    client.run(0.5)
    raw = client.model.advance(client.t + 0.1)
    uc_time = round(client.model.time * 1e6)

    payload = bytes([0x32])  # stopped
    payload += bytes(10)  # XPOS, YPOS, THPOS, LVEL, RVEL
    payload += bytes([130])  # BATTERY 13.0 V
    payload += bytes(4)  # STALL_BUMPERS, CONTROL
    payload += bytes(2)  # FLAGS: motors off, sonars off
    payload += bytes([0, 0])  # COMPASS, SONAR_COUNT
    payload += bytes([0, 0, 0, 0xFF, 0])  # GRIP_STATE, ANPORT, ANALOG, DIGIN, DIGOUT
    payload += (130).to_bytes(2, "little") + bytes([0])  # BATTERYX10, CHARGESTATE
    payload += bytes(6)  # ROTVEL, FAULTFLAGS, LATVEL
    payload += bytes([0x81, 0])  # TEMPERATURE -127 (n/a), SOC
    payload += uc_time.to_bytes(4, "little") + bytes(4)  # uC time, FLAGS3
    words = sum((payload[i] << 8) | payload[i + 1] for i in range(0, len(payload) - 1, 2)) & 0xFFFF
    checksum = words ^ payload[-1] if len(payload) % 2 else words
    assert raw == bytes([0xFA, 0xFB, len(payload) + 2]) + payload + checksum.to_bytes(2, "big")
