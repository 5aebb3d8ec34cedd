"""Reading a mission's recording back: :func:`read_recording` rebuilds the maps, alignments and summary a ``.rrd``
holds (what ``p3at review`` prints and exports), whole or cut short or with damaged messages left out (with
runtime/rrd_salvage.py). What it reads is what runtime/rerun_log.py's MissionLog wrote."""
from __future__ import annotations

import contextlib
import json
import tempfile
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import runtime.rerun_sdk  # noqa: F401  (Rerun imported quietly, before _rrd_reader imports rerun.chunk)
from estimation.landmark_map import LandmarkMap
from runtime.rerun_map_format import CLOSED_ENTITY, OPTIONAL_MAP_ARRAYS, map_arrays, map_checksum
from runtime.rrd_salvage import STOPPED_ON_DAMAGE, ReadingProcesses, copy_prefix, salvage, scan_rrd
from runtime.textfile import not_a_file


class RecordingReadError(ValueError):
    """A ``.rrd`` file is missing or holds no p3at-fusion mission; the message names the file."""


@dataclass
class RecordingContents:
    """What :func:`read_recording` finds in a mission's ``.rrd``."""

    path: Path
    robots: list[str]
    duration: float                       # seconds of sim_time covered
    maps: dict[str, LandmarkMap]          # the last logged map of each robot, and "fused"
    alignments: dict[str, dict]           # "a_b" -> the last alignment result logged for that pair
    summary: dict | None                  # the mission summary, when the mission finished
    entity_count: int
    truncated: str | None = None          # how the file was cut short (what was read is what it held), or None
    ended: bool = True                    # the writer closed it (End message or mission/closed); False after a crash
    damaged: str | None = None            # which messages did not decode and were left out (the rest was read), or None


def _last_values(rows: list[dict], key: str):
    for row in reversed(rows):
        value = row.get(key)
        if value is not None and value != []:
            return value
    return None


class _LazyScratch:
    """A ``p3at-review-*`` temporary folder made only when :meth:`path` is first asked for (a file cut short, a
    salvage) and removed as the ``with`` block ends, whichever way it ends. Reading a sound recording makes none, so
    a reader killed while reading one (the usual case) leaves nothing behind in the temporary folder."""

    def __init__(self) -> None:
        self._folder: tempfile.TemporaryDirectory | None = None

    def path(self) -> Path:
        if self._folder is None:
            self._folder = tempfile.TemporaryDirectory(prefix="p3at-review-")
        return Path(self._folder.name)

    def __enter__(self) -> _LazyScratch:
        return self

    def __exit__(self, *exc) -> None:
        if self._folder is not None:
            self._folder.cleanup()
            self._folder = None


