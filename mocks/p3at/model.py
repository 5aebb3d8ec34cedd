"""The virtual P3-AT: the robot side of ARCOS as a pure model (no sockets, no threads, no clock of its own).

Sans-I/O: a server feeds received bytes with ``receive(data, now)`` and calls ``advance(now)`` whenever it likes
(at the latest by ``next_deadline()``); both return the bytes the robot sends. ``now`` is simulated time in
seconds (any origin, never decreasing). Physics runs in fixed 10 ms steps so results do not depend on how
often the server calls in. Randomness (odometry and sonar noise) comes from an injected ``np.random.Generator``.

Behaviour follows ``../shared/reference/arcos-protocol.md``:
- handshake: SYNC0 and SYNC1 echoed, SYNC2 answered with (name, "Pioneer", subtype); out-of-order syncs reset it;
- SIPs every SipCycle (100 ms) only after OPEN, with every optional trailing field; CONFIG on request;
  ENCODER packets after each SIP while ENCODER is on; IO packets on IOREQUEST (one or continuous);
- every command of the reference's table; OPEN, CLOSE and E_STOP with or without their integer argument;
- velocity and acceleration limits (SETV/SETRV/SETA/SETRA, clamped to the *Top values), MOVE and
  HEAD/DHEAD/DCHEAD as position control, VEL/RVEL/ROTATE, VEL2 (wheel speeds in Vel2Divisor units);
- skid-steer kinematics in the world; a collision stops the robot and sets the stall and bumper flags;
- odometry from the wheels with :class:`OdometryErrors` (the world keeps the ground truth);
- sonars fire one every SonarCycle in the POLLING order, ray cast in the world, with noise and max range;
- the battery drains; the watchdog stops the motors when no packet came for Watchdog ms;
- garbage, bad checksums, malformed arguments and unknown commands are ignored and counted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from drivers.arcos.codec import (
    EncoderCounts,
    Identity,
    IoPacket,
    PacketParser,
    RobotConfig,
    Sip,
    decode_command,
    encode_config,
    encode_encoder,
    encode_identity,
    encode_io,
    encode_packet,
    encode_sip,
    unpack_vel2,
)
from drivers.arcos.commands import Command
from drivers.arcos.params import RobotParams, builtin_params
from drivers.errors import ProtocolError
from mocks.p3at.options import FirmwareDefaults, OdometryErrors, SensorOptions
from mocks.world import World, footprint_gap, footprint_overlap

STEP_S = 0.01  # physics step
ROBOT_CONTACTS = ("disc", "footprint")  # FirmwareDefaults.robot_contact
_CLEAR_M = 0.005  # further than this from what it touched, a robot's bumper is released
_HEAD_TOLERANCE_RAD = math.radians(0.5)
_MOVE_TOLERANCE_M = 0.001


class Link(IntEnum):
    """Handshake state: which packet the robot expects next."""

    WAIT_SYNC0 = 0
    WAIT_SYNC1 = 1
    WAIT_SYNC2 = 2
    WAIT_OPEN = 3
    OPEN = 4


@dataclass
class RobotStats:
    """What the robot ignored and did; the parser's own counters are in ``parser`` (bad checksums, dropped bytes)."""

    commands: int = 0  # commands acted upon
    unknown_commands: int = 0
    bad_arguments: int = 0  # a known command with a missing or wrong-typed argument
    ignored: int = 0  # good packets that do not fit the current state (commands before OPEN, out-of-order syncs)
    sessions: int = 0  # OPENs
    sips: int = 0
    watchdog_stops: int = 0
    collisions: int = 0  # times the robot ran into something (a contact that lasts counts once)
    internal_errors: int = 0  # packets that raised inside the model (a bug; tests assert it stays 0)


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def _toward(value: float, target: float, up: float, down: float) -> float:
    """Move ``value`` toward ``target`` by at most ``up`` when speeding up, ``down`` when slowing down."""
    if value * target < 0 or abs(target) < abs(value):  # slowing (or reversing: slow to zero first)
        step = down
    else:
        step = up
    if target > value:
        return min(target, value + step)
    return max(target, value - step)


