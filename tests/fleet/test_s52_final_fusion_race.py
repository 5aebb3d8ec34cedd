"""The final fusion never runs beside a live fusion still in progress (session 52, D's review: "Left alone").

``p3at demo --processes`` runs the fusion node's ``run`` on a thread; at the end it set the thread's stop, joined it for
30 s and then called ``final_fusion`` on the main thread. A live fusion still running past 30 s (a fusion of two
~1,000-landmark maps with its split checks takes seconds of CPU, more on a loaded machine) then ran beside the final one
on the node's one state: the robots' clock, the alignment cache, the history (the next fusion's seed is its length),
the sources, the published fused map and the recording. Now the node's fusions are one at a time (the final one waits
for a live one in progress, said in one line, and no live one starts after it), and the demo joins the thread however
long its last fusion takes, saying so every 30 s.

The live fusion is made slow by holding it inside ``fuse_maps`` on an event (no sleeps): the test releases it once the
final fusion has either said it waits (the fix) or started fusing beside it (the race).
"""
from __future__ import annotations

import threading

import numpy as np

import runtime.fleet.fusion_node as fusion_node
from runtime.exchange import InProcessExchange
from runtime.fleet.fusion_node import FUSED, FusionNode, FusionNodeConfig
from runtime.fleet.processes import end_fusion_thread
from runtime.fleet.synthetic import SyntheticRobot
from tests.fleet.live_node import ManualClock

BOUND = 60.0   # s: a failure bound on every wait (the events below come at once when the code is right)
NAMES = ("robot1", "robot2")


def _maps(steps: int) -> list[dict]:
    """The two robots' maps after each of ``steps`` steps (the same maps for every node they are given to)."""
    robots = [SyntheticRobot(n, k, landmarks=200, grow=40) for k, n in enumerate(NAMES)]
    return [{r.name: r.step() for r in robots} for _ in range(steps)]


def _publish(exchange: InProcessExchange, maps: dict, stamp: float) -> None:
    for name, m in maps.items():
        exchange.publish(name, m, stamp=stamp)


def _figures(report) -> tuple:
    """What a fusion found: each pair's figures and the merged map's landmarks."""
    pairs = [{k: v for k, v in p.as_dict().items() if "second" not in k and "time" not in k} for p in report.pairs]
    merged = None if report.merged is None else np.asarray(report.merged.positions).tolist()
    return report.t, repr(pairs), merged


def test_the_final_fusion_waits_for_a_live_fusion_in_progress_and_is_the_nodes_last(monkeypatch):
    first, second = _maps(2)
    # the same fusions one after the other, no thread: what the final fusion must find
    reference = FusionNode(InProcessExchange(), FusionNodeConfig(interval=10.0, min_period=0.0),
                           clock=ManualClock(1000.0))
    _publish(reference.exchange, first, 1.0)
    live_alone = reference.fuse_now()
    _publish(reference.exchange, second, 2.0)
    final_alone = reference.final_fusion()
    assert live_alone is not None and final_alone is not None

    fuse = fusion_node.fuse_maps
    live_in, release, noticed = threading.Event(), threading.Event(), threading.Event()
    in_flight, most, calls = [0], [0], []
    count = threading.Lock()

    def slow_first(*args, **kwargs):
        with count:
            in_flight[0] += 1
            most[0] = max(most[0], in_flight[0])
            calls.append(args[3])
            first_call = len(calls) == 1
            if in_flight[0] > 1:
                noticed.set()   # the race: a fusion beside the live one
        try:
            if first_call:
                live_in.set()
                assert release.wait(BOUND), "the test never released the live fusion"
            return fuse(*args, **kwargs)
        finally:
            with count:
                in_flight[0] -= 1

    monkeypatch.setattr(fusion_node, "fuse_maps", slow_first)
    lines: list[str] = []

    def event(line: str) -> None:
        lines.append(line)
        if "final fusion waits" in line:
            noticed.set()

    exchange = InProcessExchange()
    node = FusionNode(exchange, FusionNodeConfig(interval=10.0, min_period=0.0), on_event=event,
                      clock=ManualClock(1000.0))
    _publish(exchange, first, 1.0)
    stop = threading.Event()
    runner = threading.Thread(target=node.run, args=(stop,), daemon=True)
    runner.start()
    finals: list = []
    finisher = threading.Thread(target=lambda: finals.append(node.final_fusion()), daemon=True)
    try:
        assert live_in.wait(BOUND), "the node made no live fusion"
        stop.set()                      # as the demo: the robots are done, the node's stop is asked
        _publish(exchange, second, 2.0)
        finisher.start()
        assert noticed.wait(BOUND), "the final fusion neither waited nor fused"
        assert most[0] == 1, "the final fusion ran beside the live fusion in progress"
        assert [line for line in lines if "final fusion waits" in line] == [
            "the final fusion waits for the live fusion at t=1s (running 0 s) to end"]
    finally:
        release.set()
        runner.join(BOUND)
        if finisher.ident is not None:   # started
            finisher.join(BOUND)
    assert not runner.is_alive() and not finisher.is_alive()
    assert most[0] == 1
    assert calls == [1.0, 2.0]                           # the live one, then the final one: none lost, none twice
    (final,) = finals
    assert [r.t for r in node.history] == [1.0, 2.0] and node.history[-1] is final
    assert _figures(final) == _figures(final_alone)      # as without the race (its seed: the history's length)
    assert _figures(node.history[0])[:2] == _figures(live_alone)[:2]   # (its merged map dropped: keep_latest_map)
    assert exchange.receive()[FUSED].stamp == 2.0         # the fused map published last is the final one's


