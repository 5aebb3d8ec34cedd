"""A robot's health over the fleet exchange: what the runtime already counts, sent once a second of mission time.

``p3at run --exchange zenoh`` (and any mission on a fleet exchange) calls :func:`publish_robot_status` from the
mission loop every second of mission time (the progress line's tick); it sends each robot's pose estimate, map
size and :func:`robot_health` on ``p3at/<fleet>/<robot>/status`` (``ZenohExchange.publish_status``).
``p3at fuse --live`` prints them with :func:`status_line` (:class:`StatusPrinter`). No new measurement is made:
every figure is a counter or a timing the runtime keeps for its summary. Pure code (no zenoh): the exchange is
whatever offers ``publish_status``.

Health fields (a flat JSON object, docs/fleet.md): ``clock`` (``simulated`` or ``wall``), ``mission_time`` and
``wall_time`` (s since the mission started), ``frames_received``, ``frames_processed``, ``frames_dropped`` (the SLAM
stage was behind), ``frames_without_odometry``, ``camera_errors``, ``ms_<stage>`` (mean wall-clock ms per frame of
``frontend``, ``predict``, ``update``), ``battery_volts``, ``link`` (``up``/``down``), ``link_reconnects``,
``route_done``, ``last_error`` (the robot's last stage failure or runtime error, or null), ``mission_over`` (the
mission loop has ended: the last status, sent as the robot starts saving its files).
"""
from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable, Sequence

log = logging.getLogger(__name__)

PRINT_PERIOD = 10.0          # s of wall time between two printed status lines of a robot (p3at fuse --live)
STALE_AFTER = 20.0           # s: a present robot's status older than this is said again, with its age
MAX_ERROR_TEXT = 200         # characters of last_error sent


def robot_health(onboard, driver=None, *, clock: str, wall_time: float, failures: Sequence = (),
                 mission_over: bool = False) -> dict:
    """The health figures of one robot's runtime (an ``Onboard``) and its ARCOS driver (or None). ``mission_over``:
    the mission loop has ended, the robot is saving its files (no more statuses will come)."""
    s = onboard.stats
    frames = max(1, s.frames_processed)
    health: dict = {
        "clock": clock, "mission_time": round(float(onboard.mission_time), 3), "wall_time": round(wall_time, 3),
        "frames_received": s.frames_received, "frames_processed": s.frames_processed,
        "frames_dropped": s.dropped_frames, "frames_without_odometry": s.frames_without_odometry,
        "camera_errors": s.camera_errors,
    }
    health.update({f"ms_{stage}": round(1000.0 * seconds / frames, 2)
                   for stage, seconds in sorted(dict(s.stage_seconds).items())})
    state = getattr(driver, "state", None)
    health["battery_volts"] = None if state is None else float(state.battery_volts)
    health["link"] = None if driver is None else ("up" if driver.connected else "down")
    health["link_reconnects"] = getattr(onboard.link, "reconnects", None)
    health["route_done"] = onboard.route_done.is_set()
    errors = [str(f) for f in failures if getattr(f, "robot", None) == onboard.robot] + list(onboard.errors)
    health["last_error"] = errors[-1][:MAX_ERROR_TEXT] if errors else None
    health["mission_over"] = bool(mission_over)
    return health


def publish_robot_status(exchange, robots: Iterable[tuple], *, clock: str, wall_time: float,
                         failures: Sequence = (), mission_over: bool = False) -> None:
    """Each ``(onboard, driver)``'s status on ``exchange`` (if it offers ``publish_status``). Never raises: a
    status that cannot be built or sent is logged, and the robot goes on."""
    publish = getattr(exchange, "publish_status", None)
    if publish is None:
        return
    for onboard, driver in robots:
        try:
            pose = onboard.pose_estimate()
            publish(onboard.robot, stamp=float(onboard.mission_time), landmarks=onboard.stats.map_landmarks,
                    pose=None if pose is None else [float(v) for v in pose],
                    health=robot_health(onboard, driver, clock=clock, wall_time=wall_time, failures=failures,
                                        mission_over=mission_over))
        except Exception as e:  # noqa: BLE001 - health reports must never stop a robot
            log.warning("fleet status of %s not sent: %s: %s", onboard.robot, type(e).__name__, e)


def health_figure(status: dict, key: str) -> int | float | None:
    """A number of a received status's health figures, or None where it is missing or not a number (a status is
    another process's JSON: ``true`` or ``"12"`` must not print as a figure, nor break a line)."""
    value = (status.get("health") or {}).get(key)
    return value if isinstance(value, int | float) and not isinstance(value, bool) else None


def _ago(seconds) -> str | None:
    return f"{seconds:.1f} s ago" if isinstance(seconds, int | float) and not isinstance(seconds, bool) else None


