"""The live fusion node: what any machine of a fleet can run (``p3at fuse --live``).

It reads every robot's latest map from a map exchange, fuses them through ``runtime.fusion_report.fuse_maps``
when new data has arrived (at most every ``min_period`` s, a burst of updates is one fusion) and at least every
``interval`` s while anything changed, publishes the merged map on ``p3at/<fleet>/fused/map``, and logs maps,
alignments and the fused map to Rerun. A robot that leaves keeps its last map in the fusion; a restarted node
recovers every robot's map by query before its first fusion.

Its decisions run on the robots' clock (:class:`RobotClock`: the maps' stamps, their mission time), as the
single-process mission's run on mission time: a found is confirmed an ``interval`` of the robots' mapping later,
whether the robots run in real time or in simulated time many times faster (``p3at demo --processes``).
"""
from __future__ import annotations

import argparse
import math
import sys
import textwrap
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from estimation.errors import MapFileError
from fusion.prior import named_pair_priors
from runtime.exchange import MapExchange, MapMessage
from runtime.fleet.status import PresenceLines, StatusPrinter
from runtime.fusion_report import FusionReport, alignment_cache, fuse_maps, keep_latest_map
from runtime.json_output import json_text
from runtime.report import alignment_text, fusion_event_line, start_prior_line

FUSED = "fused"
_SAY = threading.Lock()
EXIT_NOTHING_TO_FUSE = 1   # p3at fuse --live: no two robots' maps ever came, so no fusion was made
CLOCK_SLACK = 10.0         # s a robot's map may run ahead of the node's clock, whatever the wall time since it moved
CLOCK_MAX_RATE = 50.0      # the robots' clock runs at most this many times the node's wall clock (simulated: 2-11x)
CLOCK_LAG = 60.0           # s a robot's first map may lag the node's clock and still be taken at its own stamp
LOOK_PERIOD = 0.2          # s: run() looks at the maps' stamps at most this often (each look copies the maps)
CLOCK_MAX_STAMP = 1e13     # s (300,000 years): a stamp above is not taken (a float's step there is 2 ms; beside
#                            1e300 s or 1.8e18 s, ns sent as s, a robot's progress would no longer move the clock)


