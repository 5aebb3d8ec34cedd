"""How what a mission logs every frame reaches its Rerun stream: :class:`RowSender`, the time this thread's rows
are stamped with, and each row: logged at once on a live stream, or, for a saved file, held per entity and sent with
the entity's other rows as one ``send_columns``.

runtime/rerun_log.py's MissionLog decides what is logged (the entity tree, the styles, the static scene) and hands
its per-frame rows here; the file holds the same rows at the same times either way (:meth:`RowSender.emit`).
"""
from __future__ import annotations

import atexit
import contextlib
import threading
import time
import weakref
import zlib
from collections.abc import Mapping

import numpy as np

from runtime.rerun_sdk import rr
from runtime.rerun_sink import FILE_FLUSH_TICK

HELD_ROWS_MAX = 32   # rows of one entity held at most (~2 s at 15 Hz) before they are sent, whatever the time


def _hold_share(path: str) -> float:
    """The share, in [0.5, 1), of FILE_FLUSH_TICK and HELD_ROWS_MAX that the entity ``path`` holds its rows for:
    fixed by its name, different between entities, so that they are sent at different frames (all sent at once, a
    frame would carry the whole second's sending: 10-40 ms on the loaded 2-core machine, against ~0.6 ms a frame)."""
    return 0.5 + 0.5 * zlib.crc32(path.encode()) / 2**32


def _send_at_exit(ref: weakref.ref) -> None:
    """At interpreter exit, send what a sender whose logger was never closed still holds (atexit runs this before
    Rerun's own shutdown, registered earlier, flushes the streams)."""
    sender = ref()
    if sender is not None and not sender.closed:
        with contextlib.suppress(Exception):  # the stream may already be gone: nothing more to save
            sender.send_held_rows()


class _HeldRows:
    """The rows of one entity held to be sent as one ``send_columns`` (:class:`RowSender`, saved files): each row's
    times and, per field, its instances ((n, ...) arrays; ``strips``: a list of (n, d) arrays)."""

    __slots__ = ("archetype", "with_frame", "since", "hold", "cap", "sim_time", "frame", "log_time", "fields")

    def __init__(self, archetype, with_frame: bool, since: float, share: float) -> None:
        self.archetype = archetype
        self.with_frame = with_frame
        self.since = since                                  # time.monotonic() of the first row held
        self.hold, self.cap = share * FILE_FLUSH_TICK, max(1, round(share * HELD_ROWS_MAX))
        self.sim_time: list[int] = []                      # ns, rounded as rr.set_time rounds seconds
        self.frame: list[int] = []
        self.log_time: list[int] = []
        self.fields: dict[str, list] = {}

    def add(self, t: float, frame: int | None, log_time: int, data: Mapping) -> None:
        self.sim_time.append(round(1e9 * t))
        if frame is not None:
            self.frame.append(frame)
        self.log_time.append(log_time)
        for name, value in data.items():  # copies: a caller may change its array after the call (particles)
            self.fields.setdefault(name, []).append([np.array(v, float) for v in value] if name == "strips"
                                                    else np.array(value, float))

    def columns(self) -> tuple[list, list]:
        """The index columns and the component columns, each row partitioned back to its own instances."""
        indexes = [rr.TimeColumn("sim_time", duration=np.array(self.sim_time, "timedelta64[ns]")),
                   rr.TimeColumn("log_time", timestamp=np.array(self.log_time, "datetime64[ns]"))]
        if self.with_frame:
            indexes.append(rr.TimeColumn("frame", sequence=self.frame))
        columns = []
        for name, rows in self.fields.items():
            if name == "strips":
                flat = [strip for row in rows for strip in row]
            else:
                flat = np.concatenate(rows)
            columns += self.archetype.columns(**{name: flat}).partition([len(row) for row in rows])
        return indexes, columns


