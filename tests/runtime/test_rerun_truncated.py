"""A recording cut short (a crash, a kill, a full disk) gives back what it holds, and says it was cut; the frame walker
never reads a payload, never raises anything but ValueError, and finds only real message boundaries."""
from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from runtime.cli import main
from runtime.rerun_read import RecordingReadError, read_recording
from runtime.rrd_salvage import scan_rrd

from .rerun_helpers import footed_recording


@pytest.fixture(scope="module")
def whole(tmp_path_factory):
    """A finished recording with Rerun's footer (its last 0.1 %: ``footer=True``, as files written before the
    footer was turned off) and what read_recording finds in it; files without one: test_rerun_memory.py."""
    return footed_recording(tmp_path_factory.mktemp("whole") / "mission.rrd", frames=40)


def _boundaries(rrd) -> list[int]:
    """Every message boundary of an intact file, from an independent walk of its frames."""
    data = rrd.read_bytes()
    position, out = 12, [12]
    while position + 16 <= len(data):
        kind, length = np.frombuffer(data[position:position + 16], "<u8")
        if kind == 0:  # End: its payload (the manifest) and trailer are whole only with the rest of the file
            break
        position += 16 + int(length)
        out.append(position)
    return out


def _cut(rrd, fraction: float, tmp_path):
    data = rrd.read_bytes()
    cut = tmp_path / f"cut-{fraction}.rrd"
    cut.write_bytes(data[: int(len(data) * fraction)])
    return cut


def test_an_intact_recording_is_not_reported_truncated(whole):
    rrd, contents = whole
    scan = scan_rrd(rrd)
    assert scan.whole_bytes == scan.file_size and scan.ended and not scan.truncated
    assert contents.truncated is None and contents.ended


def test_a_recording_cut_at_999_permille_gives_back_every_map(whole, tmp_path):
    """The last 0.1 % is Rerun's footer (its manifest): every logged message is still there."""
    rrd, contents = whole
    cut = read_recording(_cut(rrd, 0.999, tmp_path))
    assert cut.truncated and "cut short" in cut.truncated and not cut.ended
    assert cut.robots == contents.robots and cut.summary == contents.summary
    for name, m in contents.maps.items():
        np.testing.assert_array_equal(cut.maps[name].positions, m.positions)
        np.testing.assert_array_equal(cut.maps[name].covariances, m.covariances)


def test_a_recording_cut_in_half_gives_back_the_first_half(whole, tmp_path):
    rrd, contents = whole
    cut = read_recording(_cut(rrd, 0.5, tmp_path))
    assert cut.truncated and not cut.ended
    assert cut.robots == contents.robots  # the robots' plots start at once
    assert 0 < cut.duration < contents.duration


def test_review_of_a_truncated_recording_says_so_and_lists_every_file_it_writes(whole, tmp_path, capsys):
    rrd, contents = whole
    cut = _cut(rrd, 0.999, tmp_path)
    out = tmp_path / "maps"
    assert main(["review", str(cut), "--export", str(out), "--json"]) == 0
    review = json.loads(capsys.readouterr().out)
    assert review["truncated"] and "cut short" in review["truncated"]
    written = sorted(review["files_written"])
    assert written == sorted(str(out / f"{name}.{ext}") for name in contents.maps for ext in ("npz", "ply"))
    assert all((out / f).exists() for f in [p.split("/")[-1] for p in written])
    assert main(["review", str(cut), "--export", str(out)]) == 0
    text = capsys.readouterr().out
    assert "TRUNCATED" in text and all(f in text for f in written)


def test_a_file_holding_only_a_header_is_a_clear_error(whole, tmp_path):
    rrd, _ = whole
    stub = tmp_path / "stub.rrd"
    stub.write_bytes(rrd.read_bytes()[:20])
    with pytest.raises(RecordingReadError, match="stub.rrd"):
        read_recording(stub)


@settings(max_examples=60, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(fraction=st.floats(0.0, 1.0))
def test_the_walk_stops_at_the_last_whole_message_before_any_cut(whole, tmp_path, fraction):
    rrd, _ = whole
    data = rrd.read_bytes()
    cut_at = int(len(data) * fraction)
    cut = tmp_path / "cut.rrd"
    cut.write_bytes(data[:cut_at])
    boundaries = _boundaries(rrd)
    if cut_at < 12:
        with pytest.raises(ValueError):
            scan_rrd(cut)
        return
    scan = scan_rrd(cut)
    assert scan.whole_bytes <= cut_at
    if cut_at < len(data):
        # the largest boundary not past the cut (or the whole file up to its End message's trailer)
        assert scan.whole_bytes == max(b for b in boundaries if b <= cut_at)


@given(st.binary(max_size=200))
def test_the_walk_never_raises_anything_but_value_error_on_garbage(tmp_path_factory, garbage):
    path = tmp_path_factory.mktemp("g") / "g.rrd"
    for data in (garbage, b"RRF2" + bytes(8) + garbage):
        path.write_bytes(data)
        try:
            scan = scan_rrd(path)
        except ValueError:
            continue
        assert 12 <= scan.whole_bytes <= len(data)
