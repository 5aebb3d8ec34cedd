"""A fleet on loopback: robots as separate processes (synthetic map publishers, one Zenoh session each) and a
fusion node in the test process, over Zenoh with random free ports.

No test races the wall clock: each waits for a condition with a deadline far above what the condition needs on
a loaded 2-core machine (process start with numpy and zenoh imports: ~2 s; Zenoh's connect retry: ~1 s), and
fails naming the condition. The deadline for a robot's leave is Zenoh's lease (10 s) plus margin: that is
the bound if the closed socket were missed; a killed process's socket closes at once (docs/fleet.md measures it).
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("zenoh")

from runtime.fleet import mapwire  # noqa: E402
from runtime.fleet.fusion_node import FusionNode, FusionNodeConfig  # noqa: E402
from runtime.fleet.processes import free_port  # noqa: E402
from runtime.fleet.synthetic import SyntheticRobot  # noqa: E402
from runtime.fleet.zenoh_exchange import ZenohExchange  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
DEADLINE = 30.0          # s, for anything that takes a few seconds on an idle machine
LEAVE_DEADLINE = 15.0    # s, Zenoh's 10 s lease plus margin
STEPS = 6
pytestmark = pytest.mark.timeout(120)


def wait_until(condition, what: str, deadline: float = DEADLINE):
    end = time.monotonic() + deadline
    while time.monotonic() < end:
        value = condition()
        if value:
            return value
        time.sleep(0.05)
    pytest.fail(f"not within {deadline:g} s: {what}")


def endpoint_config(port: int, role: str, scheme: str = "tcp", tls: dict | None = None) -> str:
    key = "listen" if role == "fusion" else "connect"
    config = {key: {"endpoints": [f"{scheme}/127.0.0.1:{port}"]}}
    if tls is not None:
        config["transport"] = {"link": {"tls": tls}}
    return json.dumps(config)


class Fleet:
    """Robot processes started by a test, and the fusion node it runs; everything stopped at the end."""

    def __init__(self, fleet: str, port: int) -> None:
        self.fleet, self.port = fleet, port
        self.processes: dict[str, subprocess.Popen] = {}
        self.node: FusionNode | None = None
        self.exchange: ZenohExchange | None = None
        self.events: list[str] = []
        self.fusions: list[tuple[dict, object]] = []   # (the node's sources, its report), taken in the node's thread
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start_robot(self, name: str, index: int, steps: int = STEPS, config: str | None = None,
                    period: float = 0.3) -> subprocess.Popen:
        config = config or endpoint_config(self.port, "robot")
        process = subprocess.Popen(
            [sys.executable, "-m", "runtime.fleet.synthetic", "--names", name, "--first-index", str(index),
             "--exchange", f"zenoh:{config}", "--fleet", self.fleet, "--steps", str(steps), "--period", str(period),
             "--full-every", "4"],
            cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env={**os.environ, "PYTHONPATH": str(ROOT)})
        self.processes[name] = process
        return process

    def start_node(self, config: str | None = None) -> None:
        self._stop = threading.Event()
        self.exchange = ZenohExchange(self.fleet, config or endpoint_config(self.port, "fusion"), "fusion",
                                      on_event=self.events.append,
                                      on_update=lambda robot: self.node is not None and self.node.notify(robot))
        # the node's thread sets its sources before it appends the report to its history: read together from the
        # test's thread, they can be of two fusions, so each report is kept with its sources as the node made it
        self.node = FusionNode(self.exchange, FusionNodeConfig(interval=1.0, min_period=0.2),
                               on_report=lambda report: self.fusions.append((dict(self.node.sources), report)))
        self._thread = threading.Thread(target=self.node.run, args=(self._stop,), name="test-fusion", daemon=True)
        self._thread.start()

    def final_fusion(self):
        """Stop the node's loop and make its final fusion (the maps it holds, decided on them alone): a live fusion's
        found is only a candidate until a later one agrees (fusion/confirmation.py), which these tests do not wait
        for."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=DEADLINE)
        return self.node.final_fusion()

    def stop_node(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=DEADLINE)
        if self.exchange is not None:
            self.exchange.close()
        self.node = self.exchange = None

    def maps(self) -> dict:
        return self.exchange.receive()

    def close(self) -> None:
        self.stop_node()
        for process in self.processes.values():
            if process.poll() is None:
                process.kill()
            process.wait(timeout=DEADLINE)