class RobotClock:
    """The fusion node's clock: the robots' mission time, read from their maps' stamps, never going back.

    Each robot's map is placed on the node's clock at ``stamp + offset``, its robot's offset 0 unless the rules below
    set one, and the clock is the newest of those (monotone). The rules, so that a map's stamp can neither throw the
    clock forward nor hold it still:

    - in step (a robot's next map: a later sequence, a stamp not before its last): the clock may move with it, by as
      much as its stamp moved. A map that would put the clock more than ``CLOCK_SLACK + CLOCK_MAX_RATE x`` (wall time
      since the clock last moved) ahead (a stamp far in the future: a hostile or broken sender, a clock reset
      forward) is not taken: its robot is placed at the node's clock (its offset absorbs the jump) and counts from
      there. One map can move the clock no further than that bound, so no stamp confirms every candidate at once.
    - out of step (a stamp going back, a sequence going back: a restarted robot, a clock reset back): its robot is
      placed at the node's clock and its next maps move it by their own progress, so a robot whose clock went back
      never holds the node's still.
    - a robot's first map: taken at its own stamp if it lies within ``CLOCK_LAG`` behind the clock and the bound
      above ahead of it (robots started together are on one clock), else placed at the node's clock. The first
      maps the node ever sees set the clock: the oldest of them, and each within ``CLOCK_LAG`` after it.
    - a robot whose every stamp is 0 sends no time: its maps are timed by the node's own clock as they come (the
      wall clock since its first map came, so that its first map is at 0, as a robot's first map at the start of
      its mission). Stamps not finite, below 0 or above ``CLOCK_MAX_STAMP`` are not taken (the map is fused; it does
      not move the clock).

    So a robot of a real fleet (stamps in real time) and the simulated robots of ``p3at demo --processes`` (2-11x
    real time) confirm on the same mission time as the single-process mission (docs/fleet.md).
    """

    def __init__(self, wall: Callable[[], float]) -> None:
        self.wall = wall
        self.now: float | None = None       # s, on the robots' clock; None before the first map
        self.moved_at = wall()              # the wall time it last moved (or started)
        # robot -> (sequence, stamp as sent, stamp as timed (the node's clock for a robot that sends no time),
        # offset, whether it sends no time, the wall time its first map came)
        self._robots: dict[str, tuple[int, float, float, float, bool, float]] = {}

    def observe(self, messages: Mapping[str, MapMessage]) -> float:
        """Take the maps' stamps in (each robot's latest; unchanged ones change nothing); the clock after them."""
        wall = self.wall()
        timed = {}
        for robot, m in messages.items():
            stamp = float(m.stamp)
            prev = self._robots.get(robot)
            if (not math.isfinite(stamp) or not 0 <= stamp <= CLOCK_MAX_STAMP
                    or (prev is not None and prev[:2] == (m.sequence, stamp))):
                continue
            silent = stamp == 0.0 and (prev is None or prev[4])
            since = wall if prev is None else prev[5]
            timed[robot] = (m.sequence, stamp, wall - since if silent else stamp, silent, since)
        if not timed:
            return self.clock_now()
        if self.now is None:   # the first maps set the clock: the oldest, and each within CLOCK_LAG after it
            start = min(t for _, _, t, _, _ in timed.values())
            self.now = max(t for _, _, t, _, _ in timed.values() if t <= start + CLOCK_LAG)
            self.moved_at = wall
        base, ahead = self.now, CLOCK_SLACK + CLOCK_MAX_RATE * max(0.0, wall - self.moved_at)
        newest = base
        for robot, (sequence, stamp, t, silent, since) in sorted(timed.items()):
            prev = self._robots.get(robot)
            if prev is not None and sequence > prev[0] and t >= prev[2]:
                offset = prev[3]                       # in step
            elif prev is None and base - CLOCK_LAG <= t <= base + ahead:
                offset = 0.0                           # a first map on the clock
            else:
                offset = base - t                      # out of step, or far off: placed at the node's clock
            if t + offset > base + ahead:              # would throw the clock forward: not taken
                offset = base - t
            self._robots[robot] = (sequence, stamp, t, offset, silent, since)
            newest = max(newest, t + offset)
        if newest > self.now:
            self.now, self.moved_at = newest, wall
        return self.now

    def clock_now(self) -> float:
        """The clock (0 before the first map)."""
        return 0.0 if self.now is None else self.now


@dataclass(frozen=True)
class FusionNodeConfig:
    interval: float = 10.0     # s: fuse at least this often while maps change
    min_period: float = 1.0    # s: at most this often (updates arriving together make one fusion)
    preset: str = "robust"
    method: int = 1
    seed: int = 0
    out: Path | None = None    # the fused map file, rewritten (atomically) after each fusion
    # {robot: ((x, y, yaw), (σ xy, σ yaw))}: where robots started, roughly, in one frame; each pair of them is
    # aligned with the prior on their relative start (fusion/prior.py); the others blind. Empty: all blind
    starts: Mapping[str, tuple] = field(default_factory=dict)
    starts_source: str = "given start poses"

    def __post_init__(self) -> None:
        if not (self.interval > 0 and self.min_period >= 0):
            raise ValueError("--interval must be > 0 and --min-period >= 0")


