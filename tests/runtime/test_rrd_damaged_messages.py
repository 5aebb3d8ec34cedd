"""A recording with bytes flipped inside some messages (a bad disk) gives back everything else, and says which
messages it skipped; damage to the framing is the cut-short case, damage to the store information a one-line error.

Rerun's reader refused such a file whole (one flipped byte in a 4.5 MB recording: "not a readable Rerun recording
(... lz4 error ...)"), and its Rust code aborts the whole process on some flips (3 % of them): those are read here
in a reading process, as `p3at review` does (test_review_damaged.py covers its one-line answer).
"""
from __future__ import annotations

import json
import os
import re
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from runtime.cli import main
from runtime.rerun_log import MissionLog
from runtime.rerun_read import RecordingReadError, read_recording
from runtime.rerun_sink import open_recording
from runtime.rerun_style import mission_blueprint

from .rerun_helpers import ROBOTS, footed_recording, log_small_mission

pytestmark = pytest.mark.filterwarnings("ignore:.*no footer/manifest")  # candidate files are written without one

ROOT = Path(__file__).resolve().parents[2]
FIELDS = ("positions", "covariances", "descriptors", "ids", "counts", "seen_by", "trajectory")

# reads each path given on its standard input with read_recording, answers one JSON line (the maps' arrays)
WORKER = f"FIELDS = {FIELDS!r}\n" + """
import json, sys
from runtime.rerun_read import read_recording, RecordingReadError
for line in sys.stdin:
    try:
        c = read_recording(line.strip())
        out = {"maps": {k: {f: getattr(m, f).tolist() for f in FIELDS} for k, m in c.maps.items()},
               "truncated": c.truncated, "damaged": c.damaged}
    except RecordingReadError as e:
        out = {"error": str(e)}
    print(json.dumps(out), flush=True)
"""


@pytest.fixture(scope="module")
def whole(tmp_path_factory):
    """A finished recording with Rerun's footer, and what read_recording finds in it."""
    return footed_recording(tmp_path_factory.mktemp("whole") / "mission.rrd", frames=12)


def _frames(data: bytes) -> list[tuple[int, int, int]]:
    """(start, size, kind) of every message, End with its footer trailer: an independent walk of an intact file."""
    position, out = 12, []
    while position + 16 <= len(data):
        kind, length = struct.unpack("<QQ", data[position:position + 16])
        size = 16 + length + (32 if kind == 0 else 0)
        out.append((position, size, kind))
        position += size
    return out


def _held_entities(rrd: Path, message: tuple[int, int, int], tmp_path: Path) -> set[str]:
    """The entities whose chunks ``message`` of the intact ``rrd`` holds (read alone, with the store information)."""
    import rerun.chunk as rrchunk

    data = rrd.read_bytes()
    alone = tmp_path / "alone.rrd"
    store = [f for f in _frames(data) if f[2] in (1, 3)]
    alone.write_bytes(data[:12] + b"".join(data[s:s + n] for s, n, _ in sorted({*store, message})))
    if message[2] != 2:
        return set()
    reader = rrchunk.RrdReader(alone)
    return {c.entity_path.lstrip("/") for c in reader.stream()} if reader.recordings() else set()


def _maps(contents) -> dict[str, dict[str, list]]:
    return {k: {f: getattr(m, f).tolist() for f in FIELDS} for k, m in contents.maps.items()}


def _garble(data: bytes, frames: list[tuple[int, int, int]], *which: int) -> bytes:
    """``data`` with the payloads of messages ``which`` overwritten by 0xFF (no Protobuf envelope decodes)."""
    out = bytearray(data)
    for k in which:
        start, size, _ = frames[k]
        out[start + 16:start + size] = b"\xff" * (size - 16)
    return bytes(out)