@pytest.fixture
def fleet(request):
    f = Fleet(f"t{os.getpid()}{request.node.name[-12:].replace('[', '').replace(']', '')}"[:60]
              .replace("-", "_"), free_port())
    yield f
    f.close()


def replayed(name: str, index: int, steps: int):
    robot = SyntheticRobot(name, index)
    for _ in range(steps - 1):
        robot.step()
    return robot.step()


def all_published(fleet: Fleet, names, steps: int = STEPS):
    maps = fleet.maps()
    return all(n in maps and maps[n].sequence == steps - 1 for n in names)


def test_three_robot_processes_exchange_maps_and_the_fusion_aligns_them():
    names = ["robot1", "robot2", "robot3"]
    f = Fleet(f"three{os.getpid()}", free_port())
    try:
        f.start_node()
        for k, n in enumerate(names):
            f.start_robot(n, k)
        wait_until(lambda: all_published(f, names), "every robot's last update at the fusion node")
        maps = f.maps()
        for k, n in enumerate(names):  # deltas and snapshots rebuilt exactly what each process built
            expected = replayed(n, k, STEPS)
            got = maps[n].landmark_map
            np.testing.assert_array_equal(got.ids, expected.ids)
            np.testing.assert_array_equal(got.positions, expected.positions)
            np.testing.assert_array_equal(got.counts, expected.counts)
        def fusion_of_the_last_maps():
            return next((report for sources, report in reversed(f.fusions) if sources.keys() == set(names)
                         and all(sources[n][0] == STEPS - 1 for n in names)), None)

        report = wait_until(fusion_of_the_last_maps, "a fusion of every robot's last map")
        assert [p.other for p in report.pairs] == ["robot2", "robot3"]
        report = f.final_fusion()
        for pair in report.pairs:
            assert pair.aligned, pair.note
            assert pair.error_xy < 0.1 and pair.error_theta < 0.02, pair
        fused = f.exchange.fused()  # what the node published on p3at/<fleet>/fused/map
        assert set(fused.landmark_map.metadata["fused_from"]) == set(names)
        assert {"robot1", "robot2", "robot3"} <= f.exchange.present()
    finally:
        f.close()


def test_a_killed_robot_leaves_keeps_its_map_and_rejoins_with_fresh_sequence_numbers(fleet):
    fleet.start_node()
    fleet.start_robot("robot1", 0)
    robot2 = fleet.start_robot("robot2", 1)
    wait_until(lambda: all_published(fleet, ["robot1", "robot2"]), "both robots' last updates")
    session = fleet.exchange.session_of("robot2")
    robot2.send_signal(signal.SIGKILL)
    # the exchange's pump drops the token from present() first, then says the leave (on_event, outside its lock)
    wait_until(lambda: "robot2" not in fleet.exchange.present() and "robot2 left the fleet" in fleet.events,
               "robot2's liveliness token gone, and its leave said", LEAVE_DEADLINE)
    kept = fleet.maps()["robot2"]  # the fusion keeps its last map
    assert kept.sequence == STEPS - 1 and len(kept.landmark_map) == len(replayed("robot2", 1, STEPS))
    fleet.start_robot("robot2", 1, steps=3)
    wait_until(lambda: fleet.exchange.session_of("robot2") != session
               and fleet.maps()["robot2"].sequence == 2, "robot2's new session at sequence 2")
    assert "robot2" in fleet.exchange.present()
    assert any(e.startswith("robot2 restarted") for e in fleet.events), fleet.events
    assert len(fleet.maps()["robot2"].landmark_map) == len(replayed("robot2", 1, 3))


def test_a_restarted_fusion_node_recovers_every_map_by_query(fleet):
    fleet.start_node()
    for k, n in enumerate(["robot1", "robot2"]):
        fleet.start_robot(n, k)
    wait_until(lambda: all_published(fleet, ["robot1", "robot2"]), "both robots' last updates")
    wait_until(lambda: fleet.node.history and fleet.node.history[-1].pairs, "a first fusion")
    fleet.stop_node()
    fleet.start_node()  # the robots publish nothing more: only their queryables can answer
    wait_until(lambda: all_published(fleet, ["robot1", "robot2"]), "both maps recovered by query")
    wait_until(lambda: fleet.node.history and fleet.node.history[-1], "a fusion after the restart")
    report = fleet.final_fusion()
    assert report.pairs[0].aligned and report.pairs[0].error_xy < 0.1


