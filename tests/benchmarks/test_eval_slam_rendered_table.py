"""benchmarks/eval_slam_rendered.py's printed table: header, separator and rows come from one column list, so each
line has as many cells as the header (they were written out separately, each grown by hand as columns were added)."""
from __future__ import annotations

from collections import defaultdict

import pytest

from benchmarks.eval_slam_rendered import COLUMNS, main, table


def _cells(line: str) -> list[str]:
    assert line.startswith("| ") or line.startswith("|-"), line
    assert line.endswith("|"), line
    return [c.strip() for c in line[1:-1].split("|")]


def test_every_line_of_the_table_has_the_headers_columns():
    rows = [defaultdict(lambda: 0.25, robot=robot) for robot in ("robot1", "robot2")]  # every score read: 0.25
    header, separator, *lines = table(rows)
    names = _cells(header)
    assert names == [name for name, _ in COLUMNS] and len(set(names)) == len(names)
    assert _cells(separator) == ["---"] * len(names)
    assert [len(_cells(line)) for line in lines] == [len(names)] * 2
    assert [_cells(line)[0] for line in lines] == ["robot1", "robot2"]
    assert _cells(lines[0])[names.index("duplicate fraction")] == "25.0 %"


@pytest.mark.slow
def test_a_short_rendered_run_prints_a_table_whose_rows_match_the_header(capsys):
    pytest.importorskip("mocks.stereo_head.renderer", reason="the virtual stereo head renderer is not installed")
    assert main(["--seconds", "2", "--robots", "robot1,robot2"]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("|")]
    assert len(lines) == 4
    widths = [len(_cells(line)) for line in lines]
    assert widths == [len(COLUMNS)] * 4, widths
    assert [_cells(line)[0] for line in lines[2:]] == ["robot1", "robot2"]
