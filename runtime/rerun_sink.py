"""Where a recording goes: :func:`open_recording` opens one mission's ``rr.RecordingStream`` on a saved ``.rrd``
file, a viewer it starts on loopback (:func:`spawn_viewer`), a running viewer's URL, memory (tests) or nowhere.
What is logged into it is runtime/rerun_log.py's; how a saved file is read back, runtime/rerun_read.py's."""
from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import weakref
from pathlib import Path

from runtime.limits import RERUN_URL_PREFIXES  # the one spelling, shared with the CLI's checks
from runtime.rerun_sdk import rr, rrb

APPLICATION_ID = "p3at-fusion"


class ViewerError(RuntimeError):
    """A Rerun viewer could not be started."""


VIEWER_PORT = 9876  # Rerun's default, so `rerun --connect` and a viewer someone already opened find each other


def _listening(port: int) -> bool:
    with socket.socket() as probe:
        return probe.connect_ex(("127.0.0.1", port)) == 0


def spawn_viewer(port: int | None = None, timeout: float = 15.0) -> str:
    """Start a Rerun viewer listening on loopback (``port``, default ``VIEWER_PORT``) and return its URL; reuse
    one already listening there.

    ``rr.spawn`` would start it listening on every interface (the viewer's default bind is 0.0.0.0); a robot
    must not expose its data stream to the network unless asked. Raises ViewerError with the viewer's own
    reason (no display, no executable) when it does not come up.
    """
    port = VIEWER_PORT if port is None else port
    url = f"rerun+http://127.0.0.1:{port}/proxy"
    if _listening(port):
        return url
    executable = Path(sys.executable).with_name("rerun")
    if not executable.exists():
        found = shutil.which("rerun")
        if found is None:
            raise ViewerError("no rerun executable found (pip install rerun-sdk); use --rerun file instead")
        executable = Path(found)
    messages = tempfile.TemporaryFile()  # not a pipe: nobody reads it once the viewer runs
    viewer = subprocess.Popen([str(executable), "--bind", "127.0.0.1", "--port", str(port), "--memory-limit", "75%"],
                              stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=messages,
                              start_new_session=True)  # the viewer outlives the mission, as with rr.spawn
    with messages:
        deadline = time.monotonic() + timeout
        alive_since = None
        while time.monotonic() < deadline:
            if viewer.poll() is not None:
                messages.seek(0)
                reason = messages.read().decode(errors="replace").strip().splitlines()
                raise ViewerError(f"the Rerun viewer exited at start ({reason[-1] if reason else 'no message'}); "
                                  "on a machine without a display use --rerun file, or run `rerun` elsewhere and "
                                  "pass its rerun+http:// URL")
            if _listening(port):
                alive_since = alive_since or time.monotonic()
                if time.monotonic() - alive_since > 1.0:  # it listens before it opens its window, which may fail
                    return url
            time.sleep(0.1)
    viewer.kill()
    raise ViewerError(f"the Rerun viewer did not listen on 127.0.0.1:{port} within {timeout:g} s")


FILE_FLUSH_TICK = 1.0  # s
# the streams open_recording saves to a file (runtime/rerun_log.py's MissionLog holds their rows)
SAVED_STREAMS: weakref.WeakSet = weakref.WeakSet()

# -- is Rerun still writing a saved file? -----------------------------------------------------------------------------
# Rerun 0.41's file sink writes from one thread of that name; a write that fails (a full disk, a file-size limit) ends
# it with one ERROR line of Rerun's, and every later row is dropped without a word. The SDK offers no status: only a
# flush says so, and a flush queued as the writer dies is never answered, so that every later flush times out and
# the stream's disconnect, or the process's exit, waits for ever (session 48: docs/reliability.md)
WRITER_THREAD = "file_writer"
_TASKS = "/proc/self/task"   # Linux; elsewhere the watch sees only a removed file
FLUSH_STEP = 1.0   # s: a saved file is flushed in steps this long, and the writer looked at between them
BLIND_FLUSH_STEPS = 60   # steps waited for a writer whose thread could not be found (not Linux), then given up


def _writer_threads() -> set[str]:
    """The ids of this process's threads named WRITER_THREAD (empty where /proc is not)."""
    found = set()
    try:
        tasks = os.listdir(_TASKS)
    except OSError:
        return found
    for tid in tasks:
        try:
            with open(f"{_TASKS}/{tid}/comm") as comm:
                if comm.read().strip() == WRITER_THREAD:
                    found.add(tid)
        except OSError:
            continue
    return found


