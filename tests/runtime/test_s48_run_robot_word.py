"""``p3at run --robot WORD`` where WORD is neither mock, a URL nor a path (session 48, D): a mistyped ``mock`` was
taken for a serial device, and the command's first words were about the USB head ("no USB backend to look for
stereo head ...", exit 1), naming neither --robot nor the typo. Now one line naming the option, exit 2, nothing
written."""
from __future__ import annotations

import pytest

from runtime.cli import main


@pytest.mark.parametrize("word, hint", [("mokc", False), ("Mock", True)])
def test_a_robot_that_is_no_device_url_or_mock_is_refused_in_one_line(word, hint, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code = main(["run", "--robot", word, "--quiet", "--rerun", "none", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, (code, err)
    assert err[0].startswith(f"p3at run: --robot {word}: no such robot: give mock")
    assert ("did you mean mock?" in err[0]) == hint
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("word, said", [
    ("", "no such robot: give mock"), ("  ", "no such robot: give mock"),   # Path('') is the current folder
    (" mock", "did you mean mock?"),
    ("http://x:1", "no such robot URL: pyserial knows socket://host:port"),
    ("ftp://host", "no such robot URL: pyserial knows socket://host:port"),
    ("socket://", "a TCP address needs a port from 1 to 65535"),
    ("socket://[::1]:x", "a TCP address needs a port from 1 to 65535"),
])
def test_an_empty_word_or_a_url_no_driver_takes_is_refused_before_the_head_is_looked_for(word, said, tmp_path, capsys,
                                                                                         monkeypatch):
    # helper H: these reached the USB head's absence first ('no USB backend ...', exit 1), never naming --robot
    monkeypatch.chdir(tmp_path)
    code = main(["run", "--robot", word, "--quiet", "--rerun", "none", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, (code, err)
    assert err[0].startswith(f"p3at run: --robot {word}: ") and said in err[0], err
    assert not (tmp_path / "out").exists()
