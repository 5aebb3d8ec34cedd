"""A binary file given as a world (a landmark map .npz, an easy slip beside `--out MAP`) says what was expected:
`p3at slam simulate --world robot1.npz` said only "not UTF-8 text: 'utf-8' codec can't decode byte 0x8a ..."
(session 48's walkthrough of docs/world.md and docs/fastslam.md)."""
from __future__ import annotations

import contextlib
import io

import numpy as np

from estimation.landmark_map import LandmarkMap
from runtime.cli import main


def test_a_map_given_as_the_world_is_named_not_a_world_file(tmp_path):
    landmark_map = LandmarkMap(np.zeros((2, 3)), np.tile(np.eye(3), (2, 1, 1)), np.zeros((2, 64), np.float32),
                               robot="robot1")
    path = tmp_path / "robot1.npz"
    landmark_map.save(path)
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main(["slam", "simulate", "--out", str(tmp_path / "m.npz"), "--world", str(path)])
    assert status == 2 and out.getvalue() == "" and err.getvalue().count("\n") == 1
    assert f"{path}: not UTF-8 text: a world file is JSON text (" in err.getvalue(), err.getvalue()
