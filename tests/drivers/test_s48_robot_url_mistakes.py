"""The ARCOS driver's words for two ordinary URL mistakes (session 48, D), through ``p3at robot info`` and ``p3at
run``: a bare HOST:PORT (pyserial takes it for a file: "No such file or directory", with no word of socket://), and
a socket:// URL without a port or with a bad one (pyserial's "'<=' not supported between instances of 'int' and
'NoneType'"). Nothing listens on the ports used; nothing is opened."""
from __future__ import annotations

import pytest

from runtime.cli import main


def _one_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_a_bare_host_and_port_is_told_its_socket_url(capsys):
    assert main(["robot", "info", "127.0.0.1:8148"]) == 1
    line = _one_line(capsys)
    assert line.startswith("p3at robot info: 127.0.0.1:8148: no such device")
    assert line.endswith("; a TCP address is written socket://127.0.0.1:8148")


@pytest.mark.parametrize("url", ["socket://127.0.0.1", "socket://127.0.0.1:99999", "socket://127.0.0.1:abc",
                                 "socket://localhost:0"])
def test_a_socket_url_without_a_usable_port_says_so(url, capsys):
    assert main(["robot", "info", url]) == 1
    assert _one_line(capsys) == (f"p3at robot info: {url}: a TCP address needs a port from 1 to 65535: "
                                 "socket://HOST:PORT (MobileSim and AMRISim listen on 8101)")


def test_a_device_path_keeps_its_message_without_the_hint(capsys):
    assert main(["robot", "info", "/dev/no-such-tty-s48"]) == 1
    line = _one_line(capsys)
    assert "no such device" in line and "socket://" not in line


def test_run_with_a_bare_host_and_port_suggests_the_socket_url(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code = main(["run", "--robot", "127.0.0.1:8148", "--quiet", "--rerun", "none", "--out", str(tmp_path / "out")])
    assert code == 2
    assert _one_line(capsys).endswith("; did you mean socket://127.0.0.1:8148?")
    assert not (tmp_path / "out").exists()
