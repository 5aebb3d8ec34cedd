"""Parameter files, SIP -> state tracking (wrap-around) and SI -> command clamping: the driver's pure parts."""
from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.arcos import motion
from drivers.arcos.codec import Sip, decode_command, pack_vel2, unpack_vel2
from drivers.arcos.commands import Command
from drivers.arcos.params import BUILTIN_DIR, builtin_params, load_params, parse_params
from drivers.arcos.state import StateTracker, unwrap_step, wrap_angle
from drivers.errors import BadFileError, DeviceNotFoundError

SH = builtin_params("p3at-sh")
OLD = builtin_params("p3at")


def commands(packets: list[bytes]) -> list[tuple[int, object]]:
    return [tuple(decode_command(p[3:-2])) for p in packets]


# --------------------------------------------------------------------------- parameter files
def test_builtin_sets_hold_the_reference_values() -> None:
    assert SH.dist_conv_factor == 1.0 and OLD.dist_conv_factor == 0.465
    assert builtin_params("P3AT-SH") == SH and builtin_params("p3atsh") == SH
    assert SH.sonar_count == 16 and SH.max_velocity_m_s == 1.2
    assert SH.sonar_poses[3] == pytest.approx((0.245, 0.027, math.radians(10)), abs=1e-6)
    assert SH.sonar_poses[12] == pytest.approx((-0.241, 0.027, math.radians(170)), abs=1e-6)
    assert math.degrees(SH.max_rot_velocity_rad_s) == pytest.approx(300)


def test_unknown_subtype_names_the_known_ones() -> None:
    with pytest.raises(DeviceNotFoundError, match="p3at-sh"):
        builtin_params("p3dx")


def test_user_file_loads(tmp_path: Path) -> None:
    data = json.loads((BUILTIN_DIR / "p3at-sh.json").read_text())
    data["max_velocity_m_s"] = 0.5
    data["sonar_poses"] = data["sonar_poses"][:8]
    path = tmp_path / "mine.json"
    path.write_text(json.dumps(data, indent=2))
    params = load_params(path)
    assert params.max_velocity_m_s == 0.5 and params.sonar_count == 8 and params.source == str(path)


@pytest.mark.parametrize(("edit", "message"), [
    (lambda d: d.pop("DistConvFactor"), r"line \d+: field 'DistConvFactor'|field 'DistConvFactor': missing"),
    (lambda d: d.update(radius_m=-1), "'radius_m': must be > 0"),
    (lambda d: d.update(VelConvFactor="fast"), "'VelConvFactor': must be a finite number"),
    (lambda d: d.update(maxvel=3), "'maxvel': unknown field"),
    (lambda d: d["sonar_poses"].append([1, 2]), "'sonar_poses': entry 16"),
    (lambda d: d.update(version=7), "unsupported version"),
])
def test_bad_files_name_file_line_and_field(tmp_path: Path, edit, message: str) -> None:
    data = json.loads((BUILTIN_DIR / "p3at-sh.json").read_text())
    edit(data)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data, indent=2))
    with pytest.raises(BadFileError, match=message) as info:
        load_params(path)
    assert str(path) in str(info.value)


def test_syntax_error_names_the_line(tmp_path: Path) -> None:
    path = tmp_path / "broken.json"
    path.write_text('{\n  "subtype": "x",\n  oops\n}')
    with pytest.raises(BadFileError, match=r"broken.json:3: not valid JSON"):
        load_params(path)
    with pytest.raises(BadFileError, match="cannot read"):
        load_params(tmp_path / "missing.json")
    with pytest.raises(BadFileError, match="JSON object"):
        parse_params("[1, 2]", "list.json")


# --------------------------------------------------------------------------- state tracking
def test_unwrap_step_follows_the_reference_rule() -> None:
    assert unwrap_step(0x7FF0, 0x0010) == 0x20  # forward across the wrap
    assert unwrap_step(0x0010, 0x7FF0) == -0x20  # backward across it
    assert unwrap_step(100, 300) == 200
    assert unwrap_step(0, 0x1000) == 0x1000  # exactly the threshold is still motion


