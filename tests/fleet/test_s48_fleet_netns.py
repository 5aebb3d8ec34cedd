"""The fleet across network namespaces (session 48): the fusion node and a robot on two hosts joined by a real link
(a veth pair between two Linux network namespaces), the link taken down and up as a cable pulled and put back.

The robot's link goes down for longer than Zenoh's lease (10 s): the node says the robot left without a word and
keeps its map; the robot goes on publishing, and says the node left. Once the link is up again the two reconnect
on their own (no restart) and the node gets the robot's newest map, published while the link was down (it asks
for it when the robot joins again). The link goes down once more and the robot ends with no node connected: its
last map reached no node, and the robot says so as it closes.

Needs root and ``ip netns`` (skipped otherwise, with the reason). Each test makes its own namespaces, named with
the test process's id, and deletes them whatever happens. Deterministic: no random loss, the link's state is
changed only between the events the test waits for; every wait has a deadline far above what it needs (the leave:
Zenoh's 10 s lease plus margin) and nothing asserts a duration.
"""
from __future__ import annotations

import os
import queue
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("zenoh")

ROOT = Path(__file__).resolve().parents[2]
DEADLINE = 30.0          # s for what takes a few seconds (a process's start, a connection)
LEAVE_DEADLINE = 30.0    # s for a leave noticed at Zenoh's 10 s lease
pytestmark = pytest.mark.timeout(240)

NODE = """
import sys
from runtime.fleet.status import PresenceLines
from runtime.fleet.zenoh_exchange import ZenohExchange
fleet, endpoint = sys.argv[1], sys.argv[2]
said = []   # p3at fuse --live's lines for joins and leaves, once the exchange is open
node = ZenohExchange(fleet, '{"listen": {"endpoints": ["%s"]}}' % endpoint, "fusion",
                     on_event=lambda line: print("event:", said[0](line) if said else line, flush=True))
said.append(PresenceLines(node.status, node.held))
print("ready", flush=True)
while sys.stdin.readline().strip() != "close":   # the test says 'look' to have the map held printed
    now = node.held().get("robot1")
    print("held", None if now is None else now[1], flush=True)
node.close()
"""

ROBOT = """
import sys
from runtime.fleet.synthetic import SyntheticRobot
from runtime.fleet.zenoh_exchange import ZenohExchange
fleet, endpoint = sys.argv[1], sys.argv[2]
robot = ZenohExchange(fleet, '{"connect": {"endpoints": ["%s"]}}' % endpoint, "robot",
                      on_event=lambda line: print("event:", line, flush=True))
source = SyntheticRobot("robot1", 0)
robot.publish_status("robot1", 0.0)   # its liveliness token
print("ready", flush=True)
stamp = 0.0
for command in sys.stdin:
    if command.strip() == "publish":
        stamp += 1.0
        robot.publish("robot1", source.step(), stamp)
        print("published", robot._encoders["robot1"].sequence, flush=True)
    elif command.strip() == "close":
        break
robot.close()
print("closed", flush=True)
"""


def _netns_reason() -> str | None:
    if os.name != "posix" or os.geteuid() != 0:
        return "needs root to make network namespaces"
    if shutil.which("ip") is None:
        return "needs the ip command (iproute2) to make network namespaces"
    probe = f"s48probe{os.getpid()}"
    made = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True)
    if made.returncode != 0:
        return f"cannot make a network namespace: {made.stderr.strip() or made.returncode}"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True)
    return None


def ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True)