class VirtualP3AT:
    """One virtual P3-AT in a :class:`World`; registers itself there under ``name`` at ``pose`` (x, y, θ).

    params: the driver's parameter set (default: the built-in one for ``subtype``);
    rng: noise source (default ``np.random.default_rng(0)``: deterministic);
    odometry, sensors, firmware: see :mod:`mocks.p3at.options`.
    Call :meth:`close` (or use as a context manager) to take the robot out of the world.
    """

    def __init__(
        self,
        world: World,
        name: str,
        pose: np.ndarray | None = None,
        *,
        subtype: str = "p3at-sh",
        params: RobotParams | None = None,
        rng: np.random.Generator | None = None,
        odometry: OdometryErrors | None = None,
        sensors: SensorOptions | None = None,
        firmware: FirmwareDefaults | None = None,
        robot_type: str = "Pioneer",
        start_time: float = 0.0,
    ) -> None:
        if pose is None:
            if name not in world.start_poses:
                raise ValueError(
                    f"no pose given and world {world.name!r} has no start pose {name!r} "
                    f"(it has: {', '.join(sorted(world.start_poses)) or 'none'})"
                )
            pose = world.start_poses[name]
        pose = np.asarray(pose, dtype=float).reshape(3)
        self.world = world
        self.name = name
        self.params = params if params is not None else builtin_params(subtype)
        self.identity = Identity(name, robot_type, self.params.subtype if params is not None else subtype)
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.odometry_errors = odometry or OdometryErrors()
        self.sensors = sensors or SensorOptions()
        self.firmware = firmware or FirmwareDefaults()
        self.stats = RobotStats()
        self.parser = PacketParser()
        # Effective track of the skid-steer base, consistent with DiffConvFactor: ω = (R − L) / 2 · DiffConvFactor.
        self.track_m = 2.0 / self.params.diff_conv_factor / 1000.0
        self._sonar_poses = np.asarray(self.params.sonar_poses, dtype=float).reshape(-1, 3)
        # Simulated seconds of client silence before the watchdog stops the motors. A server running simulated
        # time k× faster scales this by k: the client's silence is measured on its own (wall) clock.
        self.watchdog_s = self.firmware.watchdog_ms / 1000.0
        if self.firmware.robot_contact not in ROBOT_CONTACTS:
            raise ValueError(f"robot_contact must be one of {ROBOT_CONTACTS}, got {self.firmware.robot_contact!r}")
        self.footprint = (float(self.params.length_m), float(self.params.width_m))
        world.add_robot(name, pose, footprint=self.footprint)
        self._closed = False
        self._time = float(start_time)
        self._battery = self.sensors.battery_volts
        self._last_rx = self._time
        self._reset_session()

    # ------------------------------------------------------------------ lifecycle
    def close(self) -> None:
        """Take the robot out of the world (idempotent)."""
        if not self._closed:
            self._closed = True
            self.world.remove_robot(self.name)

    def __enter__(self) -> VirtualP3AT:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def reset_session(self) -> None:
        """A new client link (a reconnected TCP client): forget the handshake and any partial packet; stop."""
        self.parser.reset()
        self._reset_session()

    def _reset_session(self) -> None:
        fw = self.firmware
        self.link = Link.WAIT_SYNC0
        self.motors_enabled = False
        self.sonar_enabled = True
        self.polling = list(range(len(self._sonar_poses)))  # firing order, 0-based
        self._poll_index = 0
        self._pending_sonar: dict[int, int] = {}
        self._sonar_latest: dict[int, float] = {}
        self.encoder_stream = False
        self.io_stream = 0  # 0 off, 1 one packet pending, 2 continuous
        self.bumpstall = 0
        self.host_baud = 0
        self.digout = 0
        self.anport = 0
        self.trans_vel_max = fw.trans_vel_max / 1000.0
        self.rot_vel_max = math.radians(fw.rot_vel_max)
        self.trans_accel = fw.trans_accel / 1000.0
        self.trans_decel = fw.trans_decel / 1000.0
        self.rot_accel = math.radians(fw.rot_accel)
        self.rot_decel = math.radians(fw.rot_decel)
        self._trans_mode, self._trans_target = "vel", 0.0  # "vel": m/s; "move": metres still to go
        self._rot_mode, self._rot_target = "rvel", 0.0  # "rvel": rad/s; "head": setpoint (odometry frame)
        self.v = 0.0  # actual translational velocity, m/s
        self.w = 0.0  # actual rotational velocity, rad/s
        self.stall_bumpers = 0
        self._in_contact = False
        self.touching: str | None = None  # what the robot is pressed against: another robot's name, "wall", None
        self._wheel_speeds = (0.0, 0.0)  # measured, m/s
        self.odometry = np.zeros(3)  # x, y (m), θ (rad) in the odometry frame: what the robot reports
        self.encoders = [0, 0]
        self._next_sip = math.inf
        self._next_sonar = math.inf
        self._watchdog_tripped = False

    # ------------------------------------------------------------------ public state
    @property
    def time(self) -> float:
        """Simulated time (s) up to which the physics has run."""
        return self._time

    @property
    def battery_volts(self) -> float:
        return self._battery

    @property
    def is_open(self) -> bool:
        return self.link == Link.OPEN

    def true_pose(self) -> np.ndarray:
        """Ground truth (3,) from the world registry."""
        return self.world.pose(self.name)

    def next_deadline(self) -> float:
        """Simulated time at which :meth:`advance` next has something to send (inf when idle)."""
        return self._next_sip

    # ------------------------------------------------------------------ sans-I/O entry points
    def receive(self, data: bytes, now: float) -> bytes:
        """Bytes from the client at simulated time ``now``; returns everything the robot sends meanwhile."""
        out = bytearray(self.advance(now))
        for payload in self.parser.feed(bytes(data)):
            self._last_rx = self._time
            self._watchdog_tripped = False
            try:
                out += self._handle(payload)
            except Exception:  # noqa: BLE001 - a safety net: no packet may crash a running robot
                self.stats.internal_errors += 1
        return bytes(out)

    def advance(self, now: float, *, watchdog: bool = True) -> bytes:
        """Run the physics up to ``now``; returns the SIPs (and ENCODER/IO packets) that fell due.

        ``watchdog=False``: the client's silence is not known over this stretch, so the watchdog does not count it
        (a wall-clock server that ran late and found bytes that came at some instant of it)."""
        out = bytearray()
        while self._time + STEP_S <= now + 1e-9:
            self._step(STEP_S, watchdog)
            self._time += STEP_S
            if self._time + 1e-9 >= self._next_sip:
                out += self._cycle_packets()
                self._next_sip += self.firmware.sip_cycle_ms / 1000.0
        return bytes(out)

    # ------------------------------------------------------------------ commands
    def _handle(self, payload: bytes) -> bytes:
        number = payload[0]
        bare = len(payload) == 1
        if self.link != Link.OPEN:
            return self._handshake(number, bare, payload)
        if number not in Command._value2member_map_:
            self.stats.unknown_commands += 1
            return b""
        try:
            arg = decode_command(payload).arg
        except ProtocolError:
            self.stats.bad_arguments += 1
            return b""
        return self._command(Command(number), arg)

    def _handshake(self, number: int, bare: bool, payload: bytes) -> bytes:
        if number == 0 and bare:  # SYNC0 may restart the handshake at any point
            self.link = Link.WAIT_SYNC1
            return encode_packet(b"\x00")
        if number == 1 and bare and self.link == Link.WAIT_SYNC1:
            self.link = Link.WAIT_SYNC2
            return encode_packet(b"\x01")
        if number == 2 and bare and self.link == Link.WAIT_SYNC2:
            self.link = Link.WAIT_OPEN
            return encode_packet(encode_identity(self.identity))
        if number == Command.OPEN and self.link == Link.WAIT_OPEN:
            self._open()
            return b""
        self.stats.ignored += 1
        if number in (1, 2) and bare:
            self.link = Link.WAIT_SYNC0  # out of order: the client must start again
        return b""

    def _open(self) -> None:
        self.link = Link.OPEN
        self.stats.sessions += 1
        self.motors_enabled = False
        self.odometry = np.zeros(3)
        self.encoders = [0, 0]
        self._rot_mode, self._rot_target = "rvel", 0.0
        self._trans_mode, self._trans_target = "vel", 0.0
        self._next_sip = self._time + self.firmware.sip_cycle_ms / 1000.0
        self._next_sonar = self._time
        self._last_rx = self._time

    def _command(self, cmd: Command, arg: int | bytes | None) -> bytes:  # noqa: C901 - one branch per command
        """Act on one command in the OPEN state; returns any immediate reply."""
        takes_int = cmd not in (Command.POLLING, Command.SAY)
        if isinstance(arg, bytes) == takes_int and arg is not None:
            self.stats.bad_arguments += 1
            return b""
        needs_int = cmd not in (Command.PULSE, Command.OPEN, Command.CLOSE, Command.SETO, Command.STOP,
                                Command.E_STOP, Command.POLLING, Command.SAY)
        if needs_int and arg is None:
            self.stats.bad_arguments += 1
            return b""
        self.stats.commands += 1
        fw = self.firmware
        reply = b""
        if cmd == Command.PULSE or cmd == Command.OPEN:
            pass
        elif cmd == Command.CLOSE:
            self._stop_now()
            self.link = Link.WAIT_SYNC0
            self.motors_enabled = False
            self._next_sip = math.inf
        elif cmd == Command.ENABLE:
            self.motors_enabled = arg != 0
            if not self.motors_enabled:
                self._stop_now()
        elif cmd == Command.SETA:
            value = min(abs(arg), fw.trans_accel_top) / 1000.0
            if arg > 0:
                self.trans_accel = value
            elif arg < 0:
                self.trans_decel = value
        elif cmd == Command.SETRA:
            value = math.radians(min(abs(arg), fw.rot_accel_top))
            if arg > 0:
                self.rot_accel = value
            elif arg < 0:
                self.rot_decel = value
        elif cmd == Command.SETV:
            self.trans_vel_max = min(abs(arg), fw.trans_vel_top) / 1000.0
        elif cmd == Command.SETRV:
            self.rot_vel_max = math.radians(min(abs(arg), fw.rot_vel_top))
        elif cmd == Command.SETO:
            self.odometry = np.zeros(3)
            if self._rot_mode == "head":
                self._rot_mode, self._rot_target = "rvel", 0.0
        elif cmd == Command.MOVE:
            self._trans_mode, self._trans_target = "move", arg * self.params.dist_conv_factor / 1000.0
        elif cmd == Command.VEL:
            self._trans_mode, self._trans_target = "vel", arg / 1000.0
        elif cmd in (Command.RVEL, Command.ROTATE):
            self._rot_mode, self._rot_target = "rvel", math.radians(arg)
        elif cmd == Command.HEAD:
            self._rot_mode, self._rot_target = "head", _wrap(math.radians(arg))
        elif cmd == Command.DHEAD:
            self._rot_mode, self._rot_target = "head", _wrap(self.odometry[2] + math.radians(arg))
        elif cmd == Command.DCHEAD:
            base = self._rot_target if self._rot_mode == "head" else self.odometry[2]
            self._rot_mode, self._rot_target = "head", _wrap(base + math.radians(arg))
        elif cmd == Command.VEL2:
            left, right = unpack_vel2(arg)
            vl, vr = left * self.params.vel2_divisor / 1000.0, right * self.params.vel2_divisor / 1000.0
            self._trans_mode, self._trans_target = "vel", (vl + vr) / 2.0
            self._rot_mode, self._rot_target = "rvel", (vr - vl) / self.track_m
        elif cmd == Command.STOP:
            self._trans_mode, self._trans_target = "vel", 0.0
            self._rot_mode, self._rot_target = "rvel", 0.0
        elif cmd == Command.E_STOP:
            self._stop_now()
        elif cmd == Command.SONAR:
            self.sonar_enabled = arg != 0
        elif cmd == Command.POLLING:
            order = [b - 1 for b in (arg or b"") if 1 <= b <= len(self._sonar_poses)]
            self.polling, self._poll_index = order, 0
        elif cmd == Command.CONFIG:
            reply = encode_packet(encode_config(self.config()))
        elif cmd == Command.ENCODER:
            self.encoder_stream = arg > 0
        elif cmd == Command.IOREQUEST:
            self.io_stream = 0 if arg <= 0 else (1 if arg == 1 else 2)
        elif cmd == Command.BUMPSTALL:
            self.bumpstall = arg & 3
        elif cmd == Command.HOSTBAUD:
            self.host_baud = arg if 0 <= arg <= 4 else self.host_baud
        elif cmd == Command.DIGOUT:
            mask, values = (arg >> 8) & 0xFF, arg & 0xFF
            self.digout = (self.digout & ~mask & 0xFF) | (values & mask)
        elif cmd == Command.ADSEL:
            self.anport = arg & 0xFF
        # SAY, SOUNDTOG, BATTERYINFO: accepted, nothing to simulate.
        return reply

    def _stop_now(self) -> None:
        """Stop at once, overriding the deceleration (E_STOP, ENABLE 0, CLOSE)."""
        self.v = self.w = 0.0
        self._trans_mode, self._trans_target = "vel", 0.0
        self._rot_mode, self._rot_target = "rvel", 0.0

    # ------------------------------------------------------------------ physics
    def _desired_velocities(self) -> tuple[float, float]:
        if self._trans_mode == "move":
            remaining = self._trans_target
            if abs(remaining) < _MOVE_TOLERANCE_M:  # arrived: the position loop holds the wheels
                self._trans_mode, self._trans_target = "vel", 0.0
                v = self.v = 0.0
            else:
                reachable = math.sqrt(2.0 * self.trans_decel * abs(remaining))  # still able to stop in time
                v = math.copysign(min(self.trans_vel_max, reachable), remaining)
        else:
            v = max(-self.trans_vel_max, min(self.trans_vel_max, self._trans_target))
        if self._rot_mode == "head":
            error = _wrap(self._rot_target - self.odometry[2])
            if abs(error) < _HEAD_TOLERANCE_RAD:
                w = 0.0
            else:
                w = math.copysign(min(self.rot_vel_max, math.sqrt(2.0 * self.rot_decel * abs(error))), error)
        else:
            w = max(-self.rot_vel_max, min(self.rot_vel_max, self._rot_target))
        return v, w

    def _step(self, dt: float, watchdog: bool = True) -> None:
        if watchdog and self.is_open and self._time - self._last_rx >= self.watchdog_s:
            if not self._watchdog_tripped:
                self._watchdog_tripped = True
                commanded = self._trans_target != 0.0 or self._rot_target != 0.0 or self._rot_mode == "head"
                if commanded or self.v != 0.0 or self.w != 0.0:
                    self.stats.watchdog_stops += 1
                self._trans_mode, self._trans_target = "vel", 0.0
                self._rot_mode, self._rot_target = "rvel", 0.0
        if self.motors_enabled and self.is_open:
            v_want, w_want = self._desired_velocities()
        else:
            v_want, w_want = 0.0, 0.0
            self.v = self.w = 0.0
        self.v = _toward(self.v, v_want, self.trans_accel * dt, self.trans_decel * dt)
        if self._trans_mode == "move" and self.motors_enabled:
            # The last millimetres: the position loop brakes onto the target instead of overshooting it.
            self.v = max(-abs(self._trans_target) / dt, min(abs(self._trans_target) / dt, self.v))
        self.w = _toward(self.w, w_want, self.rot_accel * dt, self.rot_decel * dt)

        with self.world.moving():  # no other robot moves between this look at the world and this move
            ds, dth = self._move(dt)

        # Wheels: true travel, then what the encoders measure.
        half = dth * self.track_m / 2.0
        true_l, true_r = ds - half, ds + half
        err = self.odometry_errors
        meas = []
        for d in (true_l, true_r):
            m = d * err.distance_scale
            if err.noise > 0.0 and d != 0.0:
                m += self.rng.normal(0.0, err.noise * math.sqrt(abs(d)))
            meas.append(m)
        ml, mr = meas
        self._wheel_speeds = (ml / dt, mr / dt)
        ticks = self.firmware.ticks_mm * 1000.0
        self.encoders = [self.encoders[0] + round(ml * ticks), self.encoders[1] + round(mr * ticks)]
        # Odometry: what the firmware integrates from the measured wheels and the track it believes in.
        ods = (ml + mr) / 2.0
        odth = (mr - ml) / (self.track_m * err.wheelbase_scale)
        ox, oy, oth = self.odometry
        omid = oth + odth / 2.0
        self.odometry = np.array([ox + ods * math.cos(omid), oy + ods * math.sin(omid), _wrap(oth + odth)])
        if self._trans_mode == "move":
            remaining = self._trans_target - ods
            # Crossing zero means arrived (position control does not overshoot back).
            self._trans_target = remaining if remaining * self._trans_target > 0 else 0.0

        self._battery = max(
            self.sensors.battery_floor_volts,
            self._battery - self.sensors.drain_idle_v_per_s * dt - self.sensors.drain_motion_v_per_m * abs(ds),
        )
        self._fire_sonars()

    def _move(self, dt: float) -> tuple[float, float]:
        """Ground truth: the body moves unless the new pose would push further into a wall or another robot; then it
        stops there with its wheels stalled and the bumper facing the contact pressed. Returns the true travel
        (ds, dθ) of this step."""
        x, y, th = self.world.pose(self.name)
        ds, dth = self.v * dt, self.w * dt
        mid = th + dth / 2.0
        nx, ny = x + ds * math.cos(mid), y + ds * math.sin(mid)
        footprint = self.firmware.robot_contact == "footprint"
        blocked = False
        radius = self.firmware.collision_radius_m
        clearance_new = math.inf
        if ds != 0.0:
            clearance_new, bearing, obstacle = self._clearance(nx, ny, robots=not footprint)
            if clearance_new < radius:
                clearance_old, _, _ = self._clearance(x, y, robots=not footprint)
                blocked = clearance_new < clearance_old
        if blocked:
            nx, ny, ds = x, y, 0.0
        body_gap, contact = math.inf, None
        if footprint and (ds != 0.0 or dth != 0.0):  # turning on the spot swings the corners too
            body_gap, point, other = self._body_gap(nx, ny, th + dth)
            if body_gap < 0.0 and body_gap < self._body_gap(x, y, th)[0]:
                nx, ny, ds, dth, contact = x, y, 0.0, 0.0, point
        if contact is not None:  # another robot's body: stopped, the bumper on the side facing the contact
            bearing = _wrap(math.atan2(contact[1] - y, contact[0] - x) - th)
            self._contact(bearing, abs(bearing) < math.pi / 2)
            self.touching = other
            self.w = 0.0
        elif blocked:  # a wall (or, as discs, a robot): stopped, front or rear bumper by the direction of travel
            self._contact(_wrap(bearing - th), self.v > 0)
            self.touching = obstacle
        elif ds != 0.0 and clearance_new > radius + _CLEAR_M and body_gap > _CLEAR_M:  # clear of the obstacle again
            self._in_contact = False
            self.stall_bumpers = 0
            self.touching = None
        else:  # resting against or creeping along the obstacle: the bumper stays pressed, the wheels turn freely
            self.stall_bumpers &= ~0x0101
        self.world.set_pose(self.name, np.array([nx, ny, _wrap(th + dth)]))
        return ds, dth

    def _contact(self, bearing: float, front: bool) -> None:
        """The robot ran into something at ``bearing`` (robot frame): stall and bumper flags, the motors' bumpstall."""
        if not self._in_contact:
            self.stats.collisions += 1
        self._in_contact = True
        self.stall_bumpers = self._bumper_bits(bearing, front)
        if self.bumpstall & (1 if front else 2):
            self.motors_enabled = False
        self.v = 0.0

    def _clearance(self, x: float, y: float, robots: bool = True) -> tuple[float, float, str]:
        """Distance from (x, y) to the nearest wall or (``robots``: as discs) other robot (centre to surface), its
        bearing, and what it is ("wall" or the robot's name)."""
        dist, closest = self.world.nearest_wall_points(np.array([x, y]))
        best, target, what = float(dist[0]), closest[0], "wall"
        if robots:
            for other, pose in self.world.robot_poses().items():
                if other == self.name:
                    continue
                d = math.hypot(pose[0] - x, pose[1] - y) - self.firmware.collision_radius_m
                if d < best:
                    best, target, what = d, pose[:2], other
        return best, math.atan2(target[1] - y, target[0] - x), what

    def _body_gap(self, x: float, y: float, th: float) -> tuple[float, np.ndarray | None, str | None]:
        """The smallest signed gap between this robot's body at (x, y, θ) and another robot's (negative: they
        overlap; :func:`~mocks.world.footprint_gap`), where they overlap the middle of the overlap (world frame),
        and that robot's name. A robot registered without a footprint is taken to be the size of this one."""
        sizes = self.world.footprints()
        pose = np.array([x, y, th])
        reach = math.hypot(*self.footprint)  # both half-diagonals, for bodies of this size
        best, point, nearest = math.inf, None, None
        for other, other_pose in self.world.robot_poses().items():
            if other == self.name or not np.all(np.isfinite(other_pose)):
                continue
            size = sizes.get(other, self.footprint)
            centres = math.hypot(other_pose[0] - x, other_pose[1] - y)
            if centres > (reach + math.hypot(*size)) / 2.0 + 0.1:
                best = min(best, centres - (reach + math.hypot(*size)) / 2.0)  # a lower bound is enough when far
                continue
            gap = footprint_gap(pose, self.footprint, other_pose, size)
            if gap < best:
                best, nearest = gap, other
                if gap < 0.0:
                    point = footprint_overlap(pose, self.footprint, other_pose, size).mean(axis=0)
        return best, point, nearest

    def _bumper_bits(self, bearing: float, forward: bool) -> int:
        """STALL_BUMPERS: both wheels stalled, plus the bumper segment facing the contact (segment 0 leftmost)."""
        bits = 0x0001 | 0x0100
        if forward:
            count = self.firmware.front_bumps
            k = int(np.clip((math.pi / 2 - bearing) / math.pi * count, 0, count - 1))
            bits |= 1 << (9 + k)
        else:
            count = self.firmware.rear_bumps
            rear = _wrap(bearing - math.pi)  # 0 straight behind, positive to the robot's right when reversing
            k = int(np.clip((math.pi / 2 + rear) / math.pi * count, 0, count - 1))
            bits |= 1 << (1 + k)
        return bits

    def _fire_sonars(self) -> None:
        """Fire the sonars whose turn has come (one every SonarCycle, in POLLING order)."""
        if not (self.is_open and self.sonar_enabled and self.polling):
            self._next_sonar = max(self._next_sonar, self._time)
            return
        cycle = self.firmware.sonar_cycle_ms / 1000.0
        fired = []
        while self._next_sonar <= self._time + 1e-9:
            fired.append(self.polling[self._poll_index % len(self.polling)])
            self._poll_index = (self._poll_index + 1) % len(self.polling)
            self._next_sonar += cycle
        if not fired:
            return
        ranges = self.sonar_ranges(np.array(fired))
        for number, r in zip(fired, ranges, strict=True):
            raw = round(r * 1000.0 / self.params.range_conv_factor)
            self._pending_sonar[number] = min(raw, 0xFFFF)
            self._sonar_latest[number] = r

    def sonar_ranges(self, numbers: np.ndarray) -> np.ndarray:
        """Ranges (n,) metres that sonars ``numbers`` (n,) would read now: nearest echo in the cone, noisy."""
        x, y, th = self.world.pose(self.name)
        sp = self._sonar_poses[numbers]
        c, s = math.cos(th), math.sin(th)
        ox = x + c * sp[:, 0] - s * sp[:, 1]
        oy = y + s * sp[:, 0] + c * sp[:, 1]
        beam = self.sensors.sonar_beam_rad
        offsets = np.array([-beam, 0.0, beam])
        angles = (th + sp[:, 2])[:, None] + offsets[None, :]  # (n, 3)
        origins = np.repeat(np.stack([ox, oy], axis=1), 3, axis=0)
        max_range = self.params.sonar_max_range_m
        flat_angles = angles.reshape(-1)
        ranges, _ = self.world.raycast(origins, flat_angles, max_range)
        others = [p[:2] for n, p in self.world.robot_poses().items() if n != self.name]
        if others:  # the other robots echo too: discs of the collision radius
            ranges = np.minimum(ranges, _ray_disc(origins, flat_angles, np.array(others),
                                                  self.firmware.collision_radius_m, max_range))
        true = ranges.reshape(-1, 3).min(axis=1)
        sigma = self.sensors.sonar_noise_m + self.sensors.sonar_noise_fraction * true
        noisy = true + self.rng.normal(0.0, 1.0, size=true.shape) * sigma
        return np.where(true >= max_range, max_range, np.clip(noisy, 0.0, max_range))

    # ------------------------------------------------------------------ packets the robot sends
    def _cycle_packets(self) -> bytes:
        out = bytearray(encode_packet(encode_sip(self.sip())))
        self.stats.sips += 1
        if self.encoder_stream:
            out += encode_packet(encode_encoder(EncoderCounts(*self._encoder_s32())))
        if self.io_stream:
            out += encode_packet(encode_io(self.io()))
            if self.io_stream == 1:
                self.io_stream = 0
        return bytes(out)

    def _encoder_s32(self) -> tuple[int, int]:
        return tuple(((c + 2**31) % 2**32) - 2**31 for c in self.encoders)

    def sip(self) -> Sip:
        """The SIP the robot would send now; takes (and clears) the sonar readings new since the last one."""
        p = self.params
        x_mm, y_mm = self.odometry[0] * 1000.0, self.odometry[1] * 1000.0
        control = self._rot_target if self._rot_mode == "head" else self.odometry[2]
        flags = (1 if self.motors_enabled else 0) | (0b0110 if self.sonar_enabled else 0)
        sonars = tuple(sorted(self._pending_sonar.items()))
        self._pending_sonar = {}
        lv, rv = self._wheel_speeds
        battery_dv = round(self._battery * 10.0)
        moving = self.v != 0.0 or self.w != 0.0
        return Sip(
            moving=moving,
            xpos=round(x_mm / p.dist_conv_factor) & 0x7FFF,
            ypos=round(y_mm / p.dist_conv_factor) & 0x7FFF,
            thpos=self._angle_units(self.odometry[2]),
            lvel=_s16(round(lv * 1000.0 / p.vel_conv_factor)),
            rvel=_s16(round(rv * 1000.0 / p.vel_conv_factor)),
            battery=min(255, battery_dv),
            stall_bumpers=self.stall_bumpers,
            control=self._angle_units(control),
            flags=flags,
            compass=0,
            sonars=sonars,
            grip_state=0,
            anport=self.anport,
            analog=0,
            digin=0xFF,
            digout=self.digout,
            battery_x10=battery_dv,
            charge_state=0,
            rotvel=_s16(round(math.degrees((rv - lv) / self.track_m) * 10.0)),
            fault_flags=0,
            latvel=0,
            temperature=-127,
            soc=0,
            uc_time=round(self._time * 1e6) & 0xFFFFFFFF,
            flags3=0,
        )

    def _angle_units(self, angle: float) -> int:
        units = round(_wrap(angle) / self.params.angle_conv_factor)
        return max(-32768, min(32767, units))

    def io(self) -> IoPacket:
        """The IO packet: 4 digital inputs (pulled high), the digital outputs, 8 analog inputs (10-bit)."""
        battery_counts = min(1023, round(self._battery / 15.0 * 1023))
        return IoPacket(digital_in=(0xFF,) * 4, digital_out=(self.digout, 0, 0, 0),
                        analog=(battery_counts, 0, 0, 0, 0, 0, 0, 0))

    def config(self) -> RobotConfig:
        """The CONFIG packet with every field; the current limits reflect SETV/SETRV/SETA/SETRA."""
        fw = self.firmware
        return RobotConfig(
            type=self.identity.type, subtype=self.identity.subtype, serial_num=fw.serial_num, unused=0,
            rot_vel_top=fw.rot_vel_top, trans_vel_top=fw.trans_vel_top, rot_accel_top=fw.rot_accel_top,
            trans_accel_top=fw.trans_accel_top, pwm_max=1000, name=self.identity.name[:20],
            sip_cycle=fw.sip_cycle_ms, host_baud=self.host_baud, aux1_baud=0, has_gripper=0,
            front_sonar=1, rear_sonar=1, low_battery=fw.low_battery_dv, rev_count=16570, watchdog=fw.watchdog_ms,
            normal_mpacs=0, stall_val=255, stall_count=100, joy_vel=600, joy_rot_vel=100,
            rot_vel_max=round(math.degrees(self.rot_vel_max)), trans_vel_max=round(self.trans_vel_max * 1000),
            rot_accel=round(math.degrees(self.rot_accel)), rot_decel=round(math.degrees(self.rot_decel)),
            rot_kp=40, rot_kv=20, rot_ki=0,
            trans_accel=round(self.trans_accel * 1000), trans_decel=round(self.trans_decel * 1000),
            trans_kp=40, trans_kv=20, trans_ki=0,
            front_bumps=fw.front_bumps, rear_bumps=fw.rear_bumps, has_charger=0, sonar_cycle=fw.sonar_cycle_ms,
            auto_baud=fw.auto_baud, gyro_type=0, drift_factor=0, aux2_baud=0, aux3_baud=0,
            ticks_mm=fw.ticks_mm, shutdown_volts=fw.shutdown_volts_dv, firmware_version=fw.firmware_version,
            gyro_cw=0, gyro_ccw=0, kinematics_delay=0,
            lat_vel_top=0, lat_accel_top=0, lat_vel_max=0, lat_accel=0, lat_decel=0, powerbot_charge_threshold=0,
            pdb_port=0, gyro_rate_limit=0, high_temp_shutdown=0, power_bits=0, battery_type=0,
            soc_low=0, soc_shutdown=0, bootloader_version="sim", config_flags=0, gyro_fw_version=0,
        )


def _s16(value: int) -> int:
    return max(-32768, min(32767, value))


def _ray_disc(origins: np.ndarray, angles: np.ndarray, centres: np.ndarray, radius: float, max_range: float):
    """Distance (N,) along each ray (origins (N, 2), angles (N,)) to the nearest of the discs (M, 2), else max_range.

    Rays starting inside a disc ignore that disc (a sonar cannot see the robot it is mounted on, nor through one).
    """
    d = np.stack([np.cos(angles), np.sin(angles)], axis=1)  # (N, 2)
    oc = centres[None, :, :] - origins[:, None, :]  # (N, M, 2)
    along = np.einsum("nmi,ni->nm", oc, d)
    perp2 = np.einsum("nmi,nmi->nm", oc, oc) - along**2
    half = np.sqrt(np.maximum(radius**2 - perp2, 0.0))
    t = along - half
    hit = (perp2 <= radius**2) & (t >= 0.0)
    return np.minimum(np.where(hit, t, np.inf).min(axis=1), max_range)
