"""In simulated time each robot's odometry and sensor log begin with the same SIP however late the driver's reader
thread delivers the SIPs of the setup (a busy machine): the robots start once every SIP sent has reached the
runtime. Before, they started from the setup thread and a SIP still in the driver's reader was delivered before or
after the subscription by chance, one SIP more at the head of a log (found by the alone/busy test of
test_mission.py under load)."""
from __future__ import annotations

import collections
import dataclasses
import threading
import time

from runtime.adapters import P3ATLink
from runtime.mission import Mission, MissionConfig
from runtime.sensorlog import SensorLog


def _sip_times(folder, name: str) -> list[int]:
    return [m.log_time for m in SensorLog(folder / f"{name}-log").messages({f"/{name}/sip"})]


def test_the_logs_begin_with_the_same_sip_when_the_driver_delivers_the_setups_sips_late(tmp_path, monkeypatch):
    config = MissionConfig(robots=2, seconds=1.0, seed=5, camera="synthetic", camera_rate=10.0, particles=10,
                           fusion_interval=0.0, map_save_interval=0.0, out=tmp_path / "prompt", rerun="none",
                           log_sensors=True)
    assert not Mission(config).run().failures
    deliver = P3ATLink._on_state
    delivered = collections.Counter()

    def late(self, state) -> None:   # the driver's reader thread, slow with each link's first two SIPs
        if threading.current_thread() is not threading.main_thread():
            delivered[id(self)] += 1
            if delivered[id(self)] <= 2:
                time.sleep(1.5)
        deliver(self, state)

    monkeypatch.setattr(P3ATLink, "_on_state", late)
    assert not Mission(dataclasses.replace(config, out=tmp_path / "late")).run().failures
    for name in ("robot1", "robot2"):
        prompt, slow = _sip_times(tmp_path / "prompt", name), _sip_times(tmp_path / "late", name)
        assert slow[0] == prompt[0], name
        assert slow == prompt, name