def read_recording(path: str | Path, *more: str | Path, isolated: bool = False,
                   decodes: Callable[[Path], bool] | None = None) -> RecordingContents:
    """Read a mission's ``.rrd`` (rerun 0.41 ``rerun.chunk.RrdReader``) and rebuild its maps and figures.

    ``more``: further files of the same recording, e.g. one per process of a fleet that saved its own
    (``open_recording(..., recording_id=...)``); their contents are read as one recording. Each process keeps its
    own simulated time, so the files' times do not order one entity's rows across files: a fleet's fusion node's
    file (see :func:`_fusion_node_file`) gives the alignments, the fused map and the summary (the mission's figures,
    which a robot's own fusions and summary in its file are not), and a robot's own file gives its map.

    A file cut short (a crash, a kill, a full disk) is read up to its last complete message; ``truncated`` then
    says where it was cut. Rerun's reader itself refuses such a file, so the whole prefix is copied to a
    temporary file first (see runtime/rrd_salvage.py). A file with messages Rerun cannot decode (bytes flipped
    inside them) is read without them; ``damaged`` then says which.

    **Rerun's reader can kill the calling process.** On some damaged messages (about 3 % of single-bit flips) its
    Rust code aborts (SIGABRT): no exception, the caller's process ends. By default the file is read in this
    process (fast: a 108 MB recording in ~4 s), so a script dies with it. ``isolated=True`` first reads each file
    in a child process (spawned; it imports Rerun, ~1-2 s) and, when that fails, finds the damaged messages with
    every candidate read in child processes (:class:`runtime.rrd_salvage.ReadingProcesses`): the file is then
    read whole or without its damaged messages, as for any other damage, and this process only ever reads what a
    child read through. It costs a process start and a second reading of every file, hence not the default; a
    script run as a file needs the ``if __name__ == "__main__":`` guard that spawned processes need.
    ``p3at review`` reads in a child process and, when Rerun's reader kills it, reads again this way.
    ``decodes``: how to tell whether Rerun reads a file through, asked before reading one here (``isolated``
    builds one; ``p3at review`` passes one that asks its parent process).
    """
    paths = [Path(p) for p in (path, *more)]
    chunks: list = []
    sources: list[int] = []   # for each chunk, the index in ``paths`` of the file it came from
    notes: list[str] = []
    damaged: list[str] = []
    ended = True
    pool = None
    ids: dict[str, tuple[Path, str]] = {}   # "first": the first file read whole, and its recording id
    if isolated and decodes is None:
        import multiprocessing

        decodes = pool = ReadingProcesses(_decodes, multiprocessing.get_context("spawn"))
    with _LazyScratch() as scratch, pool or contextlib.nullcontext():
        for index, p in enumerate(paths):
            if not p.is_file():  # a FIFO would block Rerun's reader; a link to nothing is not "no such" file
                raise RecordingReadError(f"{p}: {not_a_file(p, 'recording')}")
            try:
                scan = scan_rrd(p)
            except (ValueError, OSError) as e:
                raise RecordingReadError(f"{p}: not a readable Rerun recording ({e})") from None
            readable = p
            if scan.truncated:
                notes.append((f"{p.name} " if more else "") + f"cut short: {scan.damage}; read the {scan.messages} "
                             f"complete messages ({scan.whole_bytes} of {scan.file_size} bytes)")
                readable = scratch.path() / f"whole-prefix-{index}.rrd"
                copy_prefix(p, readable, scan.whole_bytes)
            refused = None
            if decodes is not None and not decodes(readable):  # it would refuse it, or kill this process
                refused = RecordingReadError(f"{p}: {STOPPED_ON_DAMAGE}")
            else:
                try:
                    held, recording_id = _read_chunks(p, readable)
                except RecordingReadError as e:
                    refused = e
                else:   # files of one recording share its id (a fleet's processes are given one)
                    first_id = ids.setdefault("first", (p, recording_id))
                    if recording_id != first_id[1]:
                        raise RecordingReadError(f"{p}: recording {recording_id}, not {first_id[0]}'s "
                                                 f"{first_id[1]}: give the files of one recording (its maps would "
                                                 "replace the other's)")
            if refused is not None:
                held, note = _read_around_damage(p, scan.whole_bytes, scratch.path() / f"salvage-{index}", refused,
                                                 decodes)
                damaged.append(note)
            # Rerun ends a stream with an End message only when it writes its footer; the logger's last entity
            # says the same of a file saved without one
            closed = any(chunk.entity_path.lstrip("/") == CLOSED_ENTITY for chunk in held)
            ended = ended and (scan.ended or (closed and not scan.truncated))
            chunks.extend(held)
            sources.extend([index] * len(held))
        contents = _contents_from_chunks(paths[0], chunks, sources)
    contents.truncated, contents.ended = ("; ".join(notes) or None), ended
    contents.damaged = "; ".join(damaged + ([contents.damaged] if contents.damaged else [])) or None
    return contents


# a failing candidate read in a child process costs a process start (Rerun's import, 1-5 s on a loaded machine), a
# sound one ~10 ms: split a failing block into many parts, so that few candidates fail (a 4 MiB block of up to
# ~2,300 messages in two steps, 48 and then at most 48 candidates, instead of 11 halvings)
ISOLATED_FANOUT = 48


def _read_around_damage(path: Path, whole_bytes: int, scratch: Path, refused: RecordingReadError,
                        decodes: Callable[[Path], bool] | None = None) -> tuple[list, str]:
    """The chunks of ``path`` without the messages Rerun cannot decode, and one line saying which were left out;
    ``refused`` (what reading the whole file said) when no message can be blamed. ``decodes``: how candidates are
    read (None: in this process)."""
    try:
        scratch.mkdir()
        found = salvage(path, whole_bytes, decodes or _decodes, scratch,
                        fanout=2 if decodes is None else ISOLATED_FANOUT)
    except (OSError, ValueError):  # the file went or changed under the reader: what the reader said stands
        raise refused from None
    if found.store_damaged:
        raise RecordingReadError(f"{path}: not a readable Rerun recording: its store information does not decode "
                                 f"({found.ranges()})") from None
    if not found.damaged and not found.had_end:
        raise refused
    held, _ = _read_chunks(path, found.copy)   # its recording id unchecked: the store information may be what broke
    if not found.damaged:  # only the footer (Rerun's manifest of the messages) failed
        return held, f"{path}: its footer does not decode, left out; all {found.total:,} messages read"
    return held, (f"{path}: {len(found.damaged):,} of {found.total:,} messages damaged ({found.ranges()}), "
                  "skipped; the rest read")


