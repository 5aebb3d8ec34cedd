"""Whether Rerun still takes a recording, seen from outside without asking Rerun anything: :class:`FileWriterWatch`
for a saved file (its writer thread, and the file through a descriptor of ours), :class:`ViewerWatch` for a live
stream to a viewer URL (this process's own TCP connection to the viewer's port). Linux (/proc); elsewhere a watch
sees less (said at each). Where a recording goes, and what is done once a watch says it stopped, is
runtime/rerun_sink.py's."""
from __future__ import annotations

import os
import threading
import time
import weakref
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from runtime.rerun_sdk import rr

# -- is Rerun still writing a saved file? -----------------------------------------------------------------------------
# Rerun 0.41's file sink writes from one thread of that name; a write that fails (a full disk, a file-size limit) ends
# it with one ERROR line of Rerun's, and every later row is dropped without a word. The SDK offers no status: only a
# flush says so, and a flush queued as the writer dies is never answered, so that every later flush times out and
# the stream's disconnect, or the process's exit, waits for ever (session 48: docs/reliability.md)
WRITER_THREAD = "file_writer"
_TASKS = "/proc/self/task"   # Linux; elsewhere the watch sees only a removed file


def _each_in_proc(folder: str, read: Callable[[str], str | None]) -> set[str]:
    """What ``read(name)`` gives for each entry of a /proc folder (None: left out), passing over an entry gone since
    the folder was listed; empty where the folder is not (not Linux)."""
    found = set()
    try:
        names = os.listdir(folder)
    except OSError:
        return found
    for name in names:
        try:
            value = read(name)
        except OSError:   # gone since it was listed
            continue
        if value is not None:
            found.add(value)
    return found


def _writer_threads() -> set[str]:
    """The ids of this process's threads named WRITER_THREAD (empty where /proc is not)."""
    def writer(tid: str) -> str | None:
        with open(f"{_TASKS}/{tid}/comm") as comm:
            return tid if comm.read().strip() == WRITER_THREAD else None

    return _each_in_proc(_TASKS, writer)


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


# -- is a viewer still taking a live stream? -----------------------------------------------------------------------
# A viewer that goes away mid-run severs the connection: a later flush says so at once ('gRPC connection severed'),
# and a flush started but not waited for (timeout 0) never does, so the watch looks at the process's own TCP
# connections instead (runtime/rerun_sink.py says what Rerun 0.41's gRPC sink does where nothing listens).
VIEWER_LOOK_INTERVAL = 2.0   # s between two looks at a live stream's connection (ViewerWatch)
_NET_TCP = ("/proc/self/net/tcp", "/proc/self/net/tcp6")   # every socket of the network namespace, not ours only
_FDS = "/proc/self/fd"
_ESTABLISHED = "01"


def _peers(port: int) -> list[tuple[str, str]]:
    """(state, inode) of the network namespace's TCP sockets whose remote port is ``port``: other processes' too."""
    hex_port = f":{port:04X}"
    found = []
    for table in _NET_TCP:
        try:
            with open(table) as rows:
                next(rows, None)
                for row in rows:
                    fields = row.split()
                    if len(fields) > 9 and fields[2].endswith(hex_port):
                        found.append((fields[3], fields[9]))
        except OSError:
            continue
    return found


def _own_sockets() -> set[str]:
    """The inodes of the sockets this process holds (``socket:[INODE]`` in /proc/self/fd)."""
    def inode(fd: str) -> str | None:
        target = os.readlink(f"{_FDS}/{fd}")
        return target[8:-1] if target.startswith("socket:[") else None

    return _each_in_proc(_FDS, inode)


def _connected(port: int) -> bool:
    """Whether this process holds an established TCP connection to ``port`` (another process's is not counted)."""
    established = {inode for state, inode in _peers(port) if state == _ESTABLISHED}
    return bool(established) and not established.isdisjoint(_own_sockets())   # the descriptors only if need be


class ViewerWatch:
    """Whether the viewer at a URL still takes the live stream, seen from outside without asking Rerun: a TCP
    connection of this process's to its port was established and is gone (another process's connection to the same
    viewer, a second mission streaming to it, is not this stream's). A viewer that never answered is not seen here
    (the URL is checked before a run, and runtime/rerun_sink.py's ``finish_live`` bounds the last flush). Linux
    (/proc); elsewhere it sees nothing.

    ``port``: the viewer's (None: the URL names none, and nothing is watched).

    A thread of its own looks every VIEWER_LOOK_INTERVAL s: reading the TCP table walks the kernel's whole socket hash
    (8 ms a read measured on the project's machine, with 61 rows), too long for a robot's logging call to wait on;
    the process's descriptors are read only when an established connection to the port is in it. :meth:`failure`
    only reads what it found."""

    def __init__(self, url: str, port: int | None) -> None:
        self.url = url
        self.port = port
        self.connected = False   # a connection to the port was seen
        self._failure: str | None = None
        self._stop = threading.Event()
        if self.port is not None:
            threading.Thread(target=self._look, name="viewer_watch", daemon=True).start()

    def _look(self) -> None:
        while not self._stop.wait(VIEWER_LOOK_INTERVAL):
            if _connected(self.port):
                self.connected = True
            elif self.connected:
                self._failure = "the viewer closed the connection"
                return

    def failure(self) -> str | None:
        """None while the viewer takes the stream (or it was never seen connected); else why not."""
        return self._failure

    def close(self) -> None:
        self._stop.set()


__all__ = ["VIEWER_LOOK_INTERVAL", "WRITER_THREAD", "FileWriterWatch", "ViewerWatch"]