def test_malformed_messages_on_a_robot_key_are_dropped_and_the_receiver_goes_on(fleet):
    import zenoh

    fleet.start_node()
    fleet.start_robot("robot1", 0, steps=0, period=0.2)  # publishes until stopped
    wait_until(lambda: "robot1" in fleet.maps(), "robot1's first update")
    config = zenoh.Config.from_json5(endpoint_config(fleet.port, "robot"))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    key = f"p3at/{fleet.fleet}/robot1/map"
    good = mapwire.encode_full("robot2", mapwire.new_session(), 0, 0.0, replayed("robot2", 1, 1))
    hostile = [b"", b"\x00" * 64, b"P3MW\x01\x01\x00\x00\xff\xff\xff\xff", good,  # good, but robot2's on robot1's key
               good[:-8], good[:4] + b"\x07" + good[5:]]
    with zenoh.open(config) as session:

        def attack() -> bool:  # put again until received: puts before the route to the node exists are lost
            for data in hostile:
                session.put(key, data)
            return fleet.exchange.dropped["malformed"] >= len(hostile)

        wait_until(attack, "hostile messages dropped")
    before = fleet.maps()["robot1"].sequence
    wait_until(lambda: fleet.maps()["robot1"].sequence > before + 1, "robot1's updates still arriving")
    assert "robot1" in fleet.exchange.last_drop_reason


def _openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True, timeout=60)


EC_KEY = ("-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1")


@pytest.fixture(scope="module")
def certificates(tmp_path_factory) -> Path:
    """A self-signed CA, a server certificate for 127.0.0.1 and two client certificates (CN client, CN intruder),
    made with the openssl CLI. P-256 keys: as good a test of TLS and its access control as RSA, and made at once
    (four RSA-2048 keys took ~6 s of a loaded machine)."""
    if shutil.which("openssl") is None:
        pytest.skip("the openssl command is not installed")
    d = tmp_path_factory.mktemp("tls")
    _openssl("req", "-x509", *EC_KEY, "-nodes", "-keyout", "ca.key", "-out", "ca.pem", "-days", "2",
             "-subj", "/CN=p3at test CA", cwd=d)
    for name, san in (("server", "IP:127.0.0.1,DNS:localhost"), ("client", "DNS:robot"), ("intruder", "DNS:robot")):
        _openssl("req", *EC_KEY, "-nodes", "-keyout", f"{name}.key", "-out", f"{name}.csr",
                 "-subj", f"/CN={name}", cwd=d)
        (d / f"{name}.ext").write_text(f"subjectAltName={san}\n")
        _openssl("x509", "-req", "-in", f"{name}.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial",
                 "-out", f"{name}.pem", "-days", "2", "-extfile", f"{name}.ext", cwd=d)
    return d


ACCESS_CONTROL = {  # Zenoh 1.x access control: only the certificate CN "client" may use the fleet's keys
    "enabled": True, "default_permission": "deny",
    "rules": [{"id": "fleet", "permission": "allow", "flows": ["ingress", "egress"], "key_exprs": ["p3at/**"],
               "messages": ["put", "query", "reply", "declare_subscriber", "declare_queryable", "liveliness_token",
                            "declare_liveliness_subscriber", "liveliness_query"]}],
    "subjects": [{"id": "robots", "cert_common_names": ["client"]}],
    "policies": [{"rules": ["fleet"], "subjects": ["robots"]}],
}