@settings(max_examples=50)
@given(st.lists(st.integers(-0x0FFF, 0x0FFF), min_size=1, max_size=80), st.integers(-0x3FFF, 0x3FFF))
def test_tracker_accumulates_any_path_across_wraps(steps: list[int], start: int) -> None:
    tracker = StateTracker(SH)
    true_x = start
    state = tracker.update(Sip(xpos=start & 0x7FFF, ypos=(-start) & 0x7FFF), 0.0)
    for i, step in enumerate(steps):
        true_x += step
        state = tracker.update(Sip(xpos=true_x & 0x7FFF, ypos=(-true_x) & 0x7FFF), float(i))
    assert state.x == pytest.approx(true_x / 1000.0)
    assert state.y == pytest.approx(-true_x / 1000.0)


def test_long_drive_past_the_15_bit_wrap_at_both_conversion_factors() -> None:
    for params in (SH, OLD):
        tracker = StateTracker(params)
        units = 0
        for i in range(400):  # 400 SIPs at 0.1 m per SIP (1 m/s): 40 m, beyond the 32.767 m wrap of p3at-sh
            units = round(i * 100 / params.dist_conv_factor)
            state = tracker.update(Sip(xpos=units & 0x7FFF), i * 0.1)
        assert state.x == pytest.approx(units * params.dist_conv_factor / 1000.0)
        assert state.x > 32.767 * params.dist_conv_factor


def test_state_fields_in_si() -> None:
    sip = Sip(moving=True, xpos=1000, ypos=0x7FFF, thpos=1024, lvel=300, rvel=500, battery=125,
              stall_bumpers=0b0000_0110_0000_0001, control=-1024, flags=0b0110_0011, sonars=((3, 2500), (40, 1)))
    state = StateTracker(SH).update(sip, 12.5)
    assert (state.x, state.y) == (pytest.approx(1.0), pytest.approx(-0.001))
    assert state.theta == pytest.approx(1024 * 0.001534)
    assert state.v == pytest.approx(0.4) and state.w == pytest.approx(200 / 2 * 0.0034)
    assert state.battery_volts == pytest.approx(12.5)
    assert state.left_stall and not state.right_stall and state.stalled
    assert state.front_bumpers == 0b11 and state.rear_bumpers == 0 and state.bumped
    assert state.motors_enabled and state.stop_pressed and state.estall and state.moving
    assert state.sonar_arrays == 1
    assert state.sonars[3].range_m == pytest.approx(2.5) and state.sonars[3].stamp == 12.5
    assert state.sonars[3].pose == SH.sonar_poses[3]
    assert state.sonars[0].range_m is None
    assert state.heading_setpoint == pytest.approx(-1024 * 0.001534)


def test_optional_fields_take_precedence() -> None:
    state = StateTracker(SH).update(Sip(lvel=0, rvel=100, battery=120, battery_x10=265, rotvel=-450), 0.0)
    assert state.w == pytest.approx(math.radians(-45.0))
    assert state.battery_volts == pytest.approx(26.5)


def test_sonar_keeps_last_range_of_each_sonar() -> None:
    tracker = StateTracker(SH)
    tracker.update(Sip(sonars=((0, 1000), (1, 2000))), 1.0)
    state = tracker.update(Sip(sonars=((1, 3000),)), 2.0)
    assert (state.sonars[0].range_m, state.sonars[0].stamp) == (1.0, 1.0)
    assert (state.sonars[1].range_m, state.sonars[1].stamp) == (3.0, 2.0)


def test_odometry_reset_waits_for_the_robot_to_have_done_it() -> None:
    tracker = StateTracker(SH)
    for raw in (0, 3000, 6000, 9000):
        tracker.update(Sip(xpos=raw), 0.0)
    tracker.expect_reset()
    assert tracker.update(Sip(xpos=9100), 0.0).x == pytest.approx(9.1)  # SIP in flight before SETO
    assert tracker.update(Sip(xpos=20), 0.0).x == pytest.approx(0.02)  # the robot has reset
    assert tracker.update(Sip(xpos=120), 0.0).x == pytest.approx(0.12)


