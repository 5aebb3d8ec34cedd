"""Driver types -> the runtime's and the estimators' types. The only place where drivers meet estimation.

- :class:`P3ATLink` wraps the ARCOS driver (``drivers.arcos.P3AT``) as a :class:`runtime.onboard.RobotLink`:
  each ``RobotState`` becomes an :class:`~runtime.onboard.OdometrySample` (sonar poses and ranges, the raw
  SIP payload for the sensor log).
- :class:`VidereCamera` wraps ``drivers.videre.StereoHead`` as a :class:`runtime.onboard.Camera`: it
  rectifies each pair with the head's stored calibration, and :func:`stereo_geometry` turns that
  calibration into the front end's ``StereoGeometry``.
- :class:`SyntheticCamera` (mocks only) gives the observations of ``mocks.synthetic_stereo`` at the robot's
  true pose, at the camera's rate: the fast stand-in when rendering is not wanted.
"""
from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable

import numpy as np

from drivers.videre.calibration import StereoCalibration
from estimation.frontend import StereoGeometry
from estimation.geometry import compose, inverse
from runtime.onboard import CameraFrame, Clock, OdometrySample


def stereo_geometry(calibration: StereoCalibration) -> StereoGeometry:
    """The front end's rectified geometry from a head's calibration (left camera pose in base_link included)."""
    return StereoGeometry.with_camera_matrix(calibration.left_camera_to_base(rectified=True),
                                             fx=calibration.fx, fy=calibration.fy, cx=calibration.cx,
                                             cy=calibration.cy, baseline=calibration.baseline)


def left_camera_mount(g: StereoGeometry) -> tuple[float, float, float]:
    """(x, y, z) of the left optical centre in base_link (for drawing the camera)."""
    if g.left_camera_pose is not None:
        T = np.asarray(g.left_camera_pose, float).reshape(4, 4)
        return float(T[0, 3]), float(T[1, 3]), float(T[2, 3])
    x, y, z = g.head_pose[:3]
    return float(x), float(y + g.baseline / 2), float(z)


# -- the P3-AT ----------------------------------------------------------------------------------------------
def odometry_sample(state, t0: float = 0.0) -> OdometrySample:
    """A ``drivers.arcos.state.RobotState`` as an :class:`OdometrySample` (t on the same clock as ``state.stamp``)."""
    from drivers.arcos.codec import encode_sip

    sonars = state.sonars
    ranges = np.array([np.nan if s.range_m is None else s.range_m for s in sonars], float)
    poses = np.array([s.pose for s in sonars], float).reshape(-1, 3)
    try:
        raw = encode_sip(state.sip)
    except Exception:  # a SIP the codec cannot re-encode is still a valid state; log it without its bytes
        raw = b""
    return OdometrySample(float(state.stamp) - t0, np.array([state.x, state.y, state.theta], float),
                          float(state.v), float(state.w), bool(state.stalled), ranges, poses, raw)


class P3ATLink:
    """The ARCOS driver as the runtime's RobotLink. ``driver``: a connected ``drivers.arcos.robot.P3AT``.

    Odometry is continuous only within one ARCOS session; when the driver reconnects after a lost link (a new
    session, motors disabled) the link re-bases the new session's odometry on the last pose of the old one,
    so the runtime sees one continuous odometry frame, and re-enables the motors if the runtime had them on.
    """

    def __init__(self, driver) -> None:
        self.driver = driver
        self._callbacks: list[Callable[[OdometrySample], None]] = []
        self._session: int | None = None
        self._offset = np.zeros(3)          # new-session odometry -> the runtime's continuous frame
        self._last = np.zeros(3)
        self._motors_on = False
        self.reconnects = 0
        self.last_delivered = -np.inf       # stamp of the last SIP whose callbacks have all returned
        self._last_sample: OdometrySample | None = None
        self.on_delivered: Callable[[], None] | None = None  # called after every SIP's callbacks (a sim clock's notify)
        driver.subscribe(self._on_state)
        state = driver.state  # the SIP of the handshake, delivered before this link existed
        if state is not None and state.stamp > self.last_delivered:
            self._on_state(state)

    def subscribe(self, callback: Callable[[OdometrySample], None]) -> None:
        """Call ``callback(sample)`` for every SIP from now on, starting with the latest one (if any), so a
        subscriber knows where the robot is before the next SIP."""
        self._callbacks.append(callback)
        last = self._last_sample
        if last is not None:
            callback(last)

    def delivered(self, stamp: float) -> bool:
        """Has every SIP up to ``stamp`` (driver clock) reached the subscribers? True while disconnected (nothing
        more will come): a quiescence predicate for a lockstep clock."""
        return self.last_delivered >= stamp or not self.driver.connected

    def _on_state(self, state) -> None:
        sample = odometry_sample(state)
        if self._session is not None and state.session != self._session:
            self.reconnects += 1
            self._offset = compose(self._last, inverse(sample.pose))
            if self._motors_on:
                try:
                    self.driver.motors_on()
                except Exception:  # lost again: the next session will retry
                    pass
        self._session = state.session
        pose = compose(self._offset, sample.pose)
        self._last = pose
        sample = dataclasses.replace(sample, pose=pose)
        self._last_sample = sample
        for callback in list(self._callbacks):
            callback(sample)
        self.last_delivered = sample.t
        if self.on_delivered is not None:
            self.on_delivered()

    def set_velocity(self, v: float, w: float) -> None:
        self.driver.set_velocity(v, w)

    def enable_motors(self, on: bool) -> None:
        self._motors_on = bool(on)
        if on:
            self.driver.motors_on()
        else:
            self.driver.motors_off()

    def close(self) -> None:
        self.driver.close()