class FusionNode:
    """Fuses an exchange's maps on new data and at intervals; ``run(stop)`` until the event is set."""

    def __init__(self, exchange: MapExchange, config: FusionNodeConfig = FusionNodeConfig(), *,
                 logger=None, on_event: Callable[[str], None] | None = None,
                 on_report: Callable[[FusionReport], None] | None = None, clock=time.monotonic) -> None:
        self.exchange = exchange
        self.config = config
        self.logger = logger
        self.on_event = on_event or (lambda line: None)
        self.on_report = on_report or (lambda report: None)
        # alignments of maps unchanged since an earlier fusion; every fusion here is live (the maps keep growing), so
        # a found is a candidate until a fusion an interval later, on the robots' clock, agrees (fusion/confirmation.py)
        self.cache = alignment_cache(confirm_after=config.interval)
        self.clock = clock                       # the node's wall clock: how long it runs, the robot clock's bounds
        self.t0 = clock()
        self.robot_clock = RobotClock(clock)     # the fusions' time: the robots' mission clock (RobotClock)
        self.history: list[FusionReport] = []
        self.sources: dict[str, tuple] = {}      # robot -> (sequence, stamp) of its map in the last fusion
        self.priors = named_pair_priors(dict(config.starts), source=config.starts_source)
        self._priors_said: set[tuple[str, str]] = set()
        self.mapped: list[str] = []    # the robots whose map the node has held, in the order they first came
        self.saved: tuple[float, int] | None = None   # (t, landmarks) of the fused map last written to config.out
        self._logged: dict[str, tuple[int, float]] = {}   # robot -> (sequence, stamp) of its map last logged
        self._new_data = threading.Event()
        self._failure_said: str | None = None   # the last live fusion's failure said (run), not said again
        # one fusion at a time: a live one (run's thread) and the final one (the caller's) share the robots' clock,
        # the alignment cache, the history (the next fusion's seed is its length), the sources, the published fused
        # map and the recording; the final one waits for a live one in progress, and no live one starts after it
        self._fusing = threading.Lock()
        self._live_since: float | None = None   # the wall clock when the live fusion in progress began
        self._fusing_t: float | None = None     # the robots' clock of the fusion in progress (its t), once known
        self._final_begun = False

    def notify(self, robot: str = "") -> None:
        """New data arrived (the exchange's ``on_update`` hook)."""
        if robot != FUSED:
            self._new_data.set()

    def run(self, stop: threading.Event) -> None:
        """Fuse on new data once ``min_period`` s have passed since the last fusion, and every ``interval`` s, until
        ``stop``: seconds of the robots' clock (:class:`RobotClock`, moved by the maps as they come) or of the node's
        wall clock, whichever has passed more (so that robots whose clock stands still, done or sending no time, are
        still fused). Waits on new data between (it spun until ``min_period`` had passed after each map before)."""
        cfg = self.config
        last_wall = last_robot = looked = -np.inf
        pending = False
        while not stop.is_set():
            if self._new_data.wait(timeout=min(cfg.interval, LOOK_PERIOD)):
                self._new_data.clear()
                pending = True
            if stop.is_set():
                break
            wall = self.clock()
            if pending and time.monotonic() - looked >= LOOK_PERIOD:   # the maps' stamps (copies): a few times a second
                looked = time.monotonic()
                self.robot_clock.observe(self.exchange.receive(excluding=FUSED))
            robots = self.robot_clock.clock_now()
            since = max(wall - last_wall, robots - last_robot)
            due = since >= cfg.interval
            if (pending and since >= cfg.min_period) or due:
                pending = False
                try:
                    fused = self._live_fusion()
                except Exception as exc:  # noqa: BLE001 - a fusion that raises must not end the node's thread
                    self._fusion_failed(exc)
                    fused = True   # tried: again on new maps after min_period, or an interval later
                if fused or due:
                    last_wall, last_robot = wall, self.robot_clock.clock_now()

    def _live_fusion(self) -> bool:
        """One fusion of :meth:`run` (whether it made one), none once the final fusion has begun."""
        with self._fusing:
            if self._final_begun:
                return False
            self._live_since, self._fusing_t = self.clock(), None
            try:
                return self._fuse() is not None
            finally:
                self._live_since = None

    def _fusion_failed(self, exc: Exception) -> None:
        """A live fusion that raised (a bug on some maps): said in one line, not again while it fails the same way;
        :meth:`run` goes on with the next maps (it ended the node's thread: the demo went on without a live fusion,
        a traceback amid its progress lines, and ``p3at fuse --live`` ended)."""
        why = f"{type(exc).__name__}: {' '.join(str(exc).split())}"
        if why != self._failure_said:
            self._failure_said = why
            self.on_event(f"fusion at t={self.robot_clock.clock_now():.0f}s failed ({why}); the node goes on with "
                          "the next maps")

    def fuse_now(self, final: bool = False, replace: Mapping[str, MapMessage] | None = None) -> FusionReport | None:
        """Fuse if any robot's map changed since the last fusion; publish and log the result.  ``final``: the maps
        are complete (the robots are done, or the node stops), so the fusion is decided on them alone, as ``p3at
        fuse`` decides on saved maps, not confirmed against earlier fusions (fusion/confirmation.py). ``replace``:
        robots' maps that stand in for those the exchange holds (a last map lost on the wire, read from its file).
        One fusion at a time: waits for one in progress on another thread."""
        with self._fusing:
            return self._fuse(final, replace)

    def _fuse(self, final: bool = False, replace: Mapping[str, MapMessage] | None = None) -> FusionReport | None:
        """:meth:`fuse_now`, its caller holding ``_fusing``."""
        messages = {**self.exchange.receive(excluding=FUSED), **(replace or {})}
        for robot in sorted(set(messages) - set(self.mapped)):
            self.mapped.append(robot)
            self.on_event(f"first map from {robot}: {len(messages[robot].landmark_map)} landmarks"
                          + ("; a fusion waits for another robot's map" if len(messages) < 2 else ""))
        sources = {r: (m.sequence, m.stamp) for r, m in messages.items()}
        t = self._fusing_t = self.robot_clock.observe(messages)
        if len(messages) < 2 or sources == self.sources:
            return None
        maps = {r: m.landmark_map for r, m in messages.items()}
        self.cache.start_round(t)
        report = fuse_maps(maps, self.config.preset, self.config.method, t,
                           np.random.default_rng(self.config.seed + len(self.history)),
                           cache=self.cache.inner if final else self.cache, priors=self.priors)
        self._say_priors(t, maps)
        keep_latest_map(self.history, report)
        self.sources = sources     # after the history: whoever sees these sources also sees their report
        if report.merged is not None and any(p.aligned for p in report.pairs):
            merged = report.merged
            # which update of each robot this fusion holds: [sequence, sender's stamp] (latency, staleness)
            fused_from = {r: [int(q), float(st)] for r, (q, st) in sources.items()}
            merged.metadata = {**merged.metadata, "fused_from": fused_from, "fusion_time": round(t, 3)}
            self.exchange.publish(FUSED, merged, stamp=t)
            if self.config.out is not None:
                try:
                    merged.save(self.config.out)
                    self.saved = (t, len(merged))
                except MapFileError as exc:  # one its reader would refuse: the file keeps the last fused map
                    self.on_event(f"fused map not saved: {exc}")
        self._log(t, messages, report)
        for pair in report.pairs:
            self.on_event(fusion_event_line(t, pair))
        self.on_report(report)
        return report

    def final_fusion(self, replace: Mapping[str, MapMessage] | None = None) -> FusionReport | None:
        """The fusion of every map the node holds (``replace``: maps standing in for some, see :meth:`fuse_now`),
        whatever the last fusion held, decided on the maps alone (the robots are done or the node stops);
        published and logged like any other. A live fusion in progress (:meth:`run`'s thread, still fusing after
        its stop was asked) is waited for, said in one line; no live fusion starts after this one has begun, so it
        is the node's last and nothing is fused twice at once (the robots' clock, the alignment cache, the history,
        the published map and the recording are the node's one state)."""
        if not self._fusing.acquire(blocking=False):
            since, t = self._live_since, self._fusing_t
            self.on_event("the final fusion waits for the live fusion" + ("" if t is None else f" at t={t:.0f}s")
                          + ("" if since is None else f" (running {self.clock() - since:.0f} s)") + " to end")
            self._fusing.acquire()
        try:
            self._final_begun = True
            self.sources = {}
            return self._fuse(final=True, replace=replace)
        finally:
            self._fusing.release()

    def _say_priors(self, t: float, maps: dict) -> None:
        """Once per pair, when both its robots are first fused: the fusion is not blind to where they started."""
        for (a, b), prior in self.priors.items():
            if a in maps and b in maps and (a, b) not in self._priors_said:
                self._priors_said.add((a, b))
                line = start_prior_line(a, b, prior)
                self.on_event(line)
                if self.logger is not None:
                    self.logger.log_event(t, line, "INFO")

    def _log(self, t: float, messages: Mapping[str, MapMessage], report: FusionReport) -> None:
        """The fusion at ``t`` (the robots' clock: :class:`RobotClock`), and each robot's map it holds at the time that
        robot made it (its stamp), once: its own process logs it at that time too, so the views of both agree."""
        if self.logger is None:
            return
        for robot, m in messages.items():
            if self._logged.get(robot) != (m.sequence, m.stamp):
                self._logged[robot] = (m.sequence, m.stamp)
                self.logger.log_map(robot, m.stamp, m.landmark_map)
        for pair in report.pairs:
            self.logger.log_alignment(t, pair.reference, pair.other, {
                **pair.as_dict(), "merged": 0 if report.merged is None else len(report.merged)})
        if report.merged is not None:
            self.logger.log_map(FUSED, t, report.merged)