def test_the_demo_joins_the_fusion_thread_until_its_live_fusion_ends_saying_so():
    go = threading.Event()
    thread = threading.Thread(target=lambda: go.wait(BOUND), daemon=True)
    thread.start()
    said: list[str] = []

    def say(line: str) -> None:
        said.append(line)
        if len(said) == 3:
            go.set()        # the live fusion ends after three of the lines: the join did not give up before

    end_fusion_thread(thread, say, period=0.01)
    assert not thread.is_alive()
    assert len(said) >= 3 and all("live fusion still runs" in line and "the final fusion waits for it" in line
                                  for line in said)


def test_a_fusion_thread_already_ended_is_not_waited_for_and_nothing_is_said():
    thread = threading.Thread(target=lambda: None)
    thread.start()
    thread.join()
    said: list[str] = []
    end_fusion_thread(thread, said.append, period=0.01)
    end_fusion_thread(threading.Thread(target=lambda: None), said.append, period=0.01)   # never started
    assert said == []


class _CountedClock(ManualClock):
    """A wall clock standing still that sets ``passed`` once it has been read ``reads`` times from ``armed`` on."""

    def __init__(self, now: float, reads: int) -> None:
        super().__init__(now)
        self.reads, self.count, self.armed = reads, 0, False
        self.passed = threading.Event()

    def __call__(self) -> float:
        if self.armed:
            self.count += 1
            if self.count >= self.reads:
                self.passed.set()
        return self.now


def test_no_live_fusion_starts_after_the_final_fusion_has_begun(monkeypatch):
    first, second = _maps(2)
    fuse, calls = fusion_node.fuse_maps, []

    def counted(*args, **kwargs):
        calls.append(args[3])
        return fuse(*args, **kwargs)

    monkeypatch.setattr(fusion_node, "fuse_maps", counted)
    # run's every turn reads the wall clock once, at most four times with a fusion: five reads are past its first turn,
    # which fuses whatever is new (nothing has been fused by run yet)
    clock = _CountedClock(1000.0, reads=5)
    exchange = InProcessExchange()
    node = FusionNode(exchange, FusionNodeConfig(interval=10.0, min_period=0.0), clock=clock)
    _publish(exchange, first, 1.0)
    assert node.final_fusion() is not None
    _publish(exchange, second, 2.0)   # new maps after the final fusion (a robot's map came late)
    stop = threading.Event()
    runner = threading.Thread(target=node.run, args=(stop,), daemon=True)
    clock.armed = True
    runner.start()
    try:
        assert clock.passed.wait(BOUND), "the node's thread did not turn"
    finally:
        stop.set()
        runner.join(BOUND)
    assert not runner.is_alive()
    assert calls == [1.0]                 # the final fusion only: it stays the node's last
    assert [r.t for r in node.history] == [1.0]
