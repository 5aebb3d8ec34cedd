"""``p3at demo --processes``: the virtual world's robots, each with its runtime, as separate operating-system
processes on loopback, maps exchanged over Zenoh, and the fusion node in this process.

Each robot is ``p3at run --robot mock --name robotK`` (its virtual P3-AT, its virtual head and its onboard
runtime in one process: the head renders from the robot's simulated pose, so they cannot be split), with the
same seeds as in the single-process mission. Each robot process keeps its own simulated time (or the wall clock
with --realtime): the robots do not interact, so no clock crosses processes (docs/fleet.md). This process runs
the fusion node (it listens on a free loopback port, the robots connect to it), fuses on new data
and at ``--fusion-interval``, waits for every robot to finish and (at most LAST_MAP_WAIT s) for the map each
robot's last status names, fuses once more and prints the same summary as the single-process demo. A robot's last map
lost on the wire is read from the map file its process wrote at its end (said on stderr and in the summary's
``last_maps_from_file``); one that can be had neither way is said in ``last_maps_missing``. A robot process that
ends without its summary (killed) leaves the map of its last periodic save: the final fusion reads it where it is
newer than the node's map of that robot (built from more camera frames), said in the robot's failure line and in the
summary's ``robot_processes_failed``; ``fused_from`` gives which map of each robot the final fusion held.
Rerun: each robot writes OUT/<robot>/mission.rrd, the fusion node OUT/mission.rrd (every robot's map as received,
the alignments, the fused map, the summary: what ``p3at review`` reads).
"""
from __future__ import annotations

import argparse
import json
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from runtime.exchange import MapMessage
from runtime.fleet.fusion_node import FusionNode, FusionNodeConfig
from runtime.fleet.status import health_figure
from runtime.json_output import json_text
from runtime.report import fusion_progress_part

# p3at run options passed through unchanged (mission arguments shared with p3at demo)
PASSED = ("seconds", "seed", "camera", "camera_rate", "camera_latency", "particles", "max_corners",
          "max_observations", "motion", "route", "speed", "preset", "method", "world", "time_scale", "odometry",
          "map_save_interval")


FUSION_END_SAY = 30.0  # s between the lines saying the fusion node's thread still runs a live fusion at the end
LAST_MAP_WAIT = 5.0  # s the final fusion waits for each robot's last map, the one its last status names


def missing_last_maps(exchange) -> dict[str, dict]:
    """Robots whose last status names a map the exchange does not hold: robot -> {"named": its sequence, "held":
    the sequence held of that session, or None}."""
    status = exchange.status() if hasattr(exchange, "status") else {}
    held = exchange.held() if hasattr(exchange, "held") else {}
    missing = {}
    for robot, s in status.items():
        if not s.get("has_map", True) or "sequence" not in s:
            continue
        have = held.get(robot)
        if have is None or have[0] != s["session"] or have[1] < s["sequence"]:
            missing[robot] = {"named": s["sequence"],
                              "held": None if have is None or have[0] != s["session"] else have[1]}
    return missing


def await_last_maps(exchange, timeout: float = LAST_MAP_WAIT) -> dict[str, dict]:
    """Wait, at most ``timeout`` s, until the exchange has handled what it received and holds every robot's last
    map (its last status names it): a map still in the node's queue, or on the way, is in the final fusion. The
    robots whose last map never came (lost on the wire after its robot exited): :func:`missing_last_maps`."""
    end = time.monotonic() + timeout
    while True:
        missing = missing_last_maps(exchange)
        if not missing and getattr(exchange, "pending_bytes", 0) == 0:
            return {}
        if time.monotonic() >= end:
            return missing
        time.sleep(0.05)


