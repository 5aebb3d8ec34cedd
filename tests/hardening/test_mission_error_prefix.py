"""``p3at run``/``demo``'s own errors name the command (session 26, C): a bad ``--exchange`` (and a setting the
mission refuses, and 'mission failed') said ``p3at: ...`` while every other command says ``p3at COMMAND: ...``."""
from __future__ import annotations

import pytest

from tests.datasets.conftest import run_cli


@pytest.mark.parametrize("command", ["run", "demo"])
def test_a_bad_exchange_is_one_line_named_by_its_command(command, tmp_path) -> None:
    status, stdout, stderr = run_cli(command, "--camera", "synthetic", "--exchange", "zenoh:BAD", "--quiet",
                                     "--rerun", "none", "--out", str(tmp_path / "out"))
    assert status == 2 and stdout == ""
    assert stderr.splitlines() == [f"p3at {command}: BAD: no such Zenoh configuration file"]
    assert not (tmp_path / "out").exists()


def test_a_setting_the_mission_refuses_is_named_by_its_command(tmp_path) -> None:
    status, _, stderr = run_cli("run", "--camera", "synthetic", "--time-scale", "2", "--quiet", "--rerun", "none",
                                "--out", str(tmp_path / "out"))
    assert status == 2 and stderr.startswith("p3at run: --time-scale needs --realtime"), stderr
