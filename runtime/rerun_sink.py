"""Where a recording goes: :func:`open_recording` opens one mission's ``rr.RecordingStream`` on a saved ``.rrd``
file, a viewer it starts on loopback (:func:`spawn_viewer`), a running viewer's URL, memory (tests) or nowhere.
What is logged into it is runtime/rerun_log.py's; how a saved file is read back, runtime/rerun_read.py's."""
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
        rec.save(sink, write_footer=footer)
        SAVED_STREAMS.add(rec)
    if blueprint is not None and sink != "none":
        # active, not only the default: a viewer keeps the layout it last showed for this application id (any earlier
        # p3at recording, a data set run's included), and a default would wait behind it for "reset blueprint"
        rec.send_blueprint(blueprint, make_active=True, make_default=True)
    return rec


def recording_id(rec: rr.RecordingStream) -> str | None:
    """The id of ``rec``'s recording: give it to the other processes of a fleet (``open_recording(recording_id=)``)."""
    return rec.get_recording_id()


__all__ = ["APPLICATION_ID", "FILE_FLUSH_TICK", "SAVED_STREAMS", "VIEWER_PORT", "ViewerError",
           "open_recording", "recording_id", "spawn_viewer"]