class Host:
    """A process in a network namespace speaking the small line protocol above; its stdout lines in a queue."""

    def __init__(self, namespace: str, script: str, *args: str) -> None:
        self.process = subprocess.Popen(
            ["ip", "netns", "exec", namespace, sys.executable, "-c", script, *args], cwd=ROOT, text=True,
            env={**os.environ, "PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "1"},
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        self.lines: queue.Queue[str] = queue.Queue()
        self.seen: list[str] = []
        self.stderr: list[str] = []
        threading.Thread(target=lambda: [self.lines.put(x.rstrip("\n")) for x in self.process.stdout],
                         daemon=True).start()
        threading.Thread(target=lambda: self.stderr.extend(self.process.stderr), daemon=True).start()

    def say(self, command: str) -> None:
        self.process.stdin.write(command + "\n")
        self.process.stdin.flush()

    def wait_for(self, wanted, what: str, deadline: float = DEADLINE) -> str:
        """The first line (since the last wait) for which ``wanted(line)`` holds."""
        end = time.monotonic() + deadline
        while time.monotonic() < end:
            try:
                line = self.lines.get(timeout=0.2)
            except queue.Empty:
                if self.process.poll() is not None and self.lines.empty():
                    break
                continue
            self.seen.append(line)
            if wanted(line):
                return line
        pytest.fail(f"not within {deadline:g} s: {what}; lines: {self.seen}; stderr: {''.join(self.stderr)}")

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
        self.process.wait(timeout=30)


@pytest.fixture
def two_hosts():
    """Namespaces node and robot, a veth pair between them (10.48.0.1 and 10.48.0.2); deleted at the end."""
    reason = _netns_reason()
    if reason is not None:
        pytest.skip(reason)
    tag = str(os.getpid())
    node, robot = f"s48node{tag}", f"s48robot{tag}"
    node_if, robot_if = f"s48n{tag}"[:15], f"s48r{tag}"[:15]
    try:
        ip("netns", "add", node)
        ip("netns", "add", robot)
        ip("link", "add", node_if, "netns", node, "type", "veth", "peer", "name", robot_if, "netns", robot)
        for namespace, link, address in ((node, node_if, "10.48.0.1/24"), (robot, robot_if, "10.48.0.2/24")):
            ip("-n", namespace, "addr", "add", address, "dev", link)
            ip("-n", namespace, "link", "set", link, "up")
            ip("-n", namespace, "link", "set", "lo", "up")
        yield node, robot, robot_if
    finally:
        for namespace in (node, robot):   # deleting a namespace deletes its end of the pair, and so the pair
            subprocess.run(["ip", "netns", "del", namespace], capture_output=True)


def test_a_robot_whose_link_goes_down_and_up_is_heard_again_with_its_newest_map(two_hosts):
    node_ns, robot_ns, robot_if = two_hosts
    fleet, endpoint = f"netns{os.getpid()}", "tcp/10.48.0.1:7447"
    node = Host(node_ns, NODE, fleet, endpoint)
    robot = None
    try:
        node.wait_for(lambda x: x == "ready", "the node's start")
        robot = Host(robot_ns, ROBOT, fleet, endpoint)
        robot.wait_for(lambda x: x == "event: the fusion node joined the fleet", "the node at the robot")
        node.wait_for(lambda x: x == "event: robot1 joined the fleet", "the robot at the node")
        robot.say("publish")
        robot.wait_for(lambda x: x == "published 0", "map 0 published")

        def node_holds(sequence: int) -> None:
            def held() -> bool:
                node.say("look")
                return node.wait_for(lambda x: x.startswith("held"), "the node's answer") == f"held {sequence}"
            end = time.monotonic() + DEADLINE
            while not held():
                if time.monotonic() > end:
                    pytest.fail(f"not within {DEADLINE:g} s: robot1's map {sequence} at the node; {node.seen}")
                time.sleep(0.2)

        node_holds(0)

        ip("-n", robot_ns, "link", "set", robot_if, "down")   # the cable pulled
        node.wait_for(lambda x: x.startswith("event: robot1 left the fleet"), "the robot's leave", LEAVE_DEADLINE)
        assert node.seen[-1] == ("event: robot1 left the fleet without a word (its link lost or its process "
                                 "ended); the fusion keeps its map 0"), node.seen
        robot.wait_for(lambda x: x == "event: the fusion node left the fleet", "the node's leave at the robot",
                       LEAVE_DEADLINE)
        for sequence in (1, 2):   # the robot goes on: a publish with no link returns
            robot.say("publish")
            robot.wait_for(lambda x, s=sequence: x == f"published {s}", f"map {sequence} published, link down")

        ip("-n", robot_ns, "link", "set", robot_if, "up")     # the cable put back: no process restarted
        robot.wait_for(lambda x: x == "event: the fusion node joined the fleet", "the node back at the robot")
        node.wait_for(lambda x: x.startswith("event: robot1 joined the fleet again"), "the robot back at the node")
        node_holds(2)   # the newest map, published while the link was down

        ip("-n", robot_ns, "link", "set", robot_if, "down")   # down again, and the robot ends so
        robot.wait_for(lambda x: x == "event: the fusion node left the fleet", "the node's second leave",
                       LEAVE_DEADLINE)
        robot.say("publish")
        robot.wait_for(lambda x: x == "published 3", "map 3 published, link down")
        robot.say("close")
        robot.wait_for(lambda x: x == "closed", "the robot's close")
        assert robot.process.wait(timeout=DEADLINE) == 0, "".join(robot.stderr)
        said = [x for x in "".join(robot.stderr).splitlines() if "reached no fusion node" in x]
        assert len(said) == 1 and "robot1's map 3," in said[0] and "the fusion node left" in said[0], robot.stderr
        node.say("close")
        assert node.process.wait(timeout=DEADLINE) == 0, "".join(node.stderr)
    finally:
        node.stop()
        if robot is not None:
            robot.stop()
