"""Sensor logs: the raw streams of one robot on disk, for deterministic replay on a machine with no robot.

Format (version 1; a folder; no pickle anywhere, read with ``np.load(allow_pickle=False)``)::

    LOG/index.json                  {"format": "p3at-sensor-log", "version": 1, "metadata": {...},
                                     "chunks": [{"file", "stream", "count", "t0", "t1"}, ...], "closed": bool}
    LOG/<stream>-<NNNNNN>.npz       one chunk of consecutive records of one stream

A record is a flat mapping of field name -> number or array, and always has ``t`` (seconds, the runtime's
clock). In a chunk each field is one array stacked over the records, axis 0. Fields whose rows differ in
shape (e.g. a variable number of points) are stored concatenated along axis 0 with ``<field>__offsets``
((count + 1,) int64) giving each record's slice. Streams the runtime writes:

    odometry      t, x, y, theta (m, rad: odometry pose), v, w, stall (0/1), sonar (S,) m, sonar_poses (S, 3)
    frames        t, seq, left, right ((H, W) or (H, W, 3) uint8 rectified or raw pair, see metadata)
    observations  t, seq, points (N, 3), covariances (N, 3, 3), descriptors (N, D), pixels (N, 2)
                  (a synthetic camera gives observations, not images)
    processed     t, seq: the frames the live pipeline processed (the rest it dropped), in order

Each chunk is written atomically, then the index is rewritten atomically, so a log cut short by a crash
or a Ctrl-C still reads up to its last complete chunk. Writing happens on the writer's own thread: a
driver's callback only appends to a queue; records not yet on disk are bounded in bytes (records beyond the
budget are counted in ``dropped``, never block the caller).
"""
from __future__ import annotations

import io
import json
import os
import queue
import threading
import zipfile
from collections.abc import Iterator, Mapping
from pathlib import Path

import numpy as np

from estimation.fileio import atomic_write_bytes

FORMAT_NAME = "p3at-sensor-log"
FORMAT_VERSION = 1
INDEX = "index.json"


class SensorLogError(ValueError):
    """A sensor log is missing, malformed or of an unknown version; the message names the file and field."""


def _stack(values: list[np.ndarray]) -> dict[str, np.ndarray]:
    if all(v.shape == values[0].shape for v in values):
        return {"": np.stack(values)}
    for v in values:
        if v.ndim == 0:
            raise ValueError("a ragged field must be an array in every record")
    offsets = np.cumsum([0] + [len(v) for v in values]).astype(np.int64)
    return {"": np.concatenate(values), "__offsets": offsets}


def encode_chunk(records: list[Mapping], compress: bool = True) -> bytes:
    """The npz bytes of one chunk of records that all have the same fields."""
    fields = list(records[0])
    arrays: dict[str, np.ndarray] = {}
    for name in fields:
        if "__" in name:
            raise ValueError(f"field name {name!r} may not contain '__'")
        for suffix, array in _stack([np.asarray(r[name]) for r in records]).items():
            arrays[name + suffix] = array
    buf = io.BytesIO()
    (np.savez_compressed if compress else np.savez)(buf, **arrays)
    return buf.getvalue()


