"""Where a recording goes: :func:`open_recording` opens one mission's ``rr.RecordingStream`` on a saved ``.rrd``
file, a viewer it starts on loopback (:func:`spawn_viewer`), a running viewer's URL, memory (tests) or nowhere.
Whether Rerun still takes it (a saved file's writer, a viewer's connection) is seen by runtime/rerun_watch.py's
watches; this module flushes and detaches a stream by what they say. What is logged into it is runtime/rerun_log.py's;
how a saved file is read back, runtime/rerun_read.py's."""
from __future__ import annotations

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
from runtime.rerun_watch import FileWriterWatch, ViewerWatch

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

# -- flushing and detaching a saved file ----------------------------------------------------------------------------
# Rerun 0.41 offers no status of its file sink: runtime/rerun_watch.py's FileWriterWatch sees from outside whether
# the writer still writes, and a flush queued as the writer dies is never answered (see finish_saved)
FLUSH_STEP = 1.0   # s: a saved file is flushed in steps this long, and the writer looked at between them
BLIND_FLUSH_STEPS = 60   # steps waited for a writer whose thread could not be found (not Linux), then given up


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
            _abandon(rec)


def _abandon(rec: rr.RecordingStream) -> None:
    """Keep ``rec`` for the life of the process and drop Rerun's exit hook: a stream whose flush Rerun may never
    answer (a saved file's stranded flush, :func:`_settle`; a viewer URL that took nothing, :func:`finish_live`)."""
    import ctypes

    ctypes.pythonapi.Py_IncRef(ctypes.py_object(rec))   # never freed: its finalizer would wait for ever
    _ABANDONED.append(rec)
    rr.unregister_shutdown()


def release_saved(rec: rr.RecordingStream) -> None:
    """Detach ``rec``'s sink (a saved file is complete afterwards) and drop its watch; a stream with a stranded
    flush (:func:`_settle`), or a live stream whose last rows nothing took (:func:`finish_live`), is left attached:
    detaching it would wait."""
    watch = WRITERS.pop(rec, None)
    viewer = VIEWERS.pop(rec, None)
    if viewer is not None:
        viewer.close()
    if not any(rec is stranded for stranded in _ABANDONED):
        rec.disconnect()
    if watch is not None:
        watch.close()


# -- a live stream to a viewer URL: checked before a run, flushed with a bound at its end ----------------------
# Rerun 0.41's gRPC sink, given a URL where nothing listens, retries for ever: rows queue, a flush without a timeout
# never returns (``p3at run --rerun rerun+http://127.0.0.1:9899/proxy`` waited in close for ever, and SIGTERM could
# not end it: the handler never ran), and a queue that fills blocks every log call. A viewer that goes away mid-run
# severs the connection; runtime/rerun_watch.py's ViewerWatch sees it from outside.
VIEWER_CHECK_TIMEOUT = 2.0   # s: the TCP connect that checks a URL before a run
LIVE_FLUSH_STEPS = 5         # FLUSH_STEP steps a live stream's last rows are waited for, then given up


def viewer_address(url: str) -> tuple[str, int] | None:
    """(host, port) of a ``rerun+http://HOST:PORT/proxy`` URL (None: no port given, or not a URL)."""
    from urllib.parse import urlsplit

    if not url.startswith(RERUN_URL_PREFIXES):
        return None
    try:
        parts = urlsplit(url.split("+", 1)[1] if url.startswith("rerun+") else url)
        port = parts.port
    except ValueError:
        return None
    return (parts.hostname, port) if parts.hostname and port else None


def viewer_url_problem(url: str, timeout: float = VIEWER_CHECK_TIMEOUT) -> str | None:
    """Why nothing at ``url`` can take a live stream, in one line naming it (None: something accepts a TCP
    connection at its host and port, or the URL names no port): said before a run, which otherwise ended in a
    close that never returned."""
    address = viewer_address(url)
    if address is None:
        return None
    host, port = address
    try:
        socket.create_connection(address, timeout=timeout).close()
    except OSError as e:
        why = ("connection refused" if isinstance(e, ConnectionRefusedError) else
               f"no answer within {timeout:g} s" if isinstance(e, TimeoutError) else (e.strerror or str(e)))
        return (f"--rerun {url}: no Rerun viewer listens at {host}:{port} ({why}); start one with `rerun` "
                f"(it listens on {VIEWER_PORT}), or give --rerun file")
    return None


# the watch of each stream open_recording connects to a viewer URL
VIEWERS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _watch_viewer(url: str) -> ViewerWatch:
    """The watch of the connection to the viewer at ``url`` (none is watched if the URL names no port)."""
    address = viewer_address(url)
    return ViewerWatch(url, None if address is None else address[1])


def viewer_lost(rec: rr.RecordingStream) -> str | None:
    """Why the viewer ``rec`` streams to stopped taking it (None: it takes it, or ``rec`` streams to no URL)."""
    watch = VIEWERS.get(rec)
    return None if watch is None else watch.failure()


def live_url(rec: rr.RecordingStream) -> str | None:
    """The viewer URL ``rec`` streams to (None: it streams to none)."""
    watch = VIEWERS.get(rec)
    return None if watch is None else watch.url


def finish_live(rec: rr.RecordingStream) -> str | None:
    """Flush a stream to a viewer URL, in FLUSH_STEP steps, at most LIVE_FLUSH_STEPS of them: None when the viewer
    took every row, else why not. A flush Rerun could not finish (nothing took the rows) leaves the stream kept for
    the process's life and Rerun's exit hook dropped (:func:`_abandon`), so that neither its detaching nor the exit
    waits on it; a severed connection says so at once and detaches at once."""
    lost = viewer_lost(rec)
    for _ in range(LIVE_FLUSH_STEPS):
        try:
            rec.flush(timeout_sec=FLUSH_STEP)
        except RuntimeError as e:
            if "timed out" in str(e) or "unable to connect" in str(e):
                continue   # 'Flush timed out ...', 'gRPC has been unable to connect for 7s ...': wait one more step
            return lost or str(e).split(", uri:")[0]   # 'gRPC connection severed: Failed to send messages: ...'
        return lost
    _abandon(rec)
    return lost or f"nothing took its last rows within {LIVE_FLUSH_STEPS * FLUSH_STEP:g} s"


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
        url = spawn_viewer()
        rec.connect_grpc(url)
        VIEWERS[rec] = _watch_viewer(url)   # a viewer window closed mid-run is said; the end is bounded
    elif sink.startswith(RERUN_URL_PREFIXES):
        if (problem := viewer_url_problem(sink)) is not None:   # else the run's close waited for ever
            raise ViewerError(problem)
        try:
            rec.connect_grpc(sink)
        except RuntimeError as e:   # Rerun's 'invalid endpoint ...': a bad URL is the user's, said in one line
            raise ViewerError(f"--rerun {sink}: {e}") from None
        VIEWERS[rec] = _watch_viewer(sink)
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


__all__ = ["APPLICATION_ID", "FILE_FLUSH_TICK", "FLUSH_STEP", "LIVE_FLUSH_STEPS", "SAVED_STREAMS", "VIEWERS",
           "VIEWER_PORT", "WRITERS", "ViewerError", "finish_live", "finish_saved", "live_url", "open_recording",
           "recording_id", "release_saved", "spawn_viewer", "viewer_address", "viewer_lost", "viewer_url_problem",
           "writer_failure"]