def _plot_messages(rrd: Path, frames, tmp_path) -> list[int]:
    """Messages holding neither a map nor the mission's summary or end mark (their loss changes no figure)."""
    out = []
    for k in range(len(frames) // 4, len(frames), max(1, len(frames) // 12)):
        held = _held_entities(rrd, frames[k], tmp_path)
        if frames[k][2] == 2 and held and all(e.startswith("plots/") for e in held):
            out.append(k)
    return out


def test_one_damaged_message_is_skipped_and_the_rest_read(whole, tmp_path):
    rrd, contents = whole
    data = rrd.read_bytes()
    frames = _frames(data)
    k = _plot_messages(rrd, frames, tmp_path)[1]
    damaged = tmp_path / "damaged.rrd"
    damaged.write_bytes(_garble(data, frames, k))
    import rerun.chunk as rrchunk

    with pytest.raises(RuntimeError, match="Failed to read RRD file"):  # what Rerun's reader alone makes of it
        list(rrchunk.RrdReader(damaged).stream())
    read = read_recording(damaged)
    start, size, _ = frames[k]
    messages = sum(1 for f in frames if f[2] != 0)
    assert read.damaged == (f"{damaged}: 1 of {messages:,} messages damaged (bytes {start:,}–{start + size - 1:,}), "
                            "skipped; the rest read")
    assert read.truncated is None and read.ended
    assert _maps(read) == _maps(contents)
    assert read.summary == contents.summary and read.alignments == contents.alignments


def test_several_damaged_messages_are_each_named(whole, tmp_path):
    rrd, contents = whole
    data = rrd.read_bytes()
    frames = _frames(data)
    chosen = _plot_messages(rrd, frames, tmp_path)[:3]
    damaged = tmp_path / "damaged.rrd"
    damaged.write_bytes(_garble(data, frames, *chosen))
    read = read_recording(damaged)
    ranges = ", ".join(f"{frames[k][0]:,}–{frames[k][0] + frames[k][1] - 1:,}" for k in chosen)
    assert read.damaged.endswith(f"3 of {sum(1 for f in frames if f[2] != 0):,} messages damaged (bytes {ranges}), "
                                 "skipped; the rest read")
    assert _maps(read) == _maps(contents)


def test_a_damaged_footer_loses_nothing(whole, tmp_path):
    rrd, contents = whole
    data = rrd.read_bytes()
    frames = _frames(data)
    end = next(i for i, f in enumerate(frames) if f[2] == 0)
    damaged = tmp_path / "damaged.rrd"
    start, size, _ = frames[end]
    damaged.write_bytes(data[:start + 16] + b"\xff" * (size - 48) + data[start + size - 32:])  # the trailer whole
    read = read_recording(damaged)
    assert read.damaged == f"{damaged}: its footer does not decode, left out; all {len(frames) - 1:,} messages read"
    assert _maps(read) == _maps(contents) and read.ended


def test_damaged_store_information_is_one_line(whole, tmp_path):
    rrd, _ = whole
    data = rrd.read_bytes()
    frames = _frames(data)
    damaged = tmp_path / "damaged.rrd"
    damaged.write_bytes(_garble(data, frames, *[k for k, f in enumerate(frames) if f[2] == 1]))
    with pytest.raises(RecordingReadError) as refused:
        read_recording(damaged)
    assert "\n" not in str(refused.value) and str(refused.value).startswith(f"{damaged}: ")


def test_review_says_which_messages_it_skipped_and_exports_the_maps(whole, tmp_path, capsys):
    rrd, contents = whole
    data = rrd.read_bytes()
    frames = _frames(data)
    damaged = tmp_path / "damaged.rrd"
    damaged.write_bytes(_garble(data, frames, _plot_messages(rrd, frames, tmp_path)[0]))
    out = tmp_path / "maps"
    assert main(["review", str(damaged), "--export", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert re.fullmatch(rf"  DAMAGED recording, {re.escape(str(damaged))}: 1 of [\d,]+ messages damaged \(bytes "
                        r"[\d,]+–[\d,]+\), skipped; the rest read", lines[1]), lines
    assert sorted(p.name for p in out.iterdir()) == sorted(f"{n}.{e}" for n in contents.maps for e in ("npz", "ply"))


@pytest.fixture(scope="module")
def reader_process():
    """A process that reads recordings with read_recording; started again when Rerun's reader aborts it."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1", RUST_BACKTRACE="0")
    state: dict = {}

    def read(path: Path) -> dict | None:
        """What read_recording answers, None when the reader killed its process."""
        if state.get("process") is None or state["process"].poll() is not None:
            state["process"] = subprocess.Popen([sys.executable, "-c", WORKER], stdin=subprocess.PIPE,
                                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                                                env=env, cwd=ROOT)
        process = state["process"]
        process.stdin.write(f"{path}\n")
        process.stdin.flush()
        line = process.stdout.readline()
        if not line:
            process.wait(timeout=60)
            assert process.returncode == -6, f"the reading process ended with {process.returncode}"  # SIGABRT
            return None
        return json.loads(line)

    yield read
    if state.get("process") is not None:
        state["process"].stdin.close()
        state["process"].wait(timeout=60)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(fraction=st.floats(0.0, 1.0, exclude_max=True), bit=st.integers(0, 7))
def test_a_flipped_bit_loses_at_most_its_own_message(whole, reader_process, tmp_path, fraction, bit):
    """Every map is the original's unless the flipped message holds it; a flip in a message's frame header may
    instead cut the file there (the maps then those of the messages before it); or a one-line error."""
    rrd, contents = whole
    data = rrd.read_bytes()
    frames = _frames(data)
    position = int(fraction * len(data))
    flipped = bytearray(data)
    flipped[position] ^= 1 << bit
    damaged = tmp_path / "flipped.rrd"
    damaged.write_bytes(flipped)
    answer = reader_process(damaged)
    if answer is None:      # Rerun's reader aborted its process: `p3at review` says so in one line
        return
    k = next((i for i, (s, n, _) in enumerate(frames) if s <= position < s + n), None)  # None: the stream header
    in_frame = k is not None and position < frames[k][0] + 16
    if "error" in answer:   # only where a flip damages the file's framing or its store information
        assert k is None or in_frame or frames[k][2] == 1, (position, answer["error"])
        assert "\n" not in answer["error"] and answer["error"].startswith(f"{damaged}: ")
        return
    original = _maps(contents)
    assert set(answer["maps"]) <= set(original)
    held = _held_entities(rrd, frames[k], tmp_path) if k is not None else set()
    before = {}
    if in_frame:
        prefix = tmp_path / "prefix.rrd"
        prefix.write_bytes(data[:frames[k][0]])
        try:
            before = _maps(read_recording(prefix))
        except RecordingReadError:   # no recording before it
            pass
    for name, m in original.items():
        if f"maps/{name}" in held:
            continue
        allowed = [m] + ([before.get(name)] if in_frame else [])
        assert answer["maps"].get(name) in allowed, (name, position, answer["damaged"], answer["truncated"])
    if answer["damaged"] and k is not None and not in_frame and frames[k][2] != 0:  # one message, named
        start, size, _ = frames[k]
        named = f": 1 of {len(frames) - 1:,} messages damaged (bytes {start:,}–{start + size - 1:,})"
        # or a flip inside a map it holds that still decodes as a message: that map's checksum says so, or its arrays
        # no longer make a map (left out, or an older snapshot read)
        by_checksum = ("checksum" in answer["damaged"] or "does not decode" in answer["damaged"]) and any(
            f"{e}: " in answer["damaged"] for e in held if e.startswith("maps/"))
        assert named in answer["damaged"] or by_checksum, (position, answer["damaged"])


def test_a_store_id_changed_in_one_of_the_repeated_store_infos_still_reads_the_data(tmp_path):
    """Rerun repeats a recording's SetStoreInfo; a bit flipped in the first one's store id gave a second, empty
    recording store, listed first when its id sorts first, and read: no map, no error (4 of the 8 bits of one byte
    of a data set's recording)."""
    rrd = tmp_path / "mission.rrd"   # saved as missions save it, without Rerun's footer (which lists the stores)
    log = MissionLog(open_recording(str(rrd), blueprint=mission_blueprint(ROBOTS)), ROBOTS, blueprint=False)
    log_small_mission(log, frames=4)
    log.close()
    contents = read_recording(rrd)
    data = bytearray(rrd.read_bytes())
    infos = [(s, n) for s, n, kind in _frames(bytes(data)) if kind == 1]
    found = next(m for s, n in infos if (m := re.search(rb"\x12 [0-9a-f]{32}", data[s + 16:s + n])))  # recording's
    start = next(s for s, n in infos if found.re.search(data[s + 16:s + n]))
    data[start + 16 + found.start() + 2] = ord("/")      # another store id, listed before the real one
    changed = tmp_path / "changed.rrd"
    changed.write_bytes(bytes(data))
    read = read_recording(changed)
    assert _maps(read) == _maps(contents) and read.summary == contents.summary and read.ended