class RowSender:
    """The per-frame rows of one RecordingStream ``rec``: sent at once, or held per entity when ``hold`` (a saved
    file: :meth:`emit`). Thread-safe: robots log from their own threads. What it keeps is bounded: each entity's held
    rows (at most HELD_ROWS_MAX, at most FILE_FLUSH_TICK s). ``closed``: its logger closed it (its rows were sent
    then, not at exit)."""

    def __init__(self, rec: rr.RecordingStream, hold: bool) -> None:
        self.rec = rec
        self.hold = bool(hold)
        self.closed = False
        self._held: dict[str, _HeldRows] = {}
        self._swept = time.monotonic()               # when held rows were last looked over for stale ones
        self._lock = threading.Lock()
        self._now = threading.local()               # this thread's (t, frame), as set_time set Rerun's (per thread)
        if self.hold:  # a script that never closes its logger still gets its last rows written at exit
            atexit.register(_send_at_exit, weakref.ref(self))

    def set_time(self, t: float, frame: int | None = None) -> None:
        """The time of what this thread logs next (Rerun's timelines are per thread): ``t`` s of sim_time and the
        stereo ``frame`` (None: no frame timeline), for the stream's ``rr.log`` and for the rows held here."""
        self._now.t, self._now.frame = float(t), (None if frame is None else int(frame))
        self.rec.set_time("sim_time", duration=float(t))
        if frame is not None:
            self.rec.set_time("frame", sequence=int(frame))
        else:  # set_time is sticky per thread: do not stamp this row with an older frame number
            self.rec.disable_timeline("frame")

    def current_time(self) -> tuple[float, int | None] | None:
        """This thread's (t, frame) as :meth:`set_time` last set it, or None if it never did."""
        t = getattr(self._now, "t", None)
        return None if t is None else (t, self._now.frame)

    def emit(self, path: str, archetype, data: Mapping) -> None:
        """One row of ``archetype``'s fields ``data`` (each a batch of instances: ``[[x, y, z]]`` for one) at the time
        :meth:`set_time` set in this thread: logged at once on a live stream; on a saved file (``hold``) held and
        sent with the entity's other rows as one ``send_columns`` when its oldest held row is a share of
        FILE_FLUSH_TICK s old or it holds that share of HELD_ROWS_MAX rows (the share, 0.5-1, differs by entity:
        :func:`_hold_share`), when an entity no longer logged has held a row for FILE_FLUSH_TICK s, or at
        :meth:`send_held_rows` (MissionLog's ``flush`` and ``close``).

        The file holds the same rows at the same times (sim_time, frame, log_time as ``rr.log`` stamps it) either
        way; a row sent with others costs a fraction of one ``rr.log`` (one conversion and one Rust call per column
        instead of per row and field). Rerun's own batcher already holds a saved file's rows up to FILE_FLUSH_TICK s,
        so a hard kill loses up to about twice that of these rows (never a map: maps/* are logged at once)."""
        if not self.hold:
            self.rec.log(path, archetype.from_fields(**data))
            return
        t, frame = self._now.t, self._now.frame
        with self._lock:
            rows = self._held.get(path)
            if rows is not None and (rows.archetype is not archetype or rows.with_frame != (frame is not None)):
                self._send(path, self._held.pop(path))  # a row of another kind: what is held goes first
                rows = None
            now = time.monotonic()
            if rows is None:
                rows = self._held[path] = _HeldRows(archetype, frame is not None, now, _hold_share(path))
            rows.add(t, frame, time.time_ns(), data)
            if now - rows.since >= rows.hold or len(rows.sim_time) >= rows.cap:
                self._send(path, self._held.pop(path))
            if now - self._swept >= FILE_FLUSH_TICK:  # entities no longer logged (a closed path segment, a robot gone)
                self._swept = now
                for stale in [p for p, r in self._held.items() if now - r.since >= FILE_FLUSH_TICK]:
                    self._send(stale, self._held.pop(stale))

    def _send(self, path: str, rows: _HeldRows) -> None:
        indexes, columns = rows.columns()
        self.rec.send_columns(path, indexes=indexes, columns=columns)

    def send_held_rows(self) -> None:
        """Send the rows held for a saved file now (MissionLog's ``flush`` and ``close`` do); under the lock, so that
        one thread sends at a time, in order."""
        with self._lock:
            held, self._held = self._held, {}
            for path, rows in held.items():
                self._send(path, rows)


__all__ = ["HELD_ROWS_MAX", "RowSender"]