# -- p3at fuse --live ----------------------------------------------------------------------------------------
def run_live(args: argparse.Namespace, starts: Mapping[str, tuple] | None = None) -> int:
    """``p3at fuse --live``: the fusion node until Ctrl-C, SIGTERM or ``--seconds``; prints each fusion.  ``starts``
    {robot: (pose, sigmas)}: the robots' rough start poses (``--start-pose ROBOT=...``), a prior for their pairs."""
    from runtime.fleet.options import open_exchange
    from runtime.mission import install_stop_signals

    if args.exchange == "inprocess":   # silently ran Zenoh before: say so, before anything starts
        print("p3at fuse: --live needs a network exchange to hear the robots' maps: --exchange zenoh or "
              "zenoh:CONFIG (inprocess is one process's own)", file=sys.stderr)
        return 2
    spec = args.exchange
    out = Path(args.out) if args.out else None
    try:
        config = FusionNodeConfig(args.interval, args.min_period, args.preset, args.method, args.seed, out,
                                  starts=starts or {})
    except ValueError as e:
        print(f"p3at fuse: {e}", file=sys.stderr)
        return 2
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)

    node_box: list[FusionNode] = []
    presence: list[PresenceLines] = []   # the exchange's joins and leaves made whole, once it is open

    def event(line: str) -> None:
        say_line(presence[0](line) if presence else line)

    try:
        exchange = open_exchange(spec, args.fleet, "fusion", on_event=event,
                                 on_update=lambda robot: node_box and node_box[0].notify(robot))
    except (ValueError, RuntimeError) as e:
        print(f"p3at fuse: {e}", file=sys.stderr)
        return 2
    presence.append(PresenceLines(exchange.status, exchange.held))
    try:
        logger, recording = _open_logger(args.rerun, out, args.recording_id)
    except RuntimeError as e:   # a --rerun URL Rerun refuses (runtime.rerun_sink.ViewerError): exit 70 before
        exchange.close()
        print(f"p3at fuse: {e}", file=sys.stderr)
        return 2
    reports: list[FusionReport] = []
    node = FusionNode(exchange, config, logger=logger, on_event=event, on_report=reports.append)
    node_box.append(node)
    stop = threading.Event()
    restore = install_stop_signals(stop.set)
    # --seconds beyond what a timer can wait (1e300: its thread died with OverflowError) is until Ctrl-C
    timer = threading.Timer(args.seconds, stop.set) if 0 < args.seconds < threading.TIMEOUT_MAX else None
    if timer is not None:
        timer.daemon = True
        timer.start()
    printer = StatusPrinter(exchange.status, event).start()  # each robot's health, every PRINT_PERIOD s
    heard: list[str] = []
    try:
        exchange.request_snapshot()  # a restarted node recovers every robot's latest map
        node.run(stop)
        node.final_fusion()          # the node's last word on the maps it holds (printed below as the last)
    finally:
        if timer is not None:
            timer.cancel()
        printer.stop()
        restore()
        heard = sorted(set(exchange.status()) - {FUSED})   # robots whose status came, with a map or not
        exchange.close()
        final = reports[-1] if reports else None
        if logger is not None:  # a final summary: p3at review then knows the node ended cleanly
            logger.log_summary({"fusion_node": True, "fusions": len(reports),
                                "fusion": None if final is None else final.as_dict(),
                                "robots": sorted(node.sources)})
            logger.close()
    nothing = None if reports else nothing_to_fuse(node.mapped, heard, node.clock() - node.t0, args.fleet)
    if args.json:
        print(json_text({"fusions": len(reports), "last": None if final is None else final.as_dict(),
                         "robots_with_maps": sorted(node.mapped), "nothing_to_fuse": nothing}))
    elif ending := ending_text(final, len(reports), out, node.saved, recording, args.recording_id):
        print(ending)
    if nothing is not None:
        print(f"p3at fuse: nothing to fuse: {nothing}", file=sys.stderr)
        return EXIT_NOTHING_TO_FUSE
    return 0