# -- the stereo head ----------------------------------------------------------------------------------------
class VidereCamera:
    """A streaming ``StereoHead`` as the runtime's Camera; pairs come out rectified, on the head's clock."""

    def __init__(self, head, calibration: StereoCalibration | None = None, *, width: int = 640, height: int = 480,
                 rate: float = 15.0) -> None:
        self.head = head
        offered = [m.rate for m in head.modes() if (m.width, m.height) == (width, height)]
        if offered:  # the nearest frame rate the head offers at this size (IIDC rates are 3.75 · 2^k)
            rate = min(offered, key=lambda r: (abs(np.log(r / rate)), -r))
        self.mode = head.set_mode(width, height, rate)
        calibration = calibration if calibration is not None else head.read_calibration()
        if tuple(calibration.size) != (self.mode.width, self.mode.height):
            calibration = calibration.scaled(self.mode.width, self.mode.height)
        self.calibration = calibration
        self.geometry = stereo_geometry(calibration)
        self.dropped_by_head = 0
        self.reconnects = 0
        head.start()

    def read(self, timeout: float) -> CameraFrame | None:
        """The next rectified pair, None if none came in ``timeout`` s. A head that vanished (unplugged) is
        reopened once per call; if it is still gone the error propagates (the runtime counts it, retries)."""
        from drivers.errors import DriverTimeoutError, NotConnectedError

        try:
            frame = self.head.grab(timeout=timeout)
        except DriverTimeoutError:
            return None
        except NotConnectedError:
            self.reconnects += 1
            self.head.reopen()  # restores mode, controls and streaming; raises while the head is still away
            return None
        self.dropped_by_head += frame.dropped
        left, right = self.calibration.rectify(frame.left, frame.right)
        return CameraFrame(float(frame.timestamp), int(frame.counter), left, right)

    def close(self) -> None:
        # stops streaming if the head is still there and releases it either way (a head unplugged for good was
        # already released: stopping it first raised NotConnectedError out of the mission's end)
        self.head.close()


class SyntheticCamera:
    """Observations of the world's features from the robot's true pose at ``rate`` Hz (mocks only).

    ``observer``: anything with ``observe(pose, timestamp) -> (StereoObservations, index)``;
    ``true_pose``: the robot's ground-truth pose in the world. Paced by ``clock``/``sleep`` (a lockstep clock's
    own ``sleep_until``: frames exactly at their instants of simulated time).
    """

    def __init__(self, observer, true_pose: Callable[[], np.ndarray], *, rate: float = 15.0,
                 clock: Clock = time.monotonic, sleep: Callable[[float], None] = time.sleep) -> None:
        self.observer, self.true_pose = observer, true_pose
        self.period = 1.0 / rate
        self.clock, self.sleep = clock, sleep
        if callable(getattr(clock, "sleep_until", None)):
            self._sleep_until = clock.sleep_until
        else:
            self._sleep_until = lambda t: sleep(max(0.0, t - clock()))
        self.seq = 0
        self._next = clock()
        self._lock = threading.Lock()
        self.geometry = StereoGeometry()

    def read(self, timeout: float) -> CameraFrame | None:
        with self._lock:
            now = self.clock()
            if self._next - now > timeout:
                self._sleep_until(now + timeout)
                return None
            if self._next > now:
                self._sleep_until(self._next)
            t = self.clock()
            self._next = max(self._next + self.period, t)  # never bursts to catch up
            observations, _ = self.observer.observe(self.true_pose(), t)
            self.seq += 1
            return CameraFrame(t, self.seq, observations=observations)

    def close(self) -> None:
        pass
