"""The map exchange over Eclipse Zenoh: the only module that imports ``zenoh`` (see docs/fleet.md).

Key space under a fleet namespace ``p3at/<fleet>/``:

    <robot>/map      map updates (mapwire full snapshots and deltas); also a queryable answering the robot's
                     latest full snapshot, on this concrete key
    <robot>/status   pose estimate, map size, health (mapwire status)
    <robot>/alive    the robot's liveliness token: join and leave
    fused/map        the fusion node's merged map: its queryable, answering the latest full snapshot (robots pull it)
    fused/status     the fusion node's word that a new fused map is there (status-shaped, naming its sequence)
    fused/alive      the fusion node's liveliness token, from the node's start: a robot knows whether a node hears it
                     (a robot that ends with maps no node received says which, as it closes)

Receiving never blocks Zenoh's threads, and Zenoh's threads never run Python: every subscriber, the liveliness
subscriber, the queryables and the snapshot requests' replies use Zenoh's own channels (no Python callback, so no
Python thread of zenoh's either). Named threads of this module do the work: a pump drains the channels
(raw bytes into a queue bounded in bytes, the oldest dropped first; liveliness; queries handed on), a worker
decodes, validates and applies what is queued, so a slow decode never holds the channels, and a replier answers the
queries (at most REPLY_QUEUE waiting: the others stay in Zenoh's ring), so a reply that waits for room on a slow link
(Zenoh's replies block: a fused map larger than the link's queue) never holds the pump. ``close`` (and, for an
exchange left open, an exit hook that runs before the interpreter finalizes) stops and joins them before closing
the session: a thread that enters a Python callback, or comes back from native code, while CPython 3.11
finalizes is ended with pthread_exit, whose forced unwind through Zenoh's Rust frames aborts the process
("FATAL: exception not rethrown"). A message that cannot be used is dropped with a logged reason. The latest
map of each robot wins.

A map missed on the way starts one wait per robot for its full snapshot (``_Wait``): a delta whose base was missed
(it names a map that exists), a map dropped from the full queue (anything newer than the miss), or a status naming
a map newer than the one held (a robot's last map, lost on the way, is followed by no delta that would show the
gap). The wait keeps the newest (session, sequence) known to exist and when it began; a map that reaches that
sequence ends it (with no sequence known: a full snapshot published after the miss, or a reply to a request sent
after it); the robot's leaving cancels it. One retry policy: the robot's queryable is asked at once (for a status:
after BEHIND_GRACE, the map may be in flight), then 2, 4, 8, 16 s later, then every 30 s; never while a map of
the robot still waits in the queue or within BEHIND_GRACE of a map of it handled (either may end the wait).

Defaults (no configuration file): peer mode, multicast scouting off, the fusion node listens on
``tcp/127.0.0.1:7447`` and robots connect to it (and listen on a loopback port of their own). A user's Zenoh
JSON5 file (``--exchange zenoh:FILE``) replaces the endpoints and may turn on TLS and access control; keys it
leaves unset get the defaults above.
"""
from __future__ import annotations

import atexit
import collections
import json
import logging
import math
import re
import threading
import time
import weakref
from collections.abc import Callable
from pathlib import Path

import numpy as np
import zenoh

from estimation.fileio import InputTooLargeError, read_bounded
from estimation.landmark_map import LandmarkMap
from runtime.exchange import MapMessage, copy_map
from runtime.fleet import mapwire
from runtime.textfile import not_a_file

log = logging.getLogger(__name__)

DEFAULT_FLEET = "p3at"
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
FUSED = "fused"                     # reserved name of the fusion node's map
MAX_PENDING_BYTES = 64 * 1024 * 1024
MAX_CONFIG_BYTES = 1 << 20        # a Zenoh configuration file is a few kB
MAX_CONFIG_DEPTH = 64             # its nesting is ~6; Zenoh's parser overflows the stack at ~30 000
SNAPSHOT_RETRY = 1.0                # s: at most one snapshot request per robot in this time
BEHIND_GRACE = 1.0                  # s a status may name a map not yet handled before its robot is asked for it
BEHIND_RETRY_MAX = 30.0             # s: a wait's asks come 2, 4, 8, 16 s apart, then every 30 s
QUERY_TIMEOUT = 5.0                 # s
FUSED_QUERY_TIMEOUT = 60.0          # s a robot's request for the fused map stays open: its reply, 77-92 kB, takes 7 s
                                    # over 100 kbit; no second request goes while one is open (one fused map in flight)
CLOSE_TIMEOUT = 10.0                # s close() waits for its threads and for sends inside Zenoh, then goes on
POLL_INTERVAL = 0.05                # s between two looks at Zenoh's channels when idle: maps come every few s
CHANNEL_CAPACITY = 1024             # samples a subscriber's ring holds between two looks (the oldest dropped)
REPLY_CAPACITY = 256                # replies to one snapshot request (one per robot answering)
REPLY_QUEUE = 64                    # queries waiting for the replier, at most (one per robot of a fleet of 64); more
                                    # wait in their queryable's ring in Zenoh, which drops the oldest when it is full
DROP_REPORT_INTERVAL = 30.0         # s: malformed messages are said once, then counted in one line at most this often
STATUS_PRIORITY = zenoh.Priority.DATA_HIGH  # statuses: one step above the maps' DATA
ACK_TIMEOUT = 20.0                  # s a robot's next map waits for the node to say it has the last, at most
CLOSE_SLOW = 5.0                    # s: a Zenoh close still waiting after this is said (a peer's link down: up to 10 s)

_SAY = ""                           # the receive queue's key of a line to say in turn (a join or a leave)
_OPEN: weakref.WeakSet[ZenohExchange] = weakref.WeakSet()


@atexit.register
def _close_open_exchanges() -> None:
    """Close every exchange still open before the interpreter finalizes (atexit runs first): its thread is
    joined while it can still take the GIL."""
    for exchange in list(_OPEN):
        exchange.close()


class _Wait:
    """A robot's full snapshot this receiver waits for: the newest (session, sequence) known to exist (None:
    anything newer than a miss), since when, and when to ask for it next (``delay``: the gap after that ask)."""

    __slots__ = ("session", "sequence", "since", "due", "delay")

    def __init__(self, since: float, due: float) -> None:
        self.session: str | None = None
        self.sequence = -1
        self.since, self.due, self.delay = since, due, SNAPSHOT_RETRY

    def reached(self, session: str | None, sequence: int) -> bool:
        return self.session is not None and session == self.session and sequence >= self.sequence


class ExchangeError(RuntimeError):
    """The exchange could not be opened (a bad configuration, an endpoint in use...)."""