def _rrd_reader(path: Path):
    """Rerun's reader of ``path`` (``rerun.chunk.RrdReader``; imported here: only reading needs it)."""
    import rerun.chunk as rrchunk

    with warnings.catch_warnings():  # files saved by a viewer or `rerun --save` have no footer: read by scanning
        warnings.filterwarnings("ignore", message=".*no footer/manifest.*")
        return rrchunk.RrdReader(path)


def _decodes(candidate: Path) -> bool:
    """Whether Rerun's reader reads ``candidate`` through (as :func:`_read_chunks` does), whatever stores it holds,
    and hands each chunk over as :func:`_contents_from_chunks` takes it (a NUL flipped into a column's name passes the
    reader and aborts the process there: "called `Result::unwrap()` on an `Err` value: NulError")."""
    try:
        reader = _rrd_reader(candidate)
        for store in reader.recordings() or reader.blueprints()[:1]:  # each: _read_chunks may read any of them
            for chunk in reader.stream(store=store).filter(content=_READ_CONTENT):
                chunk.to_record_batch()
        return True
    except Exception:  # the bindings raise several untyped errors on corrupt files
        return False


ROW_ID = "rerun.controls.RowId"   # a logged row's id, in every chunk that holds a part of it
_READ_CONTENT = ["+ /maps/**", "+ /fusion/**", "+ /mission/**", "+ /plots/**"]


def _read_chunks(path: Path, readable: Path) -> tuple[list, str]:
    """The chunks of the maps, fusion results, summary and time series (not images and point clouds), and the
    recording id of the store they are in."""
    try:
        reader = _rrd_reader(readable)
        recordings = reader.recordings()
        if not recordings:
            raise RecordingReadError(f"{path}: holds no recording")
        # a file holds one recording; a second one comes from a store id damaged in one of its SetStoreInfo
        # messages (which Rerun repeats): an empty store then, the data being in the store its messages name
        for store in recordings:
            held = list(reader.stream(store=store).filter(content=_READ_CONTENT))
            if held:
                break
        return held, str(store.recording_id)
    except RecordingReadError:
        raise
    except Exception as e:  # the bindings raise several untyped errors on corrupt files
        raise RecordingReadError(f"{path}: not a readable Rerun recording ({e})") from None


