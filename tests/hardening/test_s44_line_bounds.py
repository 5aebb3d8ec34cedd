"""Line-by-line readers bound the lines they read, not only the rows they keep (session 44, A). A gzip of blank lines
is tiny and decompresses to hundreds of millions of lines, none of them a row: `p3at slam dataset` spent 77 s on a
200 kB Robot1_Odometry.dat.gz of 200 M newlines before saying "fewer than 2 rows", and `p3at scanmatch` was killed
after 120 s on a 300 kB log of 300 M newlines (memory stayed bounded; time did not). Past 10 M lines of any kind
each reader now stops with one line naming the file and line (3-5 s on those files)."""
from __future__ import annotations

import gzip

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimation.datasets import tables
from estimation.datasets.errors import DatasetError
from estimation.scanmatch import carmen
from estimation.scanmatch.carmen import LogFormatError, read_laser_log

FLASER = "FLASER 3 1.0 1.5 2.0 0.0 0.0 0.0 0.0 0.0 0.0 1.0 host 1.0\n"


@settings(max_examples=25, deadline=None)
@given(rows=st.integers(0, 30), filler=st.integers(0, 60), bound=st.integers(5, 60),
       kind=st.sampled_from(["\n", "# comment\n", "   \n"]))
def test_a_table_is_read_or_refused_by_its_line_count(tmp_path_factory, rows, filler, bound, kind):
    """Rows then blank or comment lines: read whole up to the bound, refused past it (naming the first line over)."""
    path = tmp_path_factory.mktemp("t") / "Robot1_Odometry.dat.gz"
    path.write_bytes(gzip.compress(("".join(f"{t} 0.1 0.0\n" for t in range(rows)) + kind * filler).encode()))
    with pytest.MonkeyPatch.context() as m:
        m.setattr(tables, "MAX_LINES", bound)
        if rows + filler > bound:
            with pytest.raises(DatasetError, match=rf":{bound + 1}: more than {bound} lines"):
                tables.read_table(path, ["time", "v", "w"])
        else:
            table, _ = tables.read_table(path, ["time", "v", "w"])
            assert np.array_equal(table[:, 0], np.arange(rows))


@settings(max_examples=25, deadline=None)
@given(readings=st.integers(1, 20), filler=st.integers(0, 60), bound=st.integers(5, 60))
def test_a_laser_log_is_read_or_refused_by_its_line_count(tmp_path_factory, readings, filler, bound):
    path = tmp_path_factory.mktemp("c") / "log.gz"
    path.write_bytes(gzip.compress((FLASER * readings + "ODOM 0 0 0 0 0 0 1.0 host 1.0\n" * filler).encode()))
    with pytest.MonkeyPatch.context() as m:
        m.setattr(carmen, "MAX_LINES", bound)
        if readings + filler > bound:
            with pytest.raises(LogFormatError, match=rf":{bound + 1}: more than {bound} lines"):
                read_laser_log(path)
        else:
            assert len(read_laser_log(path)) == readings


def test_the_real_bound_stops_a_gzip_of_newlines(tmp_path):
    """10 M + 1 blank lines (a 10 kB file): refused at the bound, in seconds, instead of read through for nothing."""
    path = tmp_path / "Robot1_Odometry.dat.gz"
    path.write_bytes(gzip.compress(b"\n" * (tables.MAX_LINES + 1), compresslevel=9))
    with pytest.raises(DatasetError, match=f"more than {tables.MAX_LINES} lines"):
        tables.read_table(path, ["time", "v", "w"])
