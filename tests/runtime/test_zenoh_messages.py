"""Zenoh's errors end with where in its Rust sources they were made (" at /root/.cargo/git/.../lib.rs:183."): the
fleet's one-line messages leave that out (runtime/fleet/zenoh_exchange.py ``zenoh_message``)."""
from __future__ import annotations

import json

import pytest

zenoh = pytest.importorskip("zenoh")

from runtime.cli import main  # noqa: E402
from runtime.fleet.zenoh_exchange import zenoh_message  # noqa: E402

_CARGO = "/root/.cargo/git/checkouts/zenoh-9c599d5ef3e0480e/cc83980"

# str() of ZErrors raised by zenoh 1.x (captured in session 13: a bad endpoint, a port in use, a missing file, an
# inline JSON5 syntax error, a bad value)
CAPTURED = [
    (f"Unicast not supported for foo protocol at {_CARGO}/io/zenoh-link/src/lib.rs:183.",
     "Unicast not supported for foo protocol"),
    (f"failed to lookup address information: Name or service not known at {_CARGO}/io/zenoh-link-commons/src/"
     "lib.rs:62.", "failed to lookup address information: Name or service not known"),
    (f"Can not create a new TCP listener bound to tcp/127.0.0.1:47991: [127.0.0.1:47991: Address already in use (os "
     f"error 98) at {_CARGO}/io/zenoh-link-commons/src/tcp.rs:61.] at {_CARGO}/io/zenoh-links/zenoh-link-tcp/src/"
     "unicast.rs:338.", "Can not create a new TCP listener bound to tcp/127.0.0.1:47991: [127.0.0.1:47991: Address "
     "already in use (os error 98)]"),
    (f"No such file or directory (os error 2) at {_CARGO}/commons/zenoh-config/src/lib.rs:1507.",
     "No such file or directory (os error 2)"),
    (" --> 2:26\n  |\n2 |   listen: {endpoints: [1,}}\n  |                          ^---\n  |\n  = expected array, "
     "boolean, null, number, object, or string",
     "line 2 column 26: expected array, boolean, null, number, object, or string"),
    ("invalid type: integer `12`, expected either 'router', 'peer' or 'client'",
     "invalid type: integer `12`, expected either 'router', 'peer' or 'client'"),
]


@pytest.mark.parametrize(("text", "said"), CAPTURED)
def test_captured_zenoh_errors_lose_their_rust_source_paths(text, said):
    assert zenoh_message(Exception(text)) == said


@pytest.mark.parametrize("endpoint", ["foo/bar", "tcp/no-such-host.invalid:7447"])
def test_the_live_node_s_one_line_on_an_unusable_endpoint_has_no_rust_path(endpoint, capsys):
    """A real ZError through the CLI: the fusion node cannot listen where the configuration says."""
    config = json.dumps({"listen": {"endpoints": [endpoint]}, "scouting": {"multicast": {"enabled": False}}})
    code = main(["fuse", "--live", "--exchange", f"zenoh:{config}", "--seconds", "0.1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith("p3at fuse: cannot open the Zenoh session (") and ".rs:" not in err[0], err


def test_a_json5_syntax_error_is_one_line_with_its_place(capsys):
    code = main(["fuse", "--live", "--exchange", 'zenoh:{mode: "peer",\n listen: {endpoints: [1,}}', "--seconds",
                 "0.1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert "not a valid Zenoh configuration (line 2 column" in err[0] and "expected array" in err[0], err
