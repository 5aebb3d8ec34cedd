"""``p3at fuse --live --exchange inprocess`` (session 26, C): an in-process exchange has no robots to hear from, and
the node silently opened Zenoh instead (runtime/fleet/fusion_node.py). It is refused in one line, exit 2, before
anything starts: no exchange opened, no output folder made."""
from __future__ import annotations

from unittest import mock

from tests.datasets.conftest import run_cli


def test_fuse_live_with_the_inprocess_exchange_is_refused_before_anything_starts(tmp_path) -> None:
    out = tmp_path / "new" / "fused.npz"
    with mock.patch("runtime.fleet.options.open_exchange", side_effect=AssertionError("an exchange was opened")):
        status, stdout, stderr = run_cli("fuse", "--live", "--exchange", "inprocess", "--seconds", "1",
                                         "--out", str(out))
    assert status == 2 and stdout == ""
    assert stderr.count("\n") == 1 and stderr.startswith("p3at fuse: --live needs a network exchange"), stderr
    assert "--exchange zenoh" in stderr
    assert not out.parent.exists()
