"""The lockstep clock: who runs when, when time moves, and that nothing in it depends on the machine's speed."""
from __future__ import annotations

import threading
import time

import pytest

from mocks.simclock import SimClock, is_lockstep


def _start(clock: SimClock, name: str, body) -> threading.Thread:
    token = clock.add_participant(name)

    def run() -> None:
        with clock.participant(token):
            body()

    thread = threading.Thread(target=run, name=name, daemon=True)
    thread.start()
    return thread


@pytest.mark.parametrize("slow", ["a", "b"])
def test_participants_act_at_their_instants_in_a_fixed_order_whatever_the_thread_timing(slow):
    """Two periodic participants that meet every 0.1 s: at one instant they act in the order of their names, and
    one that computes for a while (wall time) does not let time run on without it."""
    log: list[tuple[float, str]] = []
    with SimClock() as clock:
        def loop(name: str, period: float, n: int) -> None:
            t = clock()
            for _ in range(n):
                t += period
                clock.sleep_until(t)
                log.append((round(clock(), 9), name))
                if name == slow:
                    time.sleep(0.01)  # wall time spent computing: simulated time must stand still meanwhile

        with clock.hold():  # both registered before time can move past either's first instant
            threads = [_start(clock, "b", lambda: loop("b", 0.1, 4)), _start(clock, "a", lambda: loop("a", 0.05, 8))]
        for thread in threads:
            thread.join(timeout=30)
    assert log == [(0.05, "a"), (0.1, "a"), (0.1, "b"), (0.15, "a"), (0.2, "a"), (0.2, "b"), (0.25, "a"),
                   (0.3, "a"), (0.3, "b"), (0.35, "a"), (0.4, "a"), (0.4, "b")]


def test_time_waits_for_a_quiescence_predicate_and_hooks_run_before_it_moves():
    with SimClock() as clock:
        outside = threading.Event()  # something a non-participant thread has to do first
        clock.add_quiescence("the outside thread", outside.is_set)
        seen: list[float] = []
        clock.add_on_advance(seen.append)
        woke: list[float] = []
        thread = _start(clock, "p", lambda: (clock.sleep_until(1.5), woke.append(clock())))
        time.sleep(0.05)
        assert clock() == 0.0 and woke == []  # stuck at 0 until the predicate holds
        outside.set()
        thread.join(timeout=10)
    assert woke == [1.5] and seen == [1.5]


def test_a_predicate_wakes_a_participant_without_time_moving():
    with SimClock() as clock:
        box: list[int] = []
        results: list[tuple[bool, float]] = []
        with clock.hold():
            consumer = _start(clock, "consumer", lambda: results.append((clock.wait_for(lambda: bool(box),
                                                                                        timeout=5.0), clock())))
            producer = _start(clock, "producer", lambda: (clock.sleep_until(2.0), box.append(1)))
        for thread in (producer, consumer):
            thread.join(timeout=10)
    assert results == [(True, 2.0)]


def test_a_timeout_returns_false_at_exactly_its_simulated_instant():
    with SimClock(start=10.0) as clock:
        results: list[tuple[bool, float]] = []
        _start(clock, "p", lambda: results.append((clock.wait_for(lambda: False, timeout=0.25), clock()))).join(10)
    assert results == [(False, 10.25)]


def test_a_hold_stops_time_and_a_gate_lets_it_move_while_it_is_open():
    with SimClock() as clock:
        with clock.hold():
            thread = _start(clock, "p", lambda: clock.sleep_until(1.0))
            time.sleep(0.05)
            assert clock() == 0.0
            with clock.gate(lambda: True):
                thread.join(timeout=10)
            assert clock() == 1.0


def test_release_ends_lockstep_and_waits_become_timed_waits():
    with SimClock() as clock:
        with clock.hold():  # held forever: only the release can end the sleep
            done = threading.Event()
            _start(clock, "p", lambda: (clock.sleep_until(clock() + 0.05), done.set()))
            time.sleep(0.05)
            assert not done.is_set()
            clock.release()
            assert done.wait(5.0)
        assert not clock.lockstep and clock() > 0.0


def test_a_participant_that_raises_gives_the_baton_back():
    with SimClock() as clock:
        def fail() -> None:
            raise RuntimeError("boom")

        token = clock.add_participant("failing")

        def run() -> None:
            with pytest.raises(RuntimeError), clock.participant(token):
                fail()

        threading.Thread(target=run, daemon=True).start()
        woke: list[float] = []
        _start(clock, "other", lambda: (clock.sleep_until(0.5), woke.append(clock()))).join(10)
    assert woke == [0.5] and "failing" not in clock.participants()


def test_a_stall_is_described_rather_than_hanging_silently():
    with SimClock(stall_after=0.2) as clock:
        clock.add_quiescence("a driver that never delivers", lambda: False)
        _start(clock, "p", lambda: clock.sleep_until(1.0))
        deadline = time.monotonic() + 10
        while clock.stall is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert "a driver that never delivers" in clock.stall
        clock.release()


def test_plain_callables_are_not_lockstep_clocks():
    assert not is_lockstep(time.monotonic)
    with SimClock() as clock:
        assert is_lockstep(clock)
        with pytest.raises(ValueError, match="already registered"):
            clock.add_participant("x")
            clock.add_participant("x")
