"""How much of a Rerun ``.rrd`` file is whole: walk its message frames (no ``rerun`` import, no payload read).

Rerun's own reader (``rerun.chunk.RrdReader``, 0.41) refuses a file whose last message is cut: it scans the whole
file when it opens it and fails on the first incomplete frame. A recording cut short by a crash or a kill is
still worth reading, so :func:`scan_rrd` finds the last complete message and the caller reads that prefix.

Framing of an ``.rrd`` stream (rerun 0.41, ``re_log_encoding``; checked against files this project writes)::

    stream header   12 bytes: b"RRF2", the writer's version (4 bytes), encoding options (4 bytes)
    message         kind u64 LE, length u64 LE, then ``length`` bytes of payload
                    kind: 1 SetStoreInfo, 2 ArrowMsg, 3 BlueprintActivationCommand, 0 End
    after End       a 32-byte footer trailer ending in b"RRF2FOOT" + a u32 version (the End payload is the footer)

Several streams may follow each other in one file (each starts with its own header).

A byte flipped inside a message's payload (a bad disk) leaves the frames whole, but Rerun's reader then refuses the
whole file. The format has no checksum, so only decoding tells a damaged message from a sound one: :func:`salvage`
finds the messages Rerun cannot decode by reading candidate files made of the stream header, the store information
and blocks of messages (bisecting a block that fails), and writes a copy without them. Rerun decodes each message on
its own (its own Protobuf envelope, its own LZ4 block, its own Arrow IPC schema), so a block reads if and only if
each of its messages does.

Rerun's reader (Rust) also *aborts the process* on some damaged messages (about 3 % of single-bit flips: arrow-buffer
"the offset of the new Buffer cannot exceed the existing length", arrow-ipc "Type NONE not supported"; SIGABRT, no
exception to catch). :class:`ReadingProcesses` reads the candidates in child processes instead: a candidate whose
child dies does not decode, exactly as one whose reading raises.
"""
from __future__ import annotations

import os
import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from multiprocessing.context import BaseContext
from pathlib import Path

STREAM_MAGIC = b"RRF2"
STREAM_HEADER_SIZE = 12
MESSAGE_HEADER_SIZE = 16
FOOTER_TRAILER_SIZE = 32
FOOTER_MAGIC = b"RRF2FOOT"
KIND_END = 0
KIND_ARROW = 2
# what a reading says when Rerun's reader stopped on a damaged message it could not blame or leave out (killed by it,
# or refused by a probe): written by runtime/rerun_read.py and runtime/commands/review.py, recognised by the latter
STOPPED_ON_DAMAGE = "not a readable Rerun recording: Rerun's reader stopped on a damaged message"
KNOWN_KINDS = {KIND_END, 1, KIND_ARROW, 3}


@dataclass(frozen=True)
class RrdScan:
    """What :func:`scan_rrd` found.

    whole_bytes: the length of the prefix made of complete frames (equal to ``file_size`` for an intact file);
    messages: complete messages in it; ended: the last stream closed with an End message;
    damage: why the walk stopped before the end of the file (None when it did not).
    """

    file_size: int
    whole_bytes: int
    messages: int
    ended: bool
    damage: str | None

    @property
    def truncated(self) -> bool:
        return self.damage is not None


def scan_rrd(path: str | Path) -> RrdScan:
    """Walk the frames of ``path``; never reads a payload, so memory stays constant whatever the file claims.

    Raises ValueError if the file does not start with a Rerun stream header.
    """
    path = Path(path)
    size = path.stat().st_size
    with path.open("rb") as f:
        header = f.read(STREAM_HEADER_SIZE)
        if len(header) < STREAM_HEADER_SIZE or header[:4] != STREAM_MAGIC:
            raise ValueError(f"{path}: not a Rerun recording (no {STREAM_MAGIC!r} stream header)")
        position, messages, ended, whole = STREAM_HEADER_SIZE, 0, False, STREAM_HEADER_SIZE
        while position < size:
            f.seek(position)
            head = f.read(MESSAGE_HEADER_SIZE)
            if head[:4] == STREAM_MAGIC and len(head) >= STREAM_HEADER_SIZE:  # a following stream (no kind spells it)
                position += STREAM_HEADER_SIZE
                whole, ended = position, False
                continue
            if len(head) < MESSAGE_HEADER_SIZE:
                return RrdScan(size, whole, messages, ended, f"a message header cut at byte {position}")
            kind, length = struct.unpack("<QQ", head)
            if kind not in KNOWN_KINDS:
                return RrdScan(size, whole, messages, ended, f"an unknown message kind {kind} at byte {position}")
            end = position + MESSAGE_HEADER_SIZE + length
            if end > size:
                return RrdScan(size, whole, messages, ended,
                               f"a message of {length} bytes at byte {position} runs past the end of the file")
            position = end
            if kind == KIND_END:
                # the footer trailer (it locates the End payload, Rerun's manifest); a cut one loses nothing
                f.seek(position)
                trailer = f.read(FOOTER_TRAILER_SIZE)
                if len(trailer) == FOOTER_TRAILER_SIZE and trailer[20:28] == FOOTER_MAGIC:
                    position += FOOTER_TRAILER_SIZE
                elif len(trailer) and trailer[:4] != STREAM_MAGIC:
                    return RrdScan(size, whole, messages, ended, f"a footer cut at byte {position}")
                ended = True
            else:
                messages += 1
            whole = position
    return RrdScan(size, whole, messages, ended, None)


