"""A recording on which Rerun's reader aborts the process (SIGABRT) is read all the same, without the damaged message.

Rerun's Rust reader aborts on about 3 % of single-bit flips (arrow-buffer "the offset of the new Buffer cannot exceed
the existing length", arrow-ipc "Type NONE not supported"): no exception, the process ends. `p3at review` then reads
again with every candidate of the salvage read in a child process (runtime/rrd_salvage.ReadingProcesses), and
``read_recording(..., isolated=True)`` does the same for a script.

The aborting flip is not hard-coded (a Rerun upgrade would move it silently): the test builds a small recording and
searches, in a fixed order, the plot messages for a bit whose flip aborts a reader given that message alone; the test
is skipped, naming Rerun's version, when none does.
"""
from __future__ import annotations

import os
import re
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from runtime.rrd_salvage import ReadingProcessError, ReadingProcesses, salvage, scan_rrd

pytestmark = pytest.mark.filterwarnings("ignore:.*no footer/manifest")  # candidate files are written without one

ROOT = Path(__file__).resolve().parents[2]
ENV = dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1", RUST_BACKTRACE="0")
FIELDS = ("positions", "covariances", "descriptors", "ids", "counts", "seen_by", "trajectory", "robot", "frame",
          "robots", "metadata")

# answers "1" or "0" (Rerun reads the file through, or refuses it) for each path on its standard input; dies with
# the reader when it aborts
PROBE = """
import sys
from pathlib import Path
from runtime.rerun_read import _decodes
for line in sys.stdin:
    print(int(_decodes(Path(line.strip()))), flush=True)
"""


def _frames(data: bytes) -> list[tuple[int, int, int]]:
    """(start, size, kind) of every message of an intact file without a footer (an independent walk)."""
    position, out = 12, []
    while position + 16 <= len(data):
        kind, length = struct.unpack("<QQ", data[position:position + 16])
        out.append((position, 16 + length, kind))
        position += 16 + length
    return out


