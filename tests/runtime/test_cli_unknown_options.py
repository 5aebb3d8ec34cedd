"""An option a command does not have is named with the command that refused it (argparse's top parser said
'p3at: unrecognized arguments: --duration (see p3at --help)' for `p3at fuse --live --duration 1`, pointing the user
at the wrong help)."""
from __future__ import annotations

import pytest

from runtime.cli import main


@pytest.mark.parametrize(("argv", "prog", "extra"), [
    (["fuse", "--live", "--duration", "1"], "p3at fuse", "--duration"),   # 1 is taken as a MAP
    (["slam", "simulate", "--out", "m.npz", "--frobnicate"], "p3at slam simulate", "--frobnicate"),
    (["review", "x.rrd", "--nope"], "p3at review", "--nope"),
    (["robot", "info", "socket://127.0.0.1:1", "extra"], "p3at robot info", "extra"),
    (["calib", "show", "a.yaml", "b.yaml"], "p3at calib show", "b.yaml"),
])
def test_an_unknown_option_names_the_command_and_its_help(argv, prog, extra, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"{prog}: unrecognized arguments: {extra} (see {prog} --help)"]
