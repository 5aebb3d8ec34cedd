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
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

STREAM_MAGIC = b"RRF2"
STREAM_HEADER_SIZE = 12
MESSAGE_HEADER_SIZE = 16
FOOTER_TRAILER_SIZE = 32
FOOTER_MAGIC = b"RRF2FOOT"
KIND_END = 0
KNOWN_KINDS = {KIND_END, 1, 2, 3}


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
        remaining = length
        while remaining > 0:
            data = src.read(min(block, remaining))
            if not data:
                break
            dst.write(data)
            remaining -= len(data)


__all__ = ["RrdScan", "copy_prefix", "scan_rrd"]