# where in Zenoh's Rust sources an error was made: " at /root/.cargo/git/.../io/zenoh-link/src/lib.rs:183." (nested
# errors carry one each, inside their brackets)
_RUST_SOURCE = re.compile(r"\s+at\s+\S+\.rs:\d+(?::\d+)?\.?(?=\]|\s|$)")
# a JSON5 syntax error (pest): " --> 2:26\n  |\n2 |   listen: ...\n  |  ^---\n  |\n  = expected array, ..."
_PEST = re.compile(r"-->\s*(\d+):(\d+).*?=\s*(.+)$", re.S)


def zenoh_message(error: BaseException) -> str:
    """A Zenoh error's text on one line, for a user: without the Rust source paths it ends with (which say where in
    Zenoh, not what is wrong), a JSON5 syntax error as 'line L column C: expected ...'."""
    text = _RUST_SOURCE.sub("", str(error)).strip()
    pest = _PEST.search(text)
    if pest is not None:
        text = f"line {pest.group(1)} column {pest.group(2)}: {pest.group(3).strip()}"
    return " ".join(text.split())


def _read_config(path: str) -> str:
    try:
        data = read_bounded(path, MAX_CONFIG_BYTES)   # never waits on a FIFO
    except InputTooLargeError as e:
        raise ExchangeError(f"{path}: {e}; a Zenoh configuration is a few kB (at most {MAX_CONFIG_BYTES})") from None
    except OSError as e:
        raise ExchangeError(f"{path}: cannot read the Zenoh configuration ({e.strerror or e})") from None
    return data.decode("utf-8", errors="replace")


def _check_config_text(text: str, shown: str) -> None:
    """Refuse what Zenoh's parser cannot survive: its JSON5/YAML readers recurse per level of nesting, and a
    configuration nested ~30 000 deep overflows the native stack (SIGSEGV: no exception, no message). Brackets
    are counted outside quoted strings; comments are counted too, which can only over-count."""
    if len(text) > MAX_CONFIG_BYTES:
        raise ExchangeError(f"{shown}: more than {MAX_CONFIG_BYTES} bytes; a Zenoh configuration is a few kB")
    depth = deepest = 0
    quote = ""
    escaped = False
    for ch in text:
        if quote:
            if escaped:
                escaped = False
            elif ch == "\\":
                escaped = True
            elif ch == quote:
                quote = ""
        elif ch in "\"'":
            quote = ch
        elif ch in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif ch in "]}":
            depth -= 1
    if deepest > MAX_CONFIG_DEPTH:
        raise ExchangeError(f"{shown}: nested {deepest} levels deep; a Zenoh configuration has at most "
                            f"{MAX_CONFIG_DEPTH}")


def make_config(config: str | None, role: str) -> zenoh.Config:
    """A Zenoh config: the user's (file or inline JSON5) with this project's defaults where it leaves keys unset.

    ``role``: ``"fusion"`` listens on the default endpoint; ``"robot"`` connects to it.
    """
    if role not in ("robot", "fusion"):
        raise ValueError(f"role must be robot or fusion, not {role!r}")
    try:
        if config is None:
            cfg = zenoh.Config()
        elif config.lstrip().startswith("{"):
            _check_config_text(config, " ".join(config.split())[:80])
            cfg = zenoh.Config.from_json5(config)
        else:
            if not Path(config).is_file():   # there but a folder or a FIFO: say what it is, not "no such"
                raise ExchangeError(f"{config}: {not_a_file(config, 'Zenoh configuration file')}")
            _check_config_text(_read_config(config), config)
            cfg = zenoh.Config.from_file(config)
    except zenoh.ZError as e:
        shown = " ".join(config.split())   # an inline configuration may span lines: the message is one
        raise ExchangeError(f"{shown}: not a valid Zenoh configuration ({zenoh_message(e)})") from None

    def unset(key: str) -> bool:
        return json.loads(cfg.get_json(key)) in (None, [], {})

    if unset("mode"):
        cfg.insert_json5("mode", '"peer"')
    if unset("scouting/multicast/enabled"):
        cfg.insert_json5("scouting/multicast/enabled", "false")
    user_listen = json.loads(cfg.get_json("listen/endpoints"))
    if config is None or isinstance(user_listen, dict):  # zenoh's per-mode default listens on every interface
        listen = [DEFAULT_ENDPOINT] if role == "fusion" else ["tcp/127.0.0.1:0"]
        cfg.insert_json5("listen/endpoints", json.dumps(listen))
    if role == "robot" and unset("connect/endpoints"):
        cfg.insert_json5("connect/endpoints", json.dumps([DEFAULT_ENDPOINT]))
    return cfg


