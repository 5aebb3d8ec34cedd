"""A mode the head does not offer: the list of those it does is in numeric order (session 48, D). It was sorted as
text ("1024x768@15, 1024x768@3.75, 1024x768@7.5, 1280x960@3.75, ..., 320x240@15, 320x240@3.75, 320x240@30"), so
the smallest size came last and 15 Hz before 3.75 Hz."""
from __future__ import annotations

from runtime.cli import main


def test_the_offered_modes_are_listed_by_size_then_rate(tmp_path, capsys):
    assert main(["camera", "grab", "--mock", "--mode", "800x600", "--out", str(tmp_path / "g")]) == 1
    err = capsys.readouterr().err.strip()
    assert err.endswith("it offers 320x240@3.75, 320x240@7.5, 320x240@15, 320x240@30, 640x480@3.75, 640x480@7.5, "
                        "640x480@15, 640x480@30, 1024x768@3.75, 1024x768@7.5, 1024x768@15, 1280x960@3.75, "
                        "1280x960@7.5"), err
