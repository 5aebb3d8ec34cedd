"""``--recording-id`` (``p3at run``, ``p3at demo``, ``p3at fuse --live``) is the one Rerun recording id a fleet's
processes share. An empty id fell through to a new random one without a word (session 48), and the node's and the
robots' files then no longer read as one recording; an id is now printable text of 1 to 256 characters, refused
otherwise in one line before anything runs (exit 2)."""
from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

import runtime.cli as cli
from tests.runtime.test_cli_numbers import parse_only  # noqa: F401 (a fixture: main with handlers that only parse)

COMMANDS = {"run": ["run"], "demo": ["demo"], "fuse --live": ["fuse", "--live"]}


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize("bad", ["", "   ", "lab\t1", "lab\n1", "x" * 257])
def test_a_recording_id_that_names_no_shared_recording_is_refused(command, bad, parse_only, capsys):  # noqa: F811
    code = cli.main([*COMMANDS[command], "--recording-id", bad])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and not parse_only
    assert len(err) == 1 and "--recording-id" in err[0] and "printable text of 1 to 256 characters" in err[0], err


@pytest.mark.parametrize("command", COMMANDS)
def test_a_printable_recording_id_reaches_the_command_unchanged(command, parse_only, capsys):  # noqa: F811
    @given(st.text(st.characters(codec="utf-8", exclude_categories=("Cc", "Cs", "Cf", "Co", "Cn", "Zl", "Zp", "Zs")),
                   min_size=1, max_size=256))
    def reaches(text):
        parse_only.clear()
        assert cli.main([*COMMANDS[command], f"--recording-id={text}"]) == 0, capsys.readouterr().err
        assert parse_only[0].recording_id == text

    reaches()
