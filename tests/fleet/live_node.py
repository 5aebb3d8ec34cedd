"""A live fusion node (``p3at fuse --live``) driven by real processes, for the fleet's CLI tests."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


# the entities a fleet's fusion is drawn and read on: the fusion node's alone (a robot process records none)
NODE_ENTITIES = ("fusion/", "maps/fused", "world/fused", "map/fused", "plots/fusion")


class ManualClock:
    """A node's wall clock that stands still until the test sets ``now``."""

    def __init__(self, now: float = 0.0) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now


def p3at(*args: str, **kwargs) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "runtime.cli", *args], cwd=ROOT, text=True,
                            env={**os.environ, "PYTHONPATH": str(ROOT)}, **kwargs)


def endpoint(kind: str, port: int) -> str:
    """A Zenoh exchange that listens on (``kind`` "listen") or connects to ("connect") loopback ``port``."""
    return "zenoh:" + json.dumps({kind: {"endpoints": [f"tcp/127.0.0.1:{port}"]}})


def stopped_after_first_fusion(node: subprocess.Popen, port: int, fleet: str) -> tuple[str, str]:
    """Two synthetic robots (robot1, robot2) publish six maps each to ``node``, a ``p3at fuse --live`` of fleet
    ``fleet`` listening on ``port`` with its stdout and stderr piped; once both have published their last map and the
    node has said its first fusion, it is stopped by SIGTERM, as Ctrl-C would. Returns its stdout and its stderr."""
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(node.stderr), daemon=True)  # the node's events, as they come
    reader.start()
    robots = [subprocess.Popen([sys.executable, "-m", "runtime.fleet.synthetic", "--names", name, "--first-index",
                                str(k), "--exchange", endpoint("connect", port), "--fleet", fleet, "--steps", "6",
                                "--period", "0.3"], cwd=ROOT, stdout=subprocess.PIPE, text=True)
              for k, name in enumerate(["robot1", "robot2"])]
    try:
        for robot in robots:   # "ready", then "published" after its last map (~3 s; pytest-timeout bounds the wait)
            said = [robot.stdout.readline() for _ in range(2)]
            assert said == ["ready\n", "published\n"], said
        end = time.monotonic() + 90.0   # a failure bound: the node fuses within a second of holding two maps
        while not any(line.startswith("fusion at") for line in lines) and time.monotonic() < end:
            assert node.poll() is None, "".join(lines)
            time.sleep(0.05)
        node.send_signal(signal.SIGTERM)  # stops cleanly, as Ctrl-C would: prints the last fusion
        stdout = node.stdout.read()
        node.wait(timeout=60)
        reader.join(timeout=30)
    finally:
        for r in robots:
            r.kill()
            r.wait()
        if node.poll() is None:
            node.kill()
    return stdout, "".join(lines)
