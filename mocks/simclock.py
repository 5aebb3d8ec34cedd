"""Simulated time in lockstep: one clock drives the virtual world and the runtime, so a mission on virtual
hardware gives the same answer however busy the machine is (ROS ``use_sim_time`` + Gazebo/PX4 lockstep).

Who waits for whom:

- **Participants** are the threads that act on simulated time: the virtual robots' server threads, the
  virtual heads' delivery (inside the camera threads), the runtime's camera, SLAM and control threads and
  the mission loop. They block only through :meth:`SimClock.wait_for` / :meth:`SimClock.sleep_until`.
- **One participant runs at a time** (it holds the baton). When it blocks, the coordinator thread hands the
  baton to the first participant whose predicate holds or whose deadline has come: first the virtual
  world's (robot servers, sensors), then the runtime's (observers), each group in name order. Which thread
  acts first at one instant is therefore fixed, not left to the OS scheduler: the answer cannot depend on
  the machine's load. (The cost: no two participants compute at once; with the GIL and two cores that
  loses little.)
- **Quiescence predicates** cover the threads that cannot be participants (the ARCOS driver's reader
  thread, which waits on a serial port with wall-clock timeouts): e.g. "every SIP the robot sent has reached
  the runtime". No observer gets the baton and time does not move while one of them is false; world
  participants, which read nothing the predicates guard and would run first at this instant anyway, may
  (a virtual head renders while the driver's reader is still reading a SIP).
- **Time advances** only when no participant can run and every quiescence predicate holds: to the earliest
  deadline of a waiting participant. The ``on_advance`` hooks run first (the virtual robots' physics steps
  to the new instant under their model locks), so a sensor sampling at ``t`` sees the world at ``t``.
- A **hold** (:meth:`hold`) stops time from advancing while the mission sets up (participants still run,
  e.g. a server answering the driver's handshake); ``gate`` predicates let it advance anyway while they are
  true (a driver waiting for its first SIP).
- :meth:`release` ends lockstep: from then on simulated time follows the wall clock and every wait is a
  plain timed wait. Missions release the clock once their deterministic part is done (shutdown, joins), or
  when the supervisor finds the simulation stalled.

``clock()`` (``now()``) never takes a lock: it is safe to call while holding any other lock.
"""
from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

Predicate = Callable[[], bool]


@dataclass(eq=False)
class Participant:
    """A thread taking part in lockstep (made by :meth:`SimClock.add_participant`, bound by the thread)."""

    name: str
    rank: int = 1                        # 0: the virtual world (sensors, robots); 1: observers (the runtime)
    thread: int | None = None            # ident of the bound thread
    predicate: Predicate | None = None   # what it waits for (None: running or about to)
    deadline: float = math.inf           # simulated time at which it wakes anyway
    granted: bool = False                # it holds the baton
    discarded: bool = False              # unregistered (its thread has left, or will never start)
    running_wall: float = 0.0            # wall seconds spent holding the baton
    grants: int = 0
    _granted_at: float = field(default=0.0, repr=False)
    _go: threading.Event = field(default_factory=threading.Event, repr=False)  # set when granted


class SimStall(RuntimeError):
    """The simulation made no progress for too long (a participant never blocked, or a quiescence predicate
    never came true)."""


