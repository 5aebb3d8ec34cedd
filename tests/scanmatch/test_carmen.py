"""The CARMEN log reader on good and malformed lines, plain and gzip."""
from __future__ import annotations

import gzip

import numpy as np
import pytest

from estimation.scanmatch import LogFormatError, parse_flaser, read_laser_log


def flaser(ranges, pose=(1.0, 2.0, 0.5), odom=(0.0, 0.0, 0.0), stamp=12.5, host="pippo") -> str:
    numbers = " ".join(f"{r:g}" for r in ranges)
    return (f"FLASER {len(ranges)} {numbers} {pose[0]} {pose[1]} {pose[2]} {odom[0]} {odom[1]} {odom[2]} "
            f"{stamp} {host} {stamp + 0.01}")


def test_parses_a_flaser_line():
    reading = parse_flaser(flaser([1.0, 2.0, 3.0, 50.0], pose=(1.5, -2.0, 0.25), odom=(0.1, 0.2, 0.3)))
    np.testing.assert_allclose(reading.ranges, [1.0, 2.0, 3.0, 50.0])
    np.testing.assert_allclose(reading.pose, [1.5, -2.0, 0.25])
    np.testing.assert_allclose(reading.odometry, [0.1, 0.2, 0.3])
    assert reading.timestamp == 12.5 and reading.hostname == "pippo"
    np.testing.assert_allclose(reading.angles, np.radians([-90.0, -30.0, 30.0, 90.0]))
    scan = reading.scan()
    # The 50 m reading is a dropout; the first beam points to the right (-y), the third 30° left of x.
    np.testing.assert_array_equal(scan.beam_index, [0, 1, 2])
    np.testing.assert_allclose(scan.points[0], [0.0, -1.0], atol=1e-12)
    np.testing.assert_allclose(scan.points[2], [3.0 * np.cos(np.pi / 6), 1.5], atol=1e-12)


def test_reads_gzip_and_skips_other_messages(tmp_path):
    lines = ["# message formats defined: PARAM SYNC ODOM FLASER", "PARAM robot_use_laser on nohost 0",
             "ODOM 0 0 0 0 0 0 0.11 pippo 0.11", flaser([1.0] * 180, stamp=1.0), "NEFF 30",
             "", "SYNC something", flaser([2.0] * 180, stamp=2.0)]
    path = tmp_path / "log.gz"
    with gzip.open(path, "wt") as stream:
        stream.write("\n".join(lines) + "\n")
    readings = read_laser_log(path)
    assert [r.timestamp for r in readings] == [1.0, 2.0]
    assert [r.line for r in readings] == [4, 8]
    plain = tmp_path / "log.txt"
    plain.write_text("\n".join(lines) + "\n")
    assert len(read_laser_log(plain)) == 2


@pytest.mark.parametrize(("line", "complaint"), [
    ("FLASER", "reading count missing"),
    ("FLASER x 1 2", "not an integer"),
    (flaser([1.0, 2.0, 3.0]).replace("FLASER 3", "FLASER 4"), "needs 15 fields, got 14"),
    (flaser([1.0, 2.0, 3.0]).replace(" 2 3 ", " 2 abc ", 1), "range is not a number"),
    (flaser([1.0, 2.0, 3.0], pose=("nope", 0, 0)), "field x is not a number"),
    (flaser([1.0, -2.0, 3.0]), "negative"),
    (flaser([1.0, float("nan"), 3.0]), "non-finite"),
])
def test_malformed_line_names_file_line_and_field(tmp_path, line, complaint):
    path = tmp_path / "bad.log"
    path.write_text(flaser([1.0] * 5) + "\nODOM 0 0 0 0 0 0 0 h 0\n" + line + "\n")
    with pytest.raises(LogFormatError, match=rf"bad\.log:3: .*{complaint}"):
        read_laser_log(path)


def test_log_without_scans_and_unreadable_files_raise(tmp_path):
    empty = tmp_path / "empty.log"
    empty.write_text("PARAM a b c 0\n")
    with pytest.raises(LogFormatError, match="no FLASER lines"):
        read_laser_log(empty)
    fake_gzip = tmp_path / "fake.log.gz"
    fake_gzip.write_bytes(b"FLASER 3 1 2 3 not gzip at all")
    with pytest.raises(LogFormatError, match="fake.log.gz: cannot read"):
        read_laser_log(fake_gzip)
    with pytest.raises(LogFormatError, match="missing.log"):
        read_laser_log(tmp_path / "missing.log")


def test_reads_the_real_logs(laser_data_dir):
    for name, count, beams in (("aces-corrected.log.gz", 440, 180), ("csail-corrected.log.gz", 406, 361)):
        readings = read_laser_log(laser_data_dir / name)
        assert len(readings) == count
        assert all(r.ranges.shape == (beams,) for r in readings)
        assert all(len(r.scan()) > 100 for r in readings[:20])