def status_line(robot: str, status: dict) -> str:
    """One line of a robot's status as received (``ZenohExchange.status()[robot]``): how long ago it was sent, and
    which of the robot's maps the node holds and how long ago it was made, where the exchange knows (``age``,
    ``map_held``, ``map_age``): on a slow or lossy link what the node shows may be many seconds old."""
    h = status.get("health") or {}

    def figure(key: str, spec: str, unit: str = "") -> str:
        value = health_figure(status, key)
        return "-" if value is None else f"{value:{spec}}{unit}"

    clock = h.get("clock")
    # counts as '.0f': a count sent as 45.0 is still 45 (the 'd' format refuses a float)
    parts = [f"t={figure('mission_time', '.1f', ' s')}" + (f" {clock}" if clock else ""),
             f"{figure('frames_processed', '.0f')} frames ({figure('frames_dropped', '.0f')} dropped)",
             f"{status.get('landmarks', 0)} landmarks", f"update {figure('ms_update', '.1f', ' ms')}",
             f"battery {figure('battery_volts', '.1f', ' V')}", f"link {h.get('link') or '-'}"]
    pose = status.get("pose")
    if pose:
        parts.insert(3, f"pose ({pose[0]:.2f}, {pose[1]:.2f}, {pose[2]:.2f})")
    if h.get("last_error"):
        parts.append(f"last error: {h['last_error']}")
    sent = _ago(status.get("age"))
    if sent:   # beside the status's own time: how old these figures are
        parts.insert(1, f"sent {sent}")
    line = f"status {robot}: " + ", ".join(parts)
    held, named = status.get("map_held"), status.get("sequence")
    if isinstance(held, int) and not isinstance(held, bool):
        made = _ago(status.get("map_age"))
        line += f"; fusing its map {held}" + (f", made {made}" if made else "")
        if status.get("has_map", True) and isinstance(named, int) and named > held:
            line += f" (its newest, map {named}, not here yet)"
    elif status.get("has_map", True) and "map_held" in status:
        line += "; no map of it here yet"
    return line


class StatusPrinter:
    """Prints each robot's newest status at most every ``period`` s of wall time, on its own daemon thread;
    statuses without health figures (a map update's before the first health tick, synthetic robots) are skipped.
    A robot still present whose newest status is older than ``stale_after`` s (its link slow, lossy or stalled)
    has its line said again every ``period`` s, with the growing age, rather than falling silent."""

    def __init__(self, statuses: Callable[[], dict], out: Callable[[str], None], period: float = PRINT_PERIOD,
                 clock: Callable[[], float] = time.monotonic, stale_after: float = STALE_AFTER) -> None:
        self.statuses, self.out, self.period, self.clock = statuses, out, period, clock
        self.stale_after = stale_after
        self._printed: dict[str, tuple[float, object]] = {}   # robot -> (when printed, stamp printed)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="fleet-status-printer", daemon=True)

    def poll(self) -> None:
        """Print every robot whose status is new and whose last line is ``period`` s old."""
        now = self.clock()
        for robot, status in sorted(self.statuses().items()):
            when, stamp = self._printed.get(robot, (-float("inf"), None))
            key = (status.get("session"), status.get("stamp"))
            age = status.get("age")
            stale = (status.get("present") is True and isinstance(age, int | float) and age >= self.stale_after
                     and (status.get("health") or {}).get("mission_over") is not True)
            if status.get("health") and (key != stamp or stale) and now - when >= self.period:
                self.out(status_line(robot, status))
                self._printed[robot] = (now, key)

    def _run(self) -> None:
        while not self._stop.wait(min(1.0, self.period)):
            self.poll()

    def start(self) -> StatusPrinter:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)


class PresenceLines:
    """What ``p3at fuse --live`` says when a robot joins or leaves (the exchange's lines ``robot1 joined the fleet``,
    ``robot1 left the fleet``, made whole): a leave says whether the robot's last status said its mission was over
    or it went without a word (its link lost, its process killed: Zenoh notices at its lease, 10 s), and which of
    its maps the fusion keeps, naming a newer one its status named that never came; a rejoin says how long it was
    gone (the node then asks for its latest map). ``statuses`` and ``held``: the exchange's ``status`` and
    ``held``. Other lines pass unchanged."""

    def __init__(self, statuses: Callable[[], dict], held: Callable[[], dict],
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.statuses, self.held, self.clock = statuses, held, clock
        self._left: dict[str, float] = {}   # robot -> when it was seen leaving

    def __call__(self, line: str) -> str:
        robot, joined = _presence(line)
        if robot is None:
            return line
        now = self.clock()
        if joined:
            gone = self._left.pop(robot, None)
            return line if gone is None else f"{line} again, {now - gone:.0f} s after it left"
        self._left[robot] = now
        status = self.statuses().get(robot) or {}
        held = self.held().get(robot)
        kept = "no map of it came" if held is None else f"the fusion keeps its map {held[1]}"
        named = status.get("sequence")
        if (held is not None and status.get("has_map", True) and isinstance(named, int)
                and (status.get("session") != held[0] or named > held[1])):
            kept += f"; its map {named}, named by its last status, never came"
        if (status.get("health") or {}).get("mission_over") is True:
            return f"{line}: its mission is over; {kept}"
        return f"{line} without a word (its link lost or its process ended); {kept}"


def _presence(line: str) -> tuple[str | None, bool]:
    """(robot, joined) of an exchange's 'ROBOT joined the fleet' / 'ROBOT left the fleet' line, else (None, False)."""
    for word, joined in ((" joined the fleet", True), (" left the fleet", False)):
        robot = line[:-len(word)] if line.endswith(word) else ""
        if robot and " " not in robot:
            return robot, joined
    return None, False


__all__ = ["PRINT_PERIOD", "PresenceLines", "StatusPrinter", "health_figure", "publish_robot_status",
           "robot_health", "status_line"]