def test_tls_and_access_control_admit_only_a_robot_with_an_allowed_client_certificate(fleet, certificates):
    d = certificates
    server = {"root_ca_certificate": str(d / "ca.pem"), "listen_certificate": str(d / "server.pem"),
              "listen_private_key": str(d / "server.key"), "enable_mtls": True}

    def client(name: str) -> dict:
        return {"root_ca_certificate": str(d / "ca.pem"), "connect_certificate": str(d / f"{name}.pem"),
                "connect_private_key": str(d / f"{name}.key"), "enable_mtls": True}

    node_config = json.loads(endpoint_config(fleet.port, "fusion", "tls", server))
    fleet.start_node(json.dumps({**node_config, "access_control": ACCESS_CONTROL}))
    # started first, so they have tried for longer than the admitted robot when it is checked:
    # no client certificate (refused by mutual TLS), plain TCP to the TLS port, a CA-signed certificate whose
    # CN the access control does not allow
    fleet.start_robot("nocert", 1, config=endpoint_config(fleet.port, "robot", "tls",
                                                          {"root_ca_certificate": str(d / "ca.pem")}))
    fleet.start_robot("plain", 2, config=endpoint_config(fleet.port, "robot"))
    fleet.start_robot("intruder", 3, config=endpoint_config(fleet.port, "robot", "tls", client("intruder")))
    fleet.start_robot("robot1", 0, config=endpoint_config(fleet.port, "robot", "tls", client("client")))
    wait_until(lambda: all_published(fleet, ["robot1"]), "the robot with an allowed client certificate admitted")
    assert fleet.maps().keys() == {"robot1"}
    assert fleet.exchange.present() & {"nocert", "plain", "intruder"} == set()
    assert all(p.poll() is None for p in fleet.processes.values())  # the refused ones are alive, still trying


def test_a_slow_receiver_keeps_a_bounded_queue_and_ends_with_the_latest_map():
    """The node's worker is held (its on_update hook blocks) while a robot publishes 40 updates: the queue stays
    within its byte bound by dropping the oldest, and once released the node ends with the robot's last map
    (missed deltas recovered by a snapshot query). The robot then sends its status once a second, as a runtime
    robot does (runtime/fleet/status.py): maps go with CongestionControl.DROP, and a last map lost on the wire is
    recovered because a status names it (CI lost the last map, and with it the one status the test sent, in
    session 45; statuses now travel ahead of the maps, benchmarks/fleet_status_priority.py)."""
    port, fleet = free_port(), f"slow{os.getpid()}"
    release, held = threading.Event(), threading.Event()

    def slow(robot: str) -> None:
        held.set()
        release.wait(DEADLINE)

    limit = 100_000
    node = ZenohExchange(fleet, endpoint_config(port, "fusion"), "fusion", on_update=slow, max_pending_bytes=limit)
    robot = ZenohExchange(fleet, endpoint_config(port, "robot"), "robot", full_every=10)
    try:
        source = SyntheticRobot("robot1", 0, grow=10)
        first = source.step()

        def first_update_holds_the_worker() -> bool:  # puts before the route to the node exists are lost
            robot.publish("robot1", first, 0.0)
            return held.wait(0.2)

        wait_until(first_update_holds_the_worker, "the node's worker held by the first update")
        peak = largest = 0
        for step in range(40):
            last = source.step()
            robot.publish("robot1", last, float(step))
            largest = max(largest, len(mapwire.encode_full("robot1", "0" * 16, step, 0.0, last)))
            peak = max(peak, node.pending_bytes)
        wait_until(lambda: node.dropped["queue full"] > 0, "the oldest updates dropped")
        peak = max(peak, node.pending_bytes)
        assert peak <= limit + largest  # the bound, plus at most the one message that went over it
        release.set()
        next_status = time.monotonic()

        def latest_map_held() -> bool:
            nonlocal next_status
            if time.monotonic() >= next_status:
                next_status += 1.0
                robot.publish_status("robot1", 40.0, landmarks=len(last))
            held = node.receive().get("robot1")
            return held is not None and np.array_equal(held.landmark_map.ids, last.ids)

        wait_until(latest_map_held, "the latest map")
        np.testing.assert_array_equal(node.receive()["robot1"].landmark_map.positions, last.positions)
    finally:
        release.set()
        robot.close()
        node.close()


def test_a_status_travels_ahead_of_the_maps():
    """Zenoh queues each priority apart and drops a DROP message that waits for room: a status sent at the maps'
    priority waits behind a large map's fragments and is lost with it (benchmarks/fleet_status_priority.py: 5 of
    6 trials of 200 lost statuses at the maps' priority, none one step above). A status names the map that exists,
    so it goes one step above: what a receiver sees on the wire."""
    import zenoh

    port, fleet = free_port(), f"prio{os.getpid()}"
    with ZenohExchange(fleet, endpoint_config(port, "fusion"), "fusion") as node, \
            ZenohExchange(fleet, endpoint_config(port, "robot"), "robot") as robot:
        maps = node.session.declare_subscriber(f"p3at/{fleet}/robot1/map", zenoh.handlers.RingChannel(64))
        statuses = node.session.declare_subscriber(f"p3at/{fleet}/robot1/status", zenoh.handlers.RingChannel(64))
        source = SyntheticRobot("robot1", 0)
        got: dict[str, object] = {}

        def both_seen() -> bool:  # puts before the route to the node exists are lost
            robot.publish("robot1", source.step(), 0.0)
            for name, channel in (("map", maps), ("status", statuses)):
                while (sample := channel.try_recv()) is not None:
                    got[name] = sample.priority
            return len(got) == 2

        wait_until(both_seen, "a map and a status of robot1 on the wire")
        assert got == {"map": zenoh.Priority.DATA, "status": zenoh.Priority.DATA_HIGH}


