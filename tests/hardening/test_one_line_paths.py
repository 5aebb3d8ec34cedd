"""An error that names a path holding a newline stays one line (session 25, C): the commands print their own
errors, and `p3at fuse a.npz $'no\\nsuch.npz'` printed two lines. While a command runs, a newline inside one write
to stderr is written as '\\n'; the newline that ends a message is kept."""
from __future__ import annotations

import sys

import pytest
from hypothesis import given
from hypothesis import strategies as st

from runtime.cli import _OneLineWrites, main
from tests.datasets.conftest import run_cli


@pytest.mark.parametrize("argv", [
    ["fuse", "no\nsuch.npz", "b.npz", "--out", "f.npz"],
    ["calib", "show", "no\nsuch.ini"],
    ["replay", "no\nlog"],
    ["slam", "simulate", "--seconds", "1", "--out", "m.npz", "--world", "no\nworld.json"],
    ["scanmatch", "no\nlog.gz"],
], ids=lambda argv: argv[0])
def test_an_error_naming_a_path_with_a_newline_is_one_line(argv, tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    status, _, err = run_cli(*argv)
    assert status == 2 and err.count("\n") == 1 and err.endswith("\n") and "no\\n" in err, (status, err)


def test_stderr_is_given_back_after_the_command(capsys) -> None:
    before = sys.stderr
    main(["calib", "show", "no\nsuch.ini"])
    assert sys.stderr is before
    assert capsys.readouterr().err.count("\n") == 1


@given(parts=st.lists(st.text(alphabet=st.characters(blacklist_categories=("Cs",)), max_size=6)
                     .filter(lambda text: not text.endswith("\n")), max_size=6))
def test_each_write_is_one_line_and_keeps_its_text(parts) -> None:
    """print(text) writes text, then its end: each is one line (a text that itself ends in a newline keeps it: the
    stream cannot tell it from print's end)."""
    import io

    sink = io.StringIO()
    stream = _OneLineWrites(sink)
    for part in parts:
        stream.write(part)
        stream.write("\n")
    lines = sink.getvalue().split("\n")[:-1]
    assert len(lines) == len(parts)
    assert [line.replace("\\n", "\n") for line in lines] == [p.replace("\\n", "\n") for p in parts]


def test_a_warning_is_one_line_in_the_commands_words(monkeypatch, capsys) -> None:
    """Python prints a warning as two lines (file:line: Category: message, then the source line): `robot drive --vel
    5` printed two per clamped command. While a command runs, a warning is `p3at COMMAND: warning: message`."""
    import warnings

    def handler(args) -> int:
        warnings.warn("velocity 5 m/s is outside [-1.2, 1.2] m/s; clamped to 1.2", UserWarning, stacklevel=1)
        warnings.warn("invalid value encountered in cast", RuntimeWarning, stacklevel=1)
        return 0

    monkeypatch.setattr("runtime.commands.calib.run_show", handler)
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        before = warnings.showwarning
        assert main(["calib", "show", "x.ini"]) == 0
        assert warnings.showwarning is before     # given back when the command ends
    assert capsys.readouterr().err.splitlines() == [
        "p3at calib: warning: velocity 5 m/s is outside [-1.2, 1.2] m/s; clamped to 1.2",
        "p3at calib: warning: invalid value encountered in cast"]


def test_a_developers_run_keeps_pythons_own_output(capsys, monkeypatch) -> None:
    """P3AT_DEBUG=1 (tracebacks wanted): stderr is not rewritten, so a traceback or a path keeps its newlines."""
    monkeypatch.setenv("P3AT_DEBUG", "1")
    main(["calib", "show", "no\nsuch.ini"])
    assert "no\nsuch.ini" in capsys.readouterr().err
