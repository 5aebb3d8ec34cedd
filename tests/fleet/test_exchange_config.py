"""The Zenoh exchange's configuration: loopback-only defaults with multicast scouting off, a user's file taken
as given, and bad specs or files refused with one line."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("zenoh")

from runtime.fleet.options import parse_exchange_spec  # noqa: E402
from runtime.fleet.zenoh_exchange import ExchangeError, make_config  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


def settings(config) -> dict:
    return {key: json.loads(config.get_json(key)) for key in
            ("mode", "scouting/multicast/enabled", "listen/endpoints", "connect/endpoints")}


def test_defaults_listen_on_loopback_only_with_multicast_scouting_off():
    fusion, robot = settings(make_config(None, "fusion")), settings(make_config(None, "robot"))
    assert fusion == {"mode": "peer", "scouting/multicast/enabled": False,
                      "listen/endpoints": ["tcp/127.0.0.1:7447"], "connect/endpoints": []}
    assert robot == {"mode": "peer", "scouting/multicast/enabled": False,
                     "listen/endpoints": ["tcp/127.0.0.1:0"], "connect/endpoints": ["tcp/127.0.0.1:7447"]}


def test_a_user_file_is_taken_as_given_and_completed_with_the_safe_defaults(tmp_path):
    path = tmp_path / "robot.json5"
    path.write_text('{ connect: { endpoints: ["tls/10.0.0.1:7447"] }, // the base station\n'
                    '  listen: { endpoints: ["tls/10.0.0.7:0"] } }')
    got = settings(make_config(str(path), "robot"))
    assert got["connect/endpoints"] == ["tls/10.0.0.1:7447"] and got["listen/endpoints"] == ["tls/10.0.0.7:0"]
    assert got["scouting/multicast/enabled"] is False and got["mode"] == "peer"
    explicit = settings(make_config('{ scouting: { multicast: { enabled: true } } }', "fusion"))
    assert explicit["scouting/multicast/enabled"] is True  # the user's explicit choice wins


@pytest.mark.parametrize("config, reason", [("/no/such/file.json5", "no such"), ("{ mode: ", "not a valid"),
                                            ('{ "listen": { "endpoints": 7 } }', "not a valid")])
def test_bad_configurations_are_refused_with_a_reason(config, reason):
    with pytest.raises(ExchangeError, match=reason):
        make_config(config, "robot")


def test_exchange_specs():
    assert parse_exchange_spec("inprocess") == ("inprocess", None)
    assert parse_exchange_spec("zenoh") == ("zenoh", None)
    assert parse_exchange_spec("zenoh:/etc/fleet.json5") == ("zenoh", "/etc/fleet.json5")
    for bad in ("dds", "inprocess:x", ""):
        with pytest.raises(ValueError, match="--exchange"):
            parse_exchange_spec(bad)


def test_p3at_run_with_a_bad_exchange_says_so_in_one_line(tmp_path):
    run = subprocess.run([sys.executable, "-m", "runtime.cli", "run", "--camera", "synthetic", "--exchange",
                          "zenoh:/no/such/file.json5", "--out", str(tmp_path)], cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    assert run.returncode == 2
    assert run.stderr.strip().splitlines() == ["p3at run: /no/such/file.json5: no such Zenoh configuration file"]