class FileWriterWatch:
    """Whether Rerun still writes one saved recording, seen from outside, without asking Rerun anything: its writer
    thread (``/proc/self/task``) and the file itself, through a read-only descriptor of ours that follows a rename
    (the mission's ``.starting`` file becomes ``mission.rrd``) and outlives a removal.

    :meth:`failure` is None while both are well; else why the recording stopped, kept from the first time it was
    seen. Costs two system calls and a small read (~10 µs); nothing is sent to Rerun, so it cannot hang.
    """

    def __init__(self, path: Path, thread: str | None) -> None:
        self.path = path
        self.thread = thread   # None: not found (not Linux; or several sinks opened at once): only removal is seen
        self._fd: int | None = os.open(path, os.O_RDONLY)
        self._release = weakref.finalize(self, os.close, self._fd)   # closed with the watch, if not before
        self._failure: str | None = None
        self.settled = False   # finish_saved has looked whether a flush of the dead writer is stranded

    @classmethod
    def save(cls, rec: rr.RecordingStream, path: Path, footer: bool) -> FileWriterWatch:
        """``rec.save(path)``, and the watch of the writer it starts."""
        before = _writer_threads()
        rec.save(str(path), write_footer=footer)
        new, deadline = _writer_threads() - before, time.monotonic() + 1.0
        while not new and time.monotonic() < deadline and os.path.isdir(_TASKS):  # the thread names itself
            time.sleep(0.005)
            new = _writer_threads() - before
        return cls(path, next(iter(new)) if len(new) == 1 else None)

    def current_path(self) -> str:
        """The file's name now (it may have been renamed since it was opened)."""
        if self._fd is not None:
            try:
                return os.readlink(f"/proc/self/fd/{self._fd}").removesuffix(" (deleted)")
            except OSError:
                pass
        return str(self.path)

    def _writer_alive(self) -> bool:
        if self.thread is None:
            return True
        try:
            with open(f"{_TASKS}/{self.thread}/comm") as comm:
                return comm.read().strip() == WRITER_THREAD
        except OSError:
            return False

    def failure(self) -> str | None:
        """None while Rerun writes the file; else why it stopped (the first reason seen)."""
        if self._failure is None and self._fd is not None:
            if not self._writer_alive():
                self._failure = f"Rerun's file writer stopped ({self._reason()})"
            elif os.fstat(self._fd).st_nlink == 0:
                self._failure = "its file was removed while it was written"
        return self._failure

    def _reason(self) -> str:
        """Why a write failed, as far as can be seen from here: Rerun says it only in its own ERROR line."""
        stat, disk = os.fstat(self._fd), os.fstatvfs(self._fd)
        if disk.f_bavail == 0 or disk.f_bfree == 0:
            return "[Errno 28] No space left on device"
        limit = _file_size_limit()
        if limit is not None and stat.st_size >= limit:
            return f"[Errno 27] File too large (the file-size limit, ulimit -f, is {limit:,} bytes)"
        if stat.st_nlink == 0:
            return "the file was removed"
        return "a write failed (Rerun's ERROR line above says why)"

    def close(self) -> None:
        self._release()
        self._fd = None


def _file_size_limit() -> int | None:
    try:
        import resource
    except ImportError:  # not Unix
        return None
    soft = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    return None if soft == resource.RLIM_INFINITY else soft


# the watch of each stream open_recording saves to a file
WRITERS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def writer_failure(rec: rr.RecordingStream) -> str | None:
    """Why the file ``rec`` is saved to stopped being written (None: it is written, or ``rec`` saves no file)."""
    watch = WRITERS.get(rec)
    return None if watch is None else watch.failure()


def finish_saved(rec: rr.RecordingStream) -> str | None:
    """Flush ``rec`` to its sink, and for a saved file say whether the file is whole: None, or why it is not.

    A saved file is flushed in FLUSH_STEP steps, its writer looked at between them, and not flushed once its writer
    has stopped: a flush queued as the writer dies is never answered (Rerun 0.41), and waited for without a bound it
    hung the process (session 47: 4 of 14 runs; session 48: 3 of 20 with 1-s flushes, 9 of 20 with flushes not
    waited for). A slow disk whose writer lives is waited for; one whose writer thread is not known (not Linux),
    BLIND_FLUSH_STEPS steps. Other sinks are flushed as before."""
    watch = WRITERS.get(rec)
    if watch is None:
        rec.flush()
        return None
    error, steps = None, 0
    while watch.failure() is None:
        try:
            rec.flush(timeout_sec=FLUSH_STEP)
        except RuntimeError as e:   # 'Flush timed out ...': a slow disk, or a stranded flush (the writer died)
            steps += 1
            if "timed out" not in str(e):
                error = str(e)      # 'File-writer thread shut down prematurely'
                break
            if watch.thread is None and steps >= BLIND_FLUSH_STEPS:   # no thread to look at: a bound instead
                error = f"Rerun's file writer did not finish within {steps * FLUSH_STEP:g} s"
                break
            continue
        if watch.failure() is None:
            return None
    failure = watch.failure() or error or "Rerun's file writer stopped"
    if not watch.settled:
        watch.settled = True
        _settle(rec)
    return failure


_ABANDONED: list[rr.RecordingStream] = []   # streams with a flush Rerun never answers (see _settle)