def _contents_from_chunks(path: Path, chunks: list, sources: list[int] | None = None) -> RecordingContents:
    """What the chunks hold. A logged row may come back split over several chunks, each with some of its components
    (``rerun rrd optimize`` stores a map snapshot's scalars and its arrays apart): the pieces share the row's id and
    are joined here. ``sources``: which file each chunk came from (several files of one recording; None: one)."""
    sources = sources if sources is not None else [0] * len(chunks)
    # entity -> row id -> [time, first chunk, components, file]
    rows_by_entity: dict[str, dict[object, list]] = {}
    t_min, t_max = np.inf, -np.inf
    entities: set[str] = set()
    wanted = ("maps/", "fusion/alignment/", "mission/summary")
    for order, chunk in enumerate(chunks):
        entity = chunk.entity_path.lstrip("/")
        entities.add(entity)
        batch = chunk.to_record_batch()
        names = batch.schema.names
        if "sim_time" in names:  # a duration column, nanoseconds
            times = batch.column("sim_time").cast("int64").to_numpy(zero_copy_only=False) / 1e9
            if len(times):
                t_min, t_max = min(t_min, float(times.min())), max(t_max, float(times.max()))
        else:
            times = np.full(chunk.num_rows, -np.inf)
        if not entity.startswith(wanted):
            continue
        columns = {k: batch.column(k).to_pylist() for k in names
                   if k not in ("log_time", "sim_time", "frame") and not k.startswith("rerun.")}
        ids = (batch.column(ROW_ID).to_pylist() if ROW_ID in names else [None] * chunk.num_rows)
        held = rows_by_entity.setdefault(entity, {})
        for i in range(chunk.num_rows):
            row = {k: v[i] for k, v in columns.items()}
            key = ids[i] if ids[i] is not None else (order, i)
            if key in held:
                held[key][2].update({k: v for k, v in row.items() if v is not None})
            else:
                held[key] = [float(times[i]), order, row, sources[order]]
    node = _fusion_node_file(rows_by_entity)
    maps: dict[str, LandmarkMap] = {}
    alignments: dict[str, dict] = {}
    summary = None
    stale: list[str] = []
    for entity, by_id in rows_by_entity.items():
        rows = sorted(_from_its_file(entity, list(by_id.values()), node), key=lambda r: (r[0], r[1]))
        plain = [r[2] for r in rows]
        if entity.startswith("maps/"):
            landmark_map, note = _map_from_row(path, entity, plain)
            if landmark_map is not None:
                maps[entity.removeprefix("maps/")] = landmark_map
            stale += [note] if note else []
        elif entity.startswith("fusion/alignment/"):
            text = _last_values(plain, "json")
            if text:
                alignments[entity.removeprefix("fusion/alignment/")] = json.loads(_scalar(text))
        elif entity == "mission/summary":
            text = _last_values(plain, "json")
            if text:
                summary = json.loads(_scalar(text))
    robots = sorted({e.split("/")[1] for e in entities if e.startswith("plots/") and e.count("/") >= 2}
                    - {"fusion"} | {k for k in maps if k != "fused"})
    robots = [r for r in robots if r]
    duration = float(t_max - t_min) if np.isfinite(t_min) else 0.0
    return RecordingContents(path, robots, duration, maps, alignments, summary, len(entities),
                             damaged="; ".join(stale) or None)


FUSION_NODE_ENTITIES = ("fusion/", "maps/fused", "mission/summary")   # the fusion node's word, in a fleet's files


def _summary_of(rows: list) -> dict | None:
    """The summary that ``rows`` of ``mission/summary`` (one file's) hold, or None."""
    text = _last_values([r[2] for r in sorted(rows, key=lambda r: (r[0], r[1]))], "json")
    try:
        summary = json.loads(_scalar(text)) if text else None
    except (TypeError, ValueError):
        return None
    return summary if isinstance(summary, dict) else None


def _fusion_node_file(rows_by_entity: dict[str, dict[object, list]]) -> int | None:
    """Of several files of a fleet's recording, the fusion node's (the index of its file), or None (one file, or
    none to tell). A robot process that fuses the maps it receives logs its own alignments, fused map and summary
    on its own clock (``p3at demo --processes``: robot2's at t = 141 s, the node's final fusion at 24 s), so
    ordering those rows by time across files would give a robot's figures. The node is the file whose summary
    says so (``fusion_node``: ``p3at fuse --live``; ``processes``: the node of ``p3at demo --processes``), else
    (a node that ended without its summary) the one file holding the maps of more robots than any other (the node
    logs every robot's map it fuses; a robot, its own and the fused one). Several files whose summaries say so (two
    nodes' files given with one recording id): the one of them with most robots' maps, of a tie the first given;
    a robot's file is never taken over them (it was: a tie fell back to time order, and a robot's own fusion,
    later on its clock, was printed)."""
    files = {r[3] for by_id in rows_by_entity.values() for r in by_id.values()}
    if len(files) < 2:
        return None
    summary_rows: dict[int, list] = {}
    for r in rows_by_entity.get("mission/summary", {}).values():
        summary_rows.setdefault(r[3], []).append(r)
    said = [f for f, rows in summary_rows.items()
            if (s := _summary_of(rows)) is not None and (s.get("fusion_node") is True or s.get("processes") is True)]
    if len(said) == 1:
        return said[0]
    robots_mapped = dict.fromkeys(said or files, 0)   # several that say so: one of them, never a robot's file
    for entity, by_id in rows_by_entity.items():
        if entity.startswith("maps/") and entity != "maps/fused":
            for f in {r[3] for r in by_id.values()} & robots_mapped.keys():
                robots_mapped[f] += 1
    most = max(robots_mapped.values())
    widest = sorted(f for f, n in robots_mapped.items() if n == most)
    if said:   # the one with most robots' maps, of a tie the first given
        return widest[0]
    return widest[0] if most >= 2 and len(widest) == 1 else None