class SimClock:
    """Simulated seconds, advanced in lockstep. ``start``: the initial time; ``poll``: wall seconds between the
    coordinator's looks at predicates that other threads make true (:meth:`notify` makes it look at once);
    ``stall_after``: wall seconds without progress before :attr:`stall` says why."""

    def __init__(self, start: float = 0.0, *, poll: float = 0.002, stall_after: float = 60.0) -> None:
        self._now = float(start)
        self._poll = float(poll)
        self._stall_after = float(stall_after)
        self._cond = threading.Condition()
        self._participants: list[Participant] = []   # kept sorted by name
        self._by_thread: dict[int, Participant] = {}
        self._running: Participant | None = None
        self._quiescence: list[tuple[str, Predicate]] = []
        self._hooks: list[Callable[[float], None]] = []
        self._holds = 0
        self._gates: list[Predicate] = []
        self._free = False                  # released: time follows the wall clock
        self._free_base = 0.0
        self._free_wall = 0.0
        self._closed = False
        self._extensions: dict[str, object] = {}
        self._last_progress = time.monotonic()
        self.stall: str | None = None       # why the simulation is stuck, once it is
        self.hook_errors: list[BaseException] = []
        self.advances = 0
        self.quiescence_wall: dict[str, float] = {}   # wall seconds spent waiting for each predicate
        self.participant_wall: dict[str, float] = {}  # wall seconds each participant (by name) held the baton
        self._waiting_on: str | None = None
        self._waiting_since = 0.0
        self.created_wall = time.monotonic()
        self.released_wall: float | None = None
        self._thread = threading.Thread(target=self._coordinate, name="simclock", daemon=True)
        self._thread.start()

    # -- reading the time ------------------------------------------------------------------------------
    def __call__(self) -> float:
        if self._free:
            return self._free_base + (time.monotonic() - self._free_wall)
        return self._now

    now = __call__

    @property
    def lockstep(self) -> bool:
        """True until :meth:`release`."""
        return not self._free

    # -- participants ----------------------------------------------------------------------------------
    def add_participant(self, name: str, *, world: bool = False) -> Participant:
        """Register a participant now (before its thread starts, so time cannot run past its first action;
        register several under a :meth:`hold`); the thread enters ``with clock.participant(token):``.

        ``world``: a part of the virtual world (a robot's server, a sensor) that never reads what the quiescence
        predicates guard (what the runtime has received). World participants run first at every instant and
        may run while a quiescence predicate is still false; the others (observers) wait for it. Within each
        group, the names fix the order: they must be unique."""
        with self._cond:
            if any(p.name == name for p in self._participants):
                raise ValueError(f"a participant named {name!r} is already registered")
            p = Participant(name, 0 if world else 1, predicate=_always, deadline=-math.inf)
            self._participants.append(p)
            self._participants.sort(key=lambda q: (q.rank, q.name))
            self._cond.notify_all()
            return p

    def discard(self, participant: Participant) -> None:
        """Unregister (a thread that will not start, or has ended). Releases the baton if it held it. Sets
        ``participant.discarded``: a predicate for whoever waits for that thread to end (e.g. ``wait_for(lambda:
        p.discarded)`` from a participant: it then ends at a simulated instant that does not depend on the load)."""
        with self._cond:
            participant.discarded = True
            if participant in self._participants:
                self._participants.remove(participant)
            if participant.thread is not None:
                self._by_thread.pop(participant.thread, None)
            if self._running is participant:
                self._release_baton(participant)
            self._cond.notify_all()

    @contextmanager
    def participant(self, token: Participant | str) -> Iterator[Participant]:
        """Run the body as a participant (waits for the baton first); unregisters on exit, whatever happens."""
        p = self.add_participant(token) if isinstance(token, str) else token
        with self._cond:
            p.thread = threading.get_ident()
            self._by_thread[p.thread] = p
        try:
            self._wait_for_grant(p)
            yield p
        finally:
            self.discard(p)

    def participants(self) -> list[str]:
        with self._cond:
            return [p.name for p in self._participants]

    # -- waiting -----------------------------------------------------------------------------------------
    def wait_for(self, predicate: Predicate, timeout: float | None = None, *, until: float | None = None) -> bool:
        """Block until ``predicate()`` holds (True) or simulated time reaches ``until`` / now + ``timeout``
        (False). From a participant, this is where it gives the baton up."""
        start = self()
        deadline = until if until is not None else (start + timeout if timeout is not None else math.inf)
        me = self._by_thread.get(threading.get_ident())
        with self._cond:
            if me is not None and not self._free and not self._closed:
                me.predicate, me.deadline = predicate, deadline
                self._release_baton(me)
                self._cond.notify_all()
                self._wait_for_grant(me, locked=True)
                if not self._free:
                    return bool(predicate())
            # a non-participant, or lockstep has ended: a plain polled wait on simulated time
            while True:
                if predicate():
                    return True
                if self() >= deadline or self._closed:
                    return bool(predicate())
                self._cond.wait(self._poll if not self._free else min(0.005, max(1e-4, deadline - self())))

    def sleep_until(self, t: float) -> None:
        self.wait_for(_never, until=t)

    def sleep(self, seconds: float) -> None:
        self.wait_for(_never, until=self() + max(0.0, seconds))

    def _wait_for_grant(self, p: Participant, locked: bool = False) -> None:
        """Block until the coordinator hands ``p`` the baton (or lockstep ends). Waits on the participant's own
        event, so a grant wakes one thread, not all of them."""
        if not locked:
            with self._cond:
                self._wait_for_grant(p, locked=True)
            return
        while not p.granted and not self._free and not self._closed:
            p._go.clear()
            self._cond.release()
            try:
                p._go.wait(0.05)
            finally:
                self._cond.acquire()
        p.predicate = None

    def _release_baton(self, p: Participant) -> None:
        if p.granted:
            p.granted = False
            held = time.monotonic() - p._granted_at
            p.running_wall += held
            self.participant_wall[p.name] = self.participant_wall.get(p.name, 0.0) + held
        if self._running is p:
            self._running = None

    # -- wiring --------------------------------------------------------------------------------------------
    def add_quiescence(self, name: str, predicate: Predicate) -> Callable[[], None]:
        """Hand no baton out and keep time still while ``predicate()`` is false. Returns a remover."""
        entry = (name, predicate)
        with self._cond:
            self._quiescence.append(entry)
            self._cond.notify_all()

        def remove() -> None:
            with self._cond:
                if entry in self._quiescence:
                    self._quiescence.remove(entry)
                self._cond.notify_all()
        return remove

    def notify(self) -> None:
        """Something a predicate looks at has changed (e.g. a SIP reached the runtime): look again now rather
        than at the next poll. Safe from any thread that holds no lock a predicate needs."""
        with self._cond:
            self._cond.notify_all()

    def add_on_advance(self, hook: Callable[[float], None]) -> Callable[[], None]:
        """Call ``hook(t)`` before time becomes ``t`` (every participant blocked). Returns a remover."""
        with self._cond:
            self._hooks.append(hook)

        def remove() -> None:
            with self._cond:
                if hook in self._hooks:
                    self._hooks.remove(hook)
        return remove

    @contextmanager
    def hold(self) -> Iterator[None]:
        """Time stands still inside (participants still run), except while a :meth:`gate` is open."""
        with self._cond:
            self._holds += 1
        try:
            yield
        finally:
            with self._cond:
                self._holds -= 1
                self._cond.notify_all()

    @contextmanager
    def gate(self, predicate: Predicate) -> Iterator[None]:
        """Inside a :meth:`hold`, let time advance while ``predicate()`` holds."""
        with self._cond:
            self._gates.append(predicate)
            self._cond.notify_all()
        try:
            yield
        finally:
            with self._cond:
                self._gates.remove(predicate)

    def release(self) -> None:
        """End lockstep: simulated time follows the wall clock from now on; every wait becomes a timed wait."""
        with self._cond:
            if self._free:
                return
            self._free_base, self._free_wall = self._now, time.monotonic()
            self.released_wall = self._free_wall
            self._free = True
            if self._running is not None:
                self._release_baton(self._running)
            for p in self._participants:
                p._go.set()
            self._cond.notify_all()

    def close(self) -> None:
        """Release, stop the coordinator and wake every waiter. Safe to call twice."""
        self.release()
        with self._cond:
            self._closed = True
            for p in self._participants:
                p._go.set()
            self._cond.notify_all()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)

    def __enter__(self) -> SimClock:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def extension(self, key: str, factory: Callable[[], object]) -> object:
        """One object per clock under ``key``, made by ``factory()`` on first use (e.g. the virtual robots'
        shared physics stepper)."""
        with self._cond:
            if key not in self._extensions:
                self._extensions[key] = factory()
            return self._extensions[key]

    # -- figures -------------------------------------------------------------------------------------------
    def wall_seconds(self) -> float:
        """Wall seconds of lockstep so far (until :meth:`release`)."""
        end = self.released_wall if self.released_wall is not None else time.monotonic()
        return end - self.created_wall


    # -- the coordinator -----------------------------------------------------------------------------------
    def _coordinate(self) -> None:
        with self._cond:
            while not self._closed:
                if self._free:
                    self._run_hooks(self())
                    self._cond.wait(0.002)
                    continue
                if self._step():
                    self._last_progress = time.monotonic()
                    self.stall = None
                    continue
                waited = time.monotonic() - self._last_progress
                if waited > self._stall_after and self.stall is None:
                    self.stall = self._describe_stall(waited)
                self._cond.wait(self._poll)

    def _step(self) -> bool:
        """One decision (lock held): hand the baton out, or advance time. False if nothing could be done."""
        if self._running is not None:
            return False
        quiet = True
        for name, predicate in self._quiescence:
            if not self._safe(predicate):
                if self._waiting_on is None:
                    self._waiting_on, self._waiting_since = name, time.monotonic()
                quiet = False
                break
        if quiet and self._waiting_on is not None:
            name = self._waiting_on
            self.quiescence_wall[name] = self.quiescence_wall.get(name, 0.0) + time.monotonic() - self._waiting_since
            self._waiting_on = None
        now = self._now
        for p in self._participants:
            if p.granted:
                return False   # granted, not yet noticed by its thread
            if p.predicate is None:
                return False   # between grant and its next wait: still running
        for p in self._participants:
            if p.rank > 0 and not quiet:
                return False   # observers wait until what they observe has arrived
            if p.deadline <= now or self._safe(p.predicate):
                p.granted = True
                p.grants += 1
                p._granted_at = time.monotonic()
                self._running = p
                p._go.set()
                return True
        if not quiet or (self._holds and not any(self._safe(g) for g in self._gates)):
            return False
        deadline = min((p.deadline for p in self._participants), default=math.inf)
        if not math.isfinite(deadline):
            return False
        self._run_hooks(deadline)
        self._now = deadline
        self.advances += 1
        return True

    def _run_hooks(self, t: float) -> None:
        for hook in list(self._hooks):
            try:
                hook(t)
            except Exception as exc:  # noqa: BLE001 - kept for the owner (a mock's bug); time goes on
                if len(self.hook_errors) < 100:
                    self.hook_errors.append(exc)

    @staticmethod
    def _safe(predicate: Predicate | None) -> bool:
        if predicate is None:
            return False
        try:
            return bool(predicate())
        except Exception:  # noqa: BLE001 - let the waiter run and meet the error itself
            return True

    def _describe_stall(self, waited: float) -> str:
        if self._running is not None:
            return f"{self._running.name} has run for {waited:.0f} s of wall time without waiting on the clock"
        false = [name for name, predicate in self._quiescence if not self._safe(predicate)]
        if false:
            return f"waiting {waited:.0f} s of wall time for: {', '.join(false)}"
        waiting = ", ".join(p.name for p in self._participants) or "nobody"
        return (f"no participant can run and none has a deadline (t = {self._now:.3f} s; waiting: {waiting}; "
                f"held: {bool(self._holds)})")


def _always() -> bool:
    return True


def _never() -> bool:
    return False


def is_lockstep(clock: object) -> bool:
    """Does ``clock`` offer lockstep waits (``wait_for``, ``sleep_until``)? Plain callables do not."""
    return callable(getattr(clock, "wait_for", None)) and callable(getattr(clock, "sleep_until", None))
