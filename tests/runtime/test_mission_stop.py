"""The stop of a lockstep mission runs in simulated time: what it writes does not depend on the machine's load, and
a stage that never ends cannot hang it.

The mission loop stays a participant of the clock while it stops the robots (runtime/mission.py): it waits for each
stage's participant to be discarded (mocks/simclock.py), for the robot to stand still and for the sensor log to
close, all in simulated time. Before, it joined the threads from outside the lockstep, and simulated time ran on with
the virtual robots while a thread took wall time to end: the sensor logs' last odometry records varied with the load
(one more or fewer SIP idle and beside two busy loops; 117 more per robot when each stage thread took 0.5 s of wall
time to end). The tests make a thread slow to end by delaying it right after it has left the lockstep, which is what
a loaded machine does at random.
"""
from __future__ import annotations

import dataclasses
import threading
import time

import numpy as np
import pytest

import runtime.onboard as onboard_module
from mocks.simclock import SimClock
from runtime.mission import Mission, MissionConfig
from runtime.onboard import Onboard
from runtime.sensorlog import SensorLog

ROBOTS = ("robot1", "robot2")


def _config(out, **changes) -> MissionConfig:
    config = MissionConfig(robots=2, seconds=3.0, seed=2, camera="synthetic", camera_rate=10.0, particles=10,
                           fusion_interval=0.0, out=out, rerun="none", log_sensors=True)
    return dataclasses.replace(config, **changes)


def _messages(folder) -> list[tuple[str, int, bytes]]:
    return [(m.topic, m.log_time, m.data) for m in SensorLog(folder).messages()]


def _odometry_times(folder) -> list[float]:
    return [round(float(r["t"]), 3) for r in SensorLog(folder).records("odometry")]


def test_a_stage_thread_slow_to_end_changes_nothing_the_mission_writes(tmp_path, monkeypatch):
    """Two runs of one seed, the second with every stage thread taking 0.3 s of wall time to end after it has left
    the lockstep: the same sensor logs, message for message (the last odometry records too), and the same maps."""
    first = Mission(_config(tmp_path / "prompt")).run()
    discard = SimClock.discard

    def slow_to_end(self, participant):
        discard(self, participant)
        if participant.name.split(":")[0] in ("camera", "slam", "control"):
            time.sleep(0.3)  # the thread's last steps, after its participant is gone: a loaded machine's delay

    monkeypatch.setattr(SimClock, "discard", slow_to_end)
    second = Mission(_config(tmp_path / "slow")).run()
    assert not first.failures and not second.failures
    for robot in ROBOTS:
        a, b = tmp_path / "prompt" / f"{robot}-log", tmp_path / "slow" / f"{robot}-log"
        ta, tb = _odometry_times(a), _odometry_times(b)
        assert ta == tb, f"{robot}: {len(ta)} odometry records ending {ta[-3:]}, then {len(tb)} ending {tb[-3:]}"
        assert _messages(a) == _messages(b), robot
        # and the log ends with the robot standing still, shortly after the stop
        last = list(SensorLog(a).records("odometry"))[-1]
        assert abs(float(last["v"])) < 0.01 and ta[-1] - first.summary["sim_seconds"] < 3.0
    for name in (*ROBOTS, "fused"):
        with np.load(tmp_path / "prompt" / f"{name}.npz") as a, np.load(tmp_path / "slow" / f"{name}.npz") as b:
            assert a.files == b.files
            for key in a.files:
                assert np.array_equal(a[key], b[key]), f"{name}: {key} differs"


def _control_that_never_ends(monkeypatch, robot: str, after_stop) -> threading.Event:
    """``robot``'s control stage runs as usual until the stop, then ``after_stop(onboard, done)`` until the returned
    event is set (the test sets it as it ends, so that no thread outlives it)."""
    done = threading.Event()
    control = Onboard._control_loop

    def never_ends(self):
        control(self)
        if self.robot == robot:
            after_stop(self, done)

    monkeypatch.setattr(Onboard, "_control_loop", never_ends)
    return done


