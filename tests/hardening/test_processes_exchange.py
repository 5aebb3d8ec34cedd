"""`p3at demo --processes` with `--exchange` or `--fleet`: refused in one line, exit 2, before any process starts.
Session 23 found both ignored in silence: the demo's robots and its fusion node always meet on a loopback port and a
fleet name of their own (runtime/fleet/processes.py), whatever the user asked. A fleet on the user's own exchange is
`p3at run --exchange ...` per robot and `p3at fuse --live` (docs/fleet.md)."""
from __future__ import annotations

import pytest

from tests.datasets.conftest import run_cli


@pytest.mark.parametrize("given", [["--exchange", "zenoh"], ["--exchange", "zenoh:{listen: {endpoints: []}}"],
                                   ["--exchange", "inprocess"], ["--fleet", "lab"],
                                   ["--exchange", "zenoh", "--fleet", "lab"]], ids=" ".join)
def test_demo_processes_refuses_an_exchange_or_fleet_it_would_ignore(given, tmp_path) -> None:
    out = tmp_path / "out"
    status, stdout, err = run_cli("demo", "--processes", *given, "--seconds", "1", "--quiet", "--out", str(out))
    named = [option for option in ("--exchange", "--fleet") if option in given]
    assert status == 2 and err.count("\n") == 1 and err.startswith(f"p3at demo: {' and '.join(named)} ") and \
        "p3at fuse --live" in err, err
    assert stdout == "" and not out.exists()


def test_the_in_process_demo_still_takes_them(tmp_path) -> None:
    """Without --processes the options keep their meaning (a bad one is still said as before)."""
    status, _, err = run_cli("demo", "--exchange", "carrier-pigeon", "--seconds", "1", "--quiet", "--out",
                             str(tmp_path / "out"))
    assert status == 2 and "--exchange must be inprocess, zenoh or zenoh:CONFIG" in err, err