# A robot process that never closes its exchange: it publishes its map until it receives the node's stream, then
# exits.
UNCLOSED_ROBOT = """
import sys, time
from runtime.fleet.synthetic import SyntheticRobot
from runtime.fleet.zenoh_exchange import ZenohExchange
exchange = ZenohExchange(sys.argv[1], sys.argv[2], "robot")
end = time.monotonic() + 60.0
while "robot1" not in exchange.receive() and time.monotonic() < end:
    exchange.publish("robot9", SyntheticRobot("robot9", 3, grow=30).step(), 0.0)
    time.sleep(0.05)
print("received" if "robot1" in exchange.receive() else "nothing received", flush=True)
"""


def test_a_process_that_exits_without_closing_its_exchange_exits_while_maps_stream_in():
    """The exchange's own threads are stopped and joined at exit (before the interpreter finalizes), and Zenoh
    holds no thread of Python's: a process that never calls close exits, with code 0, while the node's updates
    are still arriving. (With Python callbacks, zenoh's callback threads kept such a process alive for ever.)
    The node streams once the child's map has come: the child stops putting it when the stream reaches it, and a
    put before the route to the node exists is lost (the child put it once or twice before it had the stream: a
    lost last put left the node without robot9 for good)."""
    port, fleet = free_port(), f"unclosed{os.getpid()}"
    stop = threading.Event()
    with ZenohExchange(fleet, endpoint_config(port, "fusion"), "fusion", full_every=1) as node:
        source = SyntheticRobot("robot1", 0, grow=30)

        def stream() -> None:  # once robot9 has come: full snapshots, 20 a second, until the child has gone
            while not stop.is_set() and "robot9" not in node.receive():
                stop.wait(0.05)
            while not stop.is_set():
                node.publish("robot1", source.step(), time.time())
                stop.wait(0.05)

        streamer = threading.Thread(target=stream, daemon=True)
        streamer.start()
        try:
            child = subprocess.Popen([sys.executable, "-c", UNCLOSED_ROBOT, fleet, endpoint_config(port, "robot")],
                                     cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     env={**os.environ, "PYTHONPATH": str(ROOT)})
            try:
                stdout, stderr = child.communicate(timeout=90)  # a hang, not a slow machine: it needs ~3 s
            except subprocess.TimeoutExpired:
                child.kill()
                child.communicate()
                pytest.fail("a process whose exchange was left open did not exit")
        finally:
            stop.set()
            streamer.join()
    assert child.returncode == 0, stderr
    assert stdout.strip() == "received"   # so robot9 had come: the node streams only then
    assert "FATAL" not in stderr


def _bare_session(port: int):
    """A Zenoh session of the test's own, connected to the node like a robot: it sends mapwire messages by hand
    (so a map can be lost on the way for certain: it is simply not sent) and answers queries when the test pumps
    its queryable."""
    import zenoh

    config = zenoh.Config.from_json5(endpoint_config(port, "robot"))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    return zenoh.open(config)


def _answer_queries(queryable, queries: list, answer: bytes | None) -> bool:
    """Answer what the node asked so far (``answer`` None: as a robot with no map, nothing), noting when it asked
    for this robot's map by name (a wildcard query, ``request_snapshot("*")``, is not noted). Whether any came."""
    came = False
    while (query := queryable.try_recv()) is not None:
        came = True
        if "*" not in str(query.key_expr):
            queries.append(time.monotonic())
        if answer is not None:
            query.reply(str(query.key_expr), answer)
        query.drop()
    return came


