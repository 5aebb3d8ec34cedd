"""Settings of the virtual P3-AT that are not in the driver's parameter set: firmware defaults and sensor errors."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class OdometryErrors:
    """How the wheel odometry differs from the ground truth.

    distance_scale: measured wheel travel / true wheel travel (systematic, e.g. worn tyres: 0.99).
    wheelbase_scale: effective track the firmware assumes / true effective track (systematic heading error).
    noise: random wheel-travel error, standard deviation as a fraction per sqrt(metre) of wheel travel
      (σ = noise · sqrt(|d|) per step), independent for each wheel.
    """

    distance_scale: float = 1.0
    wheelbase_scale: float = 1.0
    noise: float = 0.0

    @classmethod
    def realistic(cls) -> OdometryErrors:
        """Typical of a skid-steer P3-AT on a hard floor: 1 % scale, 3 % track, a little noise."""
        return cls(distance_scale=0.99, wheelbase_scale=1.03, noise=0.01)


@dataclass(frozen=True)
class SensorOptions:
    """Sonar and battery behaviour.

    sonar_noise_m + sonar_noise_fraction × range: standard deviation of a sonar reading (metres).
    sonar_beam_rad: half-width of the sonar cone; three rays (−, 0, +) are cast and the nearest echo wins.
    battery_volts: initial voltage; drain_idle_v_per_s and drain_motion_v_per_m: the battery drains with
    time and with distance driven; it never drops below battery_floor_volts.
    """

    sonar_noise_m: float = 0.01
    sonar_noise_fraction: float = 0.01
    sonar_beam_rad: float = 0.13
    battery_volts: float = 13.0
    drain_idle_v_per_s: float = 2e-4
    drain_motion_v_per_m: float = 2e-3
    battery_floor_volts: float = 10.5


@dataclass(frozen=True)
class FirmwareDefaults:
    """What the robot's flash configuration holds (reported in CONFIG). Units as on the wire (mm, deg, ms)."""

    serial_num: str = "SIM-P3AT-0001"
    firmware_version: str = "ARCOS 2.8 sim"
    sip_cycle_ms: int = 100
    watchdog_ms: int = 2000
    sonar_cycle_ms: int = 40  # one sonar fires every sonar_cycle_ms
    trans_vel_top: int = 1200  # mm/s, hard limit
    rot_vel_top: int = 300  # deg/s
    trans_accel_top: int = 2000  # mm/s²
    rot_accel_top: int = 500  # deg/s²
    trans_vel_max: int = 750  # mm/s, the current limit (SETV)
    rot_vel_max: int = 100  # deg/s (SETRV)
    trans_accel: int = 300  # mm/s² (SETA +)
    trans_decel: int = 300  # mm/s² (SETA −)
    rot_accel: int = 100  # deg/s² (SETRA +)
    rot_decel: int = 100  # deg/s² (SETRA −)
    ticks_mm: int = 128  # encoder ticks per mm of wheel travel
    low_battery_dv: int = 110  # decivolts
    shutdown_volts_dv: int = 105
    auto_baud: int = 2  # lets a client switch to 38400 with HOSTBAUD
    front_bumps: int = 5
    rear_bumps: int = 5
    collision_radius_m: float = 0.33  # disc used for collisions: half the 626 mm length plus the bumpers
    # How robots meet each other (walls always meet the disc above): "disc", two collision_radius_m discs (contact
    # at 0.66 m between centres, whatever the headings); "footprint", the bodies as they are, oriented rectangles
    # of the parameter set's length_m x width_m (626 x 505 mm for a P3-AT), turning included. The default since
    # session 12: with discs, demo seed 7's bodies overlapped by 0.113 m (docs/virtual-robot.md, "Session 12: robots
    # block each other"); seeds 0-6, 8, 9 are the same to the digit either way.
    robot_contact: str = "footprint"
