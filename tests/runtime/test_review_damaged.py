"""``p3at review`` on a recording whose reader kills its process: one line, exit 2, nothing exported.

Rerun's reader (Rust) aborts the process on some damaged messages: one byte flipped in a demo's 6.9 MB
recording gave "thread '<unnamed>' panicked at .../arrow-ipc-58.3.0/src/convert.rs:390:22: Timestamp type with
unit of <UNKNOWN 16> not supported" and SIGABRT (exit 134, no Python traceback to catch). Which byte does that
depends on Rerun's encoding, so the test makes the reading process die the same way (a panic's message on
stderr, then abort) instead of shipping a damaged file.
"""
from __future__ import annotations

import faulthandler
import multiprocessing
import os
import signal
import threading
import time

from runtime.cli import main
from runtime.commands import review

from .rerun_helpers import ROBOTS, log_small_mission


def dies_like_a_rust_panic(paths, folder):
    """Runs in the reading process, in place of review.read_and_export: writes to file descriptor 2 as Rust does
    (not through sys.stderr), then aborts (faulthandler, which pytest turns on, would add its own dump)."""
    faulthandler.disable()
    os.write(2, b"\nthread '<unnamed>' (1447) panicked at /cargo/arrow-ipc-58.3.0/src/convert.rs:390:22:\n"
                b"Timestamp type with unit of <UNKNOWN 16> not supported\n"
                b"note: run with `RUST_BACKTRACE=1` environment variable to display a backtrace\n")
    os.abort()


def test_a_reader_that_aborts_is_one_line_and_exit_2(tmp_path, capsys, monkeypatch):
    rrd = tmp_path / "mission.rrd"
    rrd.write_bytes(b"RRF2" + bytes(64))
    monkeypatch.setattr(review, "read_and_export", dies_like_a_rust_panic)
    code = main(["review", str(rrd), "--export", str(tmp_path / "maps")])
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert code == 2 and captured.out == ""
    assert err == [f"p3at review: {rrd}: not a readable Rerun recording: Rerun's reader stopped on a damaged "
                   "message (Timestamp type with unit of <UNKNOWN 16> not supported)"]
    assert not (tmp_path / "maps").exists()


def test_a_sound_recording_is_read_and_exported_by_the_reading_process(tmp_path, capsys):
    from runtime.rerun_log import MissionLog
    from runtime.rerun_sink import open_recording
    from runtime.rerun_style import mission_blueprint

    rrd = tmp_path / "mission.rrd"
    log = MissionLog(open_recording(str(rrd), blueprint=mission_blueprint(ROBOTS)), ROBOTS, blueprint=False)
    log_small_mission(log, frames=8)
    log.close()
    code = main(["review", str(rrd), "--export", str(tmp_path / "maps")])
    out = capsys.readouterr().out
    assert code == 0 and "2 robot(s) (robot1, robot2)" in out
    assert sorted(p.name for p in (tmp_path / "maps").iterdir()) == [
        f"{name}.{ext}" for name in ("fused", *ROBOTS) for ext in ("npz", "ply")]


def test_an_export_folder_that_is_a_file_is_refused_before_reading(tmp_path, capsys):
    target = tmp_path / "maps"
    target.write_text("not a folder")
    code = main(["review", str(tmp_path / "absent.rrd"), "--export", str(target)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err == [f"p3at review: --export {target}: a file is there; give a folder"]
    assert target.read_text() == "not a folder"


def test_a_folder_given_as_the_recording_is_called_a_folder(tmp_path, capsys):
    """It said 'out: no such recording' of a folder that is there (a user who gave the mission's folder)."""
    code = main(["review", str(tmp_path), "--no-export"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err == [f"p3at review: {tmp_path}: a folder, not a recording (give the .rrd file in it)"]


def reads_for_ever(paths, folder):
    """Runs in the reading process, in place of review.read_and_export: a reading that would take a minute (if the
    SIGINT is lost the test fails after it, not at pytest's timeout)."""
    time.sleep(60)


def test_ctrl_c_ends_the_reading_process_at_once(tmp_path, capsys, monkeypatch):
    """Ctrl-C in the terminal reaches p3at, which stops its reading process and exits 130 (it waited for the child
    to finish its export). The SIGINT is sent while main() waits for the child, which sleeps for a minute.
    SIGINT is handled here as a terminal's p3at handles it: a test process started in the background by a
    non-interactive shell (make test from a script, CI) inherits it ignored, and the signal would be lost."""
    rrd = tmp_path / "mission.rrd"
    rrd.write_bytes(b"RRF2" + bytes(64))
    monkeypatch.setattr(review, "read_and_export", reads_for_ever)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    unblocked = signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    timer = threading.Timer(1.0, os.kill, (os.getpid(), signal.SIGINT))
    timer.start()
    try:
        code = main(["review", str(rrd), "--no-export"])
    finally:
        timer.cancel()
        signal.pthread_sigmask(signal.SIG_SETMASK, unblocked)
        signal.signal(signal.SIGINT, previous)
    assert code == 130
    assert multiprocessing.active_children() == []


class _Unpicklable(ValueError):
    def __init__(self) -> None:
        super().__init__("a reader bug")
        self.hook = lambda: None       # lambdas do not pickle


def raises_what_does_not_pickle(paths, folder):
    """Runs in the reading process, in place of review.read_and_export: a bug whose exception cannot be sent."""
    raise _Unpicklable()


def test_a_bug_in_the_reading_process_is_reported_as_a_bug(tmp_path, capsys, monkeypatch):
    """Not as a damaged recording: the exception's text reaches the parent, which reports it as internal (exit 70)."""
    rrd = tmp_path / "mission.rrd"
    rrd.write_bytes(b"RRF2" + bytes(64))
    monkeypatch.setattr(review, "read_and_export", raises_what_does_not_pickle)
    code = main(["review", str(rrd), "--no-export"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 70 and len(err) == 1 and "_Unpicklable: a reader bug" in err[0], err


def test_the_reading_process_is_forked_only_from_a_single_thread():
    """A fork copies any lock another thread holds at that instant (Rerun starts threads when imported), so a
    process with a second thread spawns its reader; `p3at review` itself runs one thread and forks (a fast start)."""
    import subprocess
    import sys

    release = threading.Event()
    other = threading.Thread(target=release.wait, daemon=True)
    other.start()
    try:
        assert not review._fork_is_safe()
    finally:
        release.set()
        other.join()
    fresh = subprocess.run([sys.executable, "-c", "from runtime.cli import main; from runtime.commands import review; "
                            "print(review._fork_is_safe())"], capture_output=True, text=True, timeout=120)
    assert fresh.stdout.strip() == "True", fresh.stderr
