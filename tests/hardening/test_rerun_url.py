"""A `--rerun` URL Rerun refuses (session 23): one line naming it, exit 2. Before, `fuse --live` and `slam dataset`
(after its run) ended in exit 70, `internal error: RuntimeError: invalid endpoint ...`."""
from __future__ import annotations

import json

import pytest

from runtime.fleet.processes import free_port
from tests.datasets.conftest import run_cli

BAD = "rerun+http://256.0.0.1:99999/proxy"


def test_open_recording_says_a_bad_url_as_a_viewer_error() -> None:
    from runtime.rerun_log import ViewerError, open_recording

    with pytest.raises(ViewerError, match=r"^--rerun rerun\+http://256\.0\.0\.1:99999/proxy: .*invalid") as info:
        open_recording(BAD)
    assert "\n" not in str(info.value)


def test_fuse_live_with_a_bad_rerun_url_is_exit_2(tmp_path) -> None:
    config = tmp_path / "node.json5"
    config.write_text(json.dumps({"listen": {"endpoints": [f"tcp/127.0.0.1:{free_port()}"]}}))
    status, _, err = run_cli("fuse", "--live", "--exchange", f"zenoh:{config}", "--seconds", "1", "--rerun", BAD)
    assert status == 2 and f"--rerun {BAD}" in err and "internal error" not in err, err
