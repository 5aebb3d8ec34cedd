"""`p3at slam simulate` and `p3at slam dataset` refuse an --out that holds a noise model, a Rerun recording or a sensor
log, or has one of their suffixes: `p3at slam dataset ... --out robot1.toml` wrote the map over the robot's noise
model, exit 0 (session 48's walkthrough of docs/fastslam.md). One line, exit 2, the file untouched."""
from __future__ import annotations

import contextlib
import io

import pytest

from runtime.cli import main

NOISE = b'# p3at-fusion noise model: read by `p3at slam dataset --noise`\nformat = "p3at-noise-model"\n'


def _run(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main(list(argv))
    return status, out.getvalue(), err.getvalue()


@pytest.mark.parametrize(("name", "content", "complaint"), [
    ("robot1.toml", NOISE, "--out {out} holds a noise model (TOML): a map would overwrite it; give MAP.npz"),
    ("noise", NOISE, "--out {out} holds a noise model (TOML)"),
    ("mission.rrd", b"RRF2 a recording", "--out {out} holds a Rerun recording: a map would overwrite it"),
    ("new.toml", None, "--out {out}: .toml is a noise model's suffix, and a map is an .npz archive; give MAP.npz"),
])
@pytest.mark.parametrize("command", [["slam", "simulate", "--seconds", "1"],
                                     ["slam", "dataset", "mrclam", "FOLDER", "--robot", "1"],
                                     ["fuse", "a.npz", "b.npz"], ["fuse", "--live"]])   # the lead, after coord-E #5
def test_a_map_is_not_written_over_another_kind_of_file(tmp_path, command, name, content, complaint):
    out = tmp_path / name
    if content is not None:
        out.write_bytes(content)
    folder = tmp_path / "data"
    folder.mkdir()
    status, stdout, err = _run(*[str(folder) if a == "FOLDER" else a for a in command], "--out", str(out))
    assert status == 2 and stdout == "" and err.count("\n") == 1, err
    assert complaint.format(out=out) in err, err
    assert (out.read_bytes() == content) if content is not None else not out.exists()