class ZenohExchange:
    """A :class:`~runtime.exchange.MapExchange` over Zenoh, for one process (a robot, or the fusion node).

    ``publish`` sends this process's robot map (delta or full snapshot), its status, declares the robot's
    liveliness token and queryable on first use; ``receive`` returns the latest map of every robot heard of
    (including those that have left: their last map is kept), copies as over any wire.
    """

    def __init__(self, fleet: str = DEFAULT_FLEET, config: str | None = None, role: str = "robot", *,
                 full_every: int = 10, on_event: Callable[[str], None] | None = None,
                 on_update: Callable[[str], None] | None = None,
                 max_pending_bytes: int = MAX_PENDING_BYTES) -> None:
        if not mapwire.ROBOT_NAME.fullmatch(fleet):
            raise ValueError(f"fleet name {fleet!r} must be 1-64 of A-Z a-z 0-9 _ -")
        self.fleet = fleet
        self.role = role
        self.prefix = f"p3at/{fleet}"
        self.full_every = full_every
        self.max_pending_bytes = max_pending_bytes
        self.on_event = on_event or (lambda line: None)
        self.on_update = on_update or (lambda robot: None)
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        # (key, bytes, when the snapshot request it answers was sent; None for a published sample)
        self._pending: collections.deque[tuple[str, bytes, float | None]] = collections.deque()
        self._pending_bytes = 0
        self._streams: dict[str, mapwire.MapStream] = {}
        self._latest: dict[str, MapMessage] = {}
        self._status: dict[str, dict] = {}
        self._health: dict[str, dict] = {}       # own robot -> the health last sent (publish_status)
        self._present: set[str] = set()
        self._encoders: dict[str, mapwire.MapEncoder] = {}
        self._own: dict[str, tuple] = {}         # robot -> (publisher, status publisher, queryable, token)
        self._asked: dict[str, float] = {}
        self._replies: list = []                 # (Zenoh reply channel, when asked, robot asked) of the requests open
        self._waits: dict[str, _Wait] = {}       # robot whose full snapshot is waited for (a map missed)
        self._left: set[str] = set()             # robots seen leaving (and not back): nothing to wait for
        self._node_left_at: float | None = None  # when (monotonic) a fusion node was last seen leaving
        # own robot -> (its first map sequence no fusion node may have received, when it was sent, the last of those
        # sent before the node was seen leaving or -1): maps sent while no node was connected, and those of the lease
        # before a node was seen leaving without a word; cleared when a node joins (it asks for the latest snapshot)
        self._unheard: dict[str, tuple[int, float, int]] = {}
        self._sent: dict[str, collections.deque[tuple[int, float]]] = {}   # own robot -> (sequence, when) of a lease
        self.dropped: collections.Counter[str] = collections.Counter()   # reason kind -> count
        self.last_drop_reason = ""
        self._unreported_drops = 0               # malformed messages dropped since the last line said so
        self._drop_said = -math.inf              # when (monotonic) the last such line was logged
        self.bytes_sent = collections.Counter()  # "full"/"delta"/"status" -> bytes
        self.received = 0
        self.send_errors = 0
        self._closed = False
        self._calls = 0                          # publish/publish_status/request_snapshot inside Zenoh now
        self._idle = threading.Condition(self._lock)
        # own robot -> (kind, map, status, sequence) not yet sent
        self._outbox: dict[str, tuple[int, bytes, bytes, int]] = {}
        self._outbox_ready = threading.Condition(self._lock)
        self._sending_stopped = False
        self.superseded = 0                      # maps replaced in the outbox by a newer one before they were sent
        # how old what this receiver holds is (docs/fleet.md, session 49): robot -> (session, the least of (arrival -
        # sender's wall) over its messages: the sender's clock offset plus the fastest transit seen), and robot ->
        # (session, sequence, sender's wall) of the map held
        self._offset: dict[str, tuple[str, float]] = {}
        self._made: dict[str, tuple[str, int, float | None]] = {}
        # one map in flight per robot while a fusion node that acknowledges is connected (session 49): own robot ->
        # (sequence, when) of the map last put into Zenoh; own robot -> the newest sequence the node acknowledged
        self._in_flight: dict[str, tuple[int, float]] = {}
        self._acked: dict[str, int] = {}
        self._acking = False                     # a fusion node's acknowledgement has come: it acknowledges
        self._link_said: set[str] = set()        # own robots whose slow link has been said
        self._skipped: collections.Counter[str] = collections.Counter()   # own robot -> maps replaced unsent
        # queries the pump has taken from Zenoh for the replier to answer: (own robot, Zenoh query), oldest first
        self._queries: collections.deque[tuple[str, object]] = collections.deque()
        self._queries_ready = threading.Condition(self._lock)
        self.replies = 0                         # queries answered (with a map, or with none when there is none)
        self.reply_failure: str | None = None    # why the replier ended before close(), if it did
        try:
            zenoh_config = make_config(config, role)
            lease = json.loads(zenoh_config.get_json("transport/link/tx/lease"))
            self.lease = lease / 1000.0 if isinstance(lease, int | float) and lease > 0 else 10.0   # s
            self.session = zenoh.open(zenoh_config)
        except zenoh.ZError as e:
            raise ExchangeError(f"cannot open the Zenoh session ({zenoh_message(e)})") from None
        ring = zenoh.handlers.RingChannel
        self._subscribers = [
            self.session.declare_subscriber(f"{self.prefix}/*/map", ring(CHANNEL_CAPACITY)),
            self.session.declare_subscriber(f"{self.prefix}/*/status", ring(CHANNEL_CAPACITY)),
        ]
        # the fusion node's word that it holds a robot's map (a status-shaped message naming it): a robot's sender
        # puts its next map into Zenoh only then, so a link slower than the map stream carries the newest maps
        # whole instead of queueing every one behind the others (docs/fleet.md, session 49)
        self._acks = self.session.declare_subscriber(f"{self.prefix}/*/ack", ring(CHANNEL_CAPACITY))
        self._liveliness = self.session.liveliness().declare_subscriber(f"{self.prefix}/*/alive",
                                                                        ring(CHANNEL_CAPACITY), history=True)
        # the fusion node's token from its start, not from its first fused map: robots know whether a node hears them
        self._node_token = (self.session.liveliness().declare_token(f"{self.prefix}/{FUSED}/alive")
                            if role == "fusion" else None)
        _OPEN.add(self)
        self._stop = threading.Event()
        self._pump_thread = threading.Thread(target=self._pump_loop, name=f"zenoh-pump-{fleet}", daemon=True)
        self._worker = threading.Thread(target=self._work, name=f"zenoh-exchange-{fleet}", daemon=True)
        self._sender = threading.Thread(target=self._send_loop, name=f"zenoh-sender-{fleet}", daemon=True)
        self._replier = threading.Thread(target=self._reply_loop, name=f"zenoh-replier-{fleet}", daemon=True)
        self._replier.start()   # first: the pump hands queries on only to a replier that is alive
        self._pump_thread.start()
        self._worker.start()
        self._sender.start()

    # -- lifecycle --------------------------------------------------------------------------------------------
    def close(self) -> None:
        """Send what the outbox holds (each robot's last map: at most CLOSE_TIMEOUT s), stop and join the sender,
        the pump and the worker, then undeclare everything (the others see this process's robots leave);
        idempotent. Called at exit for an exchange left open."""
        with self._lock:
            if self._sending_stopped:
                return
            self._sending_stopped = True   # publish() takes nothing more; the sender empties the outbox and ends
            self._outbox_ready.notify_all()
        if self._sender is not threading.current_thread():
            self._sender.join(timeout=CLOSE_TIMEOUT)
            if self._sender.is_alive():
                log.warning("closing the exchange: the last map is still being sent after %.0f s (a slow or broken "
                            "link); closing anyway", CLOSE_TIMEOUT)
        with self._lock:
            self._closed = True
            self._wake.notify_all()
            self._queries_ready.notify_all()
        self._stop.set()
        _OPEN.discard(self)
        deadline = time.monotonic() + CLOSE_TIMEOUT
        for thread in (self._pump_thread, self._worker, self._replier):
            if thread is not threading.current_thread():  # on_event/on_update may close it from these threads
                thread.join(timeout=max(0.0, deadline - time.monotonic()))
                if thread.is_alive():   # a user's hook that does not return: say so rather than hang the exit
                    log.warning("closing the exchange: thread %s still running after %.0f s", thread.name,
                                CLOSE_TIMEOUT)
        with self._lock:  # a sender's thread (a robot's stage) still in Zenoh: let it come out first
            while self._calls and time.monotonic() < deadline:
                self._idle.wait(timeout=max(0.0, deadline - time.monotonic()))
            if self._calls:
                log.warning("closing the exchange: %d send(s) still inside Zenoh after %.0f s", self._calls,
                            CLOSE_TIMEOUT)
        self._report_drops(time.monotonic())   # what the last interval counted (the worker has stopped)
        for robot in sorted(self._link_said):
            log.warning("fleet exchange: %s made %d maps and sent %d: %d skipped, its link to the fusion node carried "
                        "fewer than it made", robot, self._encoders[robot].sequence + 1,
                        self._encoders[robot].sequence + 1 - self._skipped[robot], self._skipped[robot])
        self._say_unheard(time.monotonic())
        # Zenoh's close waits up to 10 s for a peer whose link is down (before its lease ends): say it, not hang mute
        slow = threading.Timer(CLOSE_SLOW, log.warning, ("fleet exchange: closing: a peer does not answer (its link "
                                                        "down?); Zenoh waits at most 10 s for it",))
        slow.daemon = True
        slow.start()
        try:
            self.session.close()
        except zenoh.ZError as e:  # already closed by the runtime at exit
            log.debug("closing the Zenoh session: %s", zenoh_message(e))
        finally:
            slow.cancel()
            slow.join()

    def _say_unheard(self, now: float) -> None:
        """A robot that ends with no fusion node connected says, in one line per robot, which of its maps no node
        received: they are lost to the fleet (its map file holds the last). Maps sent in the lease before the node
        was seen leaving are named as perhaps received (a node stopped cleanly had them; one whose link went, not);
        a robot that sent nothing after the leave says nothing."""
        with self._lock:
            unheard = {r: (first, since, perhaps, self._encoders[r].sequence)
                       for r, (first, since, perhaps) in self._unheard.items() if r in self._encoders}
            node_left = self._node_left_at
        for robot, (first, since, perhaps, last) in sorted(unheard.items()):
            if last <= perhaps:   # every map went before the node was seen leaving: it may well have them all
                continue
            maps = f"map {last}" if first == last else f"maps {first}-{last}"
            if perhaps >= first:   # sent before the leave was seen: the node may have had them
                maps += (f" ({first if perhaps == first else f'{first}-{perhaps}'} perhaps did: sent within Zenoh's "
                         f"lease, {self.lease:.0f} s, before the node was seen leaving)")
            why = ("no fusion node was connected" if node_left is None
                   else f"the fusion node left {now - node_left:.0f} s ago")
            log.warning("fleet exchange: %s's %s, of the last %.0f s, reached no fusion node: %s; the robot's saved "
                        "map file holds the last", robot, maps, now - since, why)

    def __enter__(self) -> ZenohExchange:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- sending ----------------------------------------------------------------------------------------------
    def _declare(self, robot: str):
        if robot not in self._own:
            key = f"{self.prefix}/{robot}/map"
            publisher = self.session.declare_publisher(key, congestion_control=zenoh.CongestionControl.DROP)
            # a status names the map that exists: it goes ahead of the maps (Zenoh queues each priority apart), so
            # it is not dropped with a map whose fragments fill their queue (docs/fleet.md, session 46)
            status = self.session.declare_publisher(f"{self.prefix}/{robot}/status",
                                                    congestion_control=zenoh.CongestionControl.DROP,
                                                    priority=STATUS_PRIORITY)
            queryable = self.session.declare_queryable(key, zenoh.handlers.RingChannel(CHANNEL_CAPACITY))
            token = (self._node_token if robot == FUSED and self._node_token is not None
                     else self.session.liveliness().declare_token(f"{self.prefix}/{robot}/alive"))
            self._own[robot] = (publisher, status, queryable, token)
        return self._own[robot]

    def publish(self, robot: str, landmark_map: LandmarkMap, stamp: float = 0.0) -> None:
        """Send ``robot``'s map (delta against the previous one, or full snapshot) and its status. Returns at once:
        the sender thread puts them into Zenoh, whose put can wait for seconds on a slow link (a large query reply
        ahead of it), and the caller is a robot's mapping stage. A map still unsent when the next comes is replaced
        by it, sent as a full snapshot (its receivers never held the replaced one), and counted in ``superseded``."""
        snapshot = copy_map(landmark_map)
        with self._lock:
            if self._closed or self._sending_stopped:  # nothing enters Zenoh after close: it may be finalizing
                return
            encoder = self._encoders.get(robot)
            if encoder is None:
                encoder = self._encoders[robot] = mapwire.MapEncoder(robot, full_every=self.full_every)
            replaced = robot in self._outbox
            wall = time.time()   # when the map was made, on this machine's clock: receivers show how old it is
            kind, data = encoder.encode(snapshot, stamp, full=replaced, wall=wall)
            self._latest[robot] = MapMessage(robot, encoder.sequence, float(stamp), snapshot)
            now = time.monotonic()
            if self.role == "robot" and FUSED not in self._present:
                self._unheard.setdefault(robot, (encoder.sequence, now, -1))
            sent = self._sent.setdefault(robot, collections.deque())
            sent.append((encoder.sequence, now))
            while sent and sent[0][1] < now - self.lease:
                sent.popleft()
            self._declare(robot)
            health = self._health.get(robot)  # the latest health figures go with it: a receiver's status is complete
            pose = snapshot.trajectory[-1, 1:] if len(snapshot.trajectory) else None
            status_data = mapwire.encode_status(robot, encoder.session, encoder.sequence, stamp, pose,
                                                len(snapshot), health, wall=wall)
            if replaced:
                old_kind, old, old_status, _ = self._outbox[robot]
                self._say_slow_link(robot, now)
                self.superseded += 1
                self._skipped[robot] += 1
                if not self._pulled(robot):
                    self.bytes_sent[mapwire.KIND_NAMES[old_kind]] -= len(old)
                self.bytes_sent["status"] -= len(old_status)
            self._outbox[robot] = (kind, data, status_data, encoder.sequence)
            if not self._pulled(robot):   # a fused map goes only as the reply to a robot's request
                self.bytes_sent[mapwire.KIND_NAMES[kind]] += len(data)   # published (counted when handed over)
            self.bytes_sent["status"] += len(status_data)
            self._outbox_ready.notify_all()

    def _pulled(self, robot: str) -> bool:
        """Whether ``robot``'s maps are pulled, not put: the fusion node's fused map (session 50). The node says each
        new one with a status on ``fused/status`` and every robot asks for the newest by query, one request open at a
        time (:meth:`request_snapshot`): a slow link carries at most one fused map to its robot, and the newest is the
        one its reply carries. Put to every robot (77-92 kB every 2.5 s with two robots), fused maps queued behind
        each other on a 100-kbit link, and the node's acknowledgements and Zenoh's keep-alives behind them (session
        49)."""
        return robot == FUSED and self.role == "fusion"

    def _say_slow_link(self, robot: str, now: float) -> None:
        """Once per robot: a map replaced unsent because the node has not yet said it has the last (lock held)."""
        flight = self._in_flight.get(robot)
        if robot in self._link_said or flight is None or self._ready(robot, now):
            return
        self._link_said.add(robot)
        log.warning("fleet exchange: %s's link to the fusion node carries fewer maps than it makes: its map %d, sent "
                    "%.1f s ago, has not reached the node yet; from now on its newest map goes when the last has "
                    "arrived, the others are skipped (counted at the end)", robot, flight[0], now - flight[1])

    def _ready(self, robot: str, now: float) -> bool:
        """Whether ``robot``'s next map may go into Zenoh: a fusion node that acknowledges maps holds its last one
        (or has not said so within ACK_TIMEOUT: a map or its word lost), or no such node is connected (lock held)."""
        flight = self._in_flight.get(robot)
        if flight is None or self._sending_stopped or not self._acking or FUSED not in self._present:
            return True
        return self._acked.get(robot, -1) >= flight[0] or now - flight[1] >= ACK_TIMEOUT

    def _send_loop(self) -> None:
        """The sender thread: puts each robot's newest unsent map and its status into Zenoh, one map in flight per
        robot while a fusion node acknowledges them, until close() has seen the outbox empty."""
        while True:
            with self._lock:
                while True:
                    now = time.monotonic()
                    ready = [r for r in self._outbox if self._ready(r, now)]
                    if ready or (not self._outbox and self._sending_stopped):
                        break
                    due = [f[1] + ACK_TIMEOUT - now for r, f in self._in_flight.items() if r in self._outbox]
                    self._outbox_ready.wait(timeout=max(0.01, min(due)) if due and self._outbox else None)
                if not self._outbox:
                    return
                robot = ready[0]
                kind, data, status_data, sequence = self._outbox.pop(robot)
                publisher, status, _, _ = self._own[robot]
                self._in_flight[robot] = (sequence, time.monotonic())
                self._calls += 1
            try:
                if not self._pulled(robot):
                    publisher.put(data)
                status.put(status_data)
            except zenoh.ZError as e:  # the network's trouble must not stop the robot; the queryable still answers
                self.send_errors += 1
                log.warning("fleet exchange: could not send %s's map: %s", robot, zenoh_message(e))
            except Exception:  # a bug must not end the sending silently
                log.exception("fleet exchange: unexpected error while sending %s's map", robot)
            finally:
                self._call_done()
                with self._lock:
                    self._outbox_ready.notify_all()   # close() waits for the outbox to empty

    def publish_status(self, robot: str, stamp: float, pose=None, landmarks: int = 0,
                       health: dict | None = None) -> None:
        """A status beside the map updates (pose estimate, health figures: runtime/fleet/status.py)."""
        with self._lock:
            if self._closed:
                return
            encoder = self._encoders.setdefault(robot, mapwire.MapEncoder(robot, full_every=self.full_every))
            _, status, _, _ = self._declare(robot)
            self._health[robot] = dict(health or {})
            self._calls += 1
        try:
            # it names the map last put into Zenoh (one waiting for the node's word is not asked for: its query's
            # reply would go around the flow control)
            flight = self._in_flight.get(robot)
            data = mapwire.encode_status(robot, encoder.session, 0 if flight is None else flight[0], stamp, pose,
                                         landmarks, health, has_map=flight is not None, wall=time.time())
            status.put(data)
        except zenoh.ZError as e:  # as for maps: the network's trouble must not stop the robot
            self.send_errors += 1
            log.warning("fleet exchange: could not send %s's status: %s", robot, zenoh_message(e))
            return
        finally:
            self._call_done()
        self.bytes_sent["status"] += len(data)

    def _call_done(self) -> None:
        with self._lock:
            self._calls -= 1
            self._idle.notify_all()

    def _reply_loop(self) -> None:
        """The replier thread: answers the queries the pump hands on, oldest first, until close(). A reply may wait
        in Zenoh for room on a slow link (replies block; after 5 s Zenoh closes that link): only this thread waits,
        never the pump, so maps, statuses and joins keep coming. A bug in one answer is logged and the next is
        answered; should the thread end all the same, it says so in one line and the exchange goes on without
        answering (the askers' requests time out)."""
        try:
            while True:
                with self._lock:
                    while not self._queries and not self._closed:
                        self._queries_ready.wait()
                    if self._closed:
                        left = list(self._queries)
                        self._queries.clear()
                        break
                    robot, query = self._queries.popleft()
                try:
                    self._answer(robot, query)
                    self.replies += 1
                except zenoh.ZError as e:  # the asker or the session gone: nothing to answer
                    log.debug("fleet exchange: could not answer a query for %s's map: %s", robot, zenoh_message(e))
                except Exception:  # a bug must not end the answering; say so loudly
                    log.exception("fleet exchange: unexpected error while answering a query for %s's map", robot)
        except BaseException as e:   # noqa: BLE001 - the thread ends: said once, the exchange goes on without it
            self.reply_failure = f"{type(e).__name__}: {e}" if str(e) else type(e).__name__
            log.error("fleet exchange: the reply thread ended (%s): this process answers no more snapshot requests; "
                      "maps and statuses still come and go", self.reply_failure)
            return
        for _, query in left:   # close(): the askers' requests end now rather than at their timeout
            try:
                query.drop()
            except Exception:  # noqa: BLE001 - the session is closing
                pass

    def _answer(self, robot: str, query) -> None:
        try:
            with self._lock:
                encoder = self._encoders.get(robot)
                data = None if encoder is None else encoder.snapshot()
            if data is not None:
                query.reply(f"{self.prefix}/{robot}/map", data)  # the concrete key, not the wildcard asked for
        finally:
            query.drop()  # finalizes the query: the asker's get ends without waiting for its timeout

    # -- receiving --------------------------------------------------------------------------------------------
    def _pump(self) -> bool:
        """Move what Zenoh's channels hold: samples into the queue, liveliness changes, queries answered,
        replies; at most one channel's capacity each. Whether anything came."""
        came = False
        for subscriber in self._subscribers:
            for _ in range(CHANNEL_CAPACITY):
                sample = subscriber.try_recv()
                if sample is None:
                    break
                came = True
                self._enqueue(str(sample.key_expr), sample.payload.to_bytes())
        for _ in range(CHANNEL_CAPACITY):
            sample = self._acks.try_recv()
            if sample is None:
                break
            came = True
            self._on_ack(str(sample.key_expr), sample.payload.to_bytes())
        for _ in range(CHANNEL_CAPACITY):
            sample = self._liveliness.try_recv()
            if sample is None:
                break
            came = True
            self._on_liveliness(sample)
        with self._lock:
            own = [(robot, entry[2]) for robot, entry in self._own.items()]
            replies = list(self._replies)
        for robot, queryable in own:
            # handed on to the replier (a reply may wait for room on a slow link: not here), at most REPLY_QUEUE
            # waiting; the rest stay in Zenoh's ring until there is room. A replier that has ended takes none
            while self._replier.is_alive():
                with self._lock:
                    if len(self._queries) >= REPLY_QUEUE:
                        break
                query = queryable.try_recv()
                if query is None:
                    break
                came = True
                with self._lock:
                    self._queries.append((robot, query))
                    self._queries_ready.notify()
        for request in replies:
            channel, asked, _ = request
            for _ in range(REPLY_CAPACITY):
                try:
                    reply = channel.try_recv()
                except zenoh.ZError:  # empty and closed: the request is over (answered, or timed out)
                    with self._lock:
                        self._replies.remove(request)
                    break
                if reply is None:
                    break
                came = True
                sample = reply.ok
                if sample is not None:
                    self._enqueue(str(sample.key_expr), sample.payload.to_bytes(), asked)
        return came

    def _on_ack(self, key: str, data: bytes) -> None:
        """A fusion node holds map ``sequence`` of this process's robot: its next map may go (session 49)."""
        robot = self._robot_of(key, "ack")
        if robot is None or robot not in self._encoders:
            return   # another robot's: not for this sender
        try:
            message = mapwire.decode(data)
            if message.kind != mapwire.STATUS or message.robot != robot:
                raise mapwire.WireError(f"a {message.kind_name} message for {message.robot!r} on an ack key")
        except mapwire.WireError as e:
            self._drop(key, str(e))
            return
        with self._lock:
            if message.session == self._encoders[robot].session:
                self._acked[robot] = max(self._acked.get(robot, -1), message.sequence)
                self._acking = True
                self._outbox_ready.notify_all()

    def _acknowledge(self, robot: str, session: str, sequence: int) -> None:
        """The fusion node says it holds ``robot``'s map ``sequence`` (a status-shaped message, at the statuses'
        priority: it must not wait behind maps)."""
        try:
            self.session.put(f"{self.prefix}/{robot}/ack", mapwire.encode_status(robot, session, sequence, 0.0),
                             congestion_control=zenoh.CongestionControl.DROP, priority=STATUS_PRIORITY)
        except zenoh.ZError as e:   # the robot's sender waits ACK_TIMEOUT at most
            log.debug("fleet exchange: could not acknowledge %s's map %d: %s", robot, sequence, zenoh_message(e))

    def _enqueue(self, key: str, data: bytes, asked: float | None = None) -> None:
        """Queue a received message; ``asked``: when the snapshot request it answers was sent (None for a
        published sample)."""
        with self._lock:
            self._pending.append((key, data, asked))
            self._pending_bytes += len(data)
            while self._pending_bytes > self.max_pending_bytes and len(self._pending) > 1:
                # the oldest message goes (its robot's map is recovered by query); a line to say stays (no bytes)
                index = next(k for k, entry in enumerate(self._pending) if entry[0] != _SAY)
                if index == len(self._pending) - 1:
                    break
                old_key, old, _ = self._pending[index]
                del self._pending[index]
                self._pending_bytes -= len(old)
                self.dropped["queue full"] += 1
                robot = self._robot_of(old_key, "map")
                if robot is not None:
                    self._wait_for(robot, None, -1, 0.0)
            self._wake.notify()

    def _wait_for(self, robot: str, session: str | None, sequence: int, first_ask: float,
                  from_status: bool = False) -> None:
        """Start or raise ``robot``'s wait: (``session``, ``sequence``) is known to exist (``session`` None: only
        that something newer than now was missed); a new wait's first ask is ``first_ask`` s on. A robot seen
        leaving waits only on a status's word: a status says the robot is there (a restarted robot's join may be
        seen before its old token's leave) (lock held)."""
        if robot in self._encoders or (robot in self._left and not from_status):  # own robot; one that has gone
            return
        now = time.monotonic()
        wait = self._waits.get(robot)
        if wait is None:
            wait = self._waits[robot] = _Wait(now, now + first_ask)
        if session is not None and (session != wait.session or sequence > wait.sequence):
            wait.session, wait.sequence = session, sequence

    def _on_liveliness(self, sample) -> None:
        robot = self._robot_of(str(sample.key_expr), "alive")
        if robot is None or robot in self._encoders or (robot == FUSED and self.role == "fusion"):
            return  # this process's own robot or node: no news
        joined = sample.kind == zenoh.SampleKind.PUT
        now = time.monotonic()
        with self._lock:
            (self._present.add if joined else self._present.discard)(robot)
            (self._left.discard if joined else self._left.add)(robot)
            self._outbox_ready.notify_all()   # a node come or gone: the sender's flow control changes
            if not joined:  # its queryable has gone with it: nothing to ask (a rejoin asks anyway)
                self._waits.pop(robot, None)
            elif robot == FUSED:  # a node that joins asks every robot for its latest snapshot
                self._unheard.clear()
            if robot == FUSED and not joined:  # seen up to a lease after its link went: maps of that time may be lost
                self._node_left_at = now
                for own, sent in self._sent.items():
                    recent = [(q, t) for q, t in sent if t >= now - self.lease]
                    if recent and own not in self._unheard:
                        self._unheard[own] = (recent[0][0], recent[0][1], recent[-1][0])
        # the lines tests and callers know; p3at fuse --live says more (runtime/fleet/status.py, PresenceLines). Said by
        # the worker in turn with the messages queued before it: a robot's last map and status, on the wire before its
        # leave, were still in the queue when its leave was said from here ('left without a word; the fusion keeps its
        # map 11' while map 12 and the status saying its mission was over came 1 ms later; session 49)
        line = f"{'the fusion node' if robot == FUSED else robot} {'joined' if joined else 'left'} the fleet"
        with self._lock:
            self._pending.append((_SAY, line.encode(), None))
            self._wake.notify()
        if joined and robot not in self._encoders:
            self.request_snapshot(robot)

    def _robot_of(self, key: str, leaf: str) -> str | None:
        parts = key.split("/")
        if len(parts) != 4 or f"{parts[0]}/{parts[1]}" != self.prefix or parts[3] != leaf:
            return None
        return parts[2]

    def _pump_loop(self) -> None:
        while not self._stop.is_set():
            try:
                came = self._pump()
            except zenoh.ZError as e:  # a channel closed under us: the session is going away
                log.debug("fleet exchange: %s", zenoh_message(e))
                came = False
            except Exception:  # a bug (or an on_event hook's) must not stop the receiving; say so loudly
                log.exception("fleet exchange: unexpected error while receiving")
                came = False
            if not came:
                self._stop.wait(POLL_INTERVAL)

    def _work(self) -> None:
        while True:
            with self._lock:
                while not self._pending and not self._closed:
                    ask = self._due()
                    if ask:
                        self._lock.release()
                        try:
                            self._ask(ask)
                        finally:
                            self._lock.acquire()
                    self._wake.wait(timeout=self._idle_wait())
                if self._closed:
                    return
                ask = self._due()  # a busy queue must not hold them back
                key, data, asked = self._pending.popleft()
                if key != _SAY:   # a line to say is not counted in the queue's bytes
                    self._pending_bytes -= len(data)
            self._ask(ask)
            if key == _SAY:   # a join or leave, said after the messages that came before it
                try:
                    self.on_event(data.decode())
                except Exception:  # a hook's bug must not stop the receiving
                    log.exception("fleet exchange: unexpected error in the event hook")
                continue
            try:
                self._handle(key, data, asked)
            except mapwire.StaleMessage as e:
                self.dropped["stale"] += 1
                log.debug("fleet exchange: %s: %s", key, e)
            except mapwire.MissingBase as e:
                self.dropped["gap"] += 1
                log.info("fleet exchange: %s: %s; asking for a snapshot", key, e)
            except mapwire.WireError as e:
                self._drop(key, str(e))
            except Exception as e:  # a bug must not kill the receiver either; say so loudly
                log.exception("fleet exchange: unexpected error on %s", key)
                self._drop(key, f"internal error {type(e).__name__}: {e}")

    def _due(self) -> list[str]:
        """Robots whose wait is due to be asked now. One with a map still in the queue is not asked yet, but looked
        at again BEHIND_GRACE later: that map may end the wait (a worker more than BEHIND_GRACE behind holds a
        status's map there; a full snapshot may follow a gap) (lock held)."""
        now = time.monotonic()
        due, queued = [], None
        for robot, wait in self._waits.items():
            if wait.due > now:
                continue
            if queued is None:
                queued = {self._robot_of(key, "map") for key, _, _ in self._pending}
            if robot in queued:
                wait.due = now + BEHIND_GRACE
                continue
            due.append(robot)
        return sorted(due)

    def _ask(self, robots: list[str]) -> None:
        """Ask each robot for its snapshot; its wait's next ask is set ``delay`` on, the delay doubled (at most
        BEHIND_RETRY_MAX); an ask the rate limit held back is made as soon as the limit allows."""
        for robot in robots:
            sent = self.request_snapshot(robot)
            with self._lock:
                wait = self._waits.get(robot)
                if wait is None:
                    continue
                now = time.monotonic()
                if sent:
                    wait.delay = min(2 * wait.delay, BEHIND_RETRY_MAX)
                    wait.due = now + wait.delay
                else:   # held back by the rate limit, or (the fused map) by its request still open: a second later
                    wait.due = max(now + (SNAPSHOT_RETRY if robot == FUSED else 0.0),
                                   self._asked.get(robot, now) + SNAPSHOT_RETRY)

    def _defer(self, robot: str) -> None:
        """A map of ``robot``'s was handled that does not end its wait: no ask within BEHIND_GRACE (lock held)."""
        wait = self._waits.get(robot)
        if wait is not None:
            wait.due = max(wait.due, time.monotonic() + BEHIND_GRACE)

    def _idle_wait(self) -> float | None:
        """How long the idle worker may wait for a message before it has something to ask (lock held)."""
        now = time.monotonic()
        return min((max(0.0, w.due - now) for w in self._waits.values()), default=None)

    def _note_status(self, robot: str, message: mapwire.Message) -> None:
        """A status names the robot's latest map (session, sequence): if that is newer than the map held, the map
        was lost on the way (published with CongestionControl.DROP; a robot's last one is never followed by a
        delta that would show the gap) or is still in flight: the robot's wait, its first ask after BEHIND_GRACE.
        A status with no map (a robot restarted, no map yet) ends a wait for another session's map (lock held)."""
        stream = self._streams.get(robot)
        if not message.status["has_map"]:
            wait = self._waits.get(robot)
            if wait is not None and wait.session is not None and wait.session != message.session:
                del self._waits[robot]
            return
        if stream is not None and stream.map is not None and stream.session == message.session \
                and stream.sequence >= message.sequence:
            return
        # the fused map is pulled (_pulled): it is at the node's queryable before its status goes, so asked at once
        self._wait_for(robot, message.session, message.sequence, 0.0 if robot == FUSED else BEHIND_GRACE,
                       from_status=True)

    def _drop(self, key: str, reason: str) -> None:
        """Count a malformed message; say the first one, then at most one line every DROP_REPORT_INTERVAL with how
        many more came (a peer publishing garbage at 47,000 messages a second wrote one warning line each)."""
        self.dropped["malformed"] += 1
        self.last_drop_reason = f"{key}: {reason}"
        now = time.monotonic()
        if self.dropped["malformed"] == 1:
            log.warning("fleet exchange: dropped a message on %s: %s (further malformed messages are counted, said "
                        "at most every %.0f s)", key, reason, DROP_REPORT_INTERVAL)
            self._drop_said = now
            return
        self._unreported_drops += 1
        if now - self._drop_said >= DROP_REPORT_INTERVAL:
            self._report_drops(now)

    def _report_drops(self, now: float) -> None:
        if self._unreported_drops:
            log.warning("fleet exchange: dropped %d more malformed message(s) (%d in all); the last on %s",
                        self._unreported_drops, self.dropped["malformed"], self.last_drop_reason)
        self._unreported_drops, self._drop_said = 0, now

    def _handle(self, key: str, data: bytes, asked: float | None = None) -> None:
        leaf = key.rsplit("/", 1)[-1]
        robot = self._robot_of(key, leaf)
        if robot is None or leaf not in ("map", "status"):
            raise mapwire.WireError("key is not p3at/<fleet>/<robot>/map or .../status")
        message = mapwire.decode(data)
        if message.robot != robot:
            raise mapwire.WireError(f"message from {message.robot!r} on {robot!r}'s key")
        if robot in self._encoders:
            return  # this process's own robot: it knows its map
        self._clock_seen(robot, message)
        if leaf == "status":
            if message.kind != mapwire.STATUS:
                raise mapwire.WireError(f"a {message.kind_name} message on a status key")
            with self._lock:
                self._status[robot] = {"stamp": message.stamp, "session": message.session,
                                       "sequence": message.sequence, "wall": message.wall, **message.status}
                self._note_status(robot, message)
            return
        if message.kind == mapwire.STATUS:
            raise mapwire.WireError("a status message on a map key")
        with self._lock:
            stream = self._streams.setdefault(robot, mapwire.MapStream(robot))
            restarts = stream.restarts
        try:
            m = stream.accept(message)
        except mapwire.MissingBase:
            with self._lock:  # the delta's map exists: the wait's first ask at once (the worker's next turn)
                self._wait_for(robot, message.session, message.sequence, 0.0)
            raise
        except mapwire.StaleMessage:
            with self._lock:  # the robot's maps flow, behind a reply: the one waited for may follow
                self._defer(robot)
            raise
        if stream.restarts != restarts:
            self.on_event(f"{robot} restarted (new session, sequence {stream.sequence})")
        with self._lock:
            self._latest[robot] = MapMessage(robot, stream.sequence, stream.stamp, m)
            self._made[robot] = (stream.session, stream.sequence, message.wall)
            self.received += 1
        if self.role == "fusion":
            self._acknowledge(robot, stream.session, stream.sequence)
        with self._lock:
            # with no sequence known, a published snapshot is newer than anything missed before it was handled; a
            # reply is only if it was asked for after the miss (a request's reply may come after newer updates: the
            # reply to the request made when the robot joined came after the drops it predates)
            wait = self._waits.get(robot)
            if wait is not None:
                if wait.reached(stream.session, stream.sequence) or (
                        wait.session is None and message.kind == mapwire.FULL
                        and (asked is None or asked >= wait.since)) or (
                        stream.restarts != restarts and wait.session not in (None, stream.session)):
                    del self._waits[robot]  # (a restart: another session's map is not coming; a status renews it)
                else:  # the stream moves: the map waited for may be in flight behind this one
                    self._defer(robot)
        self.on_update(robot)

    def _clock_seen(self, robot: str, message: mapwire.Message) -> None:
        """Keep the least (arrival - sender's wall) of ``robot``'s messages in its session: its clock's offset from
        this one plus the fastest transit seen (a status on an idle link: milliseconds), as NTP's minimum filter
        does. No clock synchronisation is assumed; a new session (a restart, perhaps on another machine) starts
        afresh."""
        if message.wall is None:
            return
        seen = time.time() - message.wall
        with self._lock:
            session, offset = self._offset.get(robot, (None, math.inf))
            if session != message.session:
                offset = math.inf
            self._offset[robot] = (message.session, min(offset, seen))

    def _age(self, robot: str, session: str | None, wall: float | None, now: float) -> float | None:
        """How long ago, on this clock, ``robot`` sent (made) what it stamped ``wall`` in ``session``; None unknown
        (lock held)."""
        known = self._offset.get(robot)
        if wall is None or known is None or known[0] != session:
            return None
        return max(0.0, now - (wall + known[1]))

    def request_snapshot(self, robot: str = "*") -> bool:
        """Ask ``robot``'s queryable (``*``: every robot's and the fused map's) for the latest full snapshot;
        the replies arrive like updates. At most one request per robot every SNAPSHOT_RETRY s: whether this one
        was sent. (A robot whose map was missed is asked by the worker until it comes: the module's docstring.)"""
        now = time.monotonic()
        with self._lock:
            if now - self._asked.get(robot, -np.inf) < SNAPSHOT_RETRY or self._closed:
                return False
            if robot == FUSED and any(asked == FUSED for _, _, asked in self._replies):
                return False   # one fused map in flight: the open request's reply is the newest at its answer
            self._asked[robot] = now
            self._calls += 1
        try:  # replies: one per robot; a Fifo channel keeps them after the query's end (a ring would not)
            channel = self.session.get(f"{self.prefix}/{robot}/map", zenoh.handlers.FifoChannel(REPLY_CAPACITY),
                                       timeout=FUSED_QUERY_TIMEOUT if robot == FUSED else QUERY_TIMEOUT)
        finally:
            self._call_done()
        with self._lock:
            self._replies.append((channel, now, robot))
        return True

    # -- the MapExchange protocol and what a fusion node reads ------------------------------------------------
    def receive(self, excluding: str | None = None) -> dict[str, MapMessage]:
        """The latest map of every robot heard of (this process's own included), except ``excluding`` and
        the fused map."""
        with self._lock:
            messages = {r: m for r, m in self._latest.items() if r not in (excluding, FUSED)}
        return {r: MapMessage(m.robot, m.sequence, m.stamp, copy_map(m.landmark_map)) for r, m in messages.items()}

    def fused(self) -> MapMessage | None:
        """The latest fused map heard of."""
        with self._lock:
            return self._latest.get(FUSED)

    def session_of(self, robot: str) -> str | None:
        """The session id of ``robot``'s latest map heard of (a new one after each restart of the robot)."""
        with self._lock:
            stream = self._streams.get(robot)
            return None if stream is None else stream.session

    @property
    def pending_bytes(self) -> int:
        """Bytes received and not yet decoded (bounded by MAX_PENDING_BYTES plus one message)."""
        with self._lock:
            return self._pending_bytes

    def present(self) -> set[str]:
        """Robots (and ``fused``) whose liveliness token is alive now."""
        with self._lock:
            return set(self._present)

    def held(self) -> dict[str, tuple[str, int]]:
        """(session, sequence) of the map held of every other robot (and the fused map)."""
        with self._lock:
            return {r: (s.session, s.sequence) for r, s in self._streams.items() if s.map is not None}

    def status(self) -> dict[str, dict]:
        """The latest status of every other robot: stamp, session, sequence (of the map it names, if has_map),
        pose, landmarks, health; and what this receiver makes of it now: ``present`` (its liveliness token is
        alive), ``age`` (s since the status was sent), ``map_held`` (the sequence of its map held here, or None) and
        ``map_age`` (s since that map was made). Ages are on this receiver's clock, from the sender's ``wall``
        stamps less the least delay its messages have shown (so no clock synchronisation is needed; a constant
        transit an idle link adds, milliseconds on a LAN, is not counted); None where the sender sends no stamps."""
        now = time.time()
        with self._lock:
            out = {}
            for r, s in self._status.items():
                made = self._made.get(r)
                out[r] = {**s, "present": r in self._present,
                          "age": self._age(r, s.get("session"), s.get("wall"), now),
                          "map_held": None if made is None else made[1],
                          "map_age": None if made is None else self._age(r, made[0], made[2], now)}
            return out
