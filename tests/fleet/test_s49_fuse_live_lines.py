"""``p3at fuse --live``'s lines come from several threads (the exchange's joins and leaves, the node's fusions, the
status printer) and were printed with ``print``, which writes a line's text and its newline apart: in session 49's
namespace runs two of four nodes printed 'robot1 joined the fleetfirst map from robot1: 0 landmarks; ...' and an
empty line. Each line is now one write under one lock (runtime.fleet.fusion_node.say_line, which run_live's lines
go through). A stream that yields the processor at every write makes the interleaving of print's two writes all
but certain; the lines must still come out whole."""
from __future__ import annotations

import threading
import time

from runtime.fleet.fusion_node import say_line


class YieldingStream:
    """A stderr whose every write lets the other threads run (a slow terminal, a pipe read late)."""

    def __init__(self) -> None:
        self.parts: list[str] = []

    def write(self, text: str) -> int:
        self.parts.append(text)
        time.sleep(0.0005)
        return len(text)

    def flush(self) -> None:
        time.sleep(0.0005)


def test_lines_said_from_several_threads_at_once_come_out_whole():
    stream, start = YieldingStream(), threading.Barrier(4)
    expected = {f"thread {k} line {n}: robot{k} joined the fleet" for k in range(4) for n in range(50)}

    def say(k: int) -> None:
        start.wait()
        for n in range(50):
            say_line(f"thread {k} line {n}: robot{k} joined the fleet", stream)

    threads = [threading.Thread(target=say, args=(k,)) for k in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(60)
    lines = "".join(stream.parts).split("\n")
    assert lines[-1] == "" and set(lines[:-1]) == expected and len(lines) - 1 == len(expected), lines[:10]