def _from_its_file(entity: str, rows: list, node: int | None) -> list:
    """The rows of ``entity`` to read: with a fusion node's file (several files of a fleet), the node's for what
    the node decides (alignments, the fused map, the summary) and a robot's own file's for its map, where those
    files hold the entity; else all of them."""
    if node is None:
        return rows
    if entity.startswith(FUSION_NODE_ENTITIES):
        mine = [r for r in rows if r[3] == node]
    elif entity.startswith("maps/"):
        mine = [r for r in rows if r[3] != node]
    else:
        return rows
    return mine or rows


def _scalar(value):
    while isinstance(value, list) and len(value) == 1:
        value = value[0]
    return value


def _map_from_row(path: Path, entity: str, rows: list[dict]) -> tuple[LandmarkMap | None, str | None]:
    """The newest snapshot of ``entity`` that is whole, and a note when a newer one is damaged (it failed its checksum
    or no longer decodes into a map: it is left out, since a map read back must be the map that was logged) or None.
    A map none of whose snapshots is whole is None, with a note: it is left out, and the recording's other maps are
    still read."""
    # empty arrays are not stored by AnyValues: only the scalars are sure to be there
    complete = [r for r in rows if all(r.get(f) is not None for f in ("meta", "descriptor_size", "size"))]
    if not complete:
        raise RecordingReadError(f"{path}: entity '{entity}' does not hold a complete map")
    damages: list[str] = []
    for row in reversed(complete):
        landmark_map, damage = _map_from(entity, row)
        if damage is None:
            if not damages:
                return landmark_map, None
            what = ("fail their checksum" if all(d == CHECKSUM_FAILED for d in damages)
                    else f"are damaged ({'; '.join(dict.fromkeys(damages))})")
            return landmark_map, f"{entity}: the last {len(damages)} snapshot(s) {what}; the one before them is read"
        damages.append(damage)
    if all(d == CHECKSUM_FAILED for d in damages):
        return None, (f"{entity}: every snapshot ({len(complete)}) fails its checksum (bytes changed in the file); "
                      "the map is left out")
    return None, (f"{entity}: every snapshot ({len(complete)}) is damaged ({'; '.join(dict.fromkeys(damages))}); "
                  "the map is left out")


CHECKSUM_FAILED = "fails its checksum"


def _map_from(entity: str, row: dict) -> tuple[LandmarkMap | None, str | None]:
    """One logged snapshot as a map and None, or None and what is wrong with it: it fails its checksum (files written
    before snapshots had one are not checked), or its arrays do not decode into a map (a flipped bit can empty or
    shorten one of them)."""
    def array(name: str, dtype) -> np.ndarray:
        value = row.get(name)
        return np.asarray(value if value is not None else [], dtype)

    try:
        text = str(_scalar(row["meta"]))
        meta = json.loads(text)
        d = int(_scalar(row["descriptor_size"]))
        n = int(_scalar(row["size"]))
        robots = [str(r) for r in meta.get("robots") or [meta.get("robot", "robot")]]
        optional = {name: array(name, float).reshape(n, *OPTIONAL_MAP_ARRAYS[name])
                    for name in meta.get("optional", []) if name in OPTIONAL_MAP_ARRAYS}
        arrays = map_arrays(array("positions", float).reshape(n, 3), array("covariances", float).reshape(n, 3, 3),
                            array("descriptors", np.float32).reshape(n, d), array("ids", np.int64).reshape(n),
                            array("counts", np.int64).reshape(n),
                            array("seen_by", np.uint8).reshape(n, len(robots)),
                            array("trajectory", float).reshape(-1, 4), **optional)
        stored = row.get("checksum")
        if stored is not None and int(_scalar(stored)) != map_checksum(arrays, text):
            return None, CHECKSUM_FAILED
        return LandmarkMap(
            arrays["positions"], arrays["covariances"], arrays["descriptors"], arrays["ids"], arrays["counts"],
            str(meta.get("robot", "robot")), str(meta.get("frame", "map")), robots, arrays["seen_by"].astype(bool),
            arrays["trajectory"], dict(meta.get("metadata", {})),
            **{name: arrays.get(name) for name in OPTIONAL_MAP_ARRAYS}), None
    except (ValueError, TypeError, KeyError, AttributeError, json.JSONDecodeError) as e:
        return None, f"does not decode into a map: {e}"


__all__ = ["CHECKSUM_FAILED", "ISOLATED_FANOUT", "ROW_ID", "RecordingContents", "RecordingReadError", "read_recording"]