def last_maps_from_files(exchange, summaries: dict, missing: dict[str, dict]) -> tuple[dict, dict[str, dict], set]:
    """The robots' last maps that never came over the wire, read from their files.

    A robot process that ends with its summary has written its final map at its end, atomically, after its last
    publish (``OUT/<robot>/<robot>.npz``, the summary's ``map_file``): the map it published last. Where the fusion
    node holds another map of that robot, its last map was lost on the wire: named by a status that came
    (``missing``, :func:`await_last_maps`), or lost with its status, so that nothing named it. The file's map then
    stands in, as the wire would have carried it (the wire's fields only). A file that cannot be read, or whose
    landmark count is not the one the robot's summary gives, is not used; nor an empty map.

    Returns (robot -> ``MapMessage`` for :meth:`FusionNode.final_fusion`, robot -> what the summary says: the file,
    its landmarks, the sequence the robot's status named (None if none named it) and the one held (None: none),
    the robots whose file holds the map the node holds: their final map is in the fusion, whatever a status
    named)."""
    from estimation.errors import EstimationError
    from estimation.landmark_map import LandmarkMap

    held = exchange.receive(excluding="fused")
    messages, read, final_held = {}, {}, set()
    for robot, summary in sorted(summaries.items()):
        entry = (summary.get("robots") or {}).get(robot) or {}
        if not entry.get("map_file"):
            continue
        try:
            saved = LandmarkMap.load(entry["map_file"])
        except (EstimationError, OSError, ValueError):
            continue
        if len(saved) == 0 or len(saved) != entry.get("landmarks"):
            continue
        named = missing.get(robot, {}).get("named")
        stamp = float(summary.get("sim_seconds") or 0.0)   # the robot's stop instant: its last map's stamp
        wire = _as_wire(robot, saved, stamp)
        have = held.get(robot)
        if have is not None and _same_map(have.landmark_map, wire):
            final_held.add(robot)   # the node holds the robot's final map
            continue
        sequence = named if named is not None else -1 if have is None else have.sequence + 1
        messages[robot] = MapMessage(robot, sequence, stamp, wire)
        read[robot] = {"file": entry["map_file"], "landmarks": len(saved), "named": named,
                       "held": None if have is None else have.sequence}
    return messages, read, final_held


def _as_wire(robot: str, saved, stamp: float):
    """A map read from a file as the wire would have carried it (encoded and decoded: the wire's fields only)."""
    from runtime.fleet import mapwire

    return mapwire.decode(mapwire.encode_full(robot, "0" * 16, 0, stamp, saved)).landmark_map


def _same_map(a, b) -> bool:
    """Whether two maps of one robot are the same snapshot (its landmarks, by id and position)."""
    return np.array_equal(a.ids, b.ids) and np.array_equal(a.positions, b.positions)


def _frames(m) -> int | None:
    """The camera frames a robot's map was built from (its ``slam_frames``), None if it carries no sound count."""
    from runtime.slam_frames import read_frame_counts

    try:
        counts = read_frame_counts(m.metadata)
    except ValueError:
        return None
    return None if counts is None else counts["processed"]


def _built(landmarks: int, frames: int | None) -> str:
    """'47 landmarks from 4 frames' (the frames left out when unknown)."""
    said = f"{landmarks} landmark{'' if landmarks == 1 else 's'}"
    return said if frames is None else f"{said} from {frames} frame{'' if frames == 1 else 's'}"


@dataclass
class LeftMap:
    """A robot process that ended without its summary (killed, or died before it could print it): the map file
    its periodic saves leave (atomic: a whole map or none), and what the final fusion made of it
    (:func:`map_left`): ``used`` it, ``said`` why or why not (the end of the robot's failure line)."""

    file: Path
    used: bool = False
    said: str = ""
    landmarks: int | None = None