def copy_prefix(source: str | Path, target: str | Path, length: int, block: int = 1 << 20) -> None:
    """Copy the first ``length`` bytes of ``source`` to ``target`` in blocks (memory: one block)."""
    with Path(source).open("rb") as src, Path(target).open("wb") as dst:
        _copy(src, dst, length, block)


def _copy(src, dst, length: int, block: int) -> int:
    """Copy up to ``length`` bytes from ``src``'s position to ``dst`` in blocks; returns the bytes left (short file)."""
    remaining = length
    while remaining > 0:
        data = src.read(min(block, remaining))
        if not data:
            break
        dst.write(data)
        remaining -= len(data)
    return remaining


@dataclass(frozen=True)
class Message:
    """One complete message: ``start`` is its frame header's offset, ``size`` frame header + payload, ``header`` the
    offset of the stream header it follows (a file may hold several streams)."""

    start: int
    size: int
    kind: int
    header: int


def messages(path: str | Path, whole_bytes: int) -> tuple[list[Message], bool]:
    """The complete messages of the first ``whole_bytes`` of ``path`` (:attr:`RrdScan.whole_bytes`), in file order,
    End messages left out; and whether there was an End message (its footer, Rerun's manifest, gives the offsets of
    the messages: a copy without some of them cannot keep it). Reads the frame headers only."""
    out: list[Message] = []
    had_end = False
    with Path(path).open("rb") as f:
        position = header = 0
        while position < whole_bytes:
            f.seek(position)
            head = f.read(MESSAGE_HEADER_SIZE)
            if head[:4] == STREAM_MAGIC:
                header, position = position, position + STREAM_HEADER_SIZE
                continue
            if len(head) < MESSAGE_HEADER_SIZE:
                break
            kind, length = struct.unpack("<QQ", head)
            size = MESSAGE_HEADER_SIZE + length
            if kind == KIND_END:
                had_end = True
                f.seek(position + size)
                trailer = f.read(FOOTER_TRAILER_SIZE)
                size += FOOTER_TRAILER_SIZE if trailer[20:28] == FOOTER_MAGIC else 0
            else:
                out.append(Message(position, size, kind, header))
            position += size
    return out, had_end


def write_messages(source: str | Path, target: str | Path, chosen: list[Message], block: int = 1 << 20) -> None:
    """Write ``chosen`` (in file order) to ``target`` as one stream, atomically (a ``.part`` file renamed at the end).
    Memory: one block. A following stream's header is written only where its encoding differs from the one before
    (Rerun reads a stream header after a message only after an End message, and a copy has none)."""
    target = Path(target)
    part = target.with_name(target.name + ".part")
    with Path(source).open("rb") as src, part.open("wb") as dst:
        header = None
        for m in chosen:
            src.seek(m.header)
            if (stream := src.read(STREAM_HEADER_SIZE)) != header:
                dst.write(stream)
                header = stream
            src.seek(m.start)
            if _copy(src, dst, m.size, block):
                raise ValueError(f"{source}: changed while it was read (a message ends past its end)")
    os.replace(part, target)


@dataclass
class Salvage:
    """What :func:`salvage` found: ``damaged`` the messages left out (file order), ``total`` the messages there were,
    ``copy`` the file written without them, ``probes`` how many candidate files were read, ``store_damaged``: the
    store information itself does not decode (nothing can be read)."""

    total: int
    damaged: list[Message] = field(default_factory=list)
    copy: Path | None = None
    probes: int = 0
    had_end: bool = False
    store_damaged: bool = False

    def ranges(self, at_most: int = 3) -> str:
        """The damaged byte ranges, e.g. "bytes 1,234–5,678, 9,000–9,999"."""
        parts = [f"{m.start:,}–{m.start + m.size - 1:,}" for m in self.damaged[:at_most]]
        more = len(self.damaged) - at_most
        return ("bytes " + ", ".join(parts) + (f" and {more} more" if more > 0 else "")) if parts else ""