def _settle(rec: rr.RecordingStream) -> None:
    """A stream whose writer stopped: is a flush of it stranded (queued as the writer died, never answered)? A new
    flush is answered at once if not ('File-writer thread shut down prematurely'), and times out if so. Rerun 0.41
    then waits for ever in the stream's disconnect, in its finalizer (which flushes and disconnects it: when it is
    garbage-collected, or at the interpreter's end) and in its exit hook (``rr.shutdown``, which flushes every
    stream). Such a stream is kept for the life of the process (one reference more than anything holds, so that its
    finalizer never runs) and Rerun's exit hook is dropped, so that the process can end: measured, 3 stranded of 60
    runs ended, against 7 of 20 hung at exit with the hook and 1 of 1 with the finalizer alone (session 48). A
    stream that MissionLog closes is flushed by its close; one never closed loses its last rows at exit."""
    try:
        rec.flush(timeout_sec=FLUSH_STEP)
    except RuntimeError as e:
        if "timed out" in str(e):
            import ctypes

            ctypes.pythonapi.Py_IncRef(ctypes.py_object(rec))   # never freed: its finalizer would wait for ever
            _ABANDONED.append(rec)
            rr.unregister_shutdown()


def release_saved(rec: rr.RecordingStream) -> None:
    """Detach ``rec``'s sink (a saved file is complete afterwards) and drop its watch; a stream with a stranded
    flush (:func:`_settle`) is left attached: detaching it would wait for ever."""
    watch = WRITERS.pop(rec, None)
    if not any(rec is stranded for stranded in _ABANDONED):
        rec.disconnect()
    if watch is not None:
        watch.close()


def open_recording(sink: str, *, recording_id: str | None = None, blueprint: rrb.Blueprint | None = None,
                   mission_id: str | None = None, footer: bool = False) -> rr.RecordingStream:
    """A new RecordingStream for one mission (or for one process of a fleet).

    ``sink``: a path ending in ``.rrd`` (saved file), ``"spawn"`` (start a viewer on loopback), ``"memory"`` (tests),
    ``"none"`` (disabled), or a ``rerun+http://host:port/proxy`` URL (connect to a running viewer).

    ``recording_id``: processes that pass the same id (and the same application id, which this module fixes) write
    into ONE recording: stream them all to one viewer or ``rerun --serve``/``--save`` URL, or save one ``.rrd`` per
    process and merge them (``rerun rrd merge a.rrd b.rrd -o all.rrd``; see docs/recording.md). None: a new
    random id. ``mission_id`` is the former name of ``recording_id`` (kept for callers that still use it).
    ``blueprint``: the layout, sent with the stream as the active one (and the default); a fleet sends it from ONE
    process only (the fusion node), because the last blueprint received wins.
    ``footer``: end a saved file with Rerun's footer, an index of every chunk for random access. Off by default:
    Rerun keeps that index in memory until the file is closed, one row per chunk and one column per (timeline,
    component) the recording uses (~6 kB a chunk here, ~+30 MB per 100 s of mission: the process grew without
    bound). Without it memory stays flat; ``p3at review`` and the viewer read the file by scanning it, and
    ``rerun rrd optimize`` writes a copy with a footer. See docs/reliability.md, "Memory over a long mission".
    """
    live = sink in ("memory", "spawn", "none") or sink.startswith(RERUN_URL_PREFIXES)
    # a saved file is read later: batching rows for FILE_FLUSH_TICK s instead of Rerun's 0.2 s makes several times
    # fewer chunks (each carries its own Arrow schema), for at most that long of rows held in memory (and lost
    # on a hard kill; the maps themselves are snapshotted to disk by the runtime)
    batching = None if live else rr.ChunkBatcherConfig(flush_tick=FILE_FLUSH_TICK)
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id or mission_id,
                             default_enabled=(sink != "none"), batcher_config=batching)
    if sink == "memory":
        rec.memory_recording()
        return rec
    if sink == "spawn":
        rec.connect_grpc(spawn_viewer())
    elif sink.startswith(RERUN_URL_PREFIXES):
        try:
            rec.connect_grpc(sink)
        except RuntimeError as e:   # Rerun's 'invalid endpoint ...': a bad URL is the user's, said in one line
            raise ViewerError(f"--rerun {sink}: {e}") from None
    elif sink != "none":
        Path(sink).parent.mkdir(parents=True, exist_ok=True)
        WRITERS[rec] = FileWriterWatch.save(rec, Path(sink), footer)
        SAVED_STREAMS.add(rec)
    if blueprint is not None and sink != "none":
        # active, not only the default: a viewer keeps the layout it last showed for this application id (any earlier
        # p3at recording, a data set run's included), and a default would wait behind it for "reset blueprint"
        rec.send_blueprint(blueprint, make_active=True, make_default=True)
    return rec


def recording_id(rec: rr.RecordingStream) -> str | None:
    """The id of ``rec``'s recording: give it to the other processes of a fleet (``open_recording(recording_id=)``)."""
    return rec.get_recording_id()


__all__ = ["APPLICATION_ID", "FILE_FLUSH_TICK", "FLUSH_STEP", "SAVED_STREAMS", "VIEWER_PORT", "WRITERS",
           "WRITER_THREAD", "FileWriterWatch", "ViewerError", "finish_saved", "open_recording",
           "recording_id", "release_saved", "spawn_viewer", "writer_failure"]