@given(st.floats(-100, 100))
def test_wrap_angle_range(a: float) -> None:
    w = wrap_angle(a)
    assert -math.pi < w <= math.pi and math.isclose(math.cos(w), math.cos(a), abs_tol=1e-9)


# --------------------------------------------------------------------------- SI -> commands
def test_velocity_commands_in_robot_units() -> None:
    packets, notes = motion.velocity(SH, 0.25, math.radians(-30))
    assert commands(packets) == [(Command.VEL, 250), (Command.RVEL, -30)] and notes == []


def test_out_of_range_values_are_clamped_with_a_note() -> None:
    packets, notes = motion.velocity(SH, 5.0, -10.0)
    assert commands(packets) == [(Command.VEL, 1200), (Command.RVEL, -300)]
    assert len(notes) == 2 and "clamped to 1.2" in notes[0]
    with pytest.raises(ValueError, match="NaN"):
        motion.velocity(SH, math.nan, 0.0)


def test_wheel_velocities_use_vel2_divisor() -> None:
    packets, notes = motion.wheel_velocities(SH, 0.2, -0.4)
    ((cmd, arg),) = commands(packets)
    assert cmd == Command.VEL2 and unpack_vel2(arg) == (10, -20) and notes == []
    packets, notes = motion.wheel_velocities(SH, 3.0, 0.0)
    assert unpack_vel2(commands(packets)[0][1]) == (60, 0) and notes
    assert arg == pack_vel2(10, -20)


def test_move_heading_and_limits() -> None:
    assert commands(motion.move(OLD, 0.465)[0]) == [(Command.MOVE, 1000)]  # old units: 0.465 mm each
    assert commands(motion.move(SH, -1.5)[0]) == [(Command.MOVE, -1500)]
    assert motion.move(SH, 100.0)[1]  # beyond the 16-bit MOVE range
    assert commands(motion.heading(SH, -math.pi / 2)[0]) == [(Command.HEAD, 270)]
    assert commands(motion.delta_heading(SH, math.radians(45))[0]) == [(Command.DHEAD, 45)]
    assert commands(motion.velocity_limits(SH, 0.5, math.radians(90))[0]) == [(Command.SETV, 500),
                                                                                (Command.SETRV, 90)]
    packets, notes = motion.acceleration_limits(SH, accel=0.3, decel=0.5, rot_accel=math.radians(100))
    assert commands(packets) == [(Command.SETA, 300), (Command.SETA, -500), (Command.SETRA, 100)]
    assert motion.acceleration_limits(SH, accel=50.0)[1]


def test_hostbaud_only_on_real_serial_ports_when_config_allows(tmp_path: Path) -> None:
    from drivers.arcos.codec import RobotConfig
    from drivers.arcos.robot import hostbaud_code

    allows, refuses = RobotConfig(auto_baud=2), RobotConfig(auto_baud=0)
    assert hostbaud_code("/dev/ttyUSB0", allows, 9600, 38400) == 2
    assert hostbaud_code("/dev/ttyUSB0", allows, 9600, 115200) == 4
    assert hostbaud_code("/dev/ttyUSB0", refuses, 9600, 38400) is None
    assert hostbaud_code("/dev/ttyUSB0", None, 9600, 38400) is None  # no CONFIG reply: stay
    assert hostbaud_code("/dev/ttyUSB0", allows, 9600, None) is None
    assert hostbaud_code("/dev/ttyUSB0", allows, 9600, 12345) is None  # no code for that rate
    assert hostbaud_code("socket://127.0.0.1:8101", allows, 9600, 38400) is None
    assert hostbaud_code("/dev/pts/3", allows, 9600, 38400) is None
    link = tmp_path / "ttyRobot"
    link.symlink_to("/dev/pts/7")
    assert hostbaud_code(str(link), allows, 9600, 38400) is None  # a link to a pty is still a pty