def test_a_robots_last_map_lost_on_the_wire_is_asked_for_when_its_status_names_it():
    """Map 1 of robot1 never reaches the node (maps go with CongestionControl.DROP) and it is the robot's last, so
    no later delta shows the gap: only its statuses, which name sequence 1, do. The node asks the robot's queryable
    and ends with map 1. (Before session 19 it kept map 0 for ever.)"""
    import zenoh

    port, fleet = free_port(), f"lost{os.getpid()}"
    key, status_key = f"p3at/{fleet}/robot1/map", f"p3at/{fleet}/robot1/status"
    session = mapwire.new_session()
    source = SyntheticRobot("robot1", 0)
    first, last = source.step(), source.step()
    with ZenohExchange(fleet, endpoint_config(port, "fusion"), "fusion") as node, _bare_session(port) as robot:

        def first_map_at_the_node() -> bool:  # puts before the route to the node exists are lost
            robot.put(key, mapwire.encode_full("robot1", session, 0, 0.0, first))
            return "robot1" in node.receive()

        wait_until(first_map_at_the_node, "robot1's map 0 at the node")
        queryable = robot.declare_queryable(key, zenoh.handlers.RingChannel(16))
        queries: list[float] = []
        answer = mapwire.encode_full("robot1", session, 1, 1.0, last)

        def map_1_at_the_node() -> bool:  # map 1 is never put; the statuses say it exists (runtime: once a second)
            _answer_queries(queryable, queries, answer)
            robot.put(status_key, mapwire.encode_status("robot1", session, 1, 1.0, landmarks=len(last)))
            return node.receive()["robot1"].sequence == 1

        wait_until(map_1_at_the_node, "robot1's map 1, named by its status, recovered by query")
        got = node.receive()["robot1"].landmark_map
        np.testing.assert_array_equal(got.ids, last.ids)
        np.testing.assert_array_equal(got.positions, last.positions)
        assert queries, "recovered without a query?"


def test_a_robot_with_no_map_yet_is_not_asked_and_a_missing_map_is_asked_for_ever_less_often():
    """Statuses before a robot's first map (sequence 0, has_map false) name nothing: the node does not ask (asked,
    the queryable answers nothing, and the node would ask again and again). A status that names a map the node
    lacks and no reply brings is asked for after BEHIND_GRACE, then 2 s, 4 s... later: never a storm."""
    import zenoh

    from runtime.fleet.zenoh_exchange import BEHIND_GRACE

    port, fleet = free_port(), f"nomap{os.getpid()}"
    key, status_key = f"p3at/{fleet}/robot1/map", f"p3at/{fleet}/robot1/status"
    session = mapwire.new_session()
    with ZenohExchange(fleet, endpoint_config(port, "fusion"), "fusion") as node, _bare_session(port) as robot:
        queryable = robot.declare_queryable(key, zenoh.handlers.RingChannel(16))
        queries: list[float] = []

        def node_reaches_the_queryable() -> bool:  # so that an ask of the node's could not go unseen below
            node.request_snapshot("*")              # wildcard: not counted, even if one comes late
            return _answer_queries(queryable, queries, None)

        wait_until(node_reaches_the_queryable, "the node's query at robot1's queryable")
        assert queries == []
        stamp = 0.0

        def status_handled(has_map: bool, sequence: int, until: float) -> bool:
            nonlocal stamp
            stamp += 1.0
            robot.put(status_key, mapwire.encode_status("robot1", session, sequence, stamp, has_map=has_map))
            _answer_queries(queryable, queries, None)
            return node.status().get("robot1", {}).get("stamp", -1.0) >= until

        wait_until(lambda: status_handled(False, 0, 0.0), "robot1's first status at the node")
        # statuses sent for three grace periods after the node handled the first: each was a chance to ask
        later = stamp + 1.0
        end = time.monotonic() + 3 * BEHIND_GRACE
        wait_until(lambda: status_handled(False, 0, later) and time.monotonic() >= end, "3 s of statuses")
        wait_until(lambda: status_handled(False, 0, stamp), "the last status without a map handled")
        assert queries == [], f"asked {len(queries)} time(s) for the map of a robot that has none"
        named = time.monotonic()
        wait_until(lambda: status_handled(True, 2, 0.0) and len(queries) >= 3, "three asks for map 2",
                   DEADLINE + 7.0)
        # asked BEHIND_GRACE after the status, then 2x and 4x further on: the third >= 7 s after (every second: 3 s)
        assert queries[2] - named >= 6 * BEHIND_GRACE, [q - named for q in queries]


