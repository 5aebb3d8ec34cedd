"""`p3at robot info` of a robot whose SYNC2 name or CONFIG text fields hold control characters (session 44, A): a
damaged or hostile packet (checksums good, text garbage) was printed raw, newlines and escape sequences included,
so the robot's bytes moved the user's cursor, cleared the screen or added lines. The text output now shows every
character that does not print as \\xNN, on the lines it belongs to; --json keeps the strings exactly (JSON escapes
them)."""
from __future__ import annotations

import json
import socket
import threading
import time

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.arcos.codec import (
    Identity,
    PacketParser,
    RobotConfig,
    Sip,
    encode_config,
    encode_identity,
    encode_packet,
    encode_sip,
)
from tests.datasets.conftest import run_cli

NAME = "robot\x1b[2J\nEVIL"             # clear-screen escape, then a second line
CONFIG_TYPE = "Pioneer\r\x9b31mX\x07"    # carriage return, a C1 CSI, a bell


@pytest.fixture
def hostile_peer():
    """socket://127.0.0.1:PORT of an ARCOS peer that answers the handshake with NAME, sends a CONFIG whose type is
    CONFIG_TYPE when asked, and SIPs every 10-20 ms (`robot info` waits a sonar round counted in SIPs, 23: at a
    real robot's 100 ms, plus this loop's 100 ms reads, that was 4 s of every test)."""
    server = socket.create_server(("127.0.0.1", 0))
    stop = threading.Event()

    def serve() -> None:
        try:
            conn, _ = server.accept()
        except OSError:
            return
        conn.settimeout(0.01)
        parser, synced, opened = PacketParser(), False, False
        while not stop.is_set():
            try:
                data = conn.recv(4096)
            except TimeoutError:
                data = b""
            except OSError:
                break
            for payload in parser.feed(data):
                if not synced and payload[0] in (0, 1):   # SYNC0, SYNC1: echoed
                    conn.sendall(encode_packet(bytes([payload[0]])))
                elif not synced and payload[0] == 2:      # SYNC2: the identity
                    conn.sendall(encode_packet(encode_identity(Identity(NAME, "Pioneer", "p3at-sh"))))
                    synced = True
                elif payload[0] == 1:                     # OPEN: the SIPs start
                    opened = True
                elif payload[0] == 18:                    # CONFIG request
                    conn.sendall(encode_packet(encode_config(RobotConfig(type=CONFIG_TYPE, subtype="p3at-sh",
                                                                         serial_num="1\n2"))))
            if opened:
                try:
                    conn.sendall(encode_packet(encode_sip(Sip(battery=125))))
                except OSError:
                    break
                time.sleep(0.01)
        conn.close()

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    yield f"socket://127.0.0.1:{server.getsockname()[1]}"
    stop.set()
    server.close()
    thread.join(timeout=5)


def test_the_robots_text_is_shown_escaped_on_its_lines(hostile_peer):
    status, out, err = run_cli("robot", "info", hostile_peer)
    assert status == 0, err
    assert "\x1b" not in out and "\r" not in out and "\x9b" not in out and "\x07" not in out
    lines = out.splitlines()
    assert lines[0].startswith(r"robot     robot\x1b[2J\x0aEVIL  (Pioneer p3at-sh)"), lines[0]
    config = next(line for line in lines if line.startswith("config"))
    assert r"type=Pioneer\x0d\x9b31mX\x07" in config and r"serial_num=1\x0a2" in config
    assert [line.split()[0] for line in lines] == ["robot", "params", "config", "pose", "battery", "sonar"]


def test_json_keeps_the_strings_exactly(hostile_peer):
    status, out, _ = run_cli("robot", "info", hostile_peer, "--json")
    data = json.loads(out)
    assert status == 0 and data["identity"]["name"] == NAME and data["config"]["type"] == CONFIG_TYPE


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.binary(max_size=60))
def test_any_text_the_robot_sends_shows_on_one_line_and_printable(raw):
    from runtime.terminal import printable

    text = raw.decode("latin-1")   # what the codec makes of a string field
    shown = printable(text)
    assert shown.isprintable() and len(shown.splitlines()) <= 1
    assert shown == text or any(not c.isprintable() for c in text)