def map_left(robot: str, left: LeftMap, have: MapMessage | None) -> MapMessage | None:
    """The map a robot process that ended without its summary left in ``left.file`` (its last periodic save), as
    the final fusion's stand-in for ``have`` (the robot's ``MapMessage`` the node holds; None: none), or None; sets
    ``left.used``, ``left.said`` and ``left.landmarks``.

    Without the robot's summary nothing gives the file's landmark count to check it by (as
    :func:`last_maps_from_files` does): the file must load (the map reader's checks), be this robot's map, hold a
    landmark, and be newer than the map held: built from more camera frames (``slam_frames.processed``: a robot's
    map only grows with its frames). The same snapshot as the one held is not read again; a file whose age cannot be
    told (no frame counts) does not replace a map held."""
    from estimation.errors import EstimationError
    from estimation.landmark_map import LandmarkMap

    kept = (f"the final fusion has the map the node received last ({len(have.landmark_map)} landmarks)"
            if have is not None else "the final fusion has no map of it")
    if not left.file.is_file():
        left.said = f"it saved no map; {kept}"
        return None
    try:
        saved = LandmarkMap.load(left.file)
    except (EstimationError, OSError, ValueError) as e:
        left.said = f"its map file is not used ({e}); {kept}"
        return None
    left.landmarks = len(saved)
    why_not = (f"it is {saved.robot}'s map, not {robot}'s" if saved.robot != robot else
               "it holds no landmark" if len(saved) == 0 else None)
    if why_not is not None:
        left.said = f"its map file {left.file} is not used ({why_not}); {kept}"
        return None
    stamp = float(saved.trajectory[-1, 0]) if len(saved.trajectory) else 0.0   # mission time of its last pose
    wire = _as_wire(robot, saved, stamp)
    frames, held_frames = _frames(wire), None if have is None else _frames(have.landmark_map)
    mine = f"its last saved map {left.file} ({_built(len(saved), frames)})"
    if have is not None and _same_map(have.landmark_map, wire):
        left.said = f"{mine} is the map the node received last, in the final fusion"
        return None
    if have is not None and (frames is None or held_frames is None or frames <= held_frames):
        than = ("cannot be told older or newer than the map the node received last (no frame counts), which the "
                f"final fusion has ({len(have.landmark_map)} landmarks)" if frames is None or held_frames is None else
                f"is no newer than the map the node received last ({_built(len(have.landmark_map), held_frames)}), "
                "which the final fusion has")
        left.said = f"{mine} {than}"
        return None
    left.used = True
    left.said = (f"the final fusion reads {mine}" + ("" if have is None else
                 f", newer than the map the node received last ({_built(len(have.landmark_map), held_frames)})"))
    return MapMessage(robot, -1 if have is None else have.sequence + 1, stamp, wire)


def final_fusion(node: FusionNode, summaries: dict, timeout: float = LAST_MAP_WAIT,
                 left: dict[str, LeftMap] | None = None):
    """The demo's final fusion, once the robot processes have ended (``summaries``: their own, by robot): wait for
    the robots' last maps (:func:`await_last_maps`), read from its file each one lost on the wire
    (:func:`last_maps_from_files`) and each newer one a robot that left no summary saved (``left``, robot ->
    :class:`LeftMap`, filled in: :func:`map_left`), fuse. Returns (the fusion's report or None, last maps missing,
    last maps read from file of robots that gave their summary)."""
    missing = await_last_maps(node.exchange, timeout)
    replace, read, final_held = last_maps_from_files(node.exchange, summaries, missing)
    held = node.exchange.receive(excluding="fused") if left else {}   # copies of every map: only when one is needed
    for robot, entry in sorted((left or {}).items()):
        message = map_left(robot, entry, held.get(robot))
        if message is not None:
            replace[robot] = message
    final = node.final_fusion(replace=replace)
    used = {r for r, entry in (left or {}).items() if entry.used}
    return final, {r: m for r, m in missing.items() if r not in read and r not in final_held and r not in used}, read


def end_fusion_thread(thread: threading.Thread, say: Callable[[str], None], period: float = FUSION_END_SAY) -> None:
    """The fusion node's thread (its stop asked: it starts no fusion after) joined once its live fusion in progress
    has ended, however long that takes (one cannot be cut short): the final fusion must not run beside it. A line
    (``say``) each ``period`` s it still runs. It was joined for 30 s, then the final fusion ran beside a live one
    still going (a loaded machine), on the node's one state (session 52; the node now also serialises its fusions:
    FusionNode.final_fusion)."""
    if not thread.is_alive():
        return
    start = time.monotonic()
    thread.join(timeout=period)
    while thread.is_alive():
        say(f"p3at demo: the fusion node's live fusion still runs {time.monotonic() - start:.0f} s after the robots "
            "ended; the final fusion waits for it")
        thread.join(timeout=period)


