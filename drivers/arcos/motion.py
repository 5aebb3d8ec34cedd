"""SI motion requests -> ARCOS commands, clamped to the parameter set's limits (pure: no I/O).

Each function returns ``(packets, notes)``: the encoded command packets to send, and one human-readable note
per value that had to be clamped (the driver turns notes into ``ClampWarning``s and log warnings).
"""
from __future__ import annotations

import math

from drivers.arcos.codec import encode_command, pack_vel2
from drivers.arcos.commands import Command
from drivers.arcos.params import RobotParams

INT16_MAX = 0x7FFF
UINT16_MAX = 0xFFFF

Result = tuple[list[bytes], list[str]]


def clamp(name: str, value: float, low: float, high: float, unit: str, notes: list[str]) -> float:
    """``value`` limited to [low, high]; appends a note when it had to change. NaN is refused."""
    if math.isnan(value):
        raise ValueError(f"{name} is NaN")
    if value < low or value > high:
        clamped = min(max(value, low), high)
        notes.append(f"{name} {value:g} {unit} is outside [{low:g}, {high:g}] {unit}; clamped to {clamped:g}")
        return clamped
    return value


def velocity(params: RobotParams, v: float, w: float) -> Result:
    """VEL (mm/s) and RVEL (deg/s) for forward speed ``v`` m/s and turn rate ``w`` rad/s."""
    notes: list[str] = []
    v = clamp("velocity", v, -params.max_velocity_m_s, params.max_velocity_m_s, "m/s", notes)
    w = clamp("rotational velocity", w, -params.max_rot_velocity_rad_s, params.max_rot_velocity_rad_s, "rad/s",
              notes)
    return [encode_command(Command.VEL, round(v * 1000.0)),
            encode_command(Command.RVEL, round(math.degrees(w)))], notes


def wheel_velocities(params: RobotParams, left: float, right: float) -> Result:
    """VEL2 for wheel speeds in m/s, in units of Vel2Divisor mm/s (each a signed byte)."""
    notes: list[str] = []
    limit = min(params.max_velocity_m_s, 127 * params.vel2_divisor / 1000.0)
    left = clamp("left wheel velocity", left, -limit, limit, "m/s", notes)
    right = clamp("right wheel velocity", right, -limit, limit, "m/s", notes)
    units = [max(-128, min(127, round(x * 1000.0 / params.vel2_divisor))) for x in (left, right)]
    return [encode_command(Command.VEL2, pack_vel2(units[0], units[1]))], notes


def move(params: RobotParams, distance: float) -> Result:
    """MOVE: drive ``distance`` metres (negative = backwards) under the robot's position control."""
    notes: list[str] = []
    limit = INT16_MAX * params.dist_conv_factor / 1000.0
    distance = clamp("move distance", distance, -limit, limit, "m", notes)
    units = max(-INT16_MAX, min(INT16_MAX, round(distance * 1000.0 / params.dist_conv_factor)))
    return [encode_command(Command.MOVE, units)], notes


def heading(params: RobotParams, theta: float) -> Result:
    """HEAD: turn to absolute heading ``theta`` rad in the odometry frame (sent as 0..359 degrees)."""
    if not math.isfinite(theta):
        raise ValueError(f"heading {theta} is not finite")
    return [encode_command(Command.HEAD, round(math.degrees(theta)) % 360)], []


def delta_heading(params: RobotParams, dtheta: float) -> Result:
    """DHEAD: turn by ``dtheta`` rad relative to the current heading, positive counter-clockwise."""
    notes: list[str] = []
    dtheta = clamp("heading change", dtheta, -math.pi, math.pi, "rad", notes)
    return [encode_command(Command.DHEAD, round(math.degrees(dtheta)))], notes


def velocity_limits(params: RobotParams, max_v: float | None, max_w: float | None) -> Result:
    """SETV (mm/s) and SETRV (deg/s): the robot's maximum speeds for position control and velocity commands."""
    notes: list[str] = []
    packets = []
    if max_v is not None:
        max_v = clamp("velocity limit", max_v, 0.0, params.max_velocity_m_s, "m/s", notes)
        packets.append(encode_command(Command.SETV, round(max_v * 1000.0)))
    if max_w is not None:
        max_w = clamp("rotational velocity limit", max_w, 0.0, params.max_rot_velocity_rad_s, "rad/s", notes)
        packets.append(encode_command(Command.SETRV, round(math.degrees(max_w))))
    return packets, notes


def acceleration_limits(params: RobotParams, accel: float | None = None, decel: float | None = None,
                        rot_accel: float | None = None, rot_decel: float | None = None) -> Result:
    """SETA / SETRA: positive argument sets acceleration, negative sets deceleration (mm/s², deg/s²)."""
    notes: list[str] = []
    packets = []
    for name, value, limit, scale, cmd, sign in (
        ("acceleration", accel, params.max_accel_m_s2, 1000.0, Command.SETA, 1),
        ("deceleration", decel, params.max_accel_m_s2, 1000.0, Command.SETA, -1),
        ("rotational acceleration", rot_accel, params.max_rot_accel_rad_s2, math.degrees(1.0), Command.SETRA, 1),
        ("rotational deceleration", rot_decel, params.max_rot_accel_rad_s2, math.degrees(1.0), Command.SETRA, -1),
    ):
        if value is None:
            continue
        unit = "m/s²" if cmd == Command.SETA else "rad/s²"
        # The sign of the argument selects accel/decel, so the magnitude must be positive.
        value = clamp(name, value, 1e-3, limit, unit, notes)
        packets.append(encode_command(cmd, sign * max(1, round(value * scale))))
    return packets, notes