def test_a_map_still_queued_behind_its_status_is_not_asked_for():
    """A status handled before its map (the pump drains the map channel first, so a map that comes between the two
    drains is queued after its status) while the worker is slower than BEHIND_GRACE: the map is in the queue, not
    lost, and the robot is not asked for it (with a backlog, every robot would be asked for a full snapshot)."""
    import zenoh

    from runtime.fleet.zenoh_exchange import BEHIND_GRACE

    port, fleet = free_port(), f"queued{os.getpid()}"
    session = mapwire.new_session()
    source = SyntheticRobot("robot1", 0)
    first, second = source.step(), source.step()
    gates = {"robot1": threading.Event(), "robot2": threading.Event()}
    held: list[str] = []

    def hook(robot: str) -> None:  # the worker's on_update: it waits at each robot's gate
        held.append(robot)
        gates[robot].wait(DEADLINE)

    def key(robot: str, leaf: str) -> str:
        return f"p3at/{fleet}/{robot}/{leaf}"

    status = mapwire.encode_status("robot1", session, 1, 1.0, landmarks=len(second))
    other = mapwire.encode_full("robot2", mapwire.new_session(), 0, 0.0, replayed("robot2", 1, 1))
    map_1 = mapwire.encode_full("robot1", session, 1, 1.0, second)
    with ZenohExchange(fleet, endpoint_config(port, "fusion"), "fusion", on_update=hook) as node, \
            _bare_session(port) as robot:
        try:
            queryable = robot.declare_queryable(key("robot1", "map"), zenoh.handlers.RingChannel(16))
            queries: list[float] = []

            def reached() -> bool:  # the node's query reached the robot: so did its subscribers' declarations
                node.request_snapshot("*")
                return _answer_queries(queryable, queries, None)

            wait_until(reached, "the node's query at robot1's queryable")
            robot.put(key("robot1", "map"), mapwire.encode_full("robot1", session, 0, 0.0, first))
            wait_until(lambda: held == ["robot1"], "the worker held by robot1's map 0")
            robot.put(key("robot1", "status"), status)  # queued first, alone: a status ahead of its map
            wait_until(lambda: node.pending_bytes == len(status), "robot1's status queued")
            robot.put(key("robot2", "map"), other)
            robot.put(key("robot1", "map"), map_1)
            wait_until(lambda: node.pending_bytes == len(status) + len(other) + len(map_1), "both maps queued")
            gates["robot1"].set()  # the status is handled, then robot2's map holds the worker
            wait_until(lambda: held == ["robot1", "robot2"] and "robot1" in node.status(), "the status handled")
            handled = time.monotonic()
            wait_until(lambda: time.monotonic() >= handled + 2 * BEHIND_GRACE, "two grace periods")
            gates["robot2"].set()
            wait_until(lambda: node.receive()["robot1"].sequence == 1, "robot1's map 1 from the queue")
            # a last wildcard query: whatever the node asked before it has reached the robot by its end
            wait_until(reached, "the node's last query at robot1's queryable")
            assert queries == [], "robot1 was asked for a map that was in the queue"
        finally:
            for gate in gates.values():
                gate.set()


def _flush(node, queryable, queries: list, answer: bytes | None) -> None:
    """A wildcard query of the test's own: once it has come, every ask the node sent before it has come too."""
    def reached() -> bool:
        node.request_snapshot("*")
        return _answer_queries(queryable, queries, answer)

    wait_until(reached, "the node's wildcard query at robot1's queryable")


