"""``p3at run --robot URL``: a ``--camera`` the user gives is kept as given. ``--camera mock`` beside a robot URL (a
robot served by ``p3at robot serve``, MobileSim) was silently turned into ``--camera usb``, so the user who asked for
the virtual head got "no USB backend ... or try --mock" (exit 1, after connecting to the robot); now it is refused
before anything starts, naming why, as ``--camera synthetic`` already was."""
from __future__ import annotations

import pytest

from runtime.cli import main
from runtime.fleet.processes import free_port


@pytest.mark.parametrize("camera", ["mock", "synthetic"])
def test_a_virtual_head_beside_a_robot_url_is_refused_as_asked(camera, tmp_path, capsys):
    url = f"socket://127.0.0.1:{free_port()}"
    code = main(["run", "--robot", url, "--camera", camera, "--quiet", "--rerun", "none",
                 "--out", str(tmp_path / "out")])
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert code == 2 and len(err) == 1, (code, err)
    assert err[0].startswith(f"p3at run: --robot {url}: a robot given by URL needs a real stereo head (--camera usb)")
    assert not (tmp_path / "out").exists()


def test_the_help_says_which_camera_runs_by_default(capsys):
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    assert "(default mock; usb with --robot URL)" in " ".join(capsys.readouterr().out.split())
