"""The robot's state in SI units from successive SIPs (pure: no I/O, no threads, no clock of its own).

Position: XPOS/YPOS carry only 15 bits, so the tracker accumulates differences with the wrap-around rule of the
reference (difference > 0x1000 -> subtract 0x8000, < -0x1000 -> add 0x8000). Axes are ARIA's, which are
REP-103's (x forward, y left, heading counter-clockwise); the odometry frame is the robot's own.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from drivers.arcos.codec import Sip
from drivers.arcos.params import RobotParams

WRAP = 0x8000  # the 15-bit position field wraps here
WRAP_THRESHOLD = 0x1000
RESET_WINDOW_UNITS = 0x400  # after SETO, the first SIP this close to the origin is taken as the new origin

FLAG_MOTORS_ENABLED = 1 << 0
FLAG_SONAR_ARRAYS = 0x1E  # bits 1-4
FLAG_STOP_PRESSED = 1 << 5
FLAG_ESTALL = 1 << 6


@dataclass(frozen=True)
class SonarReading:
    """Last range of one sonar. ``range_m``/``stamp`` are ``None`` until the sonar has reported once."""

    index: int  # 0-based sonar number
    pose: tuple[float, float, float]  # (x m, y m, heading rad) in the robot frame
    range_m: float | None
    stamp: float | None  # clock time of the SIP that carried it


@dataclass(frozen=True)
class RobotState:
    """Latest robot state in SI units. Poses are in the odometry frame (x, y m; theta rad in (-pi, pi])."""

    stamp: float  # clock time the SIP was received
    session: int  # connection number; odometry is continuous only within one session
    sequence: int  # SIP count within the session
    x: float
    y: float
    theta: float
    v: float  # m/s, forward
    w: float  # rad/s, counter-clockwise
    left_velocity: float  # m/s
    right_velocity: float  # m/s
    battery_volts: float
    sonars: tuple[SonarReading, ...]  # one per sonar of the parameter set
    front_bumpers: int  # bit mask, bit 0 = first front bumper
    rear_bumpers: int
    left_stall: bool
    right_stall: bool
    motors_enabled: bool
    stop_pressed: bool  # the robot's STOP / E-stop button (FLAGS bit 5)
    estall: bool  # E_STALL (FLAGS bit 6)
    moving: bool  # SIP ID 0x33
    heading_setpoint: float  # rad, the CONTROL field
    sonar_arrays: int  # FLAGS bits 1-4 as a 4-bit mask
    sip: Sip  # the raw packet

    @property
    def stalled(self) -> bool:
        return self.left_stall or self.right_stall

    @property
    def bumped(self) -> bool:
        return bool(self.front_bumpers or self.rear_bumpers)

    @property
    def pose(self) -> tuple[float, float, float]:
        return (self.x, self.y, self.theta)

    def sonar_ranges(self) -> list[float | None]:
        """Last range of each sonar in metres (``None`` if not yet reported); length ``params.sonar_count``."""
        return [s.range_m for s in self.sonars]


def wrap_angle(a: float) -> float:
    """Angle in (-pi, pi]."""
    a = math.fmod(a + math.pi, 2.0 * math.pi)
    if a <= 0.0:
        a += 2.0 * math.pi
    return a - math.pi


def signed15(raw: int) -> int:
    """A 15-bit position taken as two's complement (used only for the first SIP of a session)."""
    raw &= WRAP - 1
    return raw - WRAP if raw >= WRAP // 2 else raw


def unwrap_step(previous_raw: int, raw: int) -> int:
    """Position units moved between two 15-bit readings, with the reference's wrap-around rule."""
    diff = (raw & (WRAP - 1)) - (previous_raw & (WRAP - 1))
    if diff > WRAP_THRESHOLD:
        diff -= WRAP
    elif diff < -WRAP_THRESHOLD:
        diff += WRAP
    return diff


class StateTracker:
    """Folds SIPs into :class:`RobotState`. Keep one per session; call :meth:`expect_reset` after sending SETO."""

    def __init__(self, params: RobotParams, session: int = 0) -> None:
        self.params = params
        self.session = session
        self._sequence = 0
        self._raw_x: int | None = None
        self._raw_y = 0
        self._acc_x = 0  # accumulated position units
        self._acc_y = 0
        self._expect_reset = False
        n = params.sonar_count
        self._sonar_range: list[float | None] = [None] * n
        self._sonar_stamp: list[float | None] = [None] * n
        self.ignored_sonar_readings = 0  # readings for sonar numbers the parameter set does not have

    def expect_reset(self) -> None:
        """SETO was sent: take the next SIP near the origin as the new origin (SIPs in flight still show the old)."""
        self._expect_reset = True

    def update(self, sip: Sip, stamp: float) -> RobotState:
        p = self.params
        if self._expect_reset and abs(signed15(sip.xpos)) < RESET_WINDOW_UNITS \
                and abs(signed15(sip.ypos)) < RESET_WINDOW_UNITS:
            self._raw_x = None
            self._expect_reset = False
        if self._raw_x is None:
            self._acc_x, self._acc_y = signed15(sip.xpos), signed15(sip.ypos)
        else:
            self._acc_x += unwrap_step(self._raw_x, sip.xpos)
            self._acc_y += unwrap_step(self._raw_y, sip.ypos)
        self._raw_x, self._raw_y = sip.xpos, sip.ypos
        self._sequence += 1

        for number, raw_range in sip.sonars:
            if 0 <= number < len(self._sonar_range):
                self._sonar_range[number] = raw_range * p.range_conv_factor / 1000.0
                self._sonar_stamp[number] = stamp
            else:
                self.ignored_sonar_readings += 1

        mm = p.dist_conv_factor / 1000.0
        left = sip.lvel * p.vel_conv_factor / 1000.0
        right = sip.rvel * p.vel_conv_factor / 1000.0
        if sip.rotvel is not None:  # the firmware's own rotational velocity, deg/s x 10
            w = math.radians(sip.rotvel / 10.0)
        else:
            w = (sip.rvel - sip.lvel) * p.vel_conv_factor / 2.0 * p.diff_conv_factor
        volts = (sip.battery_x10 if sip.battery_x10 is not None else sip.battery) / 10.0
        sb = sip.stall_bumpers
        return RobotState(
            stamp=stamp, session=self.session, sequence=self._sequence,
            x=self._acc_x * mm, y=self._acc_y * mm, theta=wrap_angle(sip.thpos * p.angle_conv_factor),
            v=(left + right) / 2.0, w=w, left_velocity=left, right_velocity=right, battery_volts=volts,
            sonars=tuple(SonarReading(i, pose, self._sonar_range[i], self._sonar_stamp[i])
                         for i, pose in enumerate(p.sonar_poses)),
            front_bumpers=(sb >> 9) & 0x7F, rear_bumpers=(sb >> 1) & 0x7F,
            left_stall=bool(sb & 1), right_stall=bool(sb & 0x100),
            motors_enabled=bool(sip.flags & FLAG_MOTORS_ENABLED), stop_pressed=bool(sip.flags & FLAG_STOP_PRESSED),
            estall=bool(sip.flags & FLAG_ESTALL), moving=sip.moving,
            heading_setpoint=wrap_angle(sip.control * p.angle_conv_factor),
            sonar_arrays=(sip.flags & FLAG_SONAR_ARRAYS) >> 1, sip=sip,
        )
