"""The runtime's bounded text read (runtime/textfile.py) and the readers built on it: the text or one line
naming the file, never more than the bound read, whatever the path is."""
from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from runtime.motion import RouteFileError, load_route
from runtime.textfile import read_bounded_text
from runtime.trajectories import TrajectoryFileError, read_tum


class Refused(ValueError):
    pass


@settings(max_examples=200, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(raw=st.binary(max_size=64) | st.text(max_size=32).map(lambda t: t.encode("utf-8", "surrogatepass")),
       max_bytes=st.integers(0, 64), encoding=st.sampled_from(["utf-8", "ascii"]))
def test_the_text_or_one_line_naming_the_file(tmp_path, raw, max_bytes, encoding):
    path = tmp_path / "f.txt"
    path.write_bytes(raw)
    try:
        text = read_bounded_text(path, max_bytes, "test file", Refused, encoding=encoding)
    except Refused as e:
        message = str(e)
        assert message.startswith(f"{path}: ") and "\n" not in message
        if len(raw) > max_bytes:
            assert f"{len(raw)} bytes; a test file has at most {max_bytes}" in message
        else:
            assert "not a text file" in message
            with pytest.raises(UnicodeDecodeError):
                raw.decode(encoding)
        return
    assert len(raw) <= max_bytes and text == raw.decode(encoding)


def test_a_missing_file_and_a_folder_are_one_line(tmp_path):
    with pytest.raises(Refused, match=r"absent\.txt: no such test file$"):
        read_bounded_text(tmp_path / "absent.txt", 100, "test file", Refused)
    with pytest.raises(Refused, match=r": cannot read the test file \(Is a directory\)$"):
        read_bounded_text(tmp_path, 100, "test file", Refused)


@pytest.mark.skipif(not Path("/dev/zero").exists(), reason="no /dev/zero here")
def test_a_path_without_end_is_refused_after_the_bound():
    """/dev/zero says its size is 0 and never ends: only max_bytes + 1 bytes are read, then it is refused."""
    with pytest.raises(Refused, match="/dev/zero: more than 1000 bytes; a test file has at most 1000"):
        read_bounded_text("/dev/zero", 1000, "test file", Refused)


def test_the_tum_and_route_readers_say_so_in_their_own_error(tmp_path):
    binary = tmp_path / "binary"
    binary.write_bytes(b"0 0\n\xff\xfe\n")
    with pytest.raises(TrajectoryFileError, match=r"binary: not a text file \(byte 4 is not ASCII\)"):
        read_tum(binary)
    with pytest.raises(RouteFileError, match=r"binary: not a text file \(byte 4 is not UTF-8\)"):
        load_route(binary)
    with pytest.raises(RouteFileError, match=r"r\.route: no such route file"):
        load_route(tmp_path / "r.route")