def say_line(line: str, stream=None) -> None:
    """One whole line on stderr (``stream``): the node's lines come from several threads (the exchange's joins and
    leaves, the fusions, the status printer), and ``print`` writes the text and its newline apart, so two lines
    printed at once came out as 'robot1 joined the fleetfirst map from robot1: ...' and an empty line (session 49)."""
    stream = sys.stderr if stream is None else stream
    with _SAY:
        stream.write(line + "\n")
        stream.flush()


def nothing_to_fuse(mapped: list[str], heard: list[str], seconds: float, fleet: str) -> str:
    """Why a live node that ends without a fusion made none, in one line: the robots of fleet ``fleet`` whose map
    came (fewer than two), and those heard (their status came) that sent none."""
    silent = [r for r in heard if r not in mapped]
    said = (f"no robot of fleet '{fleet}' sent a map in {seconds:.0f} s" if not mapped else
            f"only {mapped[0]} of fleet '{fleet}' sent a map in {seconds:.0f} s; a fusion needs the maps of two robots")
    if silent:
        said += f" ({', '.join(silent)} {'was' if len(silent) == 1 else 'were'} heard but sent no map)"
    return said


def ending_text(final: FusionReport | None, fusions: int, out: Path | None, saved: tuple[float, int] | None,
                recording: Path | None, recording_id: str | None = None) -> str:
    """``p3at fuse --live``'s last lines (text mode), as ``p3at run`` and ``p3at demo`` end: the last fusion, each pair
    in the words of ``p3at review`` (runtime.report.alignment_text), the fused map and where it was written (``saved``:
    (t, landmarks) of the fused map last written to ``out``), and the recording (a saved file) with the commands that
    open and summarise it.  "" when there was no fusion and nothing was written (the reason is said on stderr)."""
    lines: list[str] = []
    if final is not None:
        lines.append(f"{fusions} fusion{'' if fusions == 1 else 's'}; the last, at t={final.t:.0f} s:")
        for p in final.pairs:
            lines += textwrap.wrap(f"{p.other} -> {p.reference}: {alignment_text(p.as_dict())}", 118,
                                   initial_indent="  ", subsequent_indent="      ", break_on_hyphens=False)
        aligned = any(p.aligned for p in final.pairs)
        if out is None:
            lines.append(f"Fused map: {len(final.merged)} landmarks, not saved (give --out FILE.npz)"
                         if aligned and final.merged is not None else "Fused map: none (no pair aligned)")
    if out is not None and (final is not None or saved is not None):   # no fusion at all: said on stderr
        if saved is None:
            lines.append(f"Fused map: none written to {out}: no fusion aligned two robots' maps")
        else:
            t, landmarks = saved
            lines.append(f"Fused map: {landmarks} landmarks -> {out}" + (
                "" if final is not None and t == final.t else f" (the fusion at t={t:.0f} s, the last that "
                                                                         "aligned a pair)"))
    if recording is not None:
        lines += [f"Rerun recording: {recording}", f"  open it with:   rerun {recording}",
                  f"  summarise it:   p3at review {recording}"]
        if recording_id:   # the robots' `p3at run --recording-id` of the same id: their files read as one recording
            lines.append(f"  with the robots' (p3at run --recording-id {recording_id}): "
                         f"p3at review {recording} ROBOT/mission.rrd ...")
    return "\n".join(lines)


def _open_logger(sink: str, out: Path | None, recording_id: str | None = None):
    """The node's MissionLog (None for --rerun none) and the file it saves to (None unless it saves one)."""
    if sink == "none":
        return None, None
    from runtime.rerun_log import MissionLog
    from runtime.rerun_sink import SAVED_STREAMS, open_recording

    if sink == "file":
        sink = str(out.with_name("fusion.rrd") if out is not None else Path("fusion.rrd"))
    rec = open_recording(sink, recording_id=recording_id)
    return MissionLog(rec, []), (Path(sink) if rec in SAVED_STREAMS else None)   # open_recording knows what it saves
