"""Robot health statuses (runtime/fleet/status.py) without a network: the printer's rate limit, a status line from
whatever arrived, and a failing exchange never stopping the robot. The real path over Zenoh, from a running
``p3at run``, is tests/fleet/test_fleet_cli.py::test_p3at_run_publishes_its_health_once_a_second_under_its_name."""
from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from runtime.fleet.status import StatusPrinter, health_figure, publish_robot_status, status_line


class ManualClock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def _status(t: float, frames: int) -> dict:
    return {"stamp": t, "session": "a" * 16, "pose": [1.0, 2.0, 0.5], "landmarks": 40,
            "health": {"clock": "simulated", "mission_time": t, "frames_processed": frames, "frames_dropped": 0,
                       "ms_update": 6.31, "battery_volts": 12.9, "link": "up", "last_error": None}}


def test_the_printer_prints_each_robots_new_status_at_most_once_a_period():
    clock, statuses, lines = ManualClock(), {}, []
    printer = StatusPrinter(lambda: dict(statuses), lines.append, period=10.0, clock=clock)
    printer.poll()
    assert lines == []                                   # nothing heard yet
    statuses["robot1"] = {"stamp": 0.5, "session": "a" * 16, "pose": None, "landmarks": 0, "health": {}}
    printer.poll()
    assert lines == []                                   # a map update's status before any health figures
    statuses["robot1"] = _status(1.0, 15)
    printer.poll()
    assert len(lines) == 1 and lines[0].startswith("status robot1: t=1.0 s simulated, 15 frames (0 dropped)")
    statuses["robot1"] = _status(2.0, 30)
    clock.now = 9.9
    printer.poll()
    assert len(lines) == 1                               # new, but within the period
    clock.now = 10.0
    printer.poll()
    assert len(lines) == 2 and "30 frames" in lines[1]
    clock.now = 30.0
    printer.poll()
    assert len(lines) == 2                               # the period is over, but nothing new came


def test_a_status_line_shows_what_arrived_and_dashes_for_what_did_not():
    line = status_line("robot2", _status(3.0, 45))
    assert line == ("status robot2: t=3.0 s simulated, 45 frames (0 dropped), 40 landmarks, pose (1.00, 2.00, 0.50), "
                    "update 6.3 ms, battery 12.9 V, link up")
    bare = status_line("robot3", {"stamp": 0.0, "pose": None, "landmarks": 0, "health": {"last_error": "boom"}})
    assert bare == ("status robot3: t=-, - frames (- dropped), 0 landmarks, update -, battery -, link -, "
                    "last error: boom")


# what mapwire lets through in a health object: a flat object of finite numbers, strings, booleans (and null)
WIRE_VALUES = st.none() | st.booleans() | st.integers(-10**6, 10**6) | st.floats(-1e6, 1e6) | st.text(max_size=6)
FIGURES = ("mission_time", "frames_processed", "frames_dropped", "ms_update", "battery_volts")


@given(health=st.dictionaries(st.sampled_from(FIGURES), WIRE_VALUES))
def test_a_status_line_prints_numbers_as_figures_and_anything_else_as_a_dash(health):
    line = status_line("robot1", {"landmarks": 3, "pose": None, "health": health})
    assert line.startswith("status robot1: ") and "\n" not in line
    for key in FIGURES:
        value = health.get(key)
        is_number = isinstance(value, int | float) and not isinstance(value, bool)
        assert health_figure({"health": health}, key) == (value if is_number else None)
    if not isinstance(health.get("frames_processed"), int | float) or isinstance(health.get("frames_processed"), bool):
        assert ", - frames (" in line


def test_a_count_sent_as_a_float_prints_as_a_count():
    line = status_line("robot1", {"landmarks": 3, "health": {"frames_processed": 45.0, "frames_dropped": True}})
    assert "45 frames (- dropped)" in line


class _Stats:
    frames_received = frames_processed = dropped_frames = frames_without_odometry = camera_errors = 0
    map_landmarks = 0
    stage_seconds: dict = {}


class _Onboard:
    """What publish_robot_status reads of runtime.onboard.Onboard."""

    robot, mission_time, stats, errors = "robot1", 1.0, _Stats(), []

    class link:
        reconnects = 0

    class route_done:
        @staticmethod
        def is_set() -> bool:
            return False

    def pose_estimate(self):
        return None


def test_a_failing_exchange_never_stops_the_robot(caplog):
    class Broken:
        def publish_status(self, *args, **kwargs):
            raise RuntimeError("the network is gone")

    publish_robot_status(Broken(), [(_Onboard(), None)], clock="wall", wall_time=1.0)
    assert "fleet status of robot1 not sent: RuntimeError: the network is gone" in caplog.text


def test_an_exchange_without_statuses_gets_none_and_the_health_is_flat():
    publish_robot_status(object(), [(_Onboard(), None)], clock="wall", wall_time=1.0)  # the in-process one
    sent = []

    class Recording:
        def publish_status(self, robot, **kwargs):
            sent.append((robot, kwargs))

    publish_robot_status(Recording(), [(_Onboard(), None)], clock="wall", wall_time=1.5)
    (robot, kwargs), = sent
    assert robot == "robot1" and kwargs["stamp"] == 1.0 and kwargs["pose"] is None
    health = kwargs["health"]
    assert health["clock"] == "wall" and health["wall_time"] == 1.5 and health["link"] is None
    assert all(v is None or isinstance(v, str | bool | int | float) for v in health.values())