def salvage(path: str | Path, whole_bytes: int, decodes: Callable[[Path], bool], scratch: str | Path,
            block_bytes: int = 4 << 20, fanout: int = 2) -> Salvage:
    """Find the messages of ``path``'s first ``whole_bytes`` that Rerun cannot decode and write a copy without them.

    ``decodes(candidate)``: whether Rerun reads a candidate file whole (the caller's reader: in the caller's process,
    or a :class:`ReadingProcesses`). Every candidate holds the stream header and the store information (SetStoreInfo,
    blueprint activation); the Arrow messages go in blocks of about ``block_bytes``, and a block that fails is split
    into ``fanout`` parts, each read, down to its damaged messages: about one extra reading of the file, plus
    ~``fanout`` log_fanout(block's messages) small candidates per damaged message. A larger ``fanout`` reads more
    (smaller) candidates but fewer that fail: worth it when a failing candidate costs a process (one that aborts
    Rerun's reader). Store information that does not decode is left out if the rest still reads. The copy (and each
    candidate) is written in ``scratch``; memory is one copy block plus the list of message offsets. Meant for a file
    Rerun refused: a single block holding every message is taken to fail without reading it (if it does read, its
    parts all read and nothing is left out: only the reading is wasted).
    """
    if fanout < 2:
        raise ValueError(f"fanout must be at least 2, not {fanout}")
    scratch = Path(scratch)
    found, had_end = messages(path, whole_bytes)
    result = Salvage(total=len(found), had_end=had_end)
    candidate = scratch / "salvage-candidate.rrd"

    def reads(chosen: list[Message]) -> bool:
        result.probes += 1
        write_messages(path, candidate, sorted(chosen, key=lambda m: m.start))
        return decodes(candidate)

    store = [m for m in found if m.kind != KIND_ARROW]
    arrows = [m for m in found if m.kind == KIND_ARROW]
    if not reads(store):  # one at a time, keeping those that read with the ones kept before them
        kept: list[Message] = []
        for m in store:
            (kept.append if reads([*kept, m]) else result.damaged.append)(m)
        if not kept or not reads(kept):
            result.store_damaged = True
            return result
        store = kept

    def bisect(block: list[Message]) -> None:  # ``block`` does not read
        if len(block) == 1:
            result.damaged.append(block[0])
            return
        parts = min(fanout, len(block))
        bounds = [len(block) * k // parts for k in range(parts + 1)]
        for part in (block[a:b] for a, b in zip(bounds, bounds[1:], strict=False)):
            if not reads([*store, *part]):
                bisect(part)

    blocks: list[list[Message]] = [[]]
    size = 0
    for m in arrows:
        if size >= block_bytes:
            blocks.append([])
            size = 0
        blocks[-1].append(m)
        size += m.size
    # one block with the whole store information and no End: that candidate is the file, which Rerun refused (the
    # reason salvage is called): not read again (when it is an aborting file, reading it costs a process)
    is_the_file = len(blocks) == 1 and len(blocks[0]) > 1 and len(store) == len(found) - len(arrows) and not had_end
    for block in blocks:
        if block and (is_the_file or not reads([*store, *block])):
            bisect(block)   # (it reads every part of a block of several messages: nothing is blamed unread)
    result.damaged.sort(key=lambda m: m.start)
    dropped = {m.start for m in result.damaged}
    result.copy = scratch / "salvaged.rrd"
    write_messages(path, result.copy, [m for m in found if m.start not in dropped])
    candidate.unlink(missing_ok=True)
    return result


def _serve(conn, decode: Callable[[Path], bool], prepare: Callable[[], object] | None, stderr: str,
           parent: int) -> None:
    """A reading process's life: standard error to ``stderr`` (a Rust panic prints its backtrace there), ``prepare()``,
    "ready", then one answer per candidate path received, until None or the parent goes. An exception is a refusal (as
    in :func:`salvage`'s in-process reading); an abort ends the process, which the parent sees as the pipe's end.

    ``parent``: the starting process's pid, as it gave it. Not read here with ``os.getppid()``: a child that first
    runs after its parent was killed (a spare forked just before a SIGKILL, on a busy machine) would read its new
    parent's pid, never see it change, and wait for ever (a loaded CI run left one behind that way)."""
    fd = os.open(stderr, os.O_WRONLY | os.O_APPEND)
    os.dup2(fd, 2)
    os.close(fd)
    if prepare is not None:
        prepare()
    conn.send("ready")   # a child that dies before this died of its start, not of a candidate
    while True:
        try:
            # a forked child holds its elder siblings' pipe ends, so a parent killed outright (SIGKILL) closes no pipe:
            # a child whose parent is gone leaves, which closes them
            while not conn.poll(1.0):
                if os.getppid() != parent:
                    return
            candidate = conn.recv()
        except (EOFError, OSError):
            return
        if candidate is None:
            return
        try:
            answer = bool(decode(Path(candidate)))
        except Exception:  # noqa: BLE001 - the bindings raise several untyped errors on corrupt files
            answer = False
        conn.send(answer)


class ReadingProcessError(RuntimeError):
    """A reading process of :class:`ReadingProcesses` died before it could read (not a candidate's fault)."""


class ReadingProcesses:
    """``decodes(candidate)`` for :func:`salvage`, asked of a child process running ``decode``: a reader that kills
    its process (Rerun's Rust code aborts on some damaged messages) costs only that child, and the candidate counts as
    not decoding, exactly as one whose reading raises.

    A child reads candidates until one kills it (``reads_per_child=None``) or until it has read ``reads_per_child``
    of them (1: each candidate in a child of its own); the next child is started beforehand, so that its start (an
    import of Rerun, ~1 s) overlaps the reading: ``prepare()`` runs in each child as it starts (the import, when
    ``decode`` imports Rerun only when first called). ``context``: a multiprocessing context; "fork" only from a
    process that runs one thread (a forked child copies every lock another thread holds at that instant: Rerun's
    threads start when it is imported), else "spawn" (``decode`` and ``prepare`` must then be importable by name).
    ``decode`` runs only in the children. A child that dies before it is ready to read (its import failed, it was
    killed) raises :class:`ReadingProcessError` rather than blaming a candidate. Use as a context manager, or call
    :meth:`close`.
    """

    def __init__(self, decode: Callable[[Path], bool], context: BaseContext, reads_per_child: int | None = None,
                 prepare: Callable[[], object] | None = None, stderr: str = os.devnull) -> None:
        if reads_per_child is not None and reads_per_child < 1:
            raise ValueError(f"reads_per_child must be at least 1, not {reads_per_child}")
        self._decode, self._context, self._limit, self._stderr = decode, context, reads_per_child, stderr
        self._prepare = prepare
        self._active: tuple | None = None    # (process, connection, reads so far, said it is ready)
        self._spare: tuple | None = None
        self.started = 0    # children started
        self.died = 0       # children that died reading a candidate
        self.reads = 0      # candidates read

    def _start(self) -> tuple:
        mine, theirs = self._context.Pipe(duplex=True)
        child = self._context.Process(target=_serve, daemon=True,
                                      args=(theirs, self._decode, self._prepare, self._stderr, os.getpid()))
        child.start()
        theirs.close()
        self.started += 1
        return child, mine, 0, False

    def _next(self) -> tuple:
        """The child to read with: the active one, else the spare (a new spare started behind it)."""
        if self._active is None:
            self._active, self._spare = (self._spare or self._start()), None
        if self._spare is None:
            self._spare = self._start()
        return self._active

    def warm(self) -> None:
        """Start the first child and its spare now (their start overlaps whatever the caller does next)."""
        self._next()

    def __call__(self, candidate: Path) -> bool:
        child, conn, reads, ready = self._next()
        if not ready:
            try:
                conn.recv()          # "ready"
            except (EOFError, OSError):
                conn.close()
                child.join()
                self._active = None
                raise ReadingProcessError(f"a reading process died as it started (exit status {child.exitcode}), "
                                          "before it read anything") from None
        self.reads += 1
        try:
            conn.send(str(candidate))
            answer = conn.recv()
        except (EOFError, OSError):   # the child died on this candidate (SIGABRT): it does not decode
            conn.close()
            child.join()
            self.died += 1
            self._active = None
            return False
        self._active = (child, conn, reads + 1, True)
        if self._limit is not None and reads + 1 >= self._limit:
            self._retire(self._active)
            self._active = None
        return answer

    @staticmethod
    def _retire(entry: tuple | None, wait: float = 5.0) -> None:
        if entry is None:
            return
        child, conn = entry[:2]
        try:
            conn.send(None)
        except OSError:
            pass
        conn.close()
        child.join(wait)
        if child.is_alive():
            child.kill()
            child.join()

    def close(self, kill: bool = False) -> None:
        """Stop the children (the spare, one still starting, and with ``kill`` every one, are killed, not waited
        for)."""
        for entry in (self._active, self._spare):
            if entry is not None and (kill or entry is self._spare or not entry[3]):
                entry[0].kill()
            self._retire(entry)
        self._active = self._spare = None

    def __enter__(self) -> ReadingProcesses:
        return self

    def __exit__(self, kind, *exc) -> None:
        self.close(kill=kind is not None)   # Ctrl-C or an error: do not wait for a reading


__all__ = ["STOPPED_ON_DAMAGE", "Message", "ReadingProcessError", "ReadingProcesses", "RrdScan", "Salvage",
           "copy_prefix", "messages", "salvage", "scan_rrd", "write_messages"]