def decode_chunk(path: Path, count: int) -> list[dict[str, np.ndarray]]:
    """The records of one chunk file (``count`` of them)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise SensorLogError(f"{path}: chunk file is missing") from None
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as e:
        raise SensorLogError(f"{path}: not a readable chunk ({e})") from None
    if "t" not in arrays:
        raise SensorLogError(f"{path}: field 't' is missing")
    records: list[dict[str, np.ndarray]] = [{} for _ in range(count)]
    for name, array in arrays.items():
        if name.endswith("__offsets"):
            continue
        offsets = arrays.get(name + "__offsets")
        if offsets is not None:
            if offsets.shape != (count + 1,) or offsets[-1] != len(array) or np.any(np.diff(offsets) < 0):
                raise SensorLogError(f"{path}: field '{name}__offsets' does not match {count} records")
            for i in range(count):
                records[i][name] = array[offsets[i]:offsets[i + 1]]
        else:
            if len(array) != count:
                raise SensorLogError(f"{path}: field '{name}' has {len(array)} rows, the index says {count}")
            for i in range(count):
                records[i][name] = array[i]
    return records


class SensorLogWriter:
    """Writes records to a log folder from any thread without blocking it (a bounded queue, own thread).

    ``chunk_records``: records per chunk per stream; ``flush_interval``: seconds (of record time) after
    which a partial chunk is written anyway, so that little is lost on a crash.
    """

    def __init__(self, folder: str | os.PathLike, metadata: Mapping | None = None, *, chunk_records: int = 50,
                 flush_interval: float = 2.0, compress: bool = True, queue_size: int = 2000,
                 max_queued_bytes: int = 256 << 20) -> None:
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        if (self.folder / INDEX).exists():
            raise SensorLogError(f"{self.folder}: already holds a sensor log (choose a new folder)")
        self.metadata = dict(metadata or {})
        self.chunk_records, self.flush_interval, self.compress = chunk_records, flush_interval, compress
        self._chunks: list[dict] = []
        self._pending: dict[str, list[Mapping]] = {}
        self._counters: dict[str, int] = {}
        self._queue: queue.Queue = queue.Queue(maxsize=queue_size)
        self.max_queued_bytes = max_queued_bytes
        self._queued_bytes = 0
        self._bytes_lock = threading.Lock()
        self.dropped = 0
        self.error: BaseException | None = None
        self._closed = False
        self._write_index(closed=False)
        self._thread = threading.Thread(target=self._run, name=f"sensorlog:{self.folder.name}", daemon=True)
        self._thread.start()

    def write(self, stream: str, record: Mapping) -> None:
        """Queue one record (must hold ``t``); never blocks: if the disk cannot keep up it counts a drop."""
        if self._closed:
            return
        if "t" not in record:
            raise ValueError("a sensor-log record needs a time field 't'")
        size = sum(getattr(v, "nbytes", 8) for v in record.values())
        with self._bytes_lock:
            if self._queued_bytes + size > self.max_queued_bytes:
                self.dropped += 1  # images arriving faster than the disk takes them: bounded memory
                return
            self._queued_bytes += size
        try:
            self._queue.put_nowait((stream, dict(record), size))
        except queue.Full:
            with self._bytes_lock:
                self._queued_bytes -= size
            self.dropped += 1

    def flush(self) -> None:
        """Write every queued and pending record now (blocks until done)."""
        done = threading.Event()
        self._queue.put(("__flush__", done, 0))
        done.wait()

    def close(self) -> None:
        """Flush everything and mark the log complete. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        self._queue.put(("__close__", None, 0))
        self._thread.join()
        if self.error is not None:
            raise SensorLogError(f"{self.folder}: writing the log failed ({self.error})")

    def __enter__(self) -> SensorLogWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- the writer thread ------------------------------------------------------------------------------
    def _run(self) -> None:
        while True:
            stream, item, size = self._queue.get()
            try:
                if stream == "__flush__":
                    self._write_all()
                    item.set()
                    continue
                if stream == "__close__":
                    self._write_all()
                    self._write_index(closed=True)
                    return
                pending = self._pending.setdefault(stream, [])
                item["__size"] = size
                pending.append(item)
                age = float(item["t"]) - float(pending[0]["t"])
                if len(pending) >= self.chunk_records or age >= self.flush_interval:
                    self._write_stream(stream)
            except BaseException as e:  # keep running: a logging fault must not stop the robot
                self.error = e
                if stream == "__flush__":
                    item.set()
                elif stream == "__close__":
                    return

    def _write_all(self) -> None:
        for stream in list(self._pending):
            self._write_stream(stream)

    def _write_stream(self, stream: str) -> None:
        records = self._pending.pop(stream, [])
        if not records:
            return
        size = sum(r.pop("__size", 0) for r in records)
        with self._bytes_lock:  # the budget covers records until they are on disk
            self._queued_bytes -= size
        number = self._counters.get(stream, 0)
        self._counters[stream] = number + 1
        name = f"{stream}-{number:06d}.npz"
        atomic_write_bytes(self.folder / name, encode_chunk(records, self.compress))
        self._chunks.append({"file": name, "stream": stream, "count": len(records),
                             "t0": float(records[0]["t"]), "t1": float(records[-1]["t"])})
        self._write_index(closed=False)

    def _write_index(self, closed: bool) -> None:
        index = {"format": FORMAT_NAME, "version": FORMAT_VERSION, "metadata": self.metadata,
                 "chunks": self._chunks, "closed": closed}
        atomic_write_bytes(self.folder / INDEX, json.dumps(index, indent=1).encode())


class SensorLog:
    """Reads a sensor-log folder written by :class:`SensorLogWriter`."""

    def __init__(self, folder: str | os.PathLike) -> None:
        self.folder = Path(folder)
        path = self.folder / INDEX
        try:
            index = json.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise SensorLogError(f"{path}: no sensor log here (index.json is missing)") from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
            raise SensorLogError(f"{path}: not a readable index ({e})") from None
        if not isinstance(index, dict) or index.get("format") != FORMAT_NAME:
            raise SensorLogError(f"{path}: field 'format' is not {FORMAT_NAME!r}")
        if index.get("version") != FORMAT_VERSION:
            raise SensorLogError(f"{path}: version {index.get('version')!r} is not supported "
                                 f"(this reader knows version {FORMAT_VERSION})")
        self.metadata: dict = dict(index.get("metadata") or {})
        self.closed = bool(index.get("closed"))
        chunks = index.get("chunks")
        if not isinstance(chunks, list):
            raise SensorLogError(f"{path}: field 'chunks' is not a list")
        for i, c in enumerate(chunks):
            if not isinstance(c, dict) or not {"file", "stream", "count"} <= set(c):
                raise SensorLogError(f"{path}: chunks[{i}] lacks 'file', 'stream' or 'count'")
            if "/" in str(c["file"]) or str(c["file"]).startswith("."):
                raise SensorLogError(f"{path}: chunks[{i}] field 'file' must name a file in the log folder")
        self.chunks: list[dict] = chunks

    def streams(self) -> list[str]:
        return sorted({c["stream"] for c in self.chunks})

    def count(self, stream: str) -> int:
        return sum(int(c["count"]) for c in self.chunks if c["stream"] == stream)

    def records(self, stream: str) -> Iterator[dict[str, np.ndarray]]:
        """Every record of ``stream`` in the order it was written."""
        for c in self.chunks:
            if c["stream"] == stream:
                yield from decode_chunk(self.folder / c["file"], int(c["count"]))

    def time_span(self) -> tuple[float, float]:
        if not self.chunks:
            return 0.0, 0.0
        return min(float(c["t0"]) for c in self.chunks), max(float(c["t1"]) for c in self.chunks)