def test_a_gap_and_a_status_naming_a_newer_map_make_one_wait_ended_only_by_the_named_map():
    """A delta whose base was missed (sequence 3) and a status naming a newer map (5) at once: one wait for map 5,
    one series of asks (at once, then 2 s, then 4 s later; before session 20 the gap asked every second beside
    the status's own asks), and a reply with an older map (2, newer than the one held) does not end it."""
    import zenoh

    from runtime.fleet.zenoh_exchange import BEHIND_GRACE

    port, fleet = free_port(), f"merged{os.getpid()}"
    key, status_key = f"p3at/{fleet}/robot1/map", f"p3at/{fleet}/robot1/status"
    source = SyntheticRobot("robot1", 0)
    maps = [source.step() for _ in range(6)]
    encoder = mapwire.MapEncoder("robot1", full_every=100)
    messages = [encoder.encode(m, float(i))[1] for i, m in enumerate(maps)]
    session = encoder.session
    stale = mapwire.encode_full("robot1", session, 2, 2.0, maps[2])
    named = mapwire.encode_full("robot1", session, 5, 5.0, maps[5])
    with ZenohExchange(fleet, endpoint_config(port, "fusion"), "fusion") as node, _bare_session(port) as robot:
        queryable = robot.declare_queryable(key, zenoh.handlers.RingChannel(16))
        queries: list[float] = []

        def map_0_at_the_node() -> bool:  # puts before the route to the node exists are lost
            _answer_queries(queryable, queries, None)
            robot.put(key, messages[0])
            return "robot1" in node.receive()

        wait_until(map_0_at_the_node, "robot1's map 0 at the node")
        _flush(node, queryable, queries, None)
        queries.clear()
        start = time.monotonic()
        robot.put(key, messages[3])  # its base, map 2, never sent
        robot.put(status_key, mapwire.encode_status("robot1", session, 5, 5.0, landmarks=len(maps[5])))
        wait_until(lambda: _answer_queries(queryable, queries, stale) and queries, "the first ask")
        wait_until(lambda: node.receive()["robot1"].sequence == 2, "the older map 2 of the reply held")

        def asked(n: int) -> bool:
            _answer_queries(queryable, queries, stale)
            return len(queries) >= n

        wait_until(lambda: asked(3), "the wait goes on asking after the older reply", DEADLINE + 7.0)
        # one series: at once, then 2 s and 4 s on (each ask is seen after it was sent: never earlier)
        assert queries[2] - start >= 6 * BEHIND_GRACE, [q - start for q in queries]
        assert node.receive()["robot1"].sequence == 2
        wait_until(lambda: _answer_queries(queryable, queries, named) or node.receive()["robot1"].sequence == 5,
                   "map 5, named by the status, by a reply", DEADLINE + 16.0)
        wait_until(lambda: node.receive()["robot1"].sequence == 5, "map 5 at the node")
        np.testing.assert_array_equal(node.receive()["robot1"].landmark_map.ids, maps[5].ids)


def test_a_robot_that_left_is_no_longer_asked_for_a_missed_map():
    """A delta whose base was missed starts a wait; the robot's liveliness token goes (it left): the wait ends
    with it, and the node does not ask again (before session 20 it asked every second for ever). The test keeps
    the robot's queryable up, so that an ask would be seen."""
    import zenoh

    port, fleet = free_port(), f"gone{os.getpid()}"
    key = f"p3at/{fleet}/robot1/map"
    source = SyntheticRobot("robot1", 0)
    encoder = mapwire.MapEncoder("robot1", full_every=100)
    first, second = (encoder.encode(source.step(), float(i))[1] for i in range(2))
    events: list[str] = []
    with ZenohExchange(fleet, endpoint_config(port, "fusion"), "fusion", on_event=events.append) as node, \
            _bare_session(port) as robot:
        queryable = robot.declare_queryable(key, zenoh.handlers.RingChannel(16))
        token = robot.liveliness().declare_token(f"p3at/{fleet}/robot1/alive")
        queries: list[float] = []
        wait_until(lambda: "robot1" in node.present(), "robot1 present at the node")
        _flush(node, queryable, queries, None)
        queries.clear()

        def gap_asked() -> bool:  # puts before the route to the node exists are lost
            robot.put(key, second)  # its base, map 0 (``first``), never sent
            _answer_queries(queryable, queries, None)
            return bool(queries)

        wait_until(gap_asked, "the node's ask for robot1's snapshot after the gap")
        assert node.dropped["gap"] > 0 and first
        token.undeclare()
        wait_until(lambda: "robot1 left the fleet" in events, "robot1's leave at the node")
        _flush(node, queryable, queries, None)  # every ask sent before the leave has come
        queries.clear()
        end = time.monotonic() + 6.0  # the wait's next asks would have come 2 s and 6 s after its first
        wait_until(lambda: time.monotonic() >= end and not _answer_queries(queryable, queries, None), "6 s")
        _flush(node, queryable, queries, None)
        assert queries == [], f"asked {len(queries)} time(s) for the map of a robot that left"