def _aborting_flip(data: bytes, scratch: Path) -> tuple[int, int] | None:
    """(byte, bit) of a single-bit flip that aborts Rerun's reader, or None. Searched in a fixed order: 8 of the
    Arrow messages that hold a plot (their loss changes no map), from the end of the schema's "entity_path" key (the
    buffer lengths after it: most aborts of an exhaustive search were there), bits 7 and 6 of 200 bytes each. Each
    flipped message is read alone with the store information by one reading process, started again when it dies."""
    frames = _frames(data)
    store = b"".join(data[s:s + n] for s, n, kind in frames if kind != 2)
    plots = [(s, n) for s, n, kind in frames if kind == 2 and b"plots/" in data[s:s + n]]
    candidate = scratch / "one-message.rrd"
    reader = None
    try:
        for s, n in plots[len(plots) // 3::max(1, len(plots) // 12)][:8]:
            anchor = data.find(b"entity_path", s + 16, s + n)
            start = anchor + len(b"entity_path") if anchor >= 0 else s + 16
            for byte in range(start, min(s + n, start + 200)):
                for bit in (7, 6):
                    flipped = bytearray(data[s:s + n])
                    flipped[byte - s] ^= 1 << bit
                    candidate.write_bytes(data[:12] + store + bytes(flipped))
                    if reader is None or reader.poll() is not None:
                        reader = subprocess.Popen([sys.executable, "-c", PROBE], stdin=subprocess.PIPE,
                                                  stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                                                  env=ENV, cwd=ROOT)
                    reader.stdin.write(f"{candidate}\n")
                    reader.stdin.flush()
                    if not reader.stdout.readline():
                        reader.wait(timeout=60)
                        if reader.returncode == -6:   # SIGABRT
                            return byte, bit
    finally:
        if reader is not None and reader.poll() is None:
            reader.stdin.close()
            reader.wait(timeout=60)
    return None


def _reading_aborts(rrd: Path) -> int:
    """The exit status of a process that reads ``rrd`` with read_recording in the default way (in that process)."""
    return subprocess.run([sys.executable, "-c", f"from runtime.rerun_read import read_recording; "
                           f"read_recording({str(rrd)!r})"], env=ENV, cwd=ROOT, capture_output=True,
                          timeout=300).returncode


@pytest.fixture(scope="module")
def aborting(tmp_path_factory):
    """A small finished mission saved as missions save it (no footer), the same file with one bit flipped so that
    Rerun's reader aborts a process reading it, the flipped message's (start, size), and the original's contents."""
    import rerun

    from runtime.rerun_log import MissionLog
    from runtime.rerun_read import read_recording
    from runtime.rerun_sink import open_recording
    from runtime.rerun_style import mission_blueprint

    from .rerun_helpers import ROBOTS, log_small_mission

    folder = tmp_path_factory.mktemp("aborting")
    rrd = folder / "mission.rrd"
    log = MissionLog(open_recording(str(rrd), blueprint=mission_blueprint(ROBOTS)), ROBOTS, blueprint=False)
    log_small_mission(log, frames=12, flush_each_frame=True)
    log.close()
    data = rrd.read_bytes()
    found = _aborting_flip(data, folder)
    if found is None:
        pytest.skip(f"no single-bit flip searched aborts Rerun {rerun.__version__}'s reader (the test looks for one "
                    "in a plot message's Arrow schema and buffers)")
    byte, bit = found
    flipped = bytearray(data)
    flipped[byte] ^= 1 << bit
    damaged = folder / "flipped.rrd"
    damaged.write_bytes(bytes(flipped))
    status = _reading_aborts(damaged)
    assert status == -6, f"the flip at byte {byte} aborts its message alone, not the whole file (status {status})"
    message = next((s, n) for s, n, _ in _frames(data) if s <= byte < s + n)
    return damaged, message, len(_frames(data)), read_recording(rrd)


def _same_maps(got: dict, expected: dict) -> None:
    import numpy as np

    assert sorted(got) == sorted(expected)
    for name, m in expected.items():
        for f in FIELDS:
            a, b = getattr(got[name], f), getattr(m, f)
            assert (np.array_equal(a, b) if isinstance(b, np.ndarray) else a == b), (name, f)


def test_review_reads_a_recording_whose_reader_aborts(aborting, tmp_path):
    """`p3at review` (its own process, as a user runs it: it forks) prints the DAMAGED line naming the flipped
    message, exports every map, and the maps are the original's field by field (before: one line, exit 2)."""
    from estimation.landmark_map import LandmarkMap

    damaged, (start, size), total, contents = aborting
    out = tmp_path / "maps"
    review = subprocess.run([sys.executable, "-m", "runtime.cli", "review", str(damaged), "--export", str(out)],
                            env=ENV, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert review.returncode == 0, review.stderr
    lines = review.stdout.splitlines()
    assert lines[1] == (f"  DAMAGED recording, {damaged}: 1 of {total:,} messages damaged "
                        f"(bytes {start:,}–{start + size - 1:,}), skipped; the rest read"), lines
    _same_maps({p.stem: LandmarkMap.load(p) for p in out.glob("*.npz")}, contents.maps)
    assert sorted(p.name for p in out.iterdir()) == sorted(f"{n}.{e}" for n in contents.maps for e in ("npz", "ply"))


def test_read_recording_isolated_survives_the_abort(aborting):
    """A script's read_recording(..., isolated=True) reads it as `p3at review` does, and this process lives on."""
    import multiprocessing

    from runtime.rerun_read import read_recording

    damaged, (start, size), total, contents = aborting
    read = read_recording(damaged, isolated=True)
    assert read.damaged == (f"{damaged}: 1 of {total:,} messages damaged (bytes {start:,}–{start + size - 1:,}), "
                            "skipped; the rest read")
    _same_maps(read.maps, contents.maps)
    assert read.summary == contents.summary and read.alignments == contents.alignments
    assert multiprocessing.active_children() == []


# -- the reading processes and the salvage's search, without Rerun ------------------------------------------------
def decode_or_die(candidate: Path) -> bool:
    """A reader that aborts its process on b"ABORT", raises on b"RAISE", reads anything else (runs in the children:
    importable by name, as a spawned child needs)."""
    import faulthandler

    content = candidate.read_bytes()
    if b"ABORT" in content:
        faulthandler.disable()     # pytest turns it on; it would print a dump
        os.abort()
    if b"RAISE" in content:
        raise RuntimeError("Failed to read RRD file")
    return True


def _recording(path: Path, payloads: list[bytes]) -> Path:
    """A file framed as an .rrd (stream header, a SetStoreInfo, Arrow messages with ``payloads``)."""
    out = bytearray(b"RRF2" + bytes(8))
    for kind, payload in [(1, b"store"), *((2, p) for p in payloads)]:
        out += struct.pack("<QQ", kind, len(payload)) + payload
    path.write_bytes(bytes(out))
    return path


def test_a_child_that_dies_is_a_candidate_that_does_not_decode(tmp_path):
    """Each answer as the reader's (an abort and a raise both False); a dead child is replaced, the others reused."""
    import multiprocessing

    files = {name: tmp_path / f"{name}.rrd" for name in ("ok", "ABORT", "RAISE")}
    for name, f in files.items():
        f.write_bytes(name.encode())
    order = ["ok", "ABORT", "RAISE", "ok", "ABORT", "ok"]
    with ReadingProcesses(decode_or_die, multiprocessing.get_context("spawn")) as reading:
        answers = [reading(files[name]) for name in order]
        assert (reading.died, reading.reads) == (2, 6)
        assert reading.started == 4     # the first, one after each death, and the spare behind the last
    assert answers == [True, False, False, True, False, True]
    assert multiprocessing.active_children() == []


def dies_as_it_starts() -> None:
    """A reading process's preparation that kills it (an import that fails, a memory limit): runs in the children."""
    import faulthandler

    faulthandler.disable()
    os.abort()


def test_a_child_that_dies_before_reading_blames_no_candidate(tmp_path):
    """Not "does not decode" (every message would be called damaged): an error saying what happened."""
    import multiprocessing

    (tmp_path / "ok.rrd").write_bytes(b"ok")
    with ReadingProcesses(decode_or_die, multiprocessing.get_context("spawn"), prepare=dies_as_it_starts) as reading:
        with pytest.raises(ReadingProcessError, match=r"died as it started \(exit status -6\)"):
            reading(tmp_path / "ok.rrd")
        assert reading.reads == 0 and reading.died == 0
    assert multiprocessing.active_children() == []


def aborts_then_asks(paths, folder):
    """In place of review.read_and_export (runs in the reading processes): the first one dies as on a damaged message;
    the second asks its parent about a candidate, as read_recording would."""
    import faulthandler

    from runtime.commands import review

    if review._ask_parent is None:
        faulthandler.disable()
        os.abort()
    review._ask_parent(paths[0].with_name("candidate.rrd"))
    return {"error": "not reached: the parent's reading processes die as they start"}


def test_review_says_so_when_its_reading_processes_cannot_start(tmp_path, capsys, monkeypatch):
    """One line, exit 2: the first reader's death, and why reading again failed (no message blamed)."""
    from runtime.cli import main
    from runtime.commands import review

    rrd = tmp_path / "mission.rrd"
    rrd.write_bytes(b"RRF2" + bytes(64))
    monkeypatch.setattr(review, "read_and_export", aborts_then_asks)
    monkeypatch.setattr(review, "_import_reader", dies_as_it_starts)
    code = main(["review", str(rrd), "--no-export"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith(f"p3at review: {rrd}: not a readable Rerun recording: Rerun's reader stopped on a "
                             "damaged message (")
    assert err[0].endswith("; reading it again in separate processes failed: a reading process died as it started "
                           "(exit status -6), before it read anything"), err


ORPHANS = """
import multiprocessing, sys, time
from pathlib import Path
from runtime.rrd_salvage import ReadingProcesses
from tests.runtime.test_rrd_reader_aborts import decode_or_die
reading = ReadingProcesses(decode_or_die, multiprocessing.get_context("fork"))
Path(sys.argv[1]).write_bytes(b"ok")
for _ in range(3):
    reading(Path(sys.argv[1]))
print(*(p.pid for p in multiprocessing.active_children()), flush=True)
time.sleep(120)
"""


def test_reading_processes_leave_when_their_parent_is_killed(tmp_path):
    """A `p3at review` killed outright (SIGKILL: no cleanup) leaves no reading process behind: forked children hold
    each other's pipe ends, so they would wait for ever; each leaves once its parent is gone."""
    import signal
    import time

    parent = subprocess.Popen([sys.executable, "-c", ORPHANS, str(tmp_path / "ok.rrd")], stdout=subprocess.PIPE,
                              text=True, env=ENV, cwd=ROOT)
    try:
        children = [int(pid) for pid in parent.stdout.readline().split()]
    finally:
        parent.send_signal(signal.SIGKILL)
        parent.wait(timeout=60)
    assert len(children) == 2     # the reading one and its spare

    def alive(pid: int) -> bool:
        try:
            return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
        except OSError:
            return False

    deadline = time.monotonic() + 30
    while any(alive(pid) for pid in children) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not any(alive(pid) for pid in children)


def test_salvage_with_reading_processes_leaves_out_what_aborts_and_what_raises(tmp_path):
    import multiprocessing

    payloads = [b"plot %03d" % k for k in range(40)]
    payloads[7], payloads[22], payloads[31] = b"ABORT 7", b"RAISE 22", b"ABORT 31"
    rrd = _recording(tmp_path / "mission.rrd", payloads)
    (tmp_path / "scratch").mkdir()
    with ReadingProcesses(decode_or_die, multiprocessing.get_context("spawn")) as reading:
        found = salvage(rrd, scan_rrd(rrd).whole_bytes, reading, tmp_path / "scratch", block_bytes=200, fanout=4)
    kept = found.copy.read_bytes()
    assert [kept.count(p) for p in payloads] == [0 if k in (7, 22, 31) else 1 for k in range(40)]
    assert len(found.damaged) == 3 and found.total == 41
    assert reading.died >= 2


@settings(max_examples=60, deadline=None)
@given(n=st.integers(1, 80), bad=st.sets(st.integers(0, 79), max_size=6), fanout=st.integers(2, 20),
       block=st.sampled_from([1, 120, 400, 1 << 20]))
def test_salvage_finds_exactly_the_messages_that_do_not_decode(tmp_path_factory, n, bad, fanout, block):
    """Whatever the fan-out and block size: the messages left out are the ones that fail, the copy holds the rest in
    their order (a reader here that refuses any candidate holding a bad message)."""
    bad = {k for k in bad if k < n}
    folder = tmp_path_factory.mktemp("salvage")
    payloads = [(b"BAD %03d" if k in bad else b"msg %03d") % k for k in range(n)]
    rrd = _recording(folder / "mission.rrd", payloads)
    found = salvage(rrd, scan_rrd(rrd).whole_bytes, lambda c: b"BAD" not in c.read_bytes(), folder,
                    block_bytes=block, fanout=fanout)
    kept = found.copy.read_bytes()
    assert re.findall(rb"(?:msg|BAD) \d{3}", kept) == [p for k, p in enumerate(payloads) if k not in bad]
    assert len(found.damaged) == len(bad) and found.total == n + 1