def free_port() -> int:
    """A TCP port free on loopback now (the OS picks it; another process may take it before it is used): the port
    the demo's fusion node listens on, and the fleet tests' ports."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def robot_command(args: argparse.Namespace, name: str, fleet: str, port: int, out: Path) -> list[str]:
    """The ``p3at run`` command line of one robot of the demo."""
    config = json.dumps({"connect": {"endpoints": [f"tcp/127.0.0.1:{port}"]}})
    command = [sys.executable, "-m", "runtime.cli", "run", "--robot", "mock", "--name", name,
               "--exchange", f"zenoh:{config}", "--fleet", fleet, "--out", str(out / name), "--json", "--quiet",
               "--fusion-interval", "0", "--rerun", "file" if args.rerun != "none" else "none",
               "--recording-id", fleet]
    for key in PASSED:
        value = getattr(args, key, None)
        if value is not None:
            command += [f"--{key.replace('_', '-')}", str(value)]
    for flag in ("log_sensors", "realtime"):
        if getattr(args, flag, False):
            command.append(f"--{flag.replace('_', '-')}")
    command.append("--smooth" if getattr(args, "smooth", True) else "--no-smooth")   # each robot as the demo says
    return command


def run_processes_demo(args: argparse.Namespace) -> int:
    from runtime.mission_cli import hold_stop_signals

    noted, restore_held = hold_stop_signals()  # first: a Ctrl-C during the imports below is not lost (session 47)
    try:
        return _run_processes_demo(args, noted)
    finally:
        restore_held()


def _run_processes_demo(args: argparse.Namespace, noted: list[int]) -> int:
    from mocks.world import World
    from runtime.fleet.options import open_exchange
    from runtime.mission import install_stop_signals
    from runtime.mission_cli import Progress
    from runtime.report import format_summary

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    try:
        world = World.load(args.world)
    except (OSError, ValueError) as e:
        print(f"p3at demo: {e}", file=sys.stderr)
        return 2
    names = sorted(world.start_poses)[: args.robots]
    if len(names) < args.robots:
        print(f"p3at demo: the world '{world.name}' has {len(names)} start poses, {args.robots} robots asked",
              file=sys.stderr)
        return 2
    if noted:  # stopped while starting: no robot process is started, no exchange opened, nothing written
        return 128 + noted[0]
    progress = Progress(not args.quiet)
    port, fleet = free_port(), f"demo{int(time.time())}"
    node_box: list[FusionNode] = []
    exchange = open_exchange(f"zenoh:{json.dumps({'listen': {'endpoints': [f'tcp/127.0.0.1:{port}']}})}", fleet,
                             "fusion", on_event=progress.event,
                             on_update=lambda robot: node_box and node_box[0].notify(robot))
    logger = None
    if args.rerun != "none":
        from runtime.rerun_log import MissionLog
        from runtime.rerun_sink import open_recording
        from runtime.rerun_style import mission_blueprint

        sink = str(out / "mission.rrd") if args.rerun == "file" else args.rerun
        logger = MissionLog(open_recording(sink, recording_id=fleet, blueprint=mission_blueprint(names)), names,
                            blueprint=False)
        logger.log_building(world.walls, world.wall_heights)
        logger.log_robot_frame("fused", np.asarray(world.start_poses[names[0]], float))
    interval = args.fusion_interval if args.fusion_interval > 0 else 1e9
    # --start-prior: the fusion node gets the robots' configured start poses as a rough prior, as the mission does
    starts = {} if args.start_prior is None else {n: (world.start_poses[n], args.start_prior) for n in names}
    node = FusionNode(exchange, FusionNodeConfig(interval=interval, min_period=max(1.0, min(interval, 5.0)),
                                                 preset=args.preset, method=args.method, seed=args.seed,
                                                 starts=starts, starts_source="configured start poses"),
                      logger=logger, on_event=progress.event)
    node_box.append(node)
    stop = threading.Event()
    processes: dict[str, subprocess.Popen] = {}
    restore = install_stop_signals(stop.set)
    if noted:  # stopped while the exchange and the recording opened (Zenoh's import): no robot process started
        restore()
        exchange.close()
        if logger is not None:
            logger.close()
        return 128 + noted[0]
    fusion_thread = threading.Thread(target=node.run, args=(stop,), name="fusion-node", daemon=True)
    start = time.monotonic()
    try:
        for name in names:
            processes[name] = subprocess.Popen(robot_command(args, name, fleet, port, out), stdout=subprocess.PIPE,
                                               stderr=subprocess.PIPE, text=True)
        progress.event(f"robots started as processes {', '.join(f'{n} (pid {p.pid})' for n, p in processes.items())}"
                       f"; fusion node on tcp/127.0.0.1:{port}, fleet {fleet}")
        fusion_thread.start()
        outputs, stalled = _wait(processes, stop, progress, node, start)
    finally:
        stop.set()
        for process in processes.values():  # Ctrl-C: every robot stops its motors and flushes its files
            if process.poll() is None:
                process.send_signal(signal.SIGTERM)
        for process in processes.values():
            try:
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                process.kill()
        end_fusion_thread(fusion_thread, progress.warning)
        restore()
        progress.done()
    summaries, ended = {}, {}
    for name, (code, stdout, stderr) in outputs.items():
        try:
            summaries[name] = json.loads(stdout)
        except json.JSONDecodeError:
            ended[name] = (code, stderr)
    # a robot's last map still queued or on the way goes into the final fusion; one lost on the wire, from its file;
    # a robot that died without its summary (killed), from the file of its last periodic save where that is newer
    left = {name: LeftMap(out / name / f"{name}.npz") for name in ended}
    final, missing, read = final_fusion(node, summaries, left=left)
    exchange.close()
    failed = [robot_process_failure_line(name, code, stderr, left[name].said, stalled.get(name))
              for name, (code, stderr) in sorted(ended.items())]
    summary = _summary(args, summaries, node, final, time.monotonic() - start, out)
    summary["last_maps_missing"] = missing
    summary["last_maps_from_file"] = read
    summary["robot_processes_failed"] = {
        name: {"exit": code, "map_file": str(left[name].file) if left[name].landmarks is not None else None,
               "landmarks": left[name].landmarks, "map_used": left[name].used}
        for name, (code, _) in sorted(ended.items())}
    summary["fused_from"] = {r: [int(q), float(t)] for r, (q, t) in sorted(node.sources.items())}
    unsaved = False
    if final is not None and final.merged is not None:
        from estimation.errors import MapFileError

        try:
            final.merged.save(out / "fused.npz")
            final.merged.export_ply(out / "fused.ply")
        except MapFileError as e:   # a fused map its reader would refuse: written nowhere, said in one line
            print(f"p3at demo: the final fused map: {e}", file=sys.stderr)
            summary["merged_map_file"] = None
            unsaved = True
    if logger is not None:
        logger.log_summary(summary)
        logger.close()
    for line in failed:
        print(f"p3at demo: robot process failed: {line}", file=sys.stderr)
    for robot, m in sorted(missing.items()):
        print(f"p3at demo: {robot}'s last map (sequence {m['named']}) never came to the fusion node within "
              f"{LAST_MAP_WAIT:g} s (it holds {'none of that run' if m['held'] is None else m['held']}); the final "
              f"fusion has the map it holds", file=sys.stderr)
    for robot, m in sorted(read.items()):
        which = "with the status naming it" if m["named"] is None else f"sequence {m['named']}"
        print(f"p3at demo: {robot}'s last map ({which}) never came to the fusion node (it holds "
              f"{'none' if m['held'] is None else m['held']}); the final fusion reads it from {m['file']} "
              f"({m['landmarks']} landmarks), which {robot} wrote at its end", file=sys.stderr)
    if args.json:
        print(json_text(summary, indent=2))
    else:
        print(format_summary(summary))
        print()
        print(f"Maps: {', '.join(r['map_file'] for r in summary['robots'].values())}"
              + (f", merged {summary['merged_map_file']}" if summary["merged_map_file"] else ""))
    if summary["recording"]:
        files = " ".join([summary["recording"]] + [str(out / n / "mission.rrd") for n in names
                                                    if (out / n / "mission.rrd").exists()])
        print(f"Rerun recordings: {summary['recording']} (fleet view: maps, alignments, fused map) and "
              f"{out}/<robot>/mission.rrd (each robot)\n  open them together: rerun {files}\n"
              f"  summarise:          p3at review {files}", file=sys.stderr if args.json else sys.stdout)
    return 1 if failed or unsaved else 0


def robot_process_failure_line(robot: str, code: int | None, stderr: str, left: str, stalled: str | None = None) -> str:
    """What to say of a robot process that ended without its summary: its exit status (the signal that killed it),
    its last line on stderr, then ``left``: what became of the map it saved last (:func:`map_left`; its periodic
    saves are atomic: a killed robot leaves the map of its last save). ``stalled``: why this process stopped it
    (:func:`_wait`), said instead of the signal it sent."""
    lines = stderr.strip().splitlines()
    if stalled is not None:
        why = f"{stalled}: stopped, no summary"
    elif code is not None and code < 0:
        try:
            why = f"killed by {signal.Signals(-code).name}, no summary"
        except ValueError:
            why = f"killed by signal {-code}, no summary"
    else:
        why = lines[-1] if lines else "no summary, nothing on stderr"
    return f"{robot} (exit {code}): {why}; {left}"


ROBOT_STALL_AFTER = 60.0  # s of wall time without a new status from a running robot: it is stopped (as a stall ends
# an in-process mission: runtime/mission.py's watchdog, mocks/simclock.py's stall_after)
STALL_GRACE = 10.0  # s a stalled robot gets to end on SIGTERM before SIGKILL (a frozen process cannot act on it)


def _wait(processes: dict, stop: threading.Event, progress, node: FusionNode, start: float) -> tuple[dict, dict]:
    """Wait for every robot process to end (or Ctrl-C): their exit codes and outputs, and why this process stopped
    any of them. A robot whose status (once a second of its mission time) has not moved for ``ROBOT_STALL_AFTER`` s
    of wall time while its process runs has stopped making progress (frozen, deadlocked): it is stopped and said
    so, and the demo goes on to its final fusion, where before it waited for it for ever."""
    readers, outputs = {}, {}
    watch = StallWatch(processes, progress)
    for name, process in processes.items():  # read the pipes as they fill, so a chatty child never blocks
        def read(n=name, p=process) -> None:
            stdout, stderr = p.communicate()
            outputs[n] = (p.returncode, stdout, stderr)
        readers[name] = threading.Thread(target=read, name=f"read-{name}", daemon=True)
        readers[name].start()
    next_line = 0.0
    while any(r.is_alive() for r in readers.values()) and not stop.wait(0.5):
        t = time.monotonic() - start
        status = node.exchange.status() if hasattr(node.exchange, "status") else {}
        watch.stop_stalled(status)
        if t >= next_line:
            parts = [f"t={t:5.1f}s"] + [_robot_part(r, s) for r, s in sorted(status.items())]
            if node.history and node.history[-1].pairs:
                p = node.history[-1].pairs[0]
                parts.append(fusion_progress_part(p))
            progress.line(" | ".join(parts))
            next_line = t + 1.0
    for process in processes.values():
        if process.poll() is None:
            process.send_signal(signal.SIGTERM)
    for reader in readers.values():
        reader.join(timeout=60)
    return outputs, watch.stalled


class StallWatch:
    """The robot processes that have stopped making progress, and what this process did about them: ``stop_stalled``,
    called once each wait cycle with the robots' statuses, stops a robot whose status has not moved for
    ``ROBOT_STALL_AFTER`` s; ``stalled`` says why, by robot (what its failure line says instead of the signal)."""

    def __init__(self, processes: dict, progress) -> None:
        self.processes = processes                          # robot -> its subprocess.Popen
        self.progress = progress                            # the demo's Progress: one event line per stop
        self.stalled: dict[str, str] = {}                   # robot -> why it was stopped
        self._seen: dict[str, tuple[object, float]] = {}    # robot -> (its last status's session and stamp, when)
        self._stopped_at: dict[str, float] = {}             # robot -> when it got SIGTERM

    def stop_stalled(self, status: dict) -> None:
        """One look at every running robot's progress (its status's session and stamp): a robot stalled for
        ``ROBOT_STALL_AFTER`` s gets SIGTERM, and SIGKILL ``STALL_GRACE`` s later if it is still there. A robot that
        has sent no status yet is left alone (its start-up takes what the machine's load makes it take), and so is
        one whose last status says its mission is over (``mission_over``: it is saving its files, and sends no
        more)."""
        now = time.monotonic()
        for name, s in status.items():
            mark = (s.get("session"), s.get("stamp"))
            if name not in self._seen or self._seen[name][0] != mark:
                self._seen[name] = (mark, now)
        for name, process in self.processes.items():
            if process.poll() is not None or name not in self._seen or (status.get(name, {}).get("health") or {}).get(
                    "mission_over") is True:
                continue
            if name in self._stopped_at:
                if now - self._stopped_at[name] >= STALL_GRACE:
                    process.kill()
                continue
            if now - self._seen[name][1] >= ROBOT_STALL_AFTER:
                stamp = self._seen[name][0][1]
                at = f" (its last at t={stamp:.1f} s)" if isinstance(stamp, int | float) else ""
                self.stalled[name] = f"no progress for {ROBOT_STALL_AFTER:g} s of wall time: no new status{at}"
                self.progress.event(f"{name}: {self.stalled[name]}; stopping it")
                process.send_signal(signal.SIGTERM)
                self._stopped_at[name] = now


def _robot_part(robot: str, status: dict) -> str:
    """A robot's part of the progress line, from its status (the health figures once they have come). Shorter
    than ``status_line`` (``p3at fuse --live``): every robot shares this one line, rewritten in place."""
    t, frames = health_figure(status, "mission_time"), health_figure(status, "frames_processed")
    landmarks = f"map {status.get('landmarks', 0)} landmarks"
    if t is None or frames is None:
        return f"{robot}: {landmarks}"
    return f"{robot}: t={t:.0f}s, {frames:.0f} frames, {landmarks}"


def mission_timing(summaries: dict, wall: float) -> dict:
    """The demo's timing figures from its robots' own summaries (``p3at run --json``, by robot) and this process's
    wall time ``wall`` (s): the mission's length is the longest robot's ``sim_seconds`` as that robot gave it (the
    seconds of its mission clock: simulated, or the wall clock with --realtime), ``duration`` that rounded as the
    in-process mission rounds it, with the wall time and the real-time factor beside it. Robots that give no
    ``sim_seconds`` or disagree on the clock: ``duration`` is the wall time alone."""
    clocks = {s.get("clock") for s in summaries.values()}
    mission = max((s["sim_seconds"] for s in summaries.values() if s.get("sim_seconds") is not None), default=None)
    if mission is None or len(clocks) != 1:
        return {"duration": round(wall, 2)}
    return {"duration": round(mission, 2), "clock": clocks.pop(), "sim_seconds": mission,
            "wall_seconds": round(wall, 3), "realtime_factor": round(mission / wall, 3) if wall > 0 else None}


def _summary(args, summaries: dict, node: FusionNode, final, duration: float, out: Path) -> dict:
    """``duration`` is this process's wall time; the mission's length is the robots' own (:func:`mission_timing`)."""
    robots = {}
    for _, s in sorted(summaries.items()):
        robots.update(s.get("robots", {}))
    timing = mission_timing(summaries, duration)
    return {
        "robots": robots, **timing, "seed": args.seed, "camera": args.camera,
        "particles": args.particles, "processes": True,
        "fusion": None if final is None else final.as_dict(),
        "fusion_ms": None if final is None else round(1000.0 * final.seconds, 2),
        "fusions_during_mission": max(0, len(node.history) - 1),
        "merged_map_file": None if final is None or final.merged is None else str(out / "fused.npz"),
        "recording": None if args.rerun != "file" else str(out / "mission.rrd"),
        # --smooth: every robot process smoothed its map before its last publish (as the in-process mission says it)
        **({"smoothed": all((r.get("smoothing") or {}).get("smoothed", False) for r in robots.values())}
           if getattr(args, "smooth", True) else {}),
    }