def test_a_stage_that_ignores_the_stop_ends_the_mission_with_the_reason(tmp_path, monkeypatch):
    """It keeps waiting on the clock: the stop waits 10 simulated seconds for it (not wall seconds: quick), reports
    it as the mission's failure and goes on without it; the other robot's files are complete."""
    def keeps_waiting(onboard, done):
        while not done.is_set():
            onboard.clock.wait_for(done.is_set, timeout=0.1)

    done = _control_that_never_ends(monkeypatch, "robot1", keeps_waiting)
    started = time.monotonic()
    try:
        result = Mission(_config(tmp_path)).run()
    finally:
        done.set()
    assert time.monotonic() - started < 120  # a bound for a broken stop; it takes seconds
    (failure,) = result.failures
    assert (failure.robot, failure.stage) == ("robot1", "control")
    assert failure.error == "did not end within 10 s of the stop (control still running)"
    stop = result.summary["sim_seconds"]
    assert stop + 10.0 - 0.01 <= failure.t <= stop + 10.5
    assert result.summary["failures"] == [{"robot": "robot1", "stage": "control", "error": failure.error,
                                           "t": failure.t}]
    for robot in ROBOTS:
        assert SensorLog(tmp_path / f"{robot}-log").closed
    assert result.maps["robot2"] is not None and (tmp_path / "robot2.npz").exists()


def test_a_stage_that_never_waits_after_the_stop_ends_the_mission_through_the_watchdog(tmp_path, monkeypatch):
    """It holds the clock's baton and never gives it up: simulated time stalls, the watchdog releases the clock
    after ``stall_after`` wall seconds, and every wait of the stop then runs out on the wall clock; the mission ends
    with both reasons."""
    def spins(onboard, done):
        while not done.is_set():  # never waits on the clock again
            time.sleep(0.01)

    monkeypatch.setattr(onboard_module, "STAGE_END_TIMEOUT", 2.0)
    done = _control_that_never_ends(monkeypatch, "robot1", spins)
    clock = SimClock(stall_after=5.0)
    started = time.monotonic()
    try:
        result = Mission(_config(tmp_path), clock=clock).run()
    finally:
        done.set()
        clock.close()
    elapsed = time.monotonic() - started
    assert elapsed < 120  # stall_after (5 s) + the stage's 2 s + the stand-still wait (3 s) + the mission itself
    stall, late = result.failures
    assert (stall.robot, stall.stage) == ("mission", "simulation")
    assert stall.error.startswith("simulated time stalled: control:robot1 has run for ")
    assert (late.robot, late.stage) == ("robot1", "control")
    assert late.error == "did not end within 2 s of the stop (control still running)"
    for robot in ROBOTS:
        assert SensorLog(tmp_path / f"{robot}-log").closed


@pytest.mark.parametrize("stage", ["slam", "camera"])
def test_the_stop_waits_for_each_stage_in_simulated_time(tmp_path, monkeypatch, stage):
    """Called from a participant, the stop's wait for a stage is a wait on the clock for its participant's end:
    a stage that ends 2 simulated seconds after the stop (the slam stage an observer, the camera a part of the
    world) delays the logs' end by that, the same whatever the wall clock does."""
    loop = getattr(Onboard, f"_{stage}_loop")

    def ends_late(self):
        loop(self)
        if self.robot == "robot2":
            self.clock.sleep(2.0)

    monkeypatch.setattr(Onboard, f"_{stage}_loop", ends_late)
    result = Mission(_config(tmp_path, robots=2)).run()
    assert not result.failures
    stop = result.summary["sim_seconds"]
    last = _odometry_times(tmp_path / "robot2-log")[-1]
    assert stop + 2.0 <= last <= stop + 2.0 + 3.0
